"""Natural-neighbour coordinates of places far from every point: the smooth surface's fill of voids.

Kriging from the points nearest a place in a void (under a building, over
water, in a scan shadow) reads one side of the void's rim only, and its
linear drift carries that side's tilt across the void (:mod:`meshcore.smooth`).
Natural-neighbour interpolation reads the whole rim.  The natural neighbours
of a place ``q`` are the points it would be joined to in the Delaunay
triangulation, were it a point: the corners of the triangles whose
circumcircles hold ``q`` (the *cavity*), in order around it (its *star*).
Their Sibson coordinates weigh each neighbour ``x`` by the area of the
Voronoi cell ``q`` would take from ``x``'s, over the area of ``q``'s cell.
That share is a polygon bounded by the Voronoi edge ``q`` would share with
``x`` (from the circumcentre of the star's triangle before ``x`` to that of
the one after it) and by ``x``'s old Voronoi edges inside ``q``'s cell
(through the circumcentres of the cavity's triangles around ``x``).  The
weights are positive, so a value lies within the range of the neighbours'
(no ring, no bowl); they reproduce linear functions; and the interpolant
is smooth away from the points and does not depend on how a triangulation
cuts a void.  (Laplace's coordinates, by the lengths of the Voronoi edges
alone, cost less, but their interpolant creases along the Delaunay circles:
arcs across a void in a hillshade.)  :func:`natural_coordinates` also gives
the Delaunay triangle that holds each place, one of the cavity's.

Which points a place's coordinates read: the star's triangles, when their
circles hold no point, are the place's triangles in the Delaunay
triangulation of the points and the place, and they alone give its
coordinates.  :func:`natural_coordinates` triangulates the points around the
places only, and takes more until every circle of every place is empty (a
disk around the place that holds them all, each point of it taken; or,
where a circle reaches far, as beside the hull, each circle on its own).
Those disks are returned: a piece of a survey that holds every point inside
them gets the survey's star (ties broken by
:func:`meshcore.predicates.incircle_sos`, as the triangulation breaks them),
and computes the same coordinates, to the bit: each from the neighbours in
one order (counter-clockwise from the first in coordinate order), in
coordinates relative to the place.  A place on the line of an edge of the
hull (to rounding) has no star; it gets no coordinates, and reads the side
beyond the edge (:data:`_FAR`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ._buckets import _bucket_grid
from ._jit import empty, full, larger, njit, njit_helper, smaller, zeros
from .delaunay import _locate, _walk, delaunay
from .predicates import incircle_sos, lex_before, orient2d

__all__ = ["NaturalCoordinates", "natural_coordinates", "natural_values", "natural_ranges", "tin_values", "take_places",
           "join_places"]


class NaturalCoordinates(NamedTuple):
    """The natural-neighbour coordinates of some places (:func:`natural_coordinates`).

    Attributes
    ----------
    first : (q + 1,) int64, place ``i``'s neighbours are ``index[first[i]:first[i + 1]]`` (none: no coordinates)
    index : (m,) int64, the points, counter-clockwise around each place from the first in coordinate order
    weight : (m,) float64, their weights (positive, summing to 1 for each place)
    disks : (c, 3) float64, rows ``(x, y, r)``: the closed disks the coordinates read points from
    owner : (c,) int64, the place each disk is read for (ascending)
    triangle : (q, 3) int64, the Delaunay triangle that holds each place with coordinates (-1: none)
    linear : (q, 3) float64, the linear interpolant's weights of its corners there (the TIN's)
    """

    first: NDArray[np.int64]
    index: NDArray[np.int64]
    weight: NDArray[np.float64]
    disks: NDArray[np.float64]
    owner: NDArray[np.int64]
    triangle: NDArray[np.int64]
    linear: NDArray[np.float64]


_MAX_ROUNDS = 12
"""Triangulations of the points around the places tried before all the points are taken."""

_ALL_POINTS = 0.3
"""When the points around the places are more than this share of all, all are taken at once."""


@njit_helper
def _grown(a: np.ndarray, need: int) -> np.ndarray:
    """``a`` (1-d) with room for at least ``need`` items, its items kept."""
    if a.shape[0] >= need:
        return a
    out = empty(larger(2 * a.shape[0], need), dtype=a.dtype)
    for i in range(a.shape[0]):
        out[i] = a[i]
    return out


@njit_helper
def _grown_rows(a: np.ndarray, need: int) -> np.ndarray:
    """``a`` (rows of 3) with room for at least ``need`` rows, its rows kept."""
    if a.shape[0] >= need:
        return a
    out = empty((larger(2 * a.shape[0], need), 3), dtype=np.int64)
    for i in range(a.shape[0]):
        for k in range(3):
            out[i, k] = a[i, k]
    return out


@njit
def _mark_within_kernel(sxy: np.ndarray, items: np.ndarray, x0: float, y0: float, cell: float, nbx: int, nby: int,
                        start: np.ndarray, centres: np.ndarray, radius: np.ndarray, left: np.ndarray,
                        left_block: np.ndarray, skip: np.ndarray, mark: np.ndarray, hit: np.ndarray,
                        marking: bool, limit: int) -> bool:
    """For every disk ``(centres[s], radius[s])``: ``mark[p] = True`` for the points
    ``p`` of the bucket grid within it that are not ``skip``, and ``hit[s]``
    whether there was one (only ``mark`` when ``marking``, until ``limit`` points
    are marked (-1: no limit); returns whether it stopped there).  ``left[b]``: how many
    points of bucket ``b`` are not ``skip`` (a bucket with none is passed over),
    ``left_block``: of each block of buckets (:func:`_left_kernel`)."""
    px = math.nan
    py = math.nan
    pr = -1.0
    marked = 0
    for s in range(centres.shape[0]):
        cx = centres[s, 0]
        cy = centres[s, 1]
        r = radius[s]
        r2 = r * r
        hit[s] = False
        if (s > 0 and (marking or not hit[s - 1])
                and math.sqrt((cx - px) * (cx - px) + (cy - py) * (cy - py)) + r < pr * (1.0 - 1e-12)):
            # inside the disk before (the places come cell by cell): its points are marked, and
            # it held none not ``skip``, or only ``mark`` is wanted
            continue
        px = cx
        py = cy
        pr = r
        i_lo = larger(np.int64(math.floor(larger((cx - r - x0) / cell, -1.0))) - 1, 0)
        i_hi = smaller(np.int64(math.floor(smaller((cx + r - x0) / cell, nbx + 1.0))) + 1, nbx - 1)
        j_lo = larger(np.int64(math.floor(larger((cy - r - y0) / cell, -1.0))) - 1, 0)
        j_hi = smaller(np.int64(math.floor(smaller((cy + r - y0) / cell, nby + 1.0))) + 1, nby - 1)
        # blocks of _BLOCK x _BLOCK buckets first: those with no point left are passed over whole
        nbx_b = (nbx + _BLOCK - 1) // _BLOCK
        for jb in range(j_lo // _BLOCK, j_hi // _BLOCK + 1):
            for ib in range(i_lo // _BLOCK, i_hi // _BLOCK + 1):
                if left_block[jb * nbx_b + ib] == 0:
                    continue
                for j in range(larger(j_lo, jb * _BLOCK), smaller(j_hi, jb * _BLOCK + _BLOCK - 1) + 1):
                    for i in range(larger(i_lo, ib * _BLOCK), smaller(i_hi, ib * _BLOCK + _BLOCK - 1) + 1):
                        b = j * nbx + i
                        if left[b] == 0:
                            continue
                        for t in range(start[b], start[b + 1]):
                            p = items[t]
                            if skip[p]:
                                continue
                            dx = sxy[t, 0] - cx
                            dy = sxy[t, 1] - cy
                            if dx * dx + dy * dy <= r2:
                                if not mark[p]:
                                    marked += 1
                                    if marked == limit:
                                        return True
                                mark[p] = True
                                hit[s] = True
    return False


_BLOCK = 8
"""Buckets a side of the blocks :func:`_mark_within_kernel` passes over when they have no point left."""


@njit
def _left_kernel(items: np.ndarray, start: np.ndarray, nbx: int, skip: np.ndarray, out: np.ndarray,
                 out_block: np.ndarray) -> None:
    """``out[b]``: how many points of bucket ``b`` are not ``skip``; ``out_block``: of each block."""
    nbx_b = (nbx + _BLOCK - 1) // _BLOCK
    for k in range(out_block.shape[0]):
        out_block[k] = 0
    for b in range(start.shape[0] - 1):
        count = 0
        for t in range(start[b], start[b + 1]):
            if not skip[items[t]]:
                count += 1
        out[b] = count
        out_block[((b // nbx) // _BLOCK) * nbx_b + (b % nbx) // _BLOCK] += count


@njit_helper
def _cavity(gx: np.ndarray, gy: np.ndarray, tri: np.ndarray, he: np.ndarray, px: float, py: float, t0: int, q: int,
            stamp: np.ndarray, seen: np.ndarray, stack: np.ndarray, cavity: np.ndarray) -> int:
    """The triangles whose circumcircle holds ``p`` (``incircle_sos`` > 0), found from
    ``t0`` (which holds ``p``) across their edges, into ``cavity``; ``stamp[t] == q`` marks them.
    Returns their number, 0 when ``t0``'s own circle does not hold ``p`` (degenerate)."""
    a = tri[3 * t0]
    b = tri[3 * t0 + 1]
    c = tri[3 * t0 + 2]
    seen[t0] = q
    if incircle_sos(gx[a], gy[a], gx[b], gy[b], gx[c], gy[c], px, py) <= 0:
        return 0
    stamp[t0] = q
    n_stack = 1
    stack[0] = t0
    count = 0
    while n_stack > 0:
        n_stack -= 1
        t = stack[n_stack]
        cavity[count] = t
        count += 1
        for k in range(3):
            f = he[3 * t + k]
            if f < 0:
                continue
            u = f // 3
            if seen[u] == q:
                continue
            seen[u] = q
            a = tri[3 * u]
            b = tri[3 * u + 1]
            c = tri[3 * u + 2]
            if incircle_sos(gx[a], gy[a], gx[b], gy[b], gx[c], gy[c], px, py) > 0:
                stamp[u] = q
                stack[n_stack] = u
                n_stack += 1
    return count


