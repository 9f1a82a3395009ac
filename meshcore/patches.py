"""Cubic patches on triangles and quadrangles: the smooth surface's formulas.

A face of the smooth surface is a cubic Lagrange patch: the cubic triangle
(P3, ten nodes) on a triangle and the bicubic patch (Q3, sixteen nodes) on a
quadrangle, over the same isoparametric bilinear map as the linear surface.
The nodes are the face's corners (which take the points' z), two nodes on
each edge at a third and two thirds of the way from the edge's start corner
(counter-clockwise), and the inner nodes: the centroid of a triangle, the
points ``(u, v) in {1/3, 2/3}^2`` of a quadrangle.

A face's node values other than its corners come as one row of twelve::

    [e0 1/3, e0 2/3, e1 1/3, e1 2/3, e2 1/3, e2 2/3, e3 1/3, e3 2/3,
     inner0, inner1, inner2, inner3]

where edge ``k`` runs from corner ``k`` to corner ``k + 1`` (a triangle's
``e3`` and inner nodes past the first are unused) and a quadrangle's inner
nodes are at ``(1/3, 1/3), (2/3, 1/3), (2/3, 2/3), (1/3, 2/3)``.

Along an edge both kinds of patch reduce to the cubic through the edge's two
corners and two edge nodes, in the edge's length parameter (the bilinear map
is linear on an edge).  Two faces that share an edge and agree on its nodes
therefore meet continuously (C0).  Both patches reproduce every polynomial
of degree three (triangle) or every bicubic in ``(u, v)`` (quadrangle), and so
every linear function of ``(x, y)``.

These are scalar kernels without checks; :mod:`meshcore.interpolate` and
:mod:`meshcore.rasterize` locate the face and call them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, njit, njit_helper
from .errors import InvalidInputError

__all__ = ["NODES_PER_FACE", "linear_nodes", "node_deviations", "nodes_from_deviations"]

NODES_PER_FACE = 12
"""Columns of a face's row of node values (see the module docstring)."""

_THIRD = 1.0 / 3.0
_TWO_THIRDS = 2.0 / 3.0


@njit_helper
def _cubic_basis(t: float) -> tuple[float, float, float, float]:
    """The four cubic Lagrange polynomials on the nodes ``0, 1/3, 2/3, 1`` at ``t``."""
    a = 3.0 * t
    return (
        -0.5 * (a - 1.0) * (a - 2.0) * (a - 3.0) / 3.0,
        0.5 * a * (a - 2.0) * (a - 3.0),
        -0.5 * a * (a - 1.0) * (a - 3.0),
        a * (a - 1.0) * (a - 2.0) / 6.0,
    )


@njit_helper
def _cubic_basis_derivative(t: float) -> tuple[float, float, float, float]:
    """The derivatives in ``t`` of :func:`_cubic_basis`."""
    a = 3.0 * t
    return (
        -0.5 * (3.0 * a * a - 12.0 * a + 11.0),
        1.5 * (3.0 * a * a - 10.0 * a + 6.0),
        -1.5 * (3.0 * a * a - 8.0 * a + 3.0),
        0.5 * (3.0 * a * a - 6.0 * a + 2.0),
    )


@njit_helper
def triangle_patch(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float,
    za: float, zb: float, zc: float, nodes: np.ndarray, px: float, py: float,
) -> tuple[float, float, float]:
    """Value and ``(dz/dx, dz/dy)`` at ``p`` of the cubic patch on triangle ``a b c``.

    ``nodes`` is the face's row of node values (the module docstring).
    """
    bax = bx - ax
    bay = by - ay
    cax = cx - ax
    cay = cy - ay
    d = bax * cay - bay * cax
    qx = px - ax
    qy = py - ay
    l1 = (qx * cay - qy * cax) / d
    l2 = (bax * qy - bay * qx) / d
    l0 = 1.0 - l1 - l2
    # d(l1)/dx, d(l1)/dy, d(l2)/dx, d(l2)/dy; l0's are minus their sums
    l1x = cay / d
    l1y = -cax / d
    l2x = -bay / d
    l2y = bax / d
    l0x = -l1x - l2x
    l0y = -l1y - l2y
    lam = (l0, l1, l2)
    lx = (l0x, l1x, l2x)
    ly = (l0y, l1y, l2y)
    corner = (za, zb, zc)
    value = 0.0
    gx = 0.0
    gy = 0.0
    for i in range(3):
        li = lam[i]
        # corner: l (3l - 1)(3l - 2) / 2
        w = 0.5 * li * (3.0 * li - 1.0) * (3.0 * li - 2.0)
        dw = 0.5 * (27.0 * li * li - 18.0 * li + 2.0)
        value += w * corner[i]
        gx += dw * lx[i] * corner[i]
        gy += dw * ly[i] * corner[i]
        j = (i + 1) % 3
        lj = lam[j]
        n1 = nodes[2 * i]  # a third of the way from corner i to corner j
        n2 = nodes[2 * i + 1]
        # 9/2 li lj (3 li - 1) and 9/2 li lj (3 lj - 1)
        w1 = 4.5 * li * lj * (3.0 * li - 1.0)
        w2 = 4.5 * li * lj * (3.0 * lj - 1.0)
        d1i = 4.5 * lj * (6.0 * li - 1.0)
        d1j = 4.5 * li * (3.0 * li - 1.0)
        d2i = 4.5 * lj * (3.0 * lj - 1.0)
        d2j = 4.5 * li * (6.0 * lj - 1.0)
        value += w1 * n1 + w2 * n2
        gx += (d1i * lx[i] + d1j * lx[j]) * n1 + (d2i * lx[i] + d2j * lx[j]) * n2
        gy += (d1i * ly[i] + d1j * ly[j]) * n1 + (d2i * ly[i] + d2j * ly[j]) * n2
    inner = nodes[8]
    value += 27.0 * l0 * l1 * l2 * inner
    gx += 27.0 * (l0x * l1 * l2 + l0 * l1x * l2 + l0 * l1 * l2x) * inner
    gy += 27.0 * (l0y * l1 * l2 + l0 * l1y * l2 + l0 * l1 * l2y) * inner
    return value, gx, gy


