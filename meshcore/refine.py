"""Long faces cut for the smooth surface: long edges split, their faces triangulated.

A cubic patch spans its face: on a face many point spacings long (the
slivers along the convex hull, the faces across a void) it cannot follow the
ground between its nodes, however well they are kriged.
:func:`refine_long_faces` splits every edge longer than ``longer_than`` into
``ceil(length / piece)`` equal pieces and cuts each face with a split edge
into triangles through the new points (the other faces are kept as they
are); :func:`meshcore.smooth.smooth_surface` then kriges the new points and
puts its patches on the refined faces.

Everything a face computes for one of its edges depends on that edge alone:
the split is decided by the edge's length and placed from its end first in
coordinate order, like the patches' nodes, so the two faces of an edge, in
one tile or in two, put the same points at bit-identical positions (the
surface stays continuous and seamless).  How a face is cut inside (the
triangles of :func:`_cut_face`) is its own.
"""

from __future__ import annotations

import math

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, full, larger, njit, njit_helper, smaller, zeros
from .errors import InvalidInputError
from .mesh import Mesh, mesh_arrays

__all__ = ["Refinement", "refine_long_faces", "with_cut_faces", "cut_face_rows"]


class Refinement(NamedTuple):
    """A mesh with its long edges split and their faces cut (:func:`refine_long_faces`).

    Attributes
    ----------
    mesh : Mesh
        The refined mesh: the input mesh's vertices first, then the new
        points; the input mesh's faces in their rows, a face cut replaced by
        its first triangle, then the other triangles of the faces cut.
    parent : (n_f',) int64, the input mesh's face of each face (``parent[:n_f]`` is ``0 .. n_f - 1``)
    ends : (m, 2) int64, each new point's edge, its ends in coordinate order
    t : (m,) float64, each new point's place along its edge (``first + t (second - first)``)
    """

    mesh: Mesh
    parent: NDArray[np.int64]
    ends: NDArray[np.int64]
    t: NDArray[np.float64]


MAX_PIECES = 64
"""An edge is split into at most this many pieces (longer ones where it is
longer: an edge to an outlier kilometres away is no ground to follow)."""


@njit_helper
def _first_end(vertices: np.ndarray, s: int, e: int) -> bool:
    """Whether ``s`` comes before ``e`` in coordinate order (x, then y)."""
    sx = vertices[s, 0]
    ex = vertices[e, 0]
    return sx < ex or (sx == ex and vertices[s, 1] < vertices[e, 1])


@njit_helper
def _pieces(vertices: np.ndarray, a: int, b: int, longest: float, piece: float) -> int:
    """How many pieces edge ``a b`` is split into (1: not split), the same from either end."""
    s, e = (a, b) if _first_end(vertices, a, b) else (b, a)
    dx = vertices[e, 0] - vertices[s, 0]
    dy = vertices[e, 1] - vertices[s, 1]
    d2 = dx * dx + dy * dy
    if not d2 > longest * longest:
        return 1
    return np.int64(smaller(math.ceil(math.sqrt(d2) / piece), MAX_PIECES))


