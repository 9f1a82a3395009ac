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


@njit
def _vertex_numbering(order, rep):
    """Vertices are the distinct points in order of first occurrence in the input.

    Returns (vertex id of every sorted point, input index of every vertex,
    vertex of every input point).
    """
    n = order.shape[0]
    is_vertex = np.zeros(n, dtype=np.bool_)
    for k in range(n):
        r = rep[k]
        while rep[r] != r:  # chains appear only through points merged after the sweep
            r = rep[r]
        rep[k] = r
        if r == k:
            is_vertex[order[k]] = True
    input_to_vertex = np.empty(n, dtype=np.int64)  # first holds the vertex id of each vertex input
    count = 0
    for i in range(n):
        if is_vertex[i]:
            input_to_vertex[i] = count
            count += 1
    vertex_input = np.empty(count, dtype=np.int64)
    for i in range(n):
        if is_vertex[i]:
            vertex_input[input_to_vertex[i]] = i
    vertex_of_sorted = np.empty(n, dtype=np.int32)
    for k in range(n):
        vertex_of_sorted[k] = input_to_vertex[order[rep[k]]]
    for k in range(n):
        input_to_vertex[order[k]] = vertex_of_sorted[k]
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
    [[2, 3, 0, 1]]
    """
    tm = parse_option(TriangleMeasure, triangle_measure, "triangle_measure")
    qm = None if quad_measure is None else parse_option(QuadMeasure, quad_measure, "quad_measure")
    mm = parse_option(MergeMethod, merge, "merge")
    points = as_points(xy)

    triangulation = delaunay(points)
    if tm is not TriangleMeasure.DELAUNAY:
        flip_edges(triangulation, tm.value)
    nt = triangulation.triangles.shape[0] // 3
    if qm is None:
        partner = np.full(nt, -1, dtype=np.int32)
    else:
        partner = merge_triangles(triangulation, qm.value, mm.value)

    vertex_of_sorted, vertex_input, input_to_vertex = _vertex_numbering(triangulation.order, triangulation.rep)
    tri, he = triangulation.triangles, triangulation.halfedges
    del triangulation  # release the sweep's coordinates before the faces are allocated
    faces = _faces_kernel(tri, he, partner, vertex_of_sorted)
    del tri, he, partner, vertex_of_sorted
    return Mesh(
        vertices=points[vertex_input],
        faces=faces,
        input_to_vertex=input_to_vertex,
        triangle_measure=tm.value,
        quad_measure=None if qm is None else qm.value,
        merge=mm.value,
    )