@njit_helper
def _quad_node(nodes: np.ndarray, z0: float, z1: float, z2: float, z3: float, i: int, j: int) -> float:
    """The value of the quadrangle's node ``(u, v) = (i / 3, j / 3)``."""
    if j == 0:
        if i == 0:
            return z0
        if i == 3:
            return z1
        return nodes[i - 1]  # e0: 1/3, 2/3 from P0
    if j == 3:
        if i == 0:
            return z3
        if i == 3:
            return z2
        return nodes[6 - i]  # e2 runs from P2 (u = 1) to P3: u = 2/3 first
    if i == 3:
        return nodes[1 + j]  # e1 from P1 (v = 0) to P2
    if i == 0:
        return nodes[8 - j]  # e3 from P3 (v = 1) to P0: v = 2/3 first
    if j == 1:
        return nodes[7 + i]  # inner0 (1/3, 1/3), inner1 (2/3, 1/3)
    return nodes[12 - i]  # inner3 (1/3, 2/3), inner2 (2/3, 2/3)


@njit_helper
def bilinear_gradient(
    x0: float, y0: float, x1: float, y1: float, x2: float, y2: float, x3: float, y3: float,
    u: float, v: float, zu: float, zv: float,
) -> tuple[float, float]:
    """``(dz/dx, dz/dy) = J^-T (dz/du, dz/dv)`` through the quadrangle's bilinear map at ``(u, v)``."""
    xu = (1.0 - v) * (x1 - x0) + v * (x2 - x3)
    yu = (1.0 - v) * (y1 - y0) + v * (y2 - y3)
    xv = (1.0 - u) * (x3 - x0) + u * (x2 - x1)
    yv = (1.0 - u) * (y3 - y0) + u * (y2 - y1)
    det = xu * yv - yu * xv
    return (yv * zu - yu * zv) / det, (xu * zv - xv * zu) / det


@njit_helper
def quad_patch(
    x0: float, y0: float, x1: float, y1: float, x2: float, y2: float, x3: float, y3: float,
    z0: float, z1: float, z2: float, z3: float, nodes: np.ndarray, u: float, v: float,
) -> tuple[float, float, float]:
    """Value and ``(dz/dx, dz/dy)`` of the bicubic patch at the parameters ``(u, v)``.

    The caller inverts the bilinear map (``meshcore.interpolate._bilinear_inverse``).
    """
    bu = _cubic_basis(u)
    bv = _cubic_basis(v)
    du = _cubic_basis_derivative(u)
    dv = _cubic_basis_derivative(v)
    value = 0.0
    zu = 0.0
    zv = 0.0
    for j in range(4):
        for i in range(4):
            n = _quad_node(nodes, z0, z1, z2, z3, i, j)
            value += bu[i] * bv[j] * n
            zu += du[i] * bv[j] * n
            zv += bu[i] * dv[j] * n
    gx, gy = bilinear_gradient(x0, y0, x1, y1, x2, y2, x3, y3, u, v, zu, zv)
    return value, gx, gy


@njit_helper
def _face_linear_nodes(faces: np.ndarray, z: np.ndarray, f: int, row: np.ndarray) -> None:
    """The linear surface's values at face ``f``'s nodes, into ``row`` (its unused columns untouched)."""
    nc = 4 if faces[f, 3] >= 0 else 3
    for k in range(nc):
        a = z[faces[f, k]]
        b = z[faces[f, (k + 1) % nc]]
        # the same two products, summed, from either face of the edge
        row[2 * k] = _TWO_THIRDS * a + _THIRD * b
        row[2 * k + 1] = _THIRD * a + _TWO_THIRDS * b
    z0 = z[faces[f, 0]]
    z1 = z[faces[f, 1]]
    z2 = z[faces[f, 2]]
    if nc == 3:
        row[8] = (z0 + z1 + z2) * _THIRD
    else:
        z3 = z[faces[f, 3]]
        for m in range(4):
            u = _THIRD if m == 0 or m == 3 else _TWO_THIRDS
            v = _THIRD if m < 2 else _TWO_THIRDS
            row[8 + m] = (1.0 - u) * (1.0 - v) * z0 + u * (1.0 - v) * z1 + u * v * z2 + (1.0 - u) * v * z3


