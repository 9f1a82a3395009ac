"""The ground stage: the ground points of a survey classified block of
tiles by block (:func:`meshcore.classify_ground`), the same at any tiling.

When a run classifies the ground (``classify_ground``, or a survey whose
points of the default classes make no surface), routing sends every point but
noise to each tile's ``ground/`` spill folder (:data:`GROUND_SPILL`) with its
return number and number of returns.  The tiles are grouped in blocks
(:func:`ground_blocks`), and one task per block (:func:`classify_block`):

1. loads, from a range of tiles around the block, the points each tile's
   window owns: every point of that range once;
2. classifies them;
3. checks its certificate: each point routed to a tile of the block has a
   reach (:attr:`meshcore.GroundResult.reach`), the half-side of the square
   that holds every point its class depends on.  When a square leaves the
   range of tiles loaded (a side on the grid's edge holds everything beyond
   it), the task loads the tiles it reaches and classifies again.  The reach
   is bounded (:meth:`meshcore.GroundParameters.max_reach`), so this ends,
   and every point gets the class the whole survey gives it;
4. writes each tile's ground points as its spill files (one per ground spill
   file, of the same name), which the mesh stage reads as any run's.  A
   point and its exact copies get one class, the loaded cloud's.

A tile is done when each of its ground spill files has its counterpart: a run
stopped in this stage goes on with the blocks not done.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..tiling.grid import TileGrid, tile_dir
from ..tiling.routing import GROUND_SPILL, grow_hull
from ..tiling.scratch import Scratch

__all__ = ["GROUND_COLUMNS", "CLASSIFIED", "GroundJob", "GroundSummary", "classify_block", "ground_blocks", "tile_done",
           "ground_provenance"]

GROUND_COLUMNS = ("return_number", "number_of_returns")
"""The attributes the ground spill files carry after x, y and z."""

CLASSIFIED = "classified"
"""The folder, in each tile's work folder, of the positions in their files of
the ground points its window owns, one file per input (``SSSSSS.npy``)."""

METHOD = "smrf-tin"
"""The method's name in the provenance: meshcore's variant of SMRF (Pingel et al. 2013) with a ground TIN."""


@dataclass(frozen=True)
class GroundJob:
    """The ground classification of a block of tiles (small and picklable).

    Tiles are grouped into blocks (:func:`ground_blocks`) because a decision
    reads far (about a hundred metres with the default parameters): a block
    loads that margin once for all its tiles."""

    rows: tuple[int, int]
    """First and last row of the block's tiles."""
    cols: tuple[int, int]
    scratch: Scratch
    grid: TileGrid
    buffer: float
    unit: float
    """Metres in one unit of the coordinates (heights already in that unit)."""
    parameters: dict[str, float] = field(default_factory=dict)
    """:class:`meshcore.GroundParameters` fields other than the defaults."""
    columns: tuple[str, ...] = GROUND_COLUMNS
    """The spill files' columns after x, y, z: :data:`GROUND_COLUMNS`, and ``point_index`` for
    ``terrain classify``, which then gets each tile's ground points by file and position
    (:data:`CLASSIFIED`)."""
    hull: NDArray[np.float64] | None = None
    """The convex hull ``(h, 2)`` of the survey's points: the openings read no cell beyond it, in
    every block alike (None: each block's own points' hull)."""
    threads: int = 1
    """Threads the block's filter may use (:func:`meshcore.classify_ground`): the run's threads left
    idle by fewer blocks than threads (a survey of one block on one of two cores)."""

    def tiles(self) -> list[tuple[int, int]]:
        return [(r, c) for r in range(self.rows[0], self.rows[1] + 1) for c in range(self.cols[0], self.cols[1] + 1)]


def ground_blocks(grid: TileGrid, tile_points: dict[tuple[int, int], int], margin: float,
                  budget: int = 6_000_000) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """Blocks of ``k`` x ``k`` tiles, ``k`` such that a block is at least
    eight times the ``margin`` a decision reads across (the margin loaded
    around it then costs at most about half as much again as the block), but
    holds about ``budget`` points at most (``tile_points``: points routed to
    each tile).  A survey smaller than that is one block."""
    k = max(1, math.ceil(8.0 * margin / grid.tile_size))
    mean = max(1.0, sum(tile_points.values()) / max(1, len(tile_points)))
    k = max(1, min(k, int(math.sqrt(budget / mean))))
    return [((r, min(r + k, grid.n_rows) - 1), (c, min(c + k, grid.n_cols) - 1))
            for r in range(0, grid.n_rows, k) for c in range(0, grid.n_cols, k)]