@njit_helper
def _cross(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit_helper
def _on_edge(edge: np.ndarray, corner: np.ndarray, p: int, k: int, nc: int) -> bool:
    """Whether polygon point ``p`` lies on the face's edge ``k`` (a corner lies on two)."""
    if corner[p]:
        return edge[p] == k or (edge[p] + nc - 1) % nc == k
    return edge[p] == k


@njit_helper
def _share_edge(edge: np.ndarray, corner: np.ndarray, a: int, b: int, nc: int) -> bool:
    """Whether polygon points ``a`` and ``b`` lie on one edge of the face."""
    if _on_edge(edge, corner, b, edge[a], nc):
        return True
    return corner[a] and _on_edge(edge, corner, b, (edge[a] + nc - 1) % nc, nc)


@njit_helper
def _cut_face(px: np.ndarray, py: np.ndarray, ids: np.ndarray, edge: np.ndarray, corner: np.ndarray, m: int, nc: int,
              out: np.ndarray) -> int:
    """Triangulate the face's polygon ``(px, py)[:m]`` (counter-clockwise: its ``nc``
    corners and the points split on its edges) by clipping, again and again, the
    ear of shortest diagonal; writes vertex ids ``ids[...]`` triangles to ``out``,
    returns their number.

    ``edge[p]``: the face's edge point ``p`` lies on (a corner: the edge it
    starts).  An ear whose diagonal joins two points of one edge is never
    clipped, whatever rounding says (it would be flat, or leave a flat
    polygon); among the others an ear that turns left is preferred (one that
    does not can only come from rounding on a face thinner than it).  The
    polygon left stays convex.
    """
    alive = full(m, True, dtype=np.bool_)
    nxt = empty(m, dtype=np.int64)
    prv = empty(m, dtype=np.int64)
    for i in range(m):
        nxt[i] = (i + 1) % m
        prv[i] = (i - 1) % m
    left = m
    count = 0
    while left >= 3:
        best = -1
        best_bad = True
        best_d = math.inf
        for i in range(m):
            if not alive[i]:
                continue
            a = prv[i]
            b = nxt[i]
            if _share_edge(edge, corner, a, b, nc):
                continue  # the diagonal would run along an edge: a flat ear, or a flat polygon left
            cr = _cross(px[a], py[a], px[i], py[i], px[b], py[b])
            d = (px[b] - px[a]) ** 2 + (py[b] - py[a]) ** 2
            bad = not cr > 0.0
            if best < 0 or (best_bad and not bad) or (bad == best_bad and d < best_d):
                best_bad = bad
                best_d = d
                best = i
        if best < 0:
            return -1  # every point flat: not a face
        a = prv[best]
        b = nxt[best]
        out[count, 0] = ids[a]
        out[count, 1] = ids[best]
        out[count, 2] = ids[b]
        count += 1
        alive[best] = False
        nxt[a] = b
        prv[b] = a
        left -= 1
    return count


@njit
def _long_faces(vertices: np.ndarray, faces: np.ndarray, longest: float) -> np.ndarray:
    """The faces with an edge longer than ``longest`` (one pass; the squared length is
    the same bits from either end, so no order is needed to decide)."""
    limit = longest * longest
    mark = zeros(faces.shape[0], dtype=np.bool_)
    count = 0
    for f in range(faces.shape[0]):
        nc = 4 if faces[f, 3] >= 0 else 3
        for k in range(nc):
            a = faces[f, k]
            b = faces[f, (k + 1) % nc]
            dx = vertices[b, 0] - vertices[a, 0]
            dy = vertices[b, 1] - vertices[a, 1]
            if dx * dx + dy * dy > limit:
                mark[f] = True
        if mark[f]:
            count += 1
    out = empty(count, dtype=np.int64)
    m = 0
    for f in range(faces.shape[0]):
        if mark[f]:
            out[m] = f
            m += 1
    return out


@njit
def _refine_kernel(vertices: np.ndarray, faces: np.ndarray, cut: np.ndarray, longest: float, piece: float):
    """The new points and the triangles of the faces ``cut`` (their parents alongside)."""
    n_v = vertices.shape[0]
    # each cut face's edges' pieces, once: the passes below take them from here
    pieces = full((cut.shape[0], 4), 1, dtype=np.int64)
    extra = 0
    most = 0
    n_tris = 0
    for c in range(cut.shape[0]):
        f = cut[c]
        nc = 4 if faces[f, 3] >= 0 else 3
        size = nc
        for k in range(nc):
            pieces[c, k] = _pieces(vertices, faces[f, k], faces[f, (k + 1) % nc], longest, piece)
            extra += pieces[c, k] - 1  # counted from both faces of an inner edge: room enough
            size += pieces[c, k] - 1
        most = larger(most, size)
        n_tris += size - 2
    new_xy = empty((extra, 2))
    new_ends = empty((extra, 2), dtype=np.int64)
    new_t = empty(extra)
    # each split edge once: (first end, other end) -> its first new point, in a small open-addressed table
    size_table = 1
    while size_table < 4 * larger(extra, 1):
        size_table *= 2
    key_s = full(size_table, -1, dtype=np.int64)
    key_e = empty(size_table, dtype=np.int64)
    value = empty(size_table, dtype=np.int64)
    used = 0
    for c in range(cut.shape[0]):
        f = cut[c]
        nc = 4 if faces[f, 3] >= 0 else 3
        for k in range(nc):
            a = faces[f, k]
            b = faces[f, (k + 1) % nc]
            n = pieces[c, k]
            if n > 1:
                s, e = (a, b) if _first_end(vertices, a, b) else (b, a)
                h = (s * 1000003 + e) & (size_table - 1)
                while key_s[h] >= 0 and not (key_s[h] == s and key_e[h] == e):
                    h = (h + 1) & (size_table - 1)
                if key_s[h] < 0:
                    key_s[h] = s
                    key_e[h] = e
                    value[h] = n_v + used
                    for j in range(1, n):
                        t = j / n
                        new_xy[used, 0] = vertices[s, 0] + t * (vertices[e, 0] - vertices[s, 0])
                        new_xy[used, 1] = vertices[s, 1] + t * (vertices[e, 1] - vertices[s, 1])
                        new_ends[used, 0] = s
                        new_ends[used, 1] = e
                        new_t[used] = t
                        used += 1
    out = empty((n_tris, 4), dtype=np.int64)
    parent = empty(n_tris, dtype=np.int64)
    px = empty(most)
    py = empty(most)
    ids = empty(most, dtype=np.int64)
    edge = empty(most, dtype=np.int64)
    corner = empty(most, dtype=np.bool_)
    tris = empty((larger(most - 2, 1), 3), dtype=np.int64)
    m_out = 0
    failed = 0
    for c in range(cut.shape[0]):
        f = cut[c]
        nc = 4 if faces[f, 3] >= 0 else 3
        m = 0
        for k in range(nc):
            a = faces[f, k]
            b = faces[f, (k + 1) % nc]
            ids[m] = a
            px[m] = vertices[a, 0]
            py[m] = vertices[a, 1]
            edge[m] = k
            corner[m] = True
            m += 1
            n = pieces[c, k]
            if n > 1:
                forward = _first_end(vertices, a, b)
                s, e = (a, b) if forward else (b, a)
                h = (s * 1000003 + e) & (size_table - 1)
                while not (key_s[h] == s and key_e[h] == e):
                    h = (h + 1) & (size_table - 1)
                base = value[h]
                for j in range(1, n):
                    q = base + (j - 1 if forward else n - 1 - j)
                    ids[m] = q
                    px[m] = new_xy[q - n_v, 0]
                    py[m] = new_xy[q - n_v, 1]
                    edge[m] = k
                    corner[m] = False
                    m += 1
        count = _cut_face(px, py, ids, edge, corner, m, nc, tris)
        if count < 0:
            failed += 1
            count = 0
        for t in range(count):
            out[m_out, 0] = tris[t, 0]
            out[m_out, 1] = tris[t, 1]
            out[m_out, 2] = tris[t, 2]
            out[m_out, 3] = -1
            parent[m_out] = f
            m_out += 1
    return new_xy[:used].copy(), new_ends[:used].copy(), new_t[:used].copy(), out[:m_out], parent[:m_out], failed


def refine_long_faces(mesh: Mesh, spacing: float, longer_than: float, piece: float) -> Refinement:
    """The mesh with every edge over ``longer_than * spacing`` split into pieces of
    at most ``piece * spacing`` (at most :data:`MAX_PIECES` of them), and the faces with a split edge cut into
    triangles (see :class:`Refinement`).  A mesh with no long edge comes back
    as it is (``.mesh is mesh``).

    Examples
    --------
    >>> import numpy as np
    >>> square = Mesh(np.array([[0.0, 0.0], [9.0, 0.0], [9.0, 1.0], [0.0, 1.0]]), np.array([[0, 1, 2, 3]]), np.arange(4))
    >>> cut = refine_long_faces(square, 1.0, 4.0, 3.0)
    >>> cut.mesh.vertices[4:].tolist(), cut.t.round(3).tolist(), cut.parent.tolist()
    ([[3.0, 0.0], [6.0, 0.0], [3.0, 1.0], [6.0, 1.0]], [0.333, 0.667, 0.333, 0.667], [0, 0, 0, 0, 0, 0])
    """
    if not (isinstance(spacing, (int, float)) and math.isfinite(spacing) and spacing > 0.0):
        raise InvalidInputError(f"spacing must be a finite number > 0, got {spacing!r}")
    if not (math.isfinite(longer_than) and longer_than >= piece > 0.0):
        raise InvalidInputError(f"need longer_than >= piece > 0, got {longer_than!r}, {piece!r}")
    vertices, faces = mesh_arrays(mesh)
    longest = float(longer_than * spacing)
    cut = _long_faces(vertices, faces, longest)
    if cut.size == 0:
        return Refinement(mesh, np.arange(faces.shape[0]), np.empty((0, 2), dtype=np.int64), np.empty(0))
    new_xy, ends, t, out, parent, failed = _refine_kernel(vertices, faces, cut, longest, float(piece * spacing))
    if failed:
        raise InvalidInputError(f"{failed} faces could not be cut (flat)")
    refined_faces, parents = with_cut_faces(faces, out, parent)
    refined = Mesh(np.concatenate([vertices, new_xy]), refined_faces, mesh.input_to_vertex,
                   mesh.triangle_measure, mesh.quad_measure, mesh.merge, mesh.window, mesh.window_escapes)
    return Refinement(refined, parents, ends, t)


def with_cut_faces(rows: NDArray, cut_rows: NDArray, parent: NDArray[np.int64]) -> tuple[NDArray, NDArray[np.int64]]:
    """Per-face ``rows`` of a mesh (its faces, their nodes, ...) with the rows of
    its cut faces' triangles placed as a :class:`Refinement` places them: each
    face cut keeps its row for its first triangle, the others follow.

    ``cut_rows`` are grouped by their face ``parent``, a face's first triangle
    first (as :func:`cut_face_rows` gives them back).  Returns the rows and
    each one's face.

    >>> faces = np.array([[0, 1, 2, 3], [1, 4, 2, -1]])
    >>> out, parent = with_cut_faces(faces, np.array([[0, 1, 3, -1], [1, 2, 3, -1]]), np.array([0, 0]))
    >>> out.tolist(), parent.tolist()
    ([[0, 1, 3, -1], [1, 4, 2, -1], [1, 2, 3, -1]], [0, 1, 0])
    """
    n_f = rows.shape[0]
    first = np.ones(parent.size, dtype=bool)
    first[1:] = parent[1:] != parent[:-1]
    n_extra = int(np.count_nonzero(~first))
    out = np.empty((n_f + n_extra, *rows.shape[1:]), dtype=rows.dtype)
    out[:n_f] = rows
    out[parent[first]] = cut_rows[first]
    out[n_f:] = cut_rows[~first]
    parents = np.empty(n_f + n_extra, dtype=np.int64)
    parents[:n_f] = np.arange(n_f)
    parents[n_f:] = parent[~first]
    return out, parents


def cut_face_rows(parent: NDArray[np.int64], n_faces: int) -> NDArray[np.int64]:
    """The rows of a :class:`Refinement`'s cut triangles (``parent``: each row's
    face, ``n_faces`` faces before it was cut), grouped by face, each face's
    first triangle (its own row) first: what :func:`with_cut_faces` takes.

    >>> cut_face_rows(np.array([0, 1, 2, 0, 2, 2]), 3).tolist()
    [0, 3, 2, 4, 5]
    """
    extra = parent[n_faces:]
    cut = np.unique(extra)  # the faces cut: each has a triangle or more beyond its own row
    order = np.argsort(np.concatenate([cut, extra]), kind="stable")
    return np.concatenate([cut, n_faces + np.arange(extra.size)])[order]
