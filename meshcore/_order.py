"""Ordering helpers shared by the kernels: tie runs, and a numbering of a
triangulation fixed by the geometry alone."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import empty, empty_like, index, larger, njit, njit_helper, smaller, zeros
from .delaunay import Triangulation
from .errors import InvalidInputError

__all__ = ["order_ties_by", "sortable_keys", "morton_keys", "geometric_order", "lexicographic_order", "block_order"]


@njit_helper
def _merge_runs(src_o: np.ndarray, src_t: np.ndarray, dst_o: np.ndarray, dst_t: np.ndarray, lo: int, mid: int,
                hi: int) -> None:
    """Merge the sorted runs ``[lo, mid)`` and ``[mid, hi)`` of ``src_t`` (and
    ``src_o`` alongside) into ``dst_t`` (``dst_o``); on equal ties the first
    run's element comes first."""
    i = lo
    j = mid
    for k in range(lo, hi):
        if j < hi and (i >= mid or src_t[j] < src_t[i]):
            dst_o[k] = src_o[j]
            dst_t[k] = src_t[j]
            j += 1
        else:
            dst_o[k] = src_o[i]
            dst_t[k] = src_t[i]
            i += 1


@njit_helper
def _merge_sort_ties(order: np.ndarray, tie: np.ndarray, lo: int, hi: int) -> None:
    """Sort ``order[lo:hi]`` and ``tie[lo:hi]`` by increasing ``tie``: a
    stable bottom-up merge sort (numba's ``argsort(kind="mergesort")`` takes
    a second to compile)."""
    n = hi - lo
    src_o = order[lo:hi].copy()
    src_t = tie[lo:hi].copy()
    dst_o = empty_like(src_o)
    dst_t = empty_like(src_t)
    width = 1
    while width < n:
        for start in range(0, n, 2 * width):
            _merge_runs(src_o, src_t, dst_o, dst_t, start, smaller(start + width, n), smaller(start + 2 * width, n))
        src_o, dst_o = dst_o, src_o
        src_t, dst_t = dst_t, src_t
        width *= 2
    for k in range(n):  # element by element: see delaunay._merge_sort_run
        order[lo + k] = src_o[k]
        tie[lo + k] = src_t[k]


@njit
def order_ties_by(order: np.ndarray, key: np.ndarray, tie: np.ndarray) -> None:
    """Within runs of equal ``key``, reorder ``order`` (and ``tie``) by increasing ``tie``.

    Both are unsigned 64-bit integers (floats: :func:`sortable_keys`), so
    that the kernel is compiled once.  ``key`` and ``tie`` are given in ``order``'s order (``key[order]``,
    ``tie[order]``): contiguous, so the sorts of the runs stay in cache.
    ``key`` must be sorted; ``tie`` is reordered along with ``order``.  Short
    runs (the usual case for float keys of geometric data) are
    insertion-sorted; long ones (a grid, where many keys are equal) are sorted
    with a stable merge sort.
    """
    n = order.shape[0]
    k = 0
    while k < n:
        m = k + 1
        while m < n and key[m] == key[k]:
            m += 1
        if m - k > 32:
            _merge_sort_ties(order, tie, k, m)
            k = m
            continue
        for i in range(k + 1, m):
            v = order[i]
            t = tie[i]
            j = i - 1
            while j >= k and tie[j] > t:
                order[j + 1] = order[j]
                tie[j + 1] = tie[j]
                j -= 1
            order[j + 1] = v
            tie[j + 1] = t
        k = m