@dataclass(frozen=True)
class GroundSummary:
    """What a tile's classification found, over the points its window owns."""

    row: int
    col: int
    ground: int = 0
    not_ground: int = 0
    """Points classified as not ground (the low outliers among them)."""
    low_outliers: int = 0
    tiles_read: int = 0
    """The tiles whose points the certificate needed (the tile's own included)."""
    rounds: int = 0
    seconds: float = 0.0
    hull: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)), compare=False)
    """Points on the convex hull of the ground points the window owns."""

    def to_record(self) -> dict[str, Any]:
        """Every field but the hull (recorded as an array beside it)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "hull"}


def ground_provenance(parameters: dict[str, float] | None = None) -> dict[str, Any]:
    """The store's record of the ground stage: its method and every parameter."""
    from meshcore import GroundParameters

    return {"method": METHOD, "parameters": GroundParameters.from_dict(parameters or {}).to_dict(),
            "units": "metres (lengths), rise over run (slope)"}


def _spill_files(scratch: Scratch, row: int, col: int) -> list[str]:
    folder = f"{tile_dir(row, col)}/{GROUND_SPILL}"
    return sorted(name for name in scratch.names(folder) if name.endswith(".npy"))


def tile_done(scratch: Scratch, row: int, col: int) -> bool:
    """Whether every ground spill file of the tile has its ground points written."""
    own = set(scratch.names(tile_dir(row, col)))
    return all(name in own for name in _spill_files(scratch, row, col))


def _load(scratch: Scratch, row: int, col: int, width: int) -> tuple[list[str], list[NDArray[np.float64]]]:
    names = _spill_files(scratch, row, col)
    folder = f"{tile_dir(row, col)}/{GROUND_SPILL}"
    arrays = [a.reshape(-1, width) for a in scratch.load_many([f"{folder}/{n}" for n in names])]
    return names, arrays


def _tile_range(grid: TileGrid, x: NDArray[np.float64], y: NDArray[np.float64], reach: NDArray[np.float64],
                where: NDArray[np.bool_] | None = None) -> tuple[int, int, int, int]:
    """Rows and columns (inclusive) of the tiles the squares of half-side ``reach`` around the points ``x, y``
    (those of ``where``, when given; at least one) meet: the bins of the squares' extreme sides, as the bins
    rise with the coordinate."""
    def extreme(values: NDArray[np.float64], axis: int, low: bool) -> int:
        kept = True if where is None else where
        value = np.min(values, where=kept, initial=np.inf) if low else np.max(values, where=kept, initial=-np.inf)
        return int(grid.bins(np.array([value]), axis)[0])

    return (extreme(y - reach, 1, True), extreme(y + reach, 1, False),
            extreme(x - reach, 0, True), extreme(x + reach, 0, False))


def _own_rows(grid: TileGrid, row: int, col: int, parts: list[NDArray[np.float64]]) -> list[NDArray[np.bool_]]:
    """Which points of each of a tile's ground spill files (``parts``) its window owns (each point of the
    survey in one tile only)."""
    out = []
    for part in parts:
        rows, cols = grid.owner(part[:, 0], part[:, 1])
        out.append((rows == row) & (cols == col))
    return out


def _owned(parts: list[NDArray[np.float64]], own: list[NDArray[np.bool_]], width: int) -> NDArray[np.float64]:
    """The points of a tile's ground spill files that its window owns (``own``: :func:`_own_rows`), in order,
    as columns ``(width, n)``: classified from contiguous x, y and z."""
    out = np.empty((width, sum(int(np.count_nonzero(mine)) for mine in own)))
    at = 0
    for part, mine in zip(parts, own):
        count = int(np.count_nonzero(mine))
        for k in range(width):
            np.compress(mine, part[:, k], out=out[k, at:at + count])
        at += count
    return out


