"""Points in buckets: exact nearest neighbours, and which disks hold a point.

The smooth surface's kriging systems (:mod:`meshcore.smooth`) and its
voids' natural neighbours (:mod:`meshcore.natural`) search a bucket grid of
the points: about three points a bucket, the buckets in rows, each bucket's
points in one run of an array.  Nearest is exact, with ties broken by
coordinates (:func:`_before`), so a search depends only on the points inside
the disk it reaches, never on their order.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, larger, njit, njit_helper, smaller, zeros


@njit_helper
def _before(d2a: float, xa: float, ya: float, d2b: float, xb: float, yb: float) -> bool:
    """The order of neighbours: by squared distance, then x, then y."""
    if d2a != d2b:
        return d2a < d2b
    if xa != xb:
        return xa < xb
    return ya < yb


@njit_helper
def _scan_run(sxy: np.ndarray, lo: int, hi: int, qx: float, qy: float, k: int, count: int, best: np.ndarray,
              best_d2: np.ndarray) -> int:
    """Offer the points ``sxy[lo:hi]`` to the best ``count`` so far (``best``: their rows of
    ``sxy``, kept in :func:`_before` order); returns the new count.  A point's
    coordinates are read again only to break a tie of distances."""
    for s in range(lo, hi):
        px = sxy[s, 0]
        py = sxy[s, 1]
        d2 = (px - qx) * (px - qx) + (py - qy) * (py - qy)
        if count == k:
            worst = best_d2[k - 1]
            if not (d2 < worst or (d2 == worst and _before(d2, px, py, worst, sxy[best[k - 1], 0], sxy[best[k - 1], 1]))):
                continue
            pos = k - 1
        else:
            pos = count
            count += 1
        while pos > 0:
            ahead = best_d2[pos - 1]
            if not (d2 < ahead or (d2 == ahead and _before(d2, px, py, ahead, sxy[best[pos - 1], 0], sxy[best[pos - 1], 1]))):
                break
            best[pos] = best[pos - 1]
            best_d2[pos] = ahead
            pos -= 1
        best[pos] = s
        best_d2[pos] = d2
    return count


@njit_helper
def _bucket_near(i: int, j: int, x0: float, y0: float, cell: float, qx: float, qy: float, d2: float) -> bool:
    """Whether bucket ``(i, j)`` may hold a point within squared distance ``d2``
    of ``q``: its box, grown against rounding (a point's bucket is found by a
    division, the box's sides by a sum at the coordinates' scale) by a
    millionth of a bucket and a millionth of a millionth of the coordinates,
    reaches that near."""
    margin = 1e-6 * cell + 1e-12 * (abs(qx) + abs(qy))
    dx = larger(larger((x0 + i * cell - margin) - qx, qx - (x0 + (i + 1) * cell + margin)), 0.0)
    dy = larger(larger((y0 + j * cell - margin) - qy, qy - (y0 + (j + 1) * cell + margin)), 0.0)
    return dx * dx + dy * dy <= d2


@njit
def _knn_kernel(
    sxy: np.ndarray, items: np.ndarray, x0: float, y0: float, cell: float, nbx: int, nby: int,
    start: np.ndarray, queries: np.ndarray, k: int, out_index: np.ndarray, out_d2: np.ndarray,
) -> None:
    """The ``k`` nearest points of every query, in :func:`_before` order (``-1`` pads).

    ``sxy`` are the points bucket by bucket, the buckets in rows (``items``:
    the points' indices), so a bucket's points are read in one run, and so
    are a row of buckets'.  The 3 x 3 buckets around the query are read
    first, row by row, then rings of buckets farther out until none can hold
    a point nearer than the ``k``-th found.
    """
    best_d2 = empty(k)
    best = empty(k, dtype=np.int64)
    for q in range(queries.shape[0]):
        qx = queries[q, 0]
        qy = queries[q, 1]
        count = 0
        for s in range(k):
            best[s] = -1
            best_d2[s] = math.inf
        ci = smaller(larger(np.int64((qx - x0) / cell), 0), nbx - 1)
        cj = smaller(larger(np.int64((qy - y0) / cell), 0), nby - 1)
        i_lo = larger(ci - 1, 0)
        i_hi = smaller(ci + 1, nbx - 1)
        for j in range(larger(cj - 1, 0), smaller(cj + 1, nby - 1) + 1):
            count = _scan_run(sxy, start[j * nbx + i_lo], start[j * nbx + i_hi + 1], qx, qy, k, count, best, best_d2)
        ring = 1
        while True:
            covers = ci - ring <= 0 and cj - ring <= 0 and ci + ring >= nbx - 1 and cj + ring >= nby - 1
            if covers:
                break
            if count == k:
                # every point not yet seen is at least this far away
                gap = smaller(
                    smaller(qx - (x0 + (ci - ring) * cell), (x0 + (ci + ring + 1) * cell) - qx),
                    smaller(qy - (y0 + (cj - ring) * cell), (y0 + (cj + ring + 1) * cell) - qy),
                )
                gap *= 1.0 - 1e-12
                if gap > 0.0 and gap * gap > best_d2[k - 1]:
                    break
            ring += 1
            # the ring's buckets inside the grid, in rows (an outlier far from a
            # narrow grid crosses thousands of rings: each costs its buckets only)
            i_lo = larger(ci - ring, 0)
            i_hi = smaller(ci + ring, nbx - 1)
            sides = ci - ring >= 0 or ci + ring < nbx
            # with no side column in the grid, only the two edge rows (a ring of a thin grid)
            j_lo = larger(cj - ring, 0) if sides else cj - ring
            j_hi = smaller(cj + ring, nby - 1) if sides else cj + ring
            j = j_lo
            while j <= j_hi:
                if j >= 0 and j < nby:
                    if j == cj - ring or j == cj + ring:
                        if count < k:  # the whole row in one run
                            count = _scan_run(sxy, start[j * nbx + i_lo], start[j * nbx + i_hi + 1], qx, qy, k, count,
                                              best, best_d2)
                        else:
                            for i in range(i_lo, i_hi + 1):
                                if _bucket_near(i, j, x0, y0, cell, qx, qy, best_d2[k - 1]):
                                    b = j * nbx + i
                                    count = _scan_run(sxy, start[b], start[b + 1], qx, qy, k, count, best, best_d2)
                    else:
                        for i in (ci - ring, ci + ring):
                            if i >= 0 and i < nbx and (count < k or _bucket_near(i, j, x0, y0, cell, qx, qy, best_d2[k - 1])):
                                b = j * nbx + i
                                count = _scan_run(sxy, start[b], start[b + 1], qx, qy, k, count, best, best_d2)
                j += 1 if sides else larger(2 * ring, 1)
        for s in range(k):
            out_index[q, s] = items[best[s]] if best[s] >= 0 else -1
            out_d2[q, s] = best_d2[s]


@njit
def _bucket_items(key: np.ndarray, start: np.ndarray, xy: np.ndarray, sxy: np.ndarray) -> np.ndarray:
    """The points bucket by bucket, in input order within each (a stable counting
    sort); their coordinates copied to ``sxy`` in that order."""
    fill = start[:-1].copy()
    items = empty(key.shape[0], dtype=np.int64)
    for p in range(key.shape[0]):
        t = fill[key[p]]
        items[t] = p
        sxy[t, 0] = xy[p, 0]
        sxy[t, 1] = xy[p, 1]
        fill[key[p]] += 1
    return items


@njit
def _bounds_kernel(xy: np.ndarray, out: np.ndarray) -> None:
    nan_x = nan_y = False
    x0 = x1 = xy[0, 0]
    y0 = y1 = xy[0, 1]
    for i in range(xy.shape[0]):
        x = xy[i, 0]
        y = xy[i, 1]
        nan_x |= x != x
        nan_y |= y != y
        x0 = smaller(x0, x)
        x1 = larger(x1, x)
        y0 = smaller(y0, y)
        y1 = larger(y1, y)
    out[0] = math.nan if nan_x else x0
    out[1] = math.nan if nan_y else y0
    out[2] = math.nan if nan_x else x1
    out[3] = math.nan if nan_y else y1


def _bounds(xy: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The lowest and the highest ``(x, y)`` of ``(n >= 1, 2)`` points (a coordinate NaN where
    any point's is, as numpy's ``min`` and ``max``), in one pass (four of numpy's reductions over the columns took 9 ms of 1M points)."""
    out = np.empty(4)
    _bounds_kernel(np.ascontiguousarray(xy, dtype=np.float64), out)
    return out[:2], out[2:]


_BUCKET_POINTS = 3.0
"""Points per bucket of :func:`_nearest`'s grid, on average (measured: 2 or 5 were 10-20% slower)."""


def _nearest(
    xy: NDArray[np.float64], queries: NDArray[np.float64], k: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Indices ``(m, k)`` and squared distances of the ``k`` nearest points of each query."""
    n = xy.shape[0]
    k = min(k, n)
    if n == 0 or queries.shape[0] == 0 or k == 0:
        return np.full((queries.shape[0], k), -1, dtype=np.int64), np.full((queries.shape[0], k), np.inf)
    out_index = np.empty((queries.shape[0], k), dtype=np.int64)  # every row written, -1 and inf past the points found
    out_d2 = np.empty((queries.shape[0], k))
    grid = _bucket_grid(xy)
    q = np.ascontiguousarray(queries, dtype=np.float64)
    _knn_kernel(grid.sxy, grid.items, grid.x0, grid.y0, grid.cell, grid.nbx, grid.nby, grid.start, q, k, out_index, out_d2)
    return out_index, out_d2


class _BucketGrid(NamedTuple):
    """Points in the buckets of a grid (:func:`_bucket_grid`)."""

    sxy: np.ndarray  # (n, 2) the points bucket by bucket, the buckets in rows
    items: np.ndarray  # (n,) their indices
    x0: float  # the grid's lower left corner
    y0: float
    cell: float  # the buckets' side
    nbx: int  # buckets along x and y
    nby: int
    start: np.ndarray  # (nbx * nby + 1,) bucket b holds sxy[start[b]:start[b + 1]]


def _bucket_grid(xy: NDArray[np.float64]) -> _BucketGrid:
    """``(n >= 1, 2)`` points in a grid of :data:`_BUCKET_POINTS` points a bucket on average over their box."""
    n = xy.shape[0]
    lo, hi = _bounds(xy)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    area = float(max(hi[0] - lo[0], span * 1e-9) * max(hi[1] - lo[1], span * 1e-9))
    # three points a bucket: the 3 x 3 around a query hold about 27, more than the 16 sought
    cell = math.sqrt(_BUCKET_POINTS * area / n) if span > 0.0 else 1.0
    cell = max(cell, span * 1e-6, 1e-300)
    nbx = max(int((hi[0] - lo[0]) / cell) + 1, 1)
    nby = max(int((hi[1] - lo[1]) / cell) + 1, 1)
    ci = np.minimum(((xy[:, 0] - lo[0]) / cell).astype(np.int64), nbx - 1)
    cj = np.minimum(((xy[:, 1] - lo[1]) / cell).astype(np.int64), nby - 1)
    key = cj * nbx + ci
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    np.cumsum(np.bincount(key, minlength=nbx * nby), out=start[1:])
    sxy = np.empty((n, 2))
    items = _bucket_items(key, start, xy, sxy)
    return _BucketGrid(sxy, items, float(lo[0]), float(lo[1]), cell, nbx, nby, start)


@njit
def _disks_holding_kernel(
    sxy: np.ndarray, x0: float, y0: float, cell: float, nbx: int, nby: int, start: np.ndarray,
    centres: np.ndarray, radius: np.ndarray, out: np.ndarray,
) -> None:
    """Whether each closed disk ``(centres[s], radius[s])``, its radius grown by a
    billionth, holds one of the grid's points (a radius not finite: always).
    The buckets its box meets are read, one more on every side (a point's
    bucket is found by a division that may round it into its neighbour)."""
    for s in range(centres.shape[0]):
        r = radius[s]
        if not (r < math.inf):
            out[s] = True
            continue
        r = r * (1.0 + 1e-9)
        r2 = r * r
        cx = centres[s, 0]
        cy = centres[s, 1]
        out[s] = False
        if cx + r < x0 - cell or cy + r < y0 - cell or cx - r > x0 + (nbx + 1) * cell or cy - r > y0 + (nby + 1) * cell:
            continue
        i_lo = larger(np.int64(math.floor((cx - r - x0) / cell)) - 1, 0)
        i_hi = smaller(np.int64(math.floor((cx + r - x0) / cell)) + 1, nbx - 1)
        j_lo = larger(np.int64(math.floor((cy - r - y0) / cell)) - 1, 0)
        j_hi = smaller(np.int64(math.floor((cy + r - y0) / cell)) + 1, nby - 1)
        for j in range(j_lo, j_hi + 1):
            for t in range(start[j * nbx + i_lo], start[j * nbx + i_hi + 1]):
                dx = sxy[t, 0] - cx
                dy = sxy[t, 1] - cy
                if dx * dx + dy * dy <= r2:
                    out[s] = True
                    break
            if out[s]:
                break


def _disks_holding(centres: NDArray[np.float64], radius: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which of the closed disks ``(centres, radius)`` may hold one of ``points``:
    every disk that does, and a few that only come within a billionth of their radius."""
    out = np.zeros(centres.shape[0], dtype=bool)
    if points.shape[0] == 0 or centres.shape[0] == 0:
        return out
    grid = _bucket_grid(np.ascontiguousarray(points, dtype=np.float64))
    _disks_holding_kernel(grid.sxy, grid.x0, grid.y0, grid.cell, grid.nbx, grid.nby, grid.start,
                          np.ascontiguousarray(centres, dtype=np.float64), np.ascontiguousarray(radius, dtype=np.float64), out)
    return out


@njit
def _near_cells_kernel(vertices: np.ndarray, centres: np.ndarray, side: float) -> np.ndarray:
    """The vertices in the 3 x 3 blocks of cells of ``side`` around the centres."""
    size = 1
    while size < 36 * centres.shape[0]:
        size *= 2
    key_i = empty(size, dtype=np.int64)
    key_j = empty(size, dtype=np.int64)
    occupied = zeros(size, dtype=np.bool_)
    for c in range(centres.shape[0]):
        ci = np.int64(math.floor(centres[c, 0] / side))
        cj = np.int64(math.floor(centres[c, 1] / side))
        for di in range(-1, 2):
            for dj in range(-1, 2):
                i = ci + di
                j = cj + dj
                h = ((i * 73856093) ^ (j * 19349663)) & (size - 1)
                while occupied[h] and not (key_i[h] == i and key_j[h] == j):
                    h = (h + 1) & (size - 1)
                occupied[h] = True
                key_i[h] = i
                key_j[h] = j
    take = empty(vertices.shape[0], dtype=np.int64)
    m = 0
    for v in range(vertices.shape[0]):
        i = np.int64(math.floor(vertices[v, 0] / side))
        j = np.int64(math.floor(vertices[v, 1] / side))
        h = ((i * 73856093) ^ (j * 19349663)) & (size - 1)
        while occupied[h]:
            if key_i[h] == i and key_j[h] == j:
                take[m] = v
                m += 1
                break
            h = (h + 1) & (size - 1)
    return take[:m]


def _nearest_around(vertices: NDArray[np.float64], centres: NDArray[np.float64], k: int, side: float):
    """:func:`_nearest` for a few centres among many points, exactly: searched among the
    points of the cells of ``side`` around each centre, again among all where the
    ``k``-th nearest is not nearer than that block's edge."""
    near = _near_cells_kernel(vertices, centres, side)
    if near.size < min(k, vertices.shape[0]):  # too few around to give ``k`` each: searched among all
        return _nearest(vertices, centres, k)
    index, d2 = _nearest(np.ascontiguousarray(vertices[near]), centres, k)
    index = np.where(index >= 0, near[np.maximum(index, 0)], -1)
    # every point left out is at least `side` from its centre (the centre's own cell is the middle one)
    gap = np.minimum.reduce([centres[:, 0] - (np.floor(centres[:, 0] / side) - 1.0) * side,
                             (np.floor(centres[:, 0] / side) + 2.0) * side - centres[:, 0],
                             centres[:, 1] - (np.floor(centres[:, 1] / side) - 1.0) * side,
                             (np.floor(centres[:, 1] / side) + 2.0) * side - centres[:, 1]]) * (1.0 - 1e-9)
    bad = ~(d2[:, -1] < gap * gap) if d2.shape[1] else np.ones(centres.shape[0], dtype=bool)
    if bad.any():
        index[bad], d2[bad] = _nearest(vertices, np.ascontiguousarray(centres[bad]), k)
    return index, d2
