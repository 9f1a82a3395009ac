"""Gauss quadrature over the faces of a combined mesh, and L2 errors of its surface.

The rule
--------
One parameter, ``order`` = n, fixes the rule on every face.  It starts from
the tensor Gauss-Legendre rule with n nodes per direction on the unit square
``(s, t) in [0, 1]^2`` (n^2 points, exact for polynomials of degree 2n - 1 in
each of s and t) and maps it onto each face:

* a quadrangle ``P0, P1, P2, P3`` by its isoparametric bilinear map

      p(u, v) = (1-u)(1-v) P0 + u(1-v) P1 + uv P2 + (1-u)v P3,   (u, v) = (s, t)

  with weight ``w_s w_t |det J(u, v)|``;
* a triangle ``P0, P1, P2`` by the collapsed (Duffy) map of the square onto
  the reference triangle, ``(u, v) = (s, t (1 - s))`` (the side s = 1
  collapses onto P1), followed by the affine map
  ``p = P0 + u (P1 - P0) + v (P2 - P0)``; the weight is
  ``w_s w_t (1 - s) |det A|``.

Both maps are polynomial, so doubling ``order`` refines the rule on every face
in the same way, and the change it makes to an integral estimates the error.
Exactness for a polynomial integrand of total degree d in (x, y):

* triangles: d <= 2n - 2 (the Duffy factor ``1 - s`` costs one degree);
* quadrangles: d <= 2n - 2 (``det J`` is affine in u and v); on a
  parallelogram ``det J`` is constant and every degree <= 2n - 1 per
  direction of (u, v) is exact.

The squared error of a linear-or-bilinear surface against a polynomial of
degree d is integrated exactly on triangles from ``n = d + 1``; on
quadrangles the gradient error is rational in (u, v) and no finite rule is
exact, so use the doubling test.

Layout
------
:func:`face_quadrature` returns a :class:`FaceQuadrature` with, per face and
quadrature point, the physical point, the weight, the four shape function
values and their physical gradients ``J^-T [dN/du, dN/dv]``.  Triangles have
zeros in the fourth shape function, so the surface at the quadrature points is
``sum_j N_j z[face_j]`` on either kind of face with the ``-1`` padding taking
a zero weight.  :func:`l2_errors` uses these to compute
``||f - g||_2`` and ``||grad f - grad g||_2`` over the whole mesh.

Memory is ``n_faces * order^2 * 13`` doubles: fine for experiments, not meant
for whole surveys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import njit
from .errors import InvalidInputError, InvalidMeshError
from .interpolate import _surface_at
from .mesh import Mesh, mesh_arrays, vertex_values
from .patches import NODES_PER_FACE

__all__ = ["FaceQuadrature", "face_quadrature", "gauss_legendre", "l2_errors"]


@dataclass(frozen=True, eq=False)
class FaceQuadrature:
    """A quadrature rule mapped onto every face of a mesh, with the shape functions.

    Attributes
    ----------
    order : int
        Gauss-Legendre nodes per direction of the unit square; ``order**2``
        points per face.
    points : (n_f, k, 2) float64
        Quadrature points in mesh coordinates, ``k = order**2``.
    weights : (n_f, k) float64
        Weights including ``|det J|``: ``weights[f].sum()`` is the area of face f.
    shape_values : (n_f, k, 4) float64
        Shape functions of the face's vertices at the points (column 3 is zero
        on triangles); they sum to 1.
    shape_gradients : (n_f, k, 4, 2) float64
        Their gradients with respect to (x, y).
    """

    order: int
    points: NDArray[np.float64]
    weights: NDArray[np.float64]
    shape_values: NDArray[np.float64]
    shape_gradients: NDArray[np.float64]

    @property
    def points_per_face(self) -> int:
        return self.order * self.order

    def integrate(self, values: ArrayLike) -> float:
        """Integral over the mesh of a function given at the points, shape ``(n_f, k)``."""
        arr = np.asarray(values, dtype=np.float64)
        if arr.shape != self.weights.shape:
            raise InvalidInputError(f"values must have shape {self.weights.shape}, got {arr.shape}")
        return float(np.sum(self.weights * arr))


def gauss_legendre(order: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights on [0, 1] (weights sum to 1).

    Examples
    --------
    >>> nodes, weights = gauss_legendre(2)
    >>> [round(float(x), 6) for x in nodes]
    [0.211325, 0.788675]
    """
    n = _check_order(order)
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def _check_order(order: object) -> int:
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise InvalidInputError(f"order must be a positive integer, got {order!r}")
    return int(order)