def _hashes(rows: NDArray[np.float64]) -> NDArray[np.uint64]:
    """A 64-bit hash of each row's bytes (FNV-1a over its 8-byte words); ``rows`` is (n, k), n may be 0."""
    words = np.ascontiguousarray(rows, dtype=np.float64).view(np.uint64)
    h = np.full(rows.shape[0], 0xCBF29CE484222325, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for k in range(words.shape[1]):
            h ^= words[:, k]
            h *= np.uint64(0x100000001B3)
    return h


class _RowIndex:
    """Finds rows among the rows of ``cloud`` (each row sought is one of them):
    by hash, every match checked, and rows whose hash another row shares
    found byte for byte.  ``among`` (optional): the only rows of ``cloud`` the
    index holds; a row sought that is not among them is found as -1."""

    def __init__(self, cloud: NDArray[np.float64], among: NDArray[np.int64] | None = None) -> None:
        self.cloud = cloud
        self.rows = np.arange(cloud.shape[0]) if among is None else among
        hashes = _hashes(cloud[self.rows])
        order = np.argsort(hashes, kind="stable")
        self.order = self.rows[order]
        self.sorted = hashes[order]

    def find(self, rows: NDArray[np.float64]) -> NDArray[np.int64]:
        if self.sorted.shape[0] == 0:
            return np.full(rows.shape[0], -1, dtype=np.int64)
        hashes = _hashes(rows)
        at = self.order[np.minimum(np.searchsorted(self.sorted, hashes), self.sorted.shape[0] - 1)]
        wrong = np.flatnonzero(~(self.cloud[at] == rows).all(axis=1))
        for i in wrong.tolist():  # a collision of hashes: the equal rows among those of that hash
            lo, hi = np.searchsorted(self.sorted, hashes[i : i + 1], side="left")[0], \
                np.searchsorted(self.sorted, hashes[i : i + 1], side="right")[0]
            candidates = self.order[lo:hi]
            equal = candidates[(self.cloud[candidates] == rows[i]).all(axis=1)]
            at[i] = equal[0] if equal.shape[0] else -1
        return at


class _CloudRows:
    """Where each row of a tile's spill files lies in the block's cloud.

    A tile's own points (those its window owns) are the cloud's rows of that
    tile, in the same order (:func:`_owned`); the others, copies of a
    neighbour's points within the route's buffer, are found by hash among the
    rows near a tile edge (every point any tile holds as a copy lies there;
    any other row, were there one, among all rows).  Every row of the cloud is
    owned once, and a point's class depends on its coordinates alone
    (:func:`meshcore.classify_ground`), so a copy gets its original's class."""

    def __init__(self, grid: TileGrid, cloud: NDArray[np.float64], starts: dict[tuple[int, int], int],
                 slack: float) -> None:
        self.cloud = cloud
        self.starts = starts
        x, y = cloud[:, 0], cloud[:, 1]
        near = (grid.bins(x - slack, 0) != grid.bins(x + slack, 0)) | (grid.bins(y - slack, 1) != grid.bins(y + slack, 1))
        self.near_edges = _RowIndex(cloud, np.flatnonzero(near))
        self.everywhere: _RowIndex | None = None

    def rows(self, key: tuple[int, int], parts: list[NDArray[np.float64]],
             own: list[NDArray[np.bool_]]) -> list[NDArray[np.int64]]:
        """The cloud's row of each row of the tile ``key``'s spill ``parts``
        (``own``: which of them its window owns)."""
        out = []
        start = self.starts[key]
        for part, mine in zip(parts, own):
            at = np.empty(part.shape[0], dtype=np.int64)
            count = int(np.count_nonzero(mine))
            at[mine] = np.arange(start, start + count)
            start += count
            copies = np.flatnonzero(~mine)
            found = self.near_edges.find(part[copies])
            missing = found < 0
            if missing.any():
                self.everywhere = self.everywhere or _RowIndex(self.cloud)
                found[missing] = self.everywhere.find(part[copies[missing]])
                if (found < 0).any():  # the block loads every tile within the buffer of its own
                    raise RuntimeError(f"tile {key}: a point of its buffer is in no tile the block loaded")
            at[copies] = found
            out.append(at)
        return out


def classify_block(job: GroundJob) -> list[GroundSummary]:
    """Classify the points routed to a block of tiles; write each tile's ground points as its spill files."""
    from meshcore import GroundParameters, classify_ground

    t0 = time.perf_counter()
    grid, scratch = job.grid, job.scratch
    parameters = GroundParameters.from_dict(job.parameters)
    width = 3 + len(job.columns)
    x_lo, y_lo, _, _ = grid.box(job.rows[0], job.cols[0])
    _, _, x_hi, y_hi = grid.box(job.rows[1], job.cols[1])
    # the points to certify: those routed to a tile of the block (its windows and buffer), and a hair more
    slack = job.buffer + 1e-9 * max(abs(x_lo), abs(x_hi), abs(y_lo), abs(y_hi), 1.0)
    held = (x_lo - slack, y_lo - slack, x_hi + slack, y_hi + slack)
    corners = np.array([[held[0], held[1]], [held[2], held[3]]])
    # the outer tiles also hold the points beyond the grid (a stale header): every one of theirs
    held = (-math.inf if job.cols[0] == 0 else held[0], -math.inf if job.rows[0] == 0 else held[1],
            math.inf if job.cols[1] == grid.n_cols - 1 else held[2], math.inf if job.rows[1] == grid.n_rows - 1 else held[3])
    block = _tile_range(grid, corners[:, 0], corners[:, 1], np.full(2, parameters.margin(job.unit) + 2 * parameters.cell / job.unit))
    loaded: dict[tuple[int, int], NDArray[np.float64]] = {}
    spilled = {key: _load(scratch, *key, width) for key in job.tiles()}  # the block's own files, written below
    owned_rows = {key: _own_rows(grid, *key, parts) for key, (_, parts) in spilled.items()}
    rounds = 0
    while True:
        rounds += 1
        r0, r1, c0, c1 = block
        for key in ((r, c) for r in range(r0, r1 + 1) for c in range(c0, c1 + 1)):
            if key not in loaded:
                parts = spilled[key][1] if key in spilled else _load(scratch, *key, width)[1]
                mine = owned_rows[key] if key in owned_rows else _own_rows(grid, *key, parts)
                loaded[key] = _owned(parts, mine, width)
        keys = sorted(loaded)
        columns = np.concatenate([loaded[k] for k in keys], axis=1)  # (width, n): x, y, z, ...
        x, y = columns[0], columns[1]
        result = classify_ground(
            x, y, columns[2], unit=job.unit, parameters=parameters,
            return_number=columns[3], number_of_returns=columns[4], hull=job.hull, threads=job.threads,
        )
        mine = (x >= held[0]) & (x <= held[2]) & (y >= held[1]) & (y <= held[3])
        needed = _tile_range(grid, x, y, result.reach, mine) if mine.any() else block
        grown = (min(needed[0], r0), max(needed[1], r1), min(needed[2], c0), max(needed[3], c1))
        if grown == block:
            break
        block = grown
    # each tile's spill files, point by point: a point and its exact copies get one class
    sizes = np.cumsum([0] + [loaded[k].shape[1] for k in keys])
    starts = {k: int(sizes[i]) for i, k in enumerate(keys)}
    lookup = _CloudRows(grid, columns.T, starts, slack)
    summaries = []
    for row, col in job.tiles():
        names, parts = spilled[(row, col)]
        start, stop = starts[(row, col)], starts[(row, col)] + loaded[(row, col)].shape[1]  # the tile's own rows
        files = {}
        positions: dict[str, list[NDArray]] = {}
        for name, part, at in zip(names, parts, lookup.rows((row, col), parts, owned_rows[(row, col)])):
            files[f"{tile_dir(row, col)}/{name}"] = np.ascontiguousarray(part[result.ground[at], :3])
            if "point_index" in job.columns:
                mine = result.ground[at] & (at >= start) & (at < stop)
                index = part[mine, 3 + job.columns.index("point_index")].astype(np.int64)
                positions.setdefault(name.split("_", 1)[0], []).append(index)
        files.update({f"{tile_dir(row, col)}/{CLASSIFIED}/{source}.npy": np.concatenate(found)
                      for source, found in positions.items()})
        scratch.save_many(files)
        ground = result.ground[start:stop]
        kept = columns[:3, start:stop][:, ground]
        summaries.append(GroundSummary(
            row, col, ground=int(np.count_nonzero(ground)), not_ground=int(np.count_nonzero(~ground)),
            low_outliers=int(np.count_nonzero(result.low_outlier[start:stop])),
            tiles_read=(block[1] - block[0] + 1) * (block[3] - block[2] + 1), rounds=rounds,
            seconds=time.perf_counter() - t0, hull=grow_hull(np.empty((0, 3)), kept[0], kept[1], kept[2]),
        ))
    return summaries
