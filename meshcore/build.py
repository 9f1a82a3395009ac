"""``build_mesh``: Delaunay triangulation, quality flips, elimination of diagonals."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import njit
from .delaunay import Triangulation, _next, _prev, delaunay
from .errors import InvalidInputError
from .flip import flip_edges
from .merge import merge_triangles
from .mesh import Mesh
from .options import MergeMethod, QuadMeasure, TriangleMeasure, parse_option

__all__ = ["build_mesh", "as_points"]


def as_points(xy: ArrayLike, name: str = "xy") -> NDArray[np.float64]:
    """Check and cast an ``(n, 2)`` array of finite coordinates to float64."""
    arr = np.asarray(xy)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InvalidInputError(f"{name} must have shape (n, 2), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InvalidInputError(f"{name} must be numeric, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise InvalidInputError(
            f"{name} has {int((~finite).sum())} point(s) with NaN or infinite coordinates "
            f"(first at index {bad})"
        )
    return arr


@njit
def _faces_kernel(tri, he, partner, vertex_of) -> np.ndarray:
    nt = tri.shape[0] // 3
    count = 0
    for t in range(nt):
        e = partner[t]
        if e == -1 or t < he[e] // 3:
            count += 1
    faces = np.empty((count, 4), dtype=np.int64)
    k = 0
    for t in range(nt):
        e = partner[t]
        if e == -1:
            faces[k, 0] = vertex_of[tri[3 * t]]
            faces[k, 1] = vertex_of[tri[3 * t + 1]]
            faces[k, 2] = vertex_of[tri[3 * t + 2]]
            faces[k, 3] = -1
            k += 1
        else:
            f = he[e]
            if t < f // 3:
                # (a, b, c) + (b, a, d) -> quadrangle a, d, b, c (counter-clockwise)
                faces[k, 0] = vertex_of[tri[e]]
                faces[k, 1] = vertex_of[tri[_prev(f)]]
                faces[k, 2] = vertex_of[tri[_next(e)]]
                faces[k, 3] = vertex_of[tri[_prev(e)]]
                k += 1
    return faces


def _vertex_numbering(
    triangulation: Triangulation, n: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """(vertex id per sorted position, input index per vertex, vertex per input point)."""
    order = triangulation.order.astype(np.int64)
    rep = triangulation.rep.astype(np.int64)
    while True:  # resolve chains (a point merged with another merged point)
        nxt = rep[rep]
        if np.array_equal(nxt, rep):
            break
        rep = nxt
    is_vertex = np.zeros(n, dtype=bool)
    is_vertex[order[rep == np.arange(n)]] = True
    vertex_input = np.flatnonzero(is_vertex)
    vertex_id_of_input = np.cumsum(is_vertex) - 1
    vertex_of_sorted = vertex_id_of_input[order[rep]]
    input_to_vertex = np.empty(n, dtype=np.int64)
    input_to_vertex[order] = vertex_of_sorted
    return vertex_of_sorted, vertex_input, input_to_vertex


def build_mesh(
    xy: ArrayLike,
    triangle_measure: str = "s1",
    quad_measure: str | None = "s2",
    merge: str = "greedy",
) -> Mesh:
    """Build the combined triangle/quadrangle mesh of a planar point set.

    1. Delaunay triangulation (exact predicates; duplicates merged);
    2. flips to local optimality under ``triangle_measure`` ("s1" or "s3";
       "delaunay" keeps the Delaunay triangulation);
    3. elimination of diagonals under ``quad_measure`` ("s2" or "s4"; None keeps
       a pure triangulation), ``merge="greedy"`` (the paper's queue) or
       ``"optimal"`` (maximum total gain).

    Parameters
    ----------
    xy : (n, 2) array of finite coordinates

    Returns
    -------
    Mesh

    Examples
    --------
    >>> import numpy as np
    >>> mesh = build_mesh(np.array([[0., 0.], [1., 0.], [1., 1.], [0., 1.]]))
    >>> mesh.faces.tolist()
    [[0, 1, 2, 3]]
    """
    tm = parse_option(TriangleMeasure, triangle_measure, "triangle_measure")
    qm = None if quad_measure is None else parse_option(QuadMeasure, quad_measure, "quad_measure")
    mm = parse_option(MergeMethod, merge, "merge")
    points = as_points(xy)
    n = points.shape[0]

    triangulation = delaunay(points)
    if tm is not TriangleMeasure.DELAUNAY:
        flip_edges(triangulation, tm.value)
    nt = triangulation.triangles.shape[0] // 3
    if qm is None:
        partner = np.full(nt, -1, dtype=np.int32)
    else:
        partner = merge_triangles(triangulation, qm.value, mm.value)

    vertex_of_sorted, vertex_input, input_to_vertex = _vertex_numbering(triangulation, n)
    faces = _faces_kernel(triangulation.triangles, triangulation.halfedges, partner, vertex_of_sorted)
    return Mesh(
        vertices=points[vertex_input],
        faces=faces,
        input_to_vertex=input_to_vertex,
        triangle_measure=tm.value,
        quad_measure=None if qm is None else qm.value,
        merge=mm.value,
    )
