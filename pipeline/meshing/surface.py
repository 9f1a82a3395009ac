"""The run's smooth surface: one variogram for every tile, fitted once from a sample.

``surface="smooth"`` krigs the patch nodes of every tile with the same
variogram, so that neighbouring tiles compute bit-identical nodes on their
shared edges.  It is fitted once per run from the run's points (exact x, y
duplicates merged as the run merges them): all of them when they are at most
:data:`SAMPLE_POINTS`; else every point of whole cells of a lattice fixed in
the CRS (cells on multiples of their side), taken in an order fixed by their
indices until the sample holds :data:`SAMPLE_POINTS` points.  The side
follows the survey's point count and the area of its convex hull, so that a
cell holds about ``SAMPLE_POINTS / SAMPLE_CELLS`` points.  Nothing of it
depends on the tiles: any tile size and buffer gives the same sample, and so
the same variogram, bit for bit.  Whole cells keep the survey's spacing
(which the variogram measures) where a thinned sample would widen it.  It is
kept in the work folder: a resumed or incremental run reuses it, so tiles
meshed earlier and tiles meshed now agree.  The store's provenance records it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

import meshcore

from ..tiling.checkpoint import Ledger, WorkDir
from .tiles import _edge_sides, vertex_z
from ..tiling.grid import TileGrid
from ..tiling.routing import load_tile_points

__all__ = ["run_variogram", "signed_area", "SAMPLE_CELLS", "SAMPLE_POINTS", "MAX_SAMPLE_CELLS"]

SAMPLE_POINTS = 400_000
"""A survey of at most this many points kept fits its variogram from all of
them; a larger one from about this many (the cells that reach it)."""

SAMPLE_CELLS = 8
"""The sample of a larger survey is about this many cells of the lattice."""

MAX_SAMPLE_CELLS = 4 * SAMPLE_CELLS
"""At most this many cells are read: cells within the survey's convex hull
may hold no point (voids, an irregular outline), and each costs the reading
of the tiles it meets."""


def _merged(points: NDArray[np.float64], policy: str) -> NDArray[np.float64]:
    """One point per distinct x, y, with the z the run keeps (``policy``, as its tiles merge them)."""
    if points.shape[0] == 0:
        return np.empty((0, 3))
    order = meshcore.tiles.lexicographic_order(points[:, :2])  # np.unique(axis=0)'s order, several times faster
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
    work: WorkDir, grid: TileGrid, policy: str, points: int, hull: NDArray[np.float64] | None = None
) -> tuple[meshcore.Variogram, dict[str, Any]]:
    """The run's variogram (fitted now, or the one this work folder recorded)
    and its provenance entry; ``points``: how many the run kept; ``hull``:
    the survey's convex hull (counter-clockwise), which bounds the cells a
    larger survey's sample is drawn from."""
    recorded = work.recorded(Ledger.SURFACE, "variogram")
    if recorded is not None:
        variogram = meshcore.Variogram.from_dict(recorded["variogram"])
        if variogram.spacing is not None:  # else recorded before node cells: fitted again
            return variogram, recorded
    owned: dict[tuple[int, int], NDArray[np.float64]] = {}

    def tile_points(r: int, c: int) -> NDArray[np.float64]:
        """The points tile (r, c) owns (its file holds its buffer's too), read once."""
        if (r, c) not in owned:
            pts = load_tile_points(work.scratch, r, c)
            orow, ocol = grid.owner(pts[:, 0], pts[:, 1])
            owned[(r, c)] = pts[(orow == r) & (ocol == c)]
        return owned[(r, c)]

    if points <= SAMPLE_POINTS:
        parts = [tile_points(r, c) for r, c in grid.tiles()]
        how_drawn: dict[str, Any] = {"points": "all"}
    else:
        side = _cell_side(grid, points, hull)
        parts, cells = [], []
        held = 0
        for i, j in _cells_in_order(grid, side, hull)[:MAX_SAMPLE_CELLS]:
            box = (i * side, j * side, (i + 1) * side, (j + 1) * side)
            for r, c in grid.tiles_meeting([box]):
                pts = tile_points(r, c)
                inside = (pts[:, 0] >= box[0]) & (pts[:, 0] < box[2]) & (pts[:, 1] >= box[1]) & (pts[:, 1] < box[3])
                if inside.any():
                    parts.append(pts[inside])
                    held += int(np.count_nonzero(inside))
            cells.append([int(i), int(j)])
            if held >= SAMPLE_POINTS:
                break
        how_drawn = {"points": "whole cells", "cell_side": side, "cells": cells}
    parts = [p for p in parts if p.shape[0]]
    sample = _merged(np.concatenate(parts), policy) if parts else np.empty((0, 3))
    try:
        variogram = meshcore.fit_variogram(sample[:, :2], sample[:, 2], neighbours=meshcore.tiles.DEFAULT_NEIGHBOURS)
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
        "neighbours": meshcore.tiles.DEFAULT_NEIGHBOURS,
        "sample_points": int(sample.shape[0]),
        "sample": how_drawn,
    }
    work.record(Ledger.SURFACE, "variogram", entry)
    return variogram, entry


