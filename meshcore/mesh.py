"""The combined mesh: vertices plus triangle and quadrangle faces (UGRID layout)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import empty, larger, njit
from .errors import InvalidInputError, InvalidMeshError
from .predicates import lex_before

if TYPE_CHECKING:
    from .certificate import WindowCertificate

__all__ = ["Mesh", "mesh_arrays", "point_columns", "vertex_values", "with_vertices", "bounded_triangles"]


@dataclass(frozen=True, eq=False)
class Mesh:
    """A conforming mesh of triangles and strictly convex quadrangles.

    Attributes
    ----------
    vertices : (n_v, 2) float64
        Distinct input points, in the order of their first occurrence.
    faces : (n_f, 4) int64
        Vertex indices, counter-clockwise; ``-1`` in column 3 marks a triangle
        (the UGRID convention for mixed meshes).
    input_to_vertex : (n,) int64
        The vertex of every input point: duplicates share one vertex.
    triangle_measure, quad_measure, merge : str or None
        The options the mesh was built with.
    window : (x_min, y_min, x_max, y_max) or None
        Set when the mesh is the piece of a larger mesh over a window (see
        :func:`meshcore.build_mesh`); it then covers only part of the hull and
        some vertices may be used by no face.
    window_escapes : (k, 3) float64 or None
        For a window piece: the circumcircles (centre x, centre y, radius) of
        its Delaunay triangles that leave the ``known`` box passed to
        :func:`meshcore.build_mesh`.  The piece is exactly the global mesh's
        piece when no point missing from the input lies in one of them.
        Each radius is an upper bound (the exact circumdisk lies inside the
        disk given); it is infinite for a triangle too thin for the bound,
        whose disk may then be any half-plane through its vertices.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    input_to_vertex: NDArray[np.int64]
    triangle_measure: str = "delaunay"
    quad_measure: str | None = None
    merge: str = "greedy"
    window: tuple[float, float, float, float] | None = None
    window_escapes: NDArray[np.float64] | None = None
    certificate: "WindowCertificate | None" = None
    """For a window piece: whether its faces are the global mesh's (:class:`meshcore.certificate.WindowCertificate`)."""

    @property
    def is_quad(self) -> NDArray[np.bool_]:
        """Boolean mask over faces, True for quadrangles."""
        return self.faces[:, 3] >= 0

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0] - np.count_nonzero(self.is_quad))

    @property
    def n_quads(self) -> int:
        return int(np.count_nonzero(self.is_quad))

    def __repr__(self) -> str:
        return (
            f"Mesh({self.vertices.shape[0]} vertices, {self.n_triangles} triangles, "
            f"{self.n_quads} quads, triangle_measure={self.triangle_measure!r}, "
            f"quad_measure={self.quad_measure!r}, merge={self.merge!r})"
        )