def lexicographic_order(xy: ArrayLike) -> NDArray[np.int64]:
    """Indices that sort points by x, then by y (equal points keep no particular order).

    The table of a tile's points in this order is searchable by coordinates
    (``numpy.searchsorted`` on ``x + 1j * y``), at a fraction of the cost of
    sorting complex keys.

    >>> lexicographic_order([[1.0, 0.0], [0.0, 2.0], [0.0, 1.0]]).tolist()
    [2, 1, 0]
    """
    arr = np.asarray(xy, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise InvalidInputError(f"xy must have shape (n, 2), got {arr.shape}")
    x = np.ascontiguousarray(arr[:, 0])
    y = np.ascontiguousarray(arr[:, 1])
    key, y_key = _lexicographic_keys(x, y)
    order = np.argsort(key)
    order_ties_by(order, key[order], y_key[order])
    return order


def block_order(xy: ArrayLike, side: float, box: tuple[float, float, float, float]) -> NDArray[np.int64]:
    """The points ``xy`` (n, 2 or more) in blocks: square cells of ``side`` from
    the corner of ``box`` (cut to the points), cell by cell in blocks of 8 x 8
    cells, the blocks row by row, and in their given order within a cell
    (stable).

    Points outside ``box`` go to its edge cells.  Kernels that read each
    point's neighbours (the smooth surface's kriging, its layout) then find
    them near in memory, whatever the order of the points in their files.

    >>> block_order([[5.0, 0.5], [0.5, 0.5], [0.5, 9.0], [1.5, 0.5]], 1.0, (0.0, 0.0, 16.0, 16.0)).tolist()
    [1, 3, 0, 2]
    """
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 2:
        raise InvalidInputError(f"xy must have shape (n, 2), got {pts.shape}")
    x0, y0, x1, y1 = (float(v) for v in box)
    if not (side > 0.0 and np.isfinite(side) and x1 >= x0 and y1 >= y0):
        raise InvalidInputError(f"need side > 0 and a box (x0, y0, x1, y1) with x0 <= x1, y0 <= y1, got {side!r}, {box!r}")
    if pts.shape[0] == 0:
        return np.empty(0, dtype=np.int64)
    # the box cut to the points (an open side of a box is infinite)
    x0, x1 = max(x0, float(np.nanmin(pts[:, 0]))), min(x1, float(np.nanmax(pts[:, 0])))
    y0, y1 = max(y0, float(np.nanmin(pts[:, 1]))), min(y1, float(np.nanmax(pts[:, 1])))
    x1, y1 = max(x0, x1), max(y0, y1)
    if not np.isfinite([x0, y0, x1, y1]).all():
        x0 = y0 = x1 = y1 = 0.0
    # at most a few cells per point, whatever the box: larger cells where the points are spread far
    budget = 64.0 * pts.shape[0] + 4096.0
    w, h = x1 - x0, y1 - y0
    side = max(float(side), math.sqrt(w * h / budget), max(w, h) / budget)
    nx = int(w / side) + 1
    ny = int(h / side) + 1
    return _block_order_kernel(np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1]), x0, y0, float(side), nx, ny)


@njit_helper
def _block_cell(v: float, origin: float, side: float, n: int) -> int:
    t = (v - origin) / side
    if not t >= 0.0:
        return 0
    if t >= n:
        return n - 1
    return np.int64(t)


