"""The run's smooth surface: one variogram for every tile, fitted once from a sample.

``surface="smooth"`` krigs the patch nodes of every tile with the same
variogram, so that neighbouring tiles compute bit-identical nodes on their
shared edges.  It is fitted once per run from the run's points (exact x, y
duplicates merged as the run merges them): all of them when they are at most
:data:`SAMPLE_POINTS`, so that any tiling of a survey gives the same
variogram (and the same surface); else the points of up to
:data:`SAMPLE_TILES` tiles spread over the grid.  It is kept in the work
folder: a resumed or incremental run reuses it, so tiles meshed earlier and
tiles meshed now agree.  The store's provenance records it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

import meshcore

from ..tiling.checkpoint import WorkDir
from .tiles import vertex_z
from ..tiling.grid import TileGrid
from ..tiling.routing import load_tile_points

__all__ = ["run_variogram", "SAMPLE_TILES", "SAMPLE_POINTS"]

SAMPLE_TILES = 8
"""At most this many tiles give points to the fit."""

SAMPLE_POINTS = 400_000
"""The fit stops taking tiles once it holds this many points."""


def _spread(n: int, count: int) -> list[int]:
    """Up to ``count`` indices of ``0 .. n-1``, evenly spread, then all the others in order."""
    if n == 0:
        return []
    first = sorted({int(round(i)) for i in np.linspace(0, n - 1, min(count, n))})
    taken = set(first)
    return first + [i for i in range(n) if i not in taken]


def _merged(points: NDArray[np.float64], policy: str) -> NDArray[np.float64]:
    """One point per distinct x, y, with the z the run keeps (``policy``, as its tiles merge them)."""
    if points.shape[0] == 0:
        return np.empty((0, 3))
    order = meshcore.lexicographic_order(points[:, :2])  # np.unique(axis=0)'s order, several times faster
    xy = np.take(points[:, :2], order, axis=0)  # rows gathered by np.take: several times faster than points[order, :2]
    new = np.empty(order.size, dtype=bool)
    new[0] = True
    new[1:] = (xy[1:, 0] != xy[:-1, 0]) | (xy[1:, 1] != xy[:-1, 1])
    inverse = np.empty(order.size, dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    merged = np.empty((int(np.count_nonzero(new)), 3))
    merged[:, :2] = xy[new]
    merged[:, 2] = vertex_z(inverse, merged.shape[0], points[:, 2], policy)
    return merged


def run_variogram(
    work: WorkDir, grid: TileGrid, policy: str, points: int
) -> tuple[meshcore.Variogram, dict[str, Any]]:
    """The run's variogram (fitted now, or the one this work folder recorded)
    and its provenance entry; ``points``: how many the run kept."""
    recorded = work.recorded("surface", "variogram")
    if recorded is not None:
        variogram = meshcore.Variogram.from_dict(recorded["variogram"])
        if variogram.spacing is not None:  # else recorded before node cells: fitted again
            return variogram, recorded
    tiles = grid.tiles()
    parts: list[NDArray[np.float64]] = []
    used: list[list[int]] = []
    held = 0
    every = points <= SAMPLE_POINTS
    for k in _spread(len(tiles), SAMPLE_TILES):
        if not every and (len(parts) == SAMPLE_TILES or held >= SAMPLE_POINTS):
            break
        r, c = tiles[k]
        pts = load_tile_points(work.scratch, r, c)
        if pts.shape[0] == 0:
            continue
        orow, ocol = grid.owner(pts[:, 0], pts[:, 1])
        pts = pts[(orow == r) & (ocol == c)]
        if pts.shape[0] == 0:
            continue
        parts.append(pts)
        used.append([r, c])
        held += pts.shape[0]
    sample = _merged(np.concatenate(parts), policy) if parts else np.empty((0, 3))
    try:
        variogram = meshcore.fit_variogram(sample[:, :2], sample[:, 2], neighbours=meshcore.DEFAULT_NEIGHBOURS)
        how = "leave-one-out kriging errors on a sample"
    except meshcore.InvalidInputError:
        # too few points to fit: any model gives the few faces there are
        span = max(grid.tile_size, grid.resolution)
        variogram = meshcore.Variogram(nugget=0.0, sill=1.0, range=span, spacing=span)
        how = "too few points to fit: a default"
    entry = {
        "variogram": variogram.to_dict(),
        "model": variogram.model,
        "fitted": how,
        "neighbours": meshcore.DEFAULT_NEIGHBOURS,
        "sample_points": int(sample.shape[0]),
        "sample_tiles": len(used),
    }
    work.record("surface", "variogram", entry)
    return variogram, entry