def _cell_side(grid: TileGrid, points: int, hull: NDArray[np.float64] | None) -> float:
    """The side of the sample's cells: a whole number of the grid's cells, so
    that one holds about ``SAMPLE_POINTS / SAMPLE_CELLS`` of the ``points``
    spread over the hull (or, without an area, the grid)."""
    area = abs(signed_area(hull)) if hull is not None else 0.0
    if not area > 0.0:
        x0, y0, x1, y1 = grid.extent
        area = (x1 - x0) * (y1 - y0)
    wanted = math.sqrt(SAMPLE_POINTS / SAMPLE_CELLS * area / max(points, 1))
    return grid.resolution * max(1, math.ceil(wanted / grid.resolution))


def signed_area(polygon: NDArray[np.float64]) -> float:
    """The area of a simple polygon ``(n, 2+)``, > 0 counter-clockwise (shoelace; 0 for fewer than three corners)."""
    if polygon.shape[0] < 3:
        return 0.0
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _cells_in_order(grid: TileGrid, side: float, hull: NDArray[np.float64] | None) -> list[tuple[int, int]]:
    """The lattice cells ``(i, j)`` (the box ``[i, i + 1) x [j, j + 1)`` times
    ``side``) that meet the survey: those whose centre lies in the hull or
    that hold one of its corners (every cell of the grid's box when none
    does, or without a hull), in the order of a hash of their indices: a
    spread over the survey that no tiling changes."""
    x0, y0, x1, y1 = grid.extent if hull is None or hull.shape[0] == 0 else (
        float(hull[:, 0].min()), float(hull[:, 1].min()), float(hull[:, 0].max()), float(hull[:, 1].max()))
    first_i, first_j = math.floor(x0 / side), math.floor(y0 / side)
    n_i, n_j = math.floor(x1 / side) - first_i + 1, math.floor(y1 / side) - first_j + 1
    index = np.arange(n_i * n_j, dtype=np.int64)  # cell (i, j) is first_i + index // n_j, first_j + index % n_j
    i, j = first_i + index // n_j, first_j + index % n_j
    if hull is not None and hull.shape[0] >= 3:
        meets = np.zeros(index.size, dtype=bool)
        ccw = hull if signed_area(hull) >= 0.0 else hull[::-1]
        px, py = np.ascontiguousarray(ccw[:, 0]), np.ascontiguousarray(ccw[:, 1])
        step = max(1, (1 << 19) // px.size)  # cells times corners at once
        for k in range(0, index.size, step):
            cx, cy = (i[k : k + step] + 0.5) * side, (j[k : k + step] + 0.5) * side
            meets[k : k + step] = (_edge_sides(px, py, cx, cy) >= 0.0).all(axis=1)
        corner_i = np.floor(px / side).astype(np.int64) - first_i
        corner_j = np.floor(py / side).astype(np.int64) - first_j
        meets[corner_i * n_j + corner_j] = True
        if meets.any():
            i, j = i[meets], j[meets]
    order = np.lexsort((j, i, _mix(i, j)))
    return list(zip(i[order].tolist(), j[order].tolist()))


def _mix(i: NDArray[np.int64], j: NDArray[np.int64]) -> NDArray[np.uint64]:
    """A 64-bit hash of each pair of indices (SplitMix64's finaliser): the same on every machine."""
    with np.errstate(over="ignore"):
        z = i.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15) ^ (j.astype(np.uint64) + np.uint64(0x632BE59BD9B4E019))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))