@njit
def _linear_nodes_kernel(faces: np.ndarray, z: np.ndarray, out: np.ndarray) -> None:
    for f in range(faces.shape[0]):
        _face_linear_nodes(faces, z, f, out[f])


@njit
def _deviations_kernel(faces: np.ndarray, z: np.ndarray, nodes: np.ndarray, out: np.ndarray) -> None:
    row = empty(NODES_PER_FACE)
    for f in range(faces.shape[0]):
        for j in range(NODES_PER_FACE):
            row[j] = np.nan
        _face_linear_nodes(faces, z, f, row)
        for j in range(NODES_PER_FACE):
            out[f, j] = np.float32(nodes[f, j] - row[j])


@njit
def _restore_kernel(faces: np.ndarray, z: np.ndarray, deviations: np.ndarray, out: np.ndarray) -> None:
    """``out`` (uninitialised): the linear nodes plus the deviations, NaN in a triangle's unused columns."""
    for f in range(faces.shape[0]):
        if faces[f, 3] < 0:
            for j in (6, 7, 9, 10, 11):
                out[f, j] = np.nan
        _face_linear_nodes(faces, z, f, out[f])
        for j in range(NODES_PER_FACE):
            out[f, j] += np.float64(deviations[f, j])


def linear_nodes(faces: NDArray[np.integer], z: NDArray[np.floating]) -> NDArray[np.float64]:
    """The linear surface's values at every face's nodes, in the layout of the module docstring.

    Flat triangles and bilinear quadrangles, from the corners' ``z``; unused
    columns NaN.  Both faces of an edge give its nodes bit-identical values
    (the same products, summed in either order), so the smooth surface's
    nodes can be stored as small deviations from these (in single
    precision) and restored identically on both sides of every edge.

    Examples
    --------
    >>> import numpy as np
    >>> faces = np.array([[0, 1, 2, -1], [1, 3, 2, -1]])
    >>> nodes = linear_nodes(faces, np.array([0.0, 3.0, 6.0, 9.0]))
    >>> float(nodes[0, 2]), float(nodes[1, 5])  # edge 1-2 from each side: 1/3 of the way from z=3 to z=6
    (4.0, 4.0)
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    out = np.full((f.shape[0], NODES_PER_FACE), np.nan)
    _linear_nodes_kernel(f, np.ascontiguousarray(z, dtype=np.float64), out)
    return out


def node_deviations(faces: NDArray[np.integer], z: NDArray[np.floating], nodes: NDArray[np.floating]) -> NDArray[np.float32]:
    """``nodes`` (a smooth surface's, ``(n_f, 12)``) as single-precision
    deviations from :func:`linear_nodes`: half the bytes, and
    :func:`nodes_from_deviations` restores them bit-identically on both sides
    of every edge, to a few nanometres per metre of deviation.

    >>> import numpy as np
    >>> faces, z = np.array([[0, 1, 2, -1]]), np.array([0.0, 3.0, 6.0])
    >>> nodes = linear_nodes(faces, z) + 0.25
    >>> bool(np.array_equal(nodes_from_deviations(faces, z, node_deviations(faces, z, nodes)), nodes, equal_nan=True))
    True
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    values = np.ascontiguousarray(nodes, dtype=np.float64)
    if values.shape != (f.shape[0], NODES_PER_FACE):
        raise InvalidInputError(f"nodes must have shape ({f.shape[0]}, {NODES_PER_FACE}), got {values.shape}")
    out = np.empty((f.shape[0], NODES_PER_FACE), dtype=np.float32)
    _deviations_kernel(f, np.ascontiguousarray(z, dtype=np.float64), values, out)
    return out


def nodes_from_deviations(
    faces: NDArray[np.integer], z: NDArray[np.floating], deviations: NDArray[np.float32]
) -> NDArray[np.float64]:
    """The nodes that :func:`node_deviations` gave ``deviations`` for (``linear_nodes + deviations``)."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    values = np.ascontiguousarray(deviations, dtype=np.float32)
    if values.shape != (f.shape[0], NODES_PER_FACE):
        raise InvalidInputError(f"deviations must have shape ({f.shape[0]}, {NODES_PER_FACE}), got {values.shape}")
    out = np.empty((f.shape[0], NODES_PER_FACE))
    _restore_kernel(f, np.ascontiguousarray(z, dtype=np.float64), values, out)
    return out