@njit_helper
def _canonical(gx: np.ndarray, gy: np.ndarray, a: int, b: int, c: int) -> tuple[int, int, int]:
    """Triangle ``a b c`` from its first corner in coordinate order, turning the same way."""
    if lex_before(gx[b], gy[b], gx[a], gy[a]) and lex_before(gx[b], gy[b], gx[c], gy[c]):
        return b, c, a
    if lex_before(gx[c], gy[c], gx[a], gy[a]) and lex_before(gx[c], gy[c], gx[b], gy[b]):
        return c, a, b
    return a, b, c


@njit_helper
def _centre(gx: np.ndarray, gy: np.ndarray, a: int, b: int, c: int, px: float, py: float) -> tuple[float, float]:
    """The circumcentre of triangle ``a b c`` relative to ``p``, from its first corner in
    coordinate order: the same bits whichever corner a triangulation lists first."""
    a, b, c = _canonical(gx, gy, a, b, c)
    ax = gx[a] - px
    ay = gy[a] - py
    dx = gx[b] - gx[a]
    dy = gy[b] - gy[a]
    ex = gx[c] - gx[a]
    ey = gy[c] - gy[a]
    d = 2.0 * (dx * ey - dy * ex)
    return (ax + (ey * (dx * dx + dy * dy) - dy * (ex * ex + ey * ey)) / d,
            ay + (dx * (ex * ex + ey * ey) - ex * (dx * dx + dy * dy)) / d)