@njit
def _quadrature_kernel(vertices, faces, nodes, nweights, points, weights, values, gradients) -> int:
    """Fill the per-face arrays; return the first face with a non-positive Jacobian, or -1."""
    n = nodes.shape[0]
    bad = -1
    for f in range(faces.shape[0]):
        x0 = vertices[faces[f, 0], 0]
        y0 = vertices[faces[f, 0], 1]
        if faces[f, 3] < 0:
            # Affine map of the reference triangle; coordinates relative to P0.
            e1x = vertices[faces[f, 1], 0] - x0
            e1y = vertices[faces[f, 1], 1] - y0
            e2x = vertices[faces[f, 2], 0] - x0
            e2y = vertices[faces[f, 2], 1] - y0
            det = e1x * e2y - e1y * e2x
            if not det > 0.0:
                if bad < 0:
                    bad = f
                continue
            inv = 1.0 / det
            # J = [[e1x, e2x], [e1y, e2y]]; grad N = J^-T dN/d(u, v), dN/d(u, v) constant.
            g1x = e2y * inv
            g1y = -e2x * inv
            g2x = -e1y * inv
            g2y = e1x * inv
            for i in range(n):
                u = nodes[i]
                for j in range(n):
                    q = i * n + j
                    v = nodes[j] * (1.0 - u)
                    points[f, q, 0] = x0 + u * e1x + v * e2x
                    points[f, q, 1] = y0 + u * e1y + v * e2y
                    weights[f, q] = nweights[i] * nweights[j] * (1.0 - u) * det
                    values[f, q, 0] = 1.0 - u - v
                    values[f, q, 1] = u
                    values[f, q, 2] = v
                    values[f, q, 3] = 0.0
                    gradients[f, q, 0, 0] = -g1x - g2x
                    gradients[f, q, 0, 1] = -g1y - g2y
                    gradients[f, q, 1, 0] = g1x
                    gradients[f, q, 1, 1] = g1y
                    gradients[f, q, 2, 0] = g2x
                    gradients[f, q, 2, 1] = g2y
                    gradients[f, q, 3, 0] = 0.0
                    gradients[f, q, 3, 1] = 0.0
        else:
            # Bilinear map; corners relative to P0.
            ax = vertices[faces[f, 1], 0] - x0
            ay = vertices[faces[f, 1], 1] - y0
            bx = vertices[faces[f, 2], 0] - x0
            by = vertices[faces[f, 2], 1] - y0
            cx = vertices[faces[f, 3], 0] - x0
            cy = vertices[faces[f, 3], 1] - y0
            for i in range(n):
                u = nodes[i]
                for j in range(n):
                    q = i * n + j
                    v = nodes[j]
                    n0 = (1.0 - u) * (1.0 - v)
                    n1 = u * (1.0 - v)
                    n2 = u * v
                    n3 = (1.0 - u) * v
                    du0 = -(1.0 - v)
                    du1 = 1.0 - v
                    du2 = v
                    du3 = -v
                    dv0 = -(1.0 - u)
                    dv1 = -u
                    dv2 = u
                    dv3 = 1.0 - u
                    xu = du1 * ax + du2 * bx + du3 * cx
                    xv = dv1 * ax + dv2 * bx + dv3 * cx
                    yu = du1 * ay + du2 * by + du3 * cy
                    yv = dv1 * ay + dv2 * by + dv3 * cy
                    det = xu * yv - xv * yu
                    if not det > 0.0:
                        if bad < 0:
                            bad = f
                        det = math.nan
                    inv = 1.0 / det
                    points[f, q, 0] = x0 + n1 * ax + n2 * bx + n3 * cx
                    points[f, q, 1] = y0 + n1 * ay + n2 * by + n3 * cy
                    weights[f, q] = nweights[i] * nweights[j] * det
                    values[f, q, 0] = n0
                    values[f, q, 1] = n1
                    values[f, q, 2] = n2
                    values[f, q, 3] = n3
                    # J^-T = [[yv, -yu], [-xv, xu]] / det
                    gradients[f, q, 0, 0] = (yv * du0 - yu * dv0) * inv
                    gradients[f, q, 0, 1] = (xu * dv0 - xv * du0) * inv
                    gradients[f, q, 1, 0] = (yv * du1 - yu * dv1) * inv
                    gradients[f, q, 1, 1] = (xu * dv1 - xv * du1) * inv
                    gradients[f, q, 2, 0] = (yv * du2 - yu * dv2) * inv
                    gradients[f, q, 2, 1] = (xu * dv2 - xv * du2) * inv
                    gradients[f, q, 3, 0] = (yv * du3 - yu * dv3) * inv
                    gradients[f, q, 3, 1] = (xu * dv3 - xv * du3) * inv
    return bad