@njit
def _block_order_kernel(x: np.ndarray, y: np.ndarray, x0: float, y0: float, side: float, nx: int, ny: int) -> np.ndarray:
    """:func:`block_order` by a counting sort."""
    n = x.shape[0]
    blocks_x = (nx + 7) // 8
    blocks_y = (ny + 7) // 8
    key = empty(n, dtype=np.int64)
    start = zeros(blocks_x * blocks_y * 64 + 1, dtype=np.int64)
    for p in range(n):
        i = _block_cell(x[p], x0, side, nx)
        j = _block_cell(y[p], y0, side, ny)
        key[p] = ((j // 8) * blocks_x + i // 8) * 64 + (j % 8) * 8 + i % 8
        start[key[p] + 1] += 1
    for b in range(start.shape[0] - 1):
        start[b + 1] += start[b]
    order = empty(n, dtype=np.int64)
    for p in range(n):
        order[start[key[p]]] = p
        start[key[p]] += 1
    return order


def sortable_keys(values: NDArray[np.float64]) -> NDArray[np.uint64]:
    """Integers in the order of the (non-NaN) floats ``values``, equal where they are
    equal (-0.0 taken as +0.0): the keys :func:`order_ties_by` takes."""
    bits = (np.asarray(values, dtype=np.float64) + 0.0).view(np.uint64)
    return np.where(bits >> np.uint64(63), ~bits, bits | (np.uint64(1) << np.uint64(63)))


@njit_helper
def _bit_length(v: np.uint64) -> int:
    """Number of bits of ``v`` up to its highest set bit (0 for 0)."""
    bits = 0
    while v > np.uint64(0):
        bits += 1
        v >>= np.uint64(1)
    return bits


@njit
def _lexicographic_keys(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """64-bit keys in lexicographic order of the points, ties only between
    points of equal x whose y agree in their leading bits; and y's own keys
    (:func:`sortable_keys`), which break those ties.

    x and y become order-preserving integers (-0.0 taken as +0.0, which the
    float order does not tell apart); a key is the offset of x from the
    smallest, in its high bits, followed by as many leading bits of the offset
    of y as fit.  Survey coordinates of one tile (x spanning a few hundred
    metres) leave room for about 20 bits of y: points then tie only when their
    y agree to well under a millimetre, in practice never.
    """
    n = x.shape[0]
    ux = empty(n, dtype=np.uint64)
    uy = empty(n, dtype=np.uint64)
    for i in range(n):
        ux[i] = _sortable(np.float64(x[i] + 0.0).view(np.uint64))
        uy[i] = _sortable(np.float64(y[i] + 0.0).view(np.uint64))
    key = empty(n, dtype=np.uint64)
    if n == 0:
        return key, uy
    x_lo = x_hi = ux[0]  # a loop, not ux.min(): numba compiles a reduction per array type
    y_lo = y_hi = uy[0]
    for i in range(1, n):
        x_lo = smaller(x_lo, ux[i])
        x_hi = larger(x_hi, ux[i])
        y_lo = smaller(y_lo, uy[i])
        y_hi = larger(y_hi, uy[i])
    x_bits = _bit_length(x_hi - x_lo)
    y_bits = _bit_length(y_hi - y_lo)
    room = 64 - x_bits  # bits of the key below x's
    drop = larger(0, y_bits - room)  # trailing bits of y that do not fit
    for i in range(n):
        high = (ux[i] - x_lo) << np.uint64(room) if room < 64 else np.uint64(0)
        low = (uy[i] - y_lo) >> np.uint64(drop) if room > 0 else np.uint64(0)
        key[i] = high | low
    return key, uy


@njit_helper
def _spread(v: np.uint64) -> np.uint64:
    """The low 32 bits of ``v`` moved to the even bit positions of a 64-bit word."""
    v &= np.uint64(0x00000000FFFFFFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x0000FFFF0000FFFF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF00FF00FF)
    v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    v = (v | (v << np.uint64(2))) & np.uint64(0x3333333333333333)
    v = (v | (v << np.uint64(1))) & np.uint64(0x5555555555555555)
    return v


@njit_helper
def _sortable(u: np.uint64) -> np.uint64:
    """A float64's bits ``u`` as an integer whose order is the floats' order."""
    if u >> np.uint64(63):
        return ~u
    return u | (np.uint64(1) << np.uint64(63))


@njit
def morton_keys(x_bits: np.ndarray, y_bits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 128-bit Z-curve key (high, low words) of points given by their float64 bits."""
    n = x_bits.shape[0]
    high = empty(n, dtype=np.uint64)
    low = empty(n, dtype=np.uint64)
    half = np.uint64(32)
    for k in range(n):
        ux = _sortable(x_bits[k])
        uy = _sortable(y_bits[k])
        high[k] = _spread(ux >> half) | (_spread(uy >> half) << np.uint64(1))
        low[k] = _spread(ux) | (_spread(uy) << np.uint64(1))
    return high, low


def _leading_word(high: np.ndarray, low: np.ndarray) -> np.ndarray:
    """The 64 bits of 128-bit keys that follow the prefix all of them share.

    Sorting by these, then by the low word within ties, is the order of the
    full keys: the shared prefix says nothing and the dropped tail only breaks
    ties.  Keys of nearby points (one tile) share many leading bits.
    """
    if high.size == 0:
        return high
    spread = int(np.bitwise_or.reduce(high ^ high[0]))
    shift = 64 - spread.bit_length()  # leading bits every key shares
    if shift == 0:
        return high
    if shift == 64:
        return low
    return (high << np.uint64(shift)) | (low >> np.uint64(64 - shift))


def _point_ranks(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Rank of every point along the Z-curve of its coordinates (distinct points
    get distinct ranks; equal points are never both vertices)."""
    high, low = morton_keys(x.view(np.uint64), y.view(np.uint64))
    lead = _leading_word(high, low)
    order = np.argsort(lead)
    order_ties_by(order, lead[order], low[order])
    rank = np.empty(order.shape[0], dtype=np.int32)  # half the cache of int64
    rank[order] = np.arange(order.shape[0], dtype=np.int32)
    return rank


@njit
def _renumber_kernel(tri, he, rank):
    """Triangles sorted by the ranks of their corners, each starting at its
    lowest-ranked corner (a counting sort on that corner), with corners
    numbered by rank."""
    nt = tri.shape[0] // 3
    n = rank.shape[0]
    first = empty(nt, dtype=np.int8)  # rotation of each triangle
    lowest = empty(nt, dtype=np.int32)  # rank of its lowest corner
    after = empty(nt, dtype=np.int32)  # rank of the corner after the lowest
    start = zeros(n + 1, dtype=np.int32)
    for t in range(nt):
        r0 = rank[index(tri[3 * t])]
        r1 = rank[index(tri[3 * t + 1])]
        r2 = rank[index(tri[3 * t + 2])]
        if r0 < r1 and r0 < r2:
            first[t] = 0
            lowest[t] = r0
            after[t] = r1
        elif r1 < r2:
            first[t] = 1
            lowest[t] = r1
            after[t] = r2
        else:
            first[t] = 2
            lowest[t] = r2
            after[t] = r0
        start[lowest[t] + 1] += 1
    for r in range(n):
        start[r + 1] += start[r]
    base = start.copy()  # where each corner's run begins
    slot = empty(nt, dtype=np.int32)  # new position -> old triangle
    second = empty(nt, dtype=np.int32)
    for t in range(nt):
        lo = lowest[t]
        nxt = after[t]
        k = start[lo]
        start[lo] += 1
        run = base[lo]
        # a corner starts few triangles: insert into its short run; the
        # directed edge (lowest, next) is unique, so the order is strict
        while k > run and second[k - 1] > nxt:
            slot[k] = slot[k - 1]
            second[k] = second[k - 1]
            k -= 1
        slot[k] = t
        second[k] = nxt
    new_of_old = empty(3 * nt, dtype=np.int32)
    for k in range(nt):
        t = slot[k]
        j = first[t]
        for i in range(3):
            new_of_old[3 * t + (j + i) % 3] = 3 * k + i
    new_tri = empty_like(tri)
    new_he = empty_like(he)
    for e in range(3 * nt):
        g = index(new_of_old[e])
        new_tri[g] = rank[index(tri[e])]
        h = he[e]
        new_he[g] = -1 if h < 0 else new_of_old[index(h)]
    return new_tri, new_he


def geometric_order(triangulation: Triangulation) -> Triangulation:
    """The same triangulation with its triangles numbered in an order fixed by
    the geometry alone.

    Points are ranked along a Z-curve (Morton order) of their input
    coordinates, whose bits are interleaved as order-preserving integers;
    triangles follow the ranks of their lowest corner, then of the next corner
    counter-clockwise, and start at their lowest corner.  Two triangulations of
    overlapping point sets (tiles) then number the triangles they share in the
    same relative order, whatever their internal numbering or local origin, so
    order-dependent passes (flips, merges) treat them the same way.  The
    Points are renumbered by rank too, so the Z-curve keeps neighbouring
    triangles and their corners close in memory.
    """
    t = triangulation
    # the local shift is exact, so these are the input coordinates
    rank = _point_ranks(t.x + float(t.origin[0]), t.y + float(t.origin[1]))
    tri, he = _renumber_kernel(t.triangles, t.halfedges, rank)
    x, y, order, rep = _renumber_points(t.x, t.y, t.order, t.rep, rank)
    return Triangulation(x, y, t.origin, order, rep, tri, he)


@njit
def _renumber_points(x, y, order, rep, rank):
    n = x.shape[0]
    new_x = empty_like(x)
    new_y = empty_like(y)
    new_order = empty_like(order)
    new_rep = empty_like(rep)
    for k in range(n):
        r = rank[k]
        new_x[r] = x[k]
        new_y[r] = y[k]
        new_order[r] = order[k]
        new_rep[r] = rank[rep[k]]
    return new_x, new_y, new_order, new_rep