@njit_helper
def _triangle_before(gx: np.ndarray, gy: np.ndarray, tri: np.ndarray, t: int, u: int) -> bool:
    """Whether triangle ``t`` comes before ``u`` in coordinate order of their corners (canonically turned)."""
    ta = _canonical(gx, gy, tri[3 * t], tri[3 * t + 1], tri[3 * t + 2])
    ua = _canonical(gx, gy, tri[3 * u], tri[3 * u + 1], tri[3 * u + 2])
    for k in range(3):
        if ta[k] != ua[k]:
            return lex_before(gx[ta[k]], gy[ta[k]], gx[ua[k]], gy[ua[k]])
    return False


@njit_helper
def _linear_weights(gx: np.ndarray, gy: np.ndarray, a: int, b: int, c: int, px: float, py: float, ids: np.ndarray,
                    corners: np.ndarray, weights: np.ndarray) -> None:
    """The linear interpolant's weights at ``p`` of triangle ``a b c``'s corners (``ids``), canonically turned."""
    a, b, c = _canonical(gx, gy, a, b, c)
    ax = gx[a] - px
    ay = gy[a] - py
    bx = gx[b] - px
    by = gy[b] - py
    cx = gx[c] - px
    cy = gy[c] - py
    wa = bx * cy - by * cx
    wb = cx * ay - cy * ax
    wc = ax * by - ay * bx
    total = wa + wb + wc
    corners[0] = ids[a]
    corners[1] = ids[b]
    corners[2] = ids[c]
    weights[0] = wa / total
    weights[1] = wb / total
    weights[2] = wc / total