def face_quadrature(mesh: Mesh, order: int = 4) -> FaceQuadrature:
    """Map the ``order x order`` Gauss-Legendre rule onto every face of ``mesh``.

    Parameters
    ----------
    mesh : Mesh
        Faces counter-clockwise, non-degenerate, quadrangles strictly convex
        (what :func:`meshcore.build_mesh` returns).
    order : int
        Nodes per direction of the unit square (see the module docstring for
        the degrees it integrates exactly).

    Returns
    -------
    FaceQuadrature

    Raises
    ------
    InvalidMeshError
        When a face has a non-positive Jacobian at a quadrature point
        (clockwise, degenerate or, for quadrangles, not convex).

    Examples
    --------
    >>> import numpy as np
    >>> from meshcore import build_mesh
    >>> square = build_mesh(np.array([[0., 0.], [2., 0.], [2., 1.], [0., 1.]]), "s1", "s2")
    >>> q = face_quadrature(square, order=2)
    >>> q.points.shape, round(q.integrate(np.ones((1, 4))), 12)
    ((1, 4, 2), 2.0)
    """
    n = _check_order(order)
    vertices, faces = mesh_arrays(mesh)
    nodes, nweights = gauss_legendre(n)
    n_f, k = faces.shape[0], n * n
    points = np.empty((n_f, k, 2))
    weights = np.empty((n_f, k))
    values = np.empty((n_f, k, 4))
    gradients = np.empty((n_f, k, 4, 2))
    bad = _quadrature_kernel(vertices, faces, nodes, nweights, points, weights, values, gradients)
    if bad >= 0:
        raise InvalidMeshError(
            f"face {bad} {faces[bad].tolist()} has a non-positive Jacobian: it is clockwise, "
            "degenerate or not convex"
        )
    return FaceQuadrature(n, points, weights, values, gradients)


@njit
def _patch_values_kernel(
    vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, nodes: np.ndarray,
    points: np.ndarray, values: np.ndarray, gradients: np.ndarray,
) -> None:
    """Each face's cubic patch (value and gradient) at its own quadrature points."""
    for f in range(points.shape[0]):
        for k in range(points.shape[1]):
            values[f, k], gradients[f, k, 0], gradients[f, k, 1] = _surface_at(
                vertices, faces, z, nodes, f, points[f, k, 0], points[f, k, 1]
            )


def l2_errors(
    mesh: Mesh,
    z: ArrayLike,
    f_values: ArrayLike,
    f_gradients: ArrayLike,
    quadrature: FaceQuadrature,
    nodes: ArrayLike | None = None,
) -> tuple[float, float]:
    """``||f - g||_2`` and ``||grad f - grad g||_2`` over the mesh, g the surface through ``z``.

    g is linear on triangles and isoparametric bilinear on quadrangles, or,
    with ``nodes`` (:func:`meshcore.smooth_nodes`), the smooth surface's
    cubic patches; the gradient norm is ``sqrt(integral |grad f - grad g|^2)``.

    Parameters
    ----------
    mesh : Mesh
    z : (n_v,) values at the vertices
    f_values : (n_f, k) f at ``quadrature.points``
    f_gradients : (n_f, k, 2) grad f at ``quadrature.points``
    quadrature : FaceQuadrature of ``mesh``
    nodes : (n_f, 12) array, optional
        The smooth surface's node values; omitted: the linear surface.

    Examples
    --------
    >>> import numpy as np
    >>> from meshcore import build_mesh
    >>> mesh = build_mesh(np.array([[0., 0.], [1., 0.], [1., 1.], [0., 1.]]), "s1", "s2")
    >>> q = face_quadrature(mesh, 3)
    >>> x, y = q.points[..., 0], q.points[..., 1]
    >>> z = mesh.vertices[:, 0] * mesh.vertices[:, 1]          # xy is bilinear on the square
    >>> grad = np.stack([y, x], axis=-1)
    >>> [round(e, 12) for e in l2_errors(mesh, z, x * y, grad, q)]
    [0.0, 0.0]
    """
    vertices, faces = mesh_arrays(mesh)
    weights = quadrature.weights
    if weights.shape[0] != faces.shape[0]:
        raise InvalidInputError(
            f"quadrature has {weights.shape[0]} faces but the mesh has {faces.shape[0]}"
        )
    zv = vertex_values(z, vertices.shape[0])
    fv = np.asarray(f_values, dtype=np.float64)
    fg = np.asarray(f_gradients, dtype=np.float64)
    if fv.shape != weights.shape:
        raise InvalidInputError(f"f_values must have shape {weights.shape}, got {fv.shape}")
    if fg.shape != weights.shape + (2,):
        raise InvalidInputError(f"f_gradients must have shape {weights.shape + (2,)}, got {fg.shape}")
    if nodes is None:
        zf = np.where(faces >= 0, zv[np.maximum(faces, 0)], 0.0)  # (n_f, 4), 0 for the padding
        g = np.einsum("fkj,fj->fk", quadrature.shape_values, zf)
        grad_g = np.einsum("fkjd,fj->fkd", quadrature.shape_gradients, zf)
    else:
        rows = np.asarray(nodes, dtype=np.float64)
        if rows.shape != (faces.shape[0], NODES_PER_FACE):
            raise InvalidInputError(f"nodes must have shape ({faces.shape[0]}, {NODES_PER_FACE}), got {rows.shape}")
        g = np.empty(weights.shape)
        grad_g = np.empty(weights.shape + (2,))
        points = np.ascontiguousarray(quadrature.points, dtype=np.float64)
        _patch_values_kernel(vertices, faces, zv, np.ascontiguousarray(rows), points, g, grad_g)
    value_sq = np.sum(weights * (fv - g) ** 2)
    grad_sq = np.sum(weights * np.sum((fg - grad_g) ** 2, axis=-1))
    return float(math.sqrt(value_sq)), float(math.sqrt(grad_sq))