def mesh_arrays(mesh: Mesh) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Contiguous ``(n_v, 2)`` float64 vertices and ``(n_f, 4)`` int64 faces, checked.

    The shapes must be right (:class:`InvalidInputError`) and every index in
    range (:class:`InvalidMeshError`); kernels can then index without checks.
    """
    vertices = np.asarray(getattr(mesh, "vertices", None), dtype=np.float64)
    faces = np.asarray(getattr(mesh, "faces", None))
    if vertices.ndim != 2 or vertices.shape[1] < 2 or faces.ndim != 2 or faces.shape[1] != 4:
        raise InvalidInputError(
            "mesh must be a Mesh with vertices of shape (n_v, 2) and faces of shape (n_f, 4), "
            f"got vertices {vertices.shape} and faces {faces.shape}"
        )
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n_v = vertices.shape[0]
    if not _corners_in_range(faces, n_v):
        raise InvalidMeshError(f"faces refer to vertices outside 0..{n_v - 1}")
    return np.ascontiguousarray(vertices[:, :2]), faces


@njit
def _corners_in_range(faces: np.ndarray, n_v: int) -> bool:
    """Whether every corner is a vertex below ``n_v``, the fourth ``-1`` too
    (one pass; numpy's reductions along the rows of an ``(n, 4)`` array
    took 3 ms a mesh of 190k faces, a tenth of a second a tile)."""
    for f in range(faces.shape[0]):
        for k in range(4):
            v = faces[f, k]
            if v >= n_v or v < (-1 if k == 3 else 0):
                return False
    return True


def with_vertices(mesh: Mesh, points: ArrayLike) -> Mesh:
    """``mesh`` with ``points`` among its input points: those at a new place
    become vertices that no face uses, after the others and in the order of
    their first occurrence, and ``input_to_vertex`` grows by one entry a
    point (a point at a vertex's place, or at another point's, is that
    vertex).  The faces, the options and the window stay as they are: meant
    for points that lie in none of the faces' circumcircles, which a build
    with them would have left as they are (a window piece's points outside
    every one of its ``window_escapes``).

    Examples
    --------
    >>> import numpy as np
    >>> square = Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), np.array([[0, 1, 2, 3]]), np.arange(4))
    >>> more = with_vertices(square, [[5.0, 5.0], [1.0, 1.0], [5.0, 5.0], [7.0, 0.0]])
    >>> more.vertices[4:].tolist(), more.input_to_vertex[4:].tolist()
    ([[5.0, 5.0], [7.0, 0.0]], [4, 2, 4, 5])
    """
    vertices, _ = mesh_arrays(mesh)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 2:
        raise InvalidInputError(f"points must be of shape (n, 2), got {pts.shape}")
    pts = np.ascontiguousarray(pts[:, :2])
    if not np.isfinite(pts).all():
        raise InvalidInputError("points must be finite")
    if pts.shape[0] == 0:
        return mesh
    # a point's place as one complex number: sorted and compared as (x, y), 0.0 equal to -0.0
    keys = pts.view(np.complex128).ravel()
    places, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    vertex = np.full(places.size, -1, dtype=np.int64)
    known = vertices.view(np.complex128).ravel()
    at = np.minimum(np.searchsorted(places, known), places.size - 1)
    same = places[at] == known
    vertex[at[same]] = np.flatnonzero(same)
    fresh = np.flatnonzero(vertex < 0)
    fresh = fresh[np.argsort(first[fresh], kind="stable")]
    n = vertices.shape[0]
    vertex[fresh] = n + np.arange(fresh.size)
    grown = np.concatenate([vertices, pts[first[fresh]]])
    mapped = np.concatenate([np.asarray(mesh.input_to_vertex, dtype=np.int64), vertex[inverse.ravel()]])
    return replace(mesh, vertices=grown, input_to_vertex=mapped)


def point_columns(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """``x``, ``y`` and ``z`` as contiguous float64 arrays, checked: 1-D, of one length, finite."""
    arrays = [np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, z)]
    if any(a.ndim != 1 for a in arrays) or len({a.shape[0] for a in arrays}) != 1:
        raise InvalidInputError(f"x, y and z must be 1-D arrays of one length, not of shapes {[a.shape for a in arrays]}")
    if not all(np.isfinite(a).all() for a in arrays):
        raise InvalidInputError("x, y and z must be finite")
    return tuple(arrays)


def vertex_values(z: ArrayLike, n_vertices: int) -> NDArray[np.float64]:
    """``z`` as a contiguous float64 array of shape ``(n_vertices,)``, finite or NaN."""
    arr = np.asarray(z)
    if arr.dtype.kind not in "biuf":
        raise InvalidInputError(f"z must be a real numeric array, got dtype {arr.dtype}")
    if arr.shape != (n_vertices,):
        raise InvalidInputError(
            f"z must have shape (n_vertices,) = ({n_vertices},), one value per vertex, "
            f"got {arr.shape}"
        )
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if np.isinf(arr).any():
        raise InvalidInputError("z must be finite or NaN (NaN marks unknown values), got inf")
    return arr


def bounded_triangles(vertices: ArrayLike, triangles: ArrayLike, max_edge: float) -> NDArray[np.int64]:
    """The ``triangles`` ``(k, 3)`` whose longest edge and circumradius are at
    most ``max_edge``, as faces ``(m, 4)`` padded with -1, each starting at its
    corner that comes first by x, then y, in their given order.

    A tile that holds every point within ``2 * max_edge`` of a place has all
    the global Delaunay triangles over it that pass this test: each one's
    circumcircle lies inside that margin.  The test reads the corners in one
    order whatever corner a triangle was given from, so every tile decides a
    triangle alike.
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] < 2 or t.ndim != 2 or t.shape[1] != 3:
        raise InvalidInputError(f"vertices must be (n, 2) and triangles (k, 3), got {v.shape} and {t.shape}")
    if not max_edge > 0.0:
        raise InvalidInputError(f"max_edge must be a number > 0, got {max_edge!r}")
    return _bounded_kernel(v, t, float(max_edge))


@njit
def _bounded_kernel(vertices, triangles, max_edge):
    n = triangles.shape[0]
    out = empty((n, 4), dtype=np.int64)
    limit = max_edge * max_edge
    k = 0
    for t in range(n):
        i0, i1, i2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ax, ay = vertices[i0, 0], vertices[i0, 1]
        bx, by = vertices[i1, 0], vertices[i1, 1]
        cx, cy = vertices[i2, 0], vertices[i2, 1]
        # from the corner first by x, then y, turning as given
        if lex_before(bx, by, ax, ay) and lex_before(bx, by, cx, cy):
            i0, i1, i2, ax, ay, bx, by, cx, cy = i1, i2, i0, bx, by, cx, cy, ax, ay
        elif lex_before(cx, cy, ax, ay) and lex_before(cx, cy, bx, by):
            i0, i1, i2, ax, ay, bx, by, cx, cy = i2, i0, i1, cx, cy, ax, ay, bx, by
        ab = (bx - ax) ** 2 + (by - ay) ** 2
        bc = (cx - bx) ** 2 + (cy - by) ** 2
        ca = (ax - cx) ** 2 + (ay - cy) ** 2
        cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        # the circumradius is |ab| |bc| |ca| / (2 |cross|): at most max_edge, without a root
        if larger(ab, larger(bc, ca)) <= limit and ab * bc * ca <= 4.0 * limit * cross * cross:
            out[k, 0] = i0
            out[k, 1] = i1
            out[k, 2] = i2
            out[k, 3] = -1
            k += 1
    return out[:k].copy()