@njit
def _coordinates_kernel(gx: np.ndarray, gy: np.ndarray, ids: np.ndarray, tri: np.ndarray, he: np.ndarray,
                        places: np.ndarray, near: np.ndarray, cap: np.ndarray):
    """The Sibson coordinates of every place in the triangulation ``tri, he`` of the
    points ``(gx, gy)`` (``ids``: their numbers in the caller's points), each
    found from a triangle of its point ``near[i]`` (a vertex of the
    triangulation, or -1).

    Returns ``first, index, weight, status, reach, circles, corners, linear``: per
    place its neighbours (``ids``) and weights, its status (0: done, 1: outside
    the triangulation, 2: degenerate: on the line of a hull edge, to rounding),
    how far the circles of the triangles it would make with its natural
    neighbours, were it a point, reach from it, and, for each place whose circles reach
    farther than ``cap`` (or that lies beyond the hull), those triangles as rows
    ``(place, a, b)`` (counter-clockwise), and the corners (``ids``) and linear
    weights of the triangle holding each place (-1 and NaN where it has none).
    """
    n_q = places.shape[0]
    n_t = tri.shape[0] // 3
    n_v = gx.shape[0]
    stamp = full(n_t, -1, dtype=np.int64)
    seen = full(n_t, -1, dtype=np.int64)
    room = larger(n_t, 1)
    stack = empty(room, dtype=np.int64)
    cavity = empty(room, dtype=np.int64)
    # the cavity's boundary edges: start, end, their half-edge
    b_start = empty(room, dtype=np.int64)
    b_end = empty(room, dtype=np.int64)
    b_edge = empty(room, dtype=np.int64)
    edge_of = full(larger(n_v, 1), -1, dtype=np.int64)
    edge_stamp = full(larger(n_v, 1), -1, dtype=np.int64)
    ring = empty(room, dtype=np.int64)
    ring_edge = empty(room, dtype=np.int64)
    # the cavity's triangles' circumcentres, relative to the place
    tcx = empty(room)
    tcy = empty(room)
    ux = empty(room)
    uy = empty(room)
    lam = empty(room)
    ox = empty(room)
    oy = empty(room)
    first = zeros(n_q + 1, dtype=np.int64)
    index = empty(larger(8 * n_q, 16), dtype=np.int64)
    weight = empty(larger(8 * n_q, 16))
    status = zeros(n_q, dtype=np.int8)
    reach = full(n_q, math.inf)
    corners = full((n_q, 3), -1, dtype=np.int64)
    linear = full((n_q, 3), math.nan)
    circles = empty((16, 3), dtype=np.int64)
    n_circles = 0
    # a triangle of every vertex, where the walk to a place near it starts
    corner_of = full(larger(n_v, 1), 0, dtype=np.int64)
    for e in range(tri.shape[0]):
        corner_of[tri[e]] = e // 3
    n_out = 0
    start = 0
    state = 12345
    for q in range(n_q):
        first[q] = n_out
        px = places[q, 0]
        py = places[q, 1]
        if n_t == 0:
            status[q] = 1
            continue
        if near[q] >= 0:
            start = corner_of[near[q]]
        t0, state, e = _walk(tri, he, gx, gy, px, py, start, state)
        if t0 == -2:
            t0, state = _locate(tri, he, gx, gy, px, py, start, state)
        if t0 < 0:
            # beyond the hull's edge ``e`` (a place on it, rounded out): read, as on it, beyond that edge
            status[q] = 1
            if e >= 0:
                circles = _grown_rows(circles, n_circles + 1)
                circles[n_circles, 0] = q
                circles[n_circles, 1] = tri[e]
                circles[n_circles, 2] = tri[3 * (e // 3) + (e % 3 + 1) % 3]
                n_circles += 1
            continue
        start = t0
        count = _cavity(gx, gy, tri, he, px, py, t0, q, stamp, seen, stack, cavity)
        if count == 0:
            status[q] = 2
            continue
        # its boundary, counter-clockwise around the place
        m = 0
        for i in range(count):
            t = cavity[i]
            for k in range(3):
                e = 3 * t + k
                f = he[e]
                if f >= 0 and stamp[f // 3] == q:
                    continue
                a = tri[e]
                if edge_stamp[a] == q:  # a point twice on the boundary: not a star around the place
                    m = -1
                    break
                b_start[m] = a
                b_end[m] = tri[3 * t + (k + 1) % 3]
                b_edge[m] = e
                edge_stamp[a] = q
                edge_of[a] = m
                m += 1
            if m < 0:
                break
        if m < 3:
            status[q] = 2
            continue
        # from the first point in coordinate order, so that every piece takes them alike
        lead = 0
        for i in range(1, m):
            a = b_start[i]
            c = b_start[lead]
            if lex_before(gx[a], gy[a], gx[c], gy[c]):
                lead = i
        i = lead
        closed = True
        for s in range(m):
            if s > 0 and i == lead:  # back at the start early: two loops
                closed = False
                break
            ring[s] = b_start[i]
            ring_edge[s] = b_edge[i]
            nxt = b_end[i]
            if edge_stamp[nxt] != q:
                closed = False
                break
            i = edge_of[nxt]
        if not closed or i != lead:
            status[q] = 2
            continue
        # the triangles the place would make with each boundary edge, counter-clockwise:
        # centre s is that of (place, ring[s], ring[s + 1]), relative to the place
        for s in range(m):
            ux[s] = gx[ring[s]] - px
            uy[s] = gy[ring[s]] - py
        flat = False
        far = 0.0
        for s in range(m):
            j = (s + 1) % m
            d = 2.0 * (ux[s] * uy[j] - uy[s] * ux[j])
            if not d > 0.0:  # the place on the line of an edge of the hull (or as near as rounding tells)
                flat = True
                ox[s] = math.nan
                oy[s] = math.nan
                far = math.inf
                continue
            ls = ux[s] * ux[s] + uy[s] * uy[s]
            lj = ux[j] * ux[j] + uy[j] * uy[j]
            ox[s] = (uy[j] * ls - uy[s] * lj) / d
            oy[s] = (ux[s] * lj - ux[j] * ls) / d
            # how far its circle reaches from the place: to the centre and on, by the
            # farthest of its three points from the centre (against the centre's rounding)
            r2 = larger(ox[s] * ox[s] + oy[s] * oy[s], larger((ox[s] - ux[s]) ** 2 + (oy[s] - uy[s]) ** 2,
                                                               (ox[s] - ux[j]) ** 2 + (oy[s] - uy[j]) ** 2))
            far = larger(far, math.sqrt(ox[s] * ox[s] + oy[s] * oy[s]) + math.sqrt(r2))
        # these circles are the place's Delaunay triangles, were it a point, when
        # no point lies in them: they alone give its natural neighbours.  Near,
        # they are read as one disk around the place; far (beside the hull) each
        # on its own, as most of a far one lies beyond the hull
        far = far * (1.0 + 1e-9) + 1e-12 * (abs(px) + abs(py))
        reach[q] = far
        if not far <= cap[q]:
            circles = _grown_rows(circles, n_circles + m)
            for s in range(m):
                circles[n_circles, 0] = q
                circles[n_circles, 1] = ring[s]
                circles[n_circles, 2] = ring[(s + 1) % m]
                n_circles += 1
        if flat:
            status[q] = 2
            continue
        # the triangle that holds the place, the one first in coordinate order where
        # two do (the place on their edge), and its linear weights
        t_in = t0
        for k in range(3):
            a = tri[3 * t0 + k]
            b = tri[3 * t0 + (k + 1) % 3]
            f = he[3 * t0 + k]
            if f >= 0 and orient2d(gx[a], gy[a], gx[b], gy[b], px, py) == 0:
                if _triangle_before(gx, gy, tri, f // 3, t_in):
                    t_in = f // 3
        _linear_weights(gx, gy, tri[3 * t_in], tri[3 * t_in + 1], tri[3 * t_in + 2], px, py, ids, corners[q], linear[q])
        # Sibson's coordinates: the area of the cell the place would take from each
        # neighbour s, bounded by its new Voronoi edge (from centre s - 1 to centre
        # s) and the old Voronoi vertices of the cavity's triangles around s
        for i in range(count):
            t = cavity[i]
            x, y = _centre(gx, gy, tri[3 * t], tri[3 * t + 1], tri[3 * t + 2], px, py)
            tcx[t] = x
            tcy[t] = y
        total = 0.0
        good = True
        for s in range(m):
            p = (s + m - 1) % m
            # the polygon c(s - 1), c(s), then the cavity's centres around s back to the edge from s - 1
            x0, y0 = ox[p], oy[p]
            x1, y1 = ox[s], oy[s]
            area = x0 * y1 - x1 * y0
            e = ring_edge[s]
            steps = 0
            while True:
                t = e // 3
                area += x1 * tcy[t] - tcx[t] * y1
                x1, y1 = tcx[t], tcy[t]
                back = 3 * t + (e % 3 + 2) % 3  # the half-edge into s in this triangle
                f = he[back]
                steps += 1
                if f < 0 or stamp[f // 3] != q or steps > count:
                    break
                e = f
            area += x1 * y0 - x0 * y1
            lam[s] = 0.5 * area
            if not lam[s] >= -1e-9 * abs(area) - 1e-300:
                good = False
            total += lam[s]
        if not (good and total > 0.0 and math.isfinite(total)):
            status[q] = 2
            continue
        for s in range(m):
            lam[s] = larger(lam[s], 0.0)
        index = _grown(index, n_out + m)
        weight = _grown(weight, n_out + m)
        for s in range(m):
            index[n_out + s] = ids[ring[s]]
            weight[n_out + s] = lam[s] / total
        n_out += m
    first[n_q] = n_out
    index = index[:n_out].copy()
    weight = weight[:n_out].copy()
    return first, index, weight, status, reach, circles[:n_circles].copy(), corners, linear


_FAR = 1e6
"""A place on the line of a hull edge (to rounding) reads the side beyond the edge
up to this many times its distances to the edge's ends (a disk touching the
line there): a survey has no point farther along that side that would make
the edge one of its inner edges."""


@njit_helper
def _star_disk(qx: float, qy: float, ax: float, ay: float, bx: float, by: float) -> tuple[float, float, float, bool]:
    """A closed disk ``(x, y, r)`` holding the circle through the place ``q`` and the
    points ``a, b`` (counter-clockwise), and whether it is flat (the place on the
    line ``a b`` to rounding: then the disk beyond ``a b`` of :data:`_FAR`)."""
    ux = ax - qx
    uy = ay - qy
    vx = bx - qx
    vy = by - qy
    d = 2.0 * (ux * vy - uy * vx)
    if d > 0.0:
        lu = ux * ux + uy * uy
        lv = vx * vx + vy * vy
        ox = (vy * lu - uy * lv) / d
        oy = (ux * lv - vx * lu) / d
        r2 = larger(ox * ox + oy * oy, larger((ox - ux) ** 2 + (oy - uy) ** 2, (ox - vx) ** 2 + (oy - vy) ** 2))
        r = math.sqrt(r2) * (1.0 + 1e-9) + 1e-12 * (abs(qx) + abs(qy))
        if math.isfinite(r) and math.isfinite(ox) and math.isfinite(oy):
            return qx + ox, qy + oy, r, False
    # beyond the edge, outwards (right of a -> b): touching the line at the edge's middle
    ex = bx - ax
    ey = by - ay
    length = math.sqrt(ex * ex + ey * ey)
    far = _FAR * (math.sqrt(ux * ux + uy * uy) + math.sqrt(vx * vx + vy * vy))
    mx = 0.5 * (ax + bx)
    my = 0.5 * (ay + by)
    return mx + far * ey / length, my - far * ex / length, (far + length) * (1.0 + 1e-9), True


@njit
def _star_disks_kernel(places: np.ndarray, points: np.ndarray, rows: np.ndarray, out: np.ndarray,
                       flat: np.ndarray) -> None:
    """:func:`_star_disk` of every row ``(place, a, b)``."""
    for s in range(rows.shape[0]):
        q = rows[s, 0]
        a = rows[s, 1]
        b = rows[s, 2]
        x, y, r, f = _star_disk(places[q, 0], places[q, 1], points[a, 0], points[a, 1], points[b, 0], points[b, 1])
        out[s, 0] = x
        out[s, 1] = y
        out[s, 2] = r
        flat[s] = f


@njit
def _intruders_kernel(sxy: np.ndarray, items: np.ndarray, x0: float, y0: float, cell: float, nbx: int, nby: int,
                      start: np.ndarray, left: np.ndarray, left_block: np.ndarray, places: np.ndarray,
                      points: np.ndarray, rows: np.ndarray, disks: np.ndarray, flat: np.ndarray, taken: np.ndarray,
                      found: np.ndarray, hit: np.ndarray) -> None:
    """For every row ``(place, a, b)``: ``found[p] = True`` for the points ``p`` not
    ``taken`` inside its circle (``incircle_sos`` of the place, ``a`` and ``b``;
    for a flat one, beyond the line ``a b`` within its disk), and ``hit[s]``
    whether there was one.  ``disks`` (:func:`_star_disk`) bound the circles;
    ``left`` and ``left_block`` count the points not taken (:func:`_left_kernel`)."""
    for s in range(rows.shape[0]):
        hit[s] = False
        q = rows[s, 0]
        qx = places[q, 0]
        qy = places[q, 1]
        ax = points[rows[s, 1], 0]
        ay = points[rows[s, 1], 1]
        bx = points[rows[s, 2], 0]
        by = points[rows[s, 2], 1]
        cx = disks[s, 0]
        cy = disks[s, 1]
        r = disks[s, 2]
        i_lo = larger(np.int64(math.floor(larger((cx - r - x0) / cell, -1.0))) - 1, 0)
        i_hi = smaller(np.int64(math.floor(smaller((cx + r - x0) / cell, nbx + 1.0))) + 1, nbx - 1)
        j_lo = larger(np.int64(math.floor(larger((cy - r - y0) / cell, -1.0))) - 1, 0)
        j_hi = smaller(np.int64(math.floor(smaller((cy + r - y0) / cell, nby + 1.0))) + 1, nby - 1)
        margin = 1e-6 * cell
        nbx_b = (nbx + _BLOCK - 1) // _BLOCK
        # a circle far larger than its edge a b (the place near the line a b, beside
        # the hull) lies beyond the line but for a lens of height under
        # length^2 / (4 r): each row of buckets is read only where it meets that side
        ex = bx - ax
        ey = by - ay
        length = math.sqrt(ex * ex + ey * ey)
        wide = flat[s] or r > 8.0 * length
        nx = ey / length if length > 0.0 else 0.0
        ny = -ex / length if length > 0.0 else 0.0
        lens = (length * length / (2.0 * r) if not flat[s] else 0.0) + 1e-9 * (abs(ax) + abs(ay) + length) + margin
        for j in range(j_lo, j_hi + 1):
            row_lo = i_lo
            row_hi = i_hi
            if wide and length > 0.0:
                # n . (p - a) >= -lens for some y of the row
                g0 = -lens - ny * ((y0 + j * cell - margin) - ay)
                g1 = -lens - ny * ((y0 + (j + 1) * cell + margin) - ay)
                g = smaller(g0, g1)
                if abs(nx) < 1e-12:
                    if g > 0.0:
                        continue
                elif nx > 0.0:
                    row_lo = larger(row_lo, np.int64(math.floor(larger((ax + g / nx - x0) / cell, -1.0))) - 1)
                else:
                    row_hi = smaller(row_hi, np.int64(math.floor(smaller((ax + g / nx - x0) / cell, nbx + 1.0))) + 1)
            for i in range(row_lo, row_hi + 1):
                if left_block[(j // _BLOCK) * nbx_b + i // _BLOCK] == 0:
                    continue
                b = j * nbx + i
                if left[b] == 0:
                    continue
                # the bucket's box against the disk
                dx = larger(larger((x0 + i * cell - margin) - cx, cx - (x0 + (i + 1) * cell + margin)), 0.0)
                dy = larger(larger((y0 + j * cell - margin) - cy, cy - (y0 + (j + 1) * cell + margin)), 0.0)
                if dx * dx + dy * dy > r * r:
                    continue
                for t in range(start[b], start[b + 1]):
                    p = items[t]
                    if taken[p]:
                        continue
                    px = sxy[t, 0]
                    py = sxy[t, 1]
                    if flat[s]:
                        inside = (orient2d(ax, ay, bx, by, px, py) < 0
                                  and (px - cx) * (px - cx) + (py - cy) * (py - cy) <= r * r)
                    else:
                        inside = incircle_sos(qx, qy, ax, ay, bx, by, px, py) > 0
                    if inside:
                        found[p] = True
                        hit[s] = True


def natural_coordinates(
    points: NDArray[np.float64], places: NDArray[np.float64], reach: NDArray[np.float64], cap: NDArray[np.float64],
    near: NDArray[np.integer] | None = None,
) -> NaturalCoordinates:
    """The Sibson coordinates of ``places`` among ``points`` (see the module docstring), and
    the Delaunay triangle that holds each (``.triangle``, ``.linear``).

    A place outside the points' hull, or on the line of one of its edges to
    rounding, gets no coordinates (nor does one where the points around are
    too few or collinear).  A place's coordinates, and whether it has any,
    depend only on the points inside its rows of the disks returned: one disk
    around it when its circles reach no farther than ``cap[i]`` from it, each
    circle on its own when they do (as beside the hull, where most of a
    circle lies beyond it and a piece of a survey holds only the part inside),
    the disk of radius ``cap[i]`` around a place found in no star.

    ``reach``: how far around each place to take points for the first
    triangulation (any gives the same coordinates; the nearer to how far its
    circles reach, the fewer rounds).  ``near``: a point near each place (its
    nearest, say; -1: none), where the search for it starts.

    Examples
    --------
    >>> import numpy as np
    >>> square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    >>> nat = natural_coordinates(square, np.array([[1.0, 1.0]]), np.array([1.5]), np.array([5.0]))
    >>> nat.index.tolist(), nat.weight.round(6).tolist()
    ([0, 1, 2, 3], [0.25, 0.25, 0.25, 0.25])
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    places = np.ascontiguousarray(places, dtype=np.float64)
    cap = np.ascontiguousarray(cap, dtype=np.float64)
    n_q = places.shape[0]
    near = np.full(n_q, -1, dtype=np.int64) if near is None else np.asarray(near, dtype=np.int64)
    if n_q == 0 or points.shape[0] < 3:
        return NaturalCoordinates(np.zeros(n_q + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0),
                                  np.column_stack([places, cap]) if n_q else np.empty((0, 3)), np.arange(n_q),
                                  np.full((n_q, 3), -1, dtype=np.int64), np.full((n_q, 3), np.nan))
    grid = _bucket_grid(points)

    def counts(skip: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """How many points not ``skip`` each bucket and each block of buckets holds."""
        left = np.empty(grid.start.size - 1, dtype=np.int64)
        left_block = np.empty(-(-grid.nbx // _BLOCK) * -(-grid.nby // _BLOCK), dtype=np.int64)
        _left_kernel(grid.items, grid.start, grid.nbx, skip, left, left_block)
        return left, left_block

    def within(rows: NDArray[np.int64], radius: NDArray[np.float64], skip: NDArray[np.bool_],
               mark: NDArray[np.bool_], marking: bool = False, limit: int = -1):
        """Marks the points not ``skip`` within ``radius`` of the places ``rows``; which of
        them had one (``marking``: whether ``limit`` points were marked, and then stops)."""
        hit = np.empty(rows.size, dtype=bool)
        left, left_block = counts(skip)
        full_ = _mark_within_kernel(grid.sxy, grid.items, grid.x0, grid.y0, grid.cell, grid.nbx, grid.nby, grid.start,
                                    np.ascontiguousarray(places[rows]), np.ascontiguousarray(radius), left, left_block,
                                    skip, mark, hit, marking, limit)
        return full_ if marking else hit

    taken = np.zeros(points.shape[0], dtype=bool)
    reach = np.minimum(np.asarray(reach, dtype=np.float64), cap)
    covered = reach.copy()  # how far around each place every point is taken
    limit = int(_ALL_POINTS * points.shape[0]) + 1
    if within(np.arange(n_q), covered, taken, taken, marking=True, limit=limit):
        taken[:] = True  # the places are everywhere: every point, in one round
        covered[:] = np.inf
    # how far a place read by its circles, or beside the hull of the points
    # taken, takes every point before its circles are checked one by one:
    # what lies beyond is then likely the survey's hull
    before = np.minimum(2.0 * reach, cap)
    # each place's result, kept once every point its disks hold is taken: a
    # place is done again only while a round finds a point it had not
    rounds = []
    read = np.zeros(n_q)  # the disk around each place it reads, or 0: its circles, each on its own
    triangle = np.full((n_q, 3), -1, dtype=np.int64)  # the Delaunay triangle holding each place
    linear = np.full((n_q, 3), np.nan)
    pending = np.arange(n_q)
    for round_ in range(_MAX_ROUNDS + 1):
        if round_ == _MAX_ROUNDS:
            taken[:] = True  # all of them: nothing is left to find
            covered[:] = np.inf
        ids = np.flatnonzero(taken)
        triangulation = delaunay(points[ids])
        ids = ids[triangulation.order]
        gx = np.ascontiguousarray(points[ids, 0])
        gy = np.ascontiguousarray(points[ids, 1])
        vertex_of = np.full(points.shape[0] + 1, -1, dtype=np.int64)  # the last: no point
        vertex_of[ids] = np.arange(ids.size)
        first, index, weight, status, reach_of, rows, tin_corners, tin_weights = _coordinates_kernel(
            gx, gy, ids, triangulation.triangles, triangulation.halfedges, np.ascontiguousarray(places[pending]),
            vertex_of[near[pending]], cap[pending])
        rows = np.column_stack([pending[rows[:, 0]], ids[rows[:, 1]], ids[rows[:, 2]]]) if rows.size else rows
        by_circles = np.zeros(n_q, dtype=bool)
        by_circles[rows[:, 0]] = True
        # outside the points taken with no edge of their hull before it, or
        # found in no star: farther each time, up to ``cap``
        lost = (status != 0) & ~by_circles[pending]
        grow = pending[lost & (covered[pending] >= before[pending])]
        before[grow] = np.minimum(2.0 * before[grow], cap[grow])
        short = np.zeros(n_q, dtype=bool)
        short[pending] = (by_circles[pending] | lost) & (covered[pending] < before[pending])
        # the disk around each place that it reads, or 0: its circles
        read[pending] = np.where(short[pending], before[pending], np.where(by_circles[pending], 0.0,
                              np.where(status == 0, reach_of, cap[pending])))
        disks = np.empty((rows.shape[0], 3))
        flat = np.empty(rows.shape[0], dtype=bool)
        _star_disks_kernel(places, points, rows, disks, flat)
        rounds.append((pending, first, index, weight, rows, disks))
        triangle[pending] = np.where(status[:, None] == 0, tin_corners, -1)
        linear[pending] = np.where(status[:, None] == 0, tin_weights, np.nan)
        if taken.all():
            break
        more = np.zeros(points.shape[0], dtype=bool)
        # a place whose disk lies within what was taken around it is done; one
        # short of points is done again, with them
        open_ = pending[read[pending] > covered[pending]]
        again = open_[within(open_, read[open_], taken, more)]
        covered[open_] = read[open_]
        again = np.union1d(again, pending[short[pending]])
        # one read by its circles is done when none holds a point not taken (a
        # circle within what was taken around its place holds none)
        owner_xy = places[rows[:, 0]]
        mine = ~short[rows[:, 0]] & (np.hypot(disks[:, 0] - owner_xy[:, 0], disks[:, 1] - owner_xy[:, 1]) + disks[:, 2]
                                     > covered[rows[:, 0]])
        checked = rows[mine]
        hit = np.zeros(checked.shape[0], dtype=bool)
        if checked.size:
            left, left_block = counts(taken)
            _intruders_kernel(grid.sxy, grid.items, grid.x0, grid.y0, grid.cell, grid.nbx, grid.nby, grid.start, left,
                              left_block, places, points, checked, disks[mine], flat[mine], taken, more, hit)
        again = np.union1d(again, checked[hit, 0])
        if not again.size:
            break
        taken |= more
        pending = again
    first, index, weight = _last_rows(n_q, rounds)
    # the disks each place reads, from the round that computed it last
    last = np.empty(n_q, dtype=np.int64)
    for r, (pending, *_) in enumerate(rounds):
        last[pending] = r
    circles = [disks[last[rows[:, 0]] == r] for r, (*_, rows, disks) in enumerate(rounds)]
    owners = [rows[last[rows[:, 0]] == r, 0] for r, (*_, rows, disks) in enumerate(rounds)]
    around = np.flatnonzero(read > 0.0)
    owner = np.concatenate([around] + owners)
    order = np.argsort(owner, kind="stable")
    disks = np.concatenate([np.column_stack([places[around], read[around]])] + circles)[order]
    return NaturalCoordinates(first, index, weight, disks, owner[order], triangle, linear)


def _last_rows(n_q: int, rounds: list) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """``first, index, weight`` of every place from the last round that computed it
    (rounds of ``(places, first, index, weight, ...)``)."""
    last = np.empty(n_q, dtype=np.int64)
    at = np.empty(n_q, dtype=np.int64)
    for r, (pending, *_) in enumerate(rounds):
        last[pending] = r
        at[pending] = np.arange(pending.size)
    counts = np.empty(n_q, dtype=np.int64)
    for r, (pending, first, *_) in enumerate(rounds):
        mine = pending[last[pending] == r]
        counts[mine] = np.diff(first)[at[mine]]
    out_first = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    index = np.empty(out_first[-1], dtype=np.int64)
    weight = np.empty(out_first[-1])
    for r, (pending, first, found, w, *_) in enumerate(rounds):
        mine = pending[last[pending] == r]
        n = counts[mine]
        rank = _ranks(n)
        src = np.repeat(first[at[mine]], n) + rank
        dst = np.repeat(out_first[mine], n) + rank
        index[dst] = found[src]
        weight[dst] = w[src]
    return out_first, index, weight


def _ranks(counts: NDArray[np.int64]) -> NDArray[np.int64]:
    """``0 .. counts[i] - 1`` for each ``i``, one after the other."""
    total = int(counts.sum())
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total) - starts


def take_places(coordinates: NaturalCoordinates, places: NDArray[np.int64]) -> NaturalCoordinates:
    """The coordinates of the ``places`` (indices, in their order), renumbered ``0 .. len(places) - 1``."""
    places = np.asarray(places, dtype=np.int64)
    counts = np.diff(coordinates.first)[places]
    rank = _ranks(counts)
    src = np.repeat(coordinates.first[places], counts) + rank
    where = np.full(coordinates.first.size - 1, -1, dtype=np.int64)
    where[places] = np.arange(places.size)
    owner = where[coordinates.owner]
    kept = owner >= 0
    order = np.argsort(owner[kept], kind="stable")
    return NaturalCoordinates(np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), coordinates.index[src],
                              coordinates.weight[src], coordinates.disks[kept][order], owner[kept][order],
                              coordinates.triangle[places], coordinates.linear[places])


def join_places(*parts: NaturalCoordinates) -> NaturalCoordinates:
    """The coordinates of the places of ``parts``, one part's after the other's."""
    firsts, owners = [np.zeros(1, dtype=np.int64)], []
    offset = 0
    places = 0
    for part in parts:
        firsts.append(part.first[1:] + offset)
        owners.append(part.owner + places)
        offset += int(part.first[-1])
        places += part.first.size - 1
    return NaturalCoordinates(np.concatenate(firsts), np.concatenate([p.index for p in parts]),
                              np.concatenate([p.weight for p in parts]), np.concatenate([p.disks for p in parts]),
                              np.concatenate(owners), np.concatenate([p.triangle for p in parts]),
                              np.concatenate([p.linear for p in parts]))


@njit
def _values_kernel(first: np.ndarray, index: np.ndarray, weight: np.ndarray, z: np.ndarray, out: np.ndarray) -> None:
    for q in range(first.shape[0] - 1):
        if first[q + 1] == first[q]:
            out[q] = math.nan
            continue
        s = 0.0
        for k in range(first[q], first[q + 1]):
            s += weight[k] * z[index[k]]
        out[q] = s


def tin_values(coordinates: NaturalCoordinates, z: NDArray[np.float64]) -> NDArray[np.float64]:
    """The Delaunay triangulation's linear interpolant of ``z`` at the places with coordinates (NaN elsewhere)."""
    found = (coordinates.triangle >= 0).all(axis=1)
    corners = np.asarray(z)[np.maximum(coordinates.triangle, 0)]
    return np.where(found, np.sum(coordinates.linear * corners, axis=1), np.nan)


@njit
def _ranges_kernel(first: np.ndarray, index: np.ndarray, z: np.ndarray, low: np.ndarray, high: np.ndarray) -> None:
    for q in range(first.shape[0] - 1):
        lo = math.inf
        hi = -math.inf
        for k in range(first[q], first[q + 1]):
            lo = smaller(lo, z[index[k]])
            hi = larger(hi, z[index[k]])
        low[q] = lo if first[q + 1] > first[q] else math.nan
        high[q] = hi if first[q + 1] > first[q] else math.nan


def natural_ranges(coordinates: NaturalCoordinates,
                   z: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The lowest and highest of ``z`` over each place's natural neighbours (NaN where none)."""
    n = coordinates.first.shape[0] - 1
    low, high = np.empty(n), np.empty(n)
    _ranges_kernel(coordinates.first, coordinates.index, np.ascontiguousarray(z, dtype=np.float64), low, high)
    return low, high


def natural_values(coordinates: NaturalCoordinates, z: NDArray[np.float64]) -> NDArray[np.float64]:
    """The natural-neighbour interpolant of the points' values ``z`` at the places (NaN where none)."""
    out = np.empty(coordinates.first.shape[0] - 1)
    z = np.ascontiguousarray(z, dtype=np.float64)
    _values_kernel(coordinates.first, coordinates.index, coordinates.weight, z, out)
    return out
