"""The cells the smooth surface's nodes are kriged in, and the point spacing they are measured in.

The nodes are grouped in square cells of :data:`CELL_PER_SPACING` point
spacings, aligned on multiples of the cell's side, so that every tile puts a
node in the same cell; each cell's nodes share one kriging system
(:mod:`meshcore.kriging`).
"""

from __future__ import annotations
import math

import numpy as np
from numpy.typing import NDArray

from ._buckets import _bounds, _nearest
from ._jit import empty, njit, njit_helper, zeros
from .errors import InvalidInputError

__all__ = ["CELL_PER_SPACING"]


@njit_helper
def _cell_key(x: float, y: float, cell: float, i0: int, j0: int, blocks_x: int) -> int:
    """The sort key of the cell holding ``(x, y)``: blocks of 8 x 8 cells in rows, cells in rows within a block."""
    ri = np.int64(math.floor(x / cell)) - i0
    rj = np.int64(math.floor(y / cell)) - j0
    return ((rj >> 3) * blocks_x + (ri >> 3)) * 64 + (rj & 7) * 8 + (ri & 7)


@njit
def _cells_kernel(positions: np.ndarray, cell: float, i0: int, j0: int, blocks_x: int, blocks_y: int,
                  order: np.ndarray) -> np.ndarray:
    """Fill ``order`` (the nodes cell by cell, blocks of 8 x 8 cells in rows)
    by a counting sort; returns the cells' ``(i, j)`` and their first nodes.
    ``(i0, j0)``: the lowest cell of any node (keys count from it)."""
    n = positions.shape[0]
    key = empty(n, dtype=np.int64)
    start = zeros(blocks_x * blocks_y * 64 + 1, dtype=np.int64)
    for p in range(n):
        kp = _cell_key(positions[p, 0], positions[p, 1], cell, i0, j0, blocks_x)
        key[p] = kp
        start[kp + 1] += 1
    cells = 0
    for b in range(start.size - 1):
        if start[b + 1] > 0:
            cells += 1
        start[b + 1] += start[b]
    out = empty((cells, 3), dtype=np.int64)  # i, j, first node
    pos = start[:-1].copy()
    for p in range(n):
        order[pos[key[p]]] = p
        pos[key[p]] += 1
    m = 0
    for b in range(start.size - 1):
        if start[b + 1] > start[b]:
            lead = order[start[b]]
            out[m, 0] = np.int64(math.floor(positions[lead, 0] / cell))
            out[m, 1] = np.int64(math.floor(positions[lead, 1] / cell))
            out[m, 2] = start[b]
            m += 1
    return out


def _cells(positions: NDArray[np.float64], cell: float) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """The nodes grouped by cell: ``order`` (the nodes cell by cell), ``first`` and the cells' centres.

    A node's cell is ``floor(position / cell)``, on multiples of ``cell`` from
    the origin, so every piece of a survey puts a node in the same cell and
    gives it the same centre.  The cells go in blocks of 8 x 8, so that
    neighbouring systems read the same points, which stay in the cache.
    """
    if positions.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64), np.empty((0, 2))
    lo, hi = _bounds(positions)
    if not max(np.abs(lo).max(), np.abs(hi).max()) / cell < 2.0**52:
        raise InvalidInputError(f"the smooth surface's cell {cell!r} is too small for coordinates up to "
                                f"{max(np.abs(lo).max(), np.abs(hi).max()):.6g}")
    if float(((hi[0] - lo[0]) / cell + 9.0) * ((hi[1] - lo[1]) / cell + 9.0)) < 64.0 * positions.shape[0] + 1e6:
        order = np.empty(positions.shape[0], dtype=np.int64)
        # floor(x / cell) grows with x: the lowest and highest cells are those of the extremes
        i0, j0, i1, j1 = (int(math.floor(v / cell)) for v in (lo[0], lo[1], hi[0], hi[1]))
        cells = _cells_kernel(np.ascontiguousarray(positions), float(cell), i0, j0, (i1 - i0) // 8 + 1, (j1 - j0) // 8 + 1,
                              order)
        first = np.append(cells[:, 2], order.size)
        ci, cj = cells[:, 0], cells[:, 1]
    else:  # nodes spread far (an outlier's faces): sorted, not counted in a grid mostly empty
        order, first, ci, cj = _sparse_cells(positions, cell)
    centres = np.column_stack([(ci + 0.5) * cell, (cj + 0.5) * cell])
    return order, first, centres


def _sparse_cells(positions: NDArray[np.float64], cell: float):
    """:func:`_cells_kernel`'s order, by a sort: cell by cell, blocks of 8 x 8 cells in rows, stable."""
    ci = np.floor(positions[:, 0] / cell).astype(np.int64)
    cj = np.floor(positions[:, 1] / cell).astype(np.int64)
    ri = ci - ci.min()
    rj = cj - cj.min()
    order = np.lexsort((ri % 8, rj % 8, ri // 8, rj // 8))
    new = np.ones(order.size, dtype=bool)
    new[1:] = (ci[order][1:] != ci[order][:-1]) | (cj[order][1:] != cj[order][:-1])
    lead = np.flatnonzero(new)
    return order, np.append(lead, order.size), ci[order[lead]], cj[order[lead]]


CELL_PER_SPACING = 1.4
"""The side of the smooth surface's cells, in point spacings (:attr:`Variogram.spacing`).

Measured (``bench/bench_accuracy.py``): smaller cells centre each system
better on its nodes but cost one system per cell.  At 1.4 spacings (a system
per two points) the errors are those of 0.7 or 1.0 spacings, or of a system
per edge and face (five per point), within the noise of the test; at 2
spacings they grow."""


def _spacing(d2_last: NDArray[np.float64], k: int) -> float:
    """The point spacing ``1 / sqrt(density)`` from the squared distances to the ``k``-th nearest point."""
    r = np.sqrt(d2_last[np.isfinite(d2_last)])
    if r.size == 0:
        return 1.0
    value = float(np.median(r)) * math.sqrt(math.pi / k)
    return value if value > 0.0 else 1.0


def _mesh_spacing(vertices: NDArray[np.float64], k: int) -> float:
    """:func:`_spacing` of a mesh's own vertices (a deterministic sample of them)."""
    if vertices.shape[0] < 2:
        return 1.0
    order = np.lexsort((vertices[:, 1], vertices[:, 0]))
    sample = order[:: max(1, order.size // 2000)]
    kk = min(k, vertices.shape[0] - 1)
    _, d2 = _nearest(vertices, vertices[sample], kk + 1)
    return _spacing(d2[:, -1], kk)
