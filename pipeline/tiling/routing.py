"""Routing points to tiles in one streaming pass, the spill files, and the survey's hull.

Routing sends each point to every tile whose core grown by ``buffer`` holds
it, appending to that tile's spill files on disk, so memory stays bounded
whatever the archive size.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

import meshcore
from meshcore.kernels import empty, larger, zeros

from .binning import bin_of
from .grid import TileGrid, tile_dir
from .scratch import Scratch

__all__ = [
    "PointCounts", "POINT_FATES", "RouteResult", "TileSpiller", "route_rows", "route_points", "drop_source_spill",
    "source_spill", "spill_by_source", "spill_intact", "load_tile_points", "neighbour_tile_points", "points_in_box",
    "hull_candidates", "grow_hull", "PRODUCT_SPILL", "GROUND_SPILL",
]


@dataclass(frozen=True)
class PointCounts:
    """One input file's points by fate: read, left out by class or as
    withheld, outside the bbox, kept."""

    path: str
    read: int = 0
    filtered_class: int = 0
    filtered_withheld: int = 0
    outside_bbox: int = 0
    kept: int = 0

    def by_fate(self) -> dict[str, int]:
        """The counts by name, in :data:`POINT_FATES` order."""
        return {name: getattr(self, name) for name in POINT_FATES}


POINT_FATES = ("read", "filtered_class", "filtered_withheld", "outside_bbox", "kept")
"""The counts of :class:`PointCounts`, in order."""


@dataclass(frozen=True)
class RouteResult(PointCounts):
    """What routing one input file leaves, and its route record in the work
    folder: its points counted by fate, its spill files, its digest and the
    convex hull of its kept points.

    Three kinds: a routed file; a bad file skipped with ``skip_bad_files``
    (``skipped`` says why; its spill files are dropped); and a window source
    (``window``: a COPC file the tiles read by window, of which routing only
    takes the hull and bounds; its counts come from the tiles, :meth:`counted`).
    """

    beyond_grid: int = 0
    """Kept points outside the grid (a stale header)."""
    bounds: tuple[float, float, float, float] | None = None
    """The kept points' box; None when none was kept."""
    parts: tuple[tuple[int, ...], ...] = ()
    """The spill files written, for a resume to check they are still there."""
    product_parts: tuple[tuple[int, ...], ...] = ()
    """The product points' spill files written (:mod:`pipeline.products`)."""
    tile_points: tuple[tuple[int, int, int], ...] = ()
    """(row, col, points) of every tile it spilled to: the tiles' work."""
    sha256: str | None = None
    seconds: float | None = None
    skipped: str | None = None
    window: bool = False
    hull: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)), compare=False, repr=False)
    filtered_returns: int = 0
    """Points of the DTM's classes left out by the return filter (and read for no product)."""
    products_only: int = 0
    """Points read for the products only: not of the DTM's classes or returns."""

    def _more_fates(self) -> dict[str, int]:
        """The fates of a return filter or of products, when the file had any
        (records and reports of other runs stay as they always were)."""
        return {k: getattr(self, k) for k in ("filtered_returns", "products_only") if getattr(self, k)}

    def counted(self, read: int, filtered_class: int, filtered_withheld: int, outside_bbox: int, kept: int) -> RouteResult:
        """This result with the counts the tiles made of a window source."""
        return replace(self, read=read, filtered_class=filtered_class, filtered_withheld=filtered_withheld,
                       outside_bbox=outside_bbox, kept=kept)

    def _bounds(self) -> dict[str, Any]:
        return {} if self.bounds is None else {"bounds": list(self.bounds)}

    def to_record(self) -> dict[str, Any]:
        """The record's JSON payload (the hull is saved beside it): each kind
        with the entries, in the order, that work folders have always held,
        so that a work folder of an earlier version resumes."""
        if self.skipped is not None:
            return {"path": self.path, "skipped": self.skipped, **self.by_fate()}
        if self.window:
            return {"path": self.path, "window": True, "parts": [list(p) for p in self.parts], "sha256": self.sha256,
                    **self._bounds()}
        products = {"product_parts": [list(p) for p in self.product_parts]} if self.product_parts else {}
        return {"path": self.path, **self.by_fate(), "beyond_grid": self.beyond_grid, **self._bounds(),
                "parts": [list(p) for p in self.parts], "tile_points": [list(t) for t in self.tile_points],
                "sha256": self.sha256, "seconds": self.seconds, **products, **self._more_fates()}

    @classmethod
    def from_record(cls, payload: Mapping[str, Any]) -> RouteResult:
        """The result of a record read by ``WorkDir.recorded("route", key, "hull")``."""
        data = {k: v for k, v in payload.items() if k in _ROUTE_FIELDS}
        if data.get("bounds") is not None:
            data["bounds"] = tuple(data["bounds"])
        data["parts"] = tuple(tuple(p) for p in data.get("parts", ()))
        data["product_parts"] = tuple(tuple(p) for p in data.get("product_parts", ()))
        data["tile_points"] = tuple(tuple(t) for t in data.get("tile_points", ()))
        return cls(**data)

    def to_report(self) -> dict[str, Any]:
        """The file's entry in the run report (``RunReport.files``)."""
        if self.window:
            return {"path": self.path, "sha256": self.sha256, **self._bounds(), **self.by_fate()}
        return {"path": self.path, **self.by_fate(), "beyond_grid": self.beyond_grid, **self._bounds(),
                "sha256": self.sha256, "seconds": self.seconds, **self._more_fates()}


_ROUTE_FIELDS = frozenset(f.name for f in fields(RouteResult))


class TileSpiller:
    """Routes points of one source to the tiles' spill files, holding at most
    ``budget`` points in memory (bounded memory whatever the archive size).

    ``folder``: a folder inside each tile's where its files go (the product
    points' spill files, :mod:`pipeline.products`; empty: the DTM's points,
    in the tile's own folder).  Points are rows of any number of columns,
    x, y, z first (:meth:`add`)."""

    def __init__(self, scratch: Scratch, grid: TileGrid, buffer: float, source: int, budget: int = 4_000_000,
                 folder: str = ""):
        self.folder = folder
        self.scratch = scratch
        self.grid = grid
        self.buffer = float(buffer)
        self.source = int(source)
        self.budget = int(budget)
        self._pending: dict[tuple[int, int], list[NDArray[np.float64]]] = {}
        self._held = 0
        self._parts: dict[tuple[int, int], int] = {}
        self._points: dict[tuple[int, int], int] = {}

    def add(self, x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64],
            extra: NDArray[np.float64] | None = None) -> None:
        """Route points: their rows in the spill files are x, y, z, then the
        columns of ``extra`` ``(n, k)``, if given (:func:`route_rows`)."""
        if x.shape[0] == 0:
            return
        g = self.grid
        offsets, pts = route_rows(g, self.buffer, x, y, z, extra)
        for k in np.flatnonzero(offsets[1:] > offsets[:-1]).tolist():
            s, e = int(offsets[k]), int(offsets[k + 1])
            key = (k // g.n_cols, k % g.n_cols)
            self._pending.setdefault(key, []).append(pts[s:e])
            self._points[key] = self._points.get(key, 0) + (e - s)
            self._held += e - s
        if self._held > self.budget:
            self.flush()

    @property
    def parts(self) -> list[list[int]]:
        """``[row, col, n]``: the spill files written for each tile (for the record)."""
        return [[r, c, n] for (r, c), n in sorted(self._parts.items())]

    @property
    def points(self) -> list[list[int]]:
        """``[row, col, n]``: the points sent to each tile (its window and buffer)."""
        return [[r, c, n] for (r, c), n in sorted(self._points.items())]

    def flush(self) -> None:
        files = {}
        for key, chunks in self._pending.items():
            part = self._parts.get(key, 0)
            folder = f"{tile_dir(*key)}/{self.folder}" if self.folder else tile_dir(*key)
            files[f"{folder}/{_spill_name(self.source, part)}"] = chunks[0] if len(chunks) == 1 else np.concatenate(chunks)
            self._parts[key] = part + 1
        self.scratch.save_many(files)
        self._pending.clear()
        self._held = 0


_ROUNDOFF = 2.0**-53


def _read_only(values: NDArray) -> NDArray[np.float64]:
    """A C-contiguous float64 read-only view (one compiled kernel, whatever the caller's arrays)."""
    view = np.ascontiguousarray(values, dtype=np.float64).view()
    view.flags.writeable = False
    return view


def route_rows(grid: TileGrid, buffer: float, x: NDArray[np.float64], y: NDArray[np.float64],
               z: NDArray[np.float64], extra: NDArray[np.float64] | None = None,
               ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The rows ``x, y, z, *extra`` of the points routed to each tile
    (``extra``: ``(n, k)`` more columns, or none): tile ``t`` (``row *
    n_cols + col``) gets ``rows[offsets[t]:offsets[t + 1]]``.  The columns
    are gathered straight into the tiles' rows: the points are never first
    stacked into rows of their own (a copy of every point, 20 MB for a
    700k-point file's product rows)."""
    g = grid
    more = np.empty((x.shape[0], 0)) if extra is None else np.asarray(extra)
    if more.ndim == 1:
        more = more.reshape(-1, 1)
    return _route_kernel(_read_only(x), _read_only(y), _read_only(z), _read_only(more), g.x0, g.y0,
                         1.0 / g.tile_size, *g.bin_bounds(0), *g.bin_bounds(1), float(buffer), g.n_cols, g.n_tiles)


@meshcore.kernels.kernel
def _route_kernel(xs, ys, zs, extra, x0, y0, inv_size, below_x, above_x, below_y, above_y, buffer, n_cols, n_tiles):
    """Every point (x, y, z and its row of ``extra``) copied to each tile
    whose core grown by ``buffer`` holds it: ``pts[offsets[t]:offsets[t + 1]]`` goes to
    tile ``t``.  Within a tile, points for which it is the lowest row and
    column of their reach come first, then the next column, row, ...; each
    group in input order (a counting sort, stable)."""
    n = xs.shape[0]
    more = extra.shape[1]
    width = 3 + more
    c_lo = empty(n, dtype=np.int32)
    r_lo = empty(n, dtype=np.int32)
    c_span = empty(n, dtype=np.int32)
    r_span = empty(n, dtype=np.int32)
    span_c = 1
    span_r = 1
    for i in range(n):
        xi = xs[i]
        yi = ys[i]
        # a tile claims every point of its closed window grown by the buffer
        # (``held_box``): a point on that box's edge, or a rounding away from
        # it, goes to the tile too (to both tiles, on a shared edge)
        mx = 8.0 * _ROUNDOFF * (abs(xi) + buffer)
        my = 8.0 * _ROUNDOFF * (abs(yi) + buffer)
        c0 = bin_of(xi - buffer - mx, x0, inv_size, below_x, above_x)
        r0 = bin_of(yi - buffer - my, y0, inv_size, below_y, above_y)
        sc = bin_of(xi + buffer + mx, x0, inv_size, below_x, above_x) - c0 + 1
        sr = bin_of(yi + buffer + my, y0, inv_size, below_y, above_y) - r0 + 1
        c_lo[i] = c0
        r_lo[i] = r0
        c_span[i] = sc
        r_span[i] = sr
        span_c = larger(span_c, sc)
        span_r = larger(span_r, sr)
    groups = span_r * span_c
    start = zeros(n_tiles * groups + 1, dtype=np.int64)
    for i in range(n):
        if r_span[i] == 1 and c_span[i] == 1:  # most points: one tile
            start[(r_lo[i] * n_cols + c_lo[i]) * groups + 1] += 1
            continue
        for dr in range(r_span[i]):
            for dc in range(c_span[i]):
                start[((r_lo[i] + dr) * n_cols + c_lo[i] + dc) * groups + dr * span_c + dc + 1] += 1
    for k in range(n_tiles * groups):
        start[k + 1] += start[k]
    pts = empty((start[n_tiles * groups], width))
    offsets = empty(n_tiles + 1, dtype=np.int64)
    for t in range(n_tiles + 1):
        offsets[t] = start[t * groups]
    for i in range(n):
        for dr in range(r_span[i]):  # most points: one tile
            for dc in range(c_span[i]):
                slot = ((r_lo[i] + dr) * n_cols + c_lo[i] + dc) * groups + dr * span_c + dc
                at = start[slot]
                start[slot] = at + 1
                pts[at, 0] = xs[i]
                pts[at, 1] = ys[i]
                pts[at, 2] = zs[i]
                for k in range(more):
                    pts[at, 3 + k] = extra[i, k]
    return offsets, pts


def route_points(grid: TileGrid, buffer: float, points: NDArray[np.float64], row: int, col: int) -> NDArray[np.float64]:
    """The points of ``points`` (n, 3) that routing sends to tile (row, col),
    in the order routing gives them (:class:`TileSpiller`)."""
    g = grid
    offsets, pts = route_rows(g, buffer, points[:, 0], points[:, 1], points[:, 2])
    t = row * g.n_cols + col
    return pts[offsets[t]:offsets[t + 1]]


def spill_by_source(scratch: Scratch, row: int, col: int) -> dict[int, NDArray[np.float64]]:
    """The points routed to a tile, by source number (each in reading order)."""
    folder = tile_dir(row, col)
    names = [name for name in scratch.names(folder) if name.endswith(".npy")]
    arrays = scratch.load_many([f"{folder}/{name}" for name in names])
    out: dict[int, list[NDArray[np.float64]]] = {}
    for name, array in zip(names, arrays):
        out.setdefault(int(name.split("_", 1)[0]), []).append(array)
    return {k: np.concatenate(v) if len(v) > 1 else v[0] for k, v in out.items()}


def drop_source_spill(scratch: Scratch, source: int) -> None:
    """Delete every spill file of one source, its product points' too (it is routed again, or left out)."""
    scratch.remove(source_spill(scratch, f"{source:06d}") + scratch.glob(f"tiles/*/*/{source:06d}_*.npy"))


def source_spill(scratch: Scratch, source: str) -> list[str]:
    """The keys of every spill file of one source (its number, as in the file names)."""
    return scratch.glob(f"tiles/*/{source}_*.npy")


def _spill_name(source: int, part: int) -> str:
    """The file of one source's ``part``-th flush into a tile."""
    return f"{source:06d}_{part:06d}.npy"


def spill_intact(scratch: Scratch, source: int, parts: list[list[int]]) -> bool:
    """Whether every spill file :attr:`TileSpiller.parts` listed is still there."""
    for r, c, n in parts:
        names = set(scratch.names(tile_dir(r, c)))
        if not all(_spill_name(source, k) in names for k in range(n)):
            return False
    return True


GROUND_SPILL = "ground"
"""The folder, in each tile's work folder, of the points routed to it for the
ground stage (:mod:`pipeline.meshing.ground`): x, y, z, return number and
number of returns.  The stage writes the ground ones as the tile's spill files."""

PRODUCT_SPILL = "products"
"""The folder, in each tile's work folder, of the product points routed to it (:mod:`pipeline.products`)."""


def load_tile_points(scratch: Scratch, row: int, col: int, folder: str = "", width: int = 3) -> NDArray[np.float64]:
    """All points routed to a tile, ``(n, 3)``, in source then reading order
    (``folder``: the points of that spill folder, rows of ``width`` columns)."""
    folder = f"{tile_dir(row, col)}/{folder}" if folder else tile_dir(row, col)
    parts = [f"{folder}/{name}" for name in scratch.names(folder) if name.endswith(".npy")]
    if not parts:
        return np.empty((0, width))
    return np.concatenate(scratch.load_many(parts))


class _RecentTilePoints:
    """Tiles' points read by this process, the most recently used first, up to
    a budget of bytes; read only.  Keys hold a run's id: a later run (whose
    routing may have rewritten a tile) never sees an earlier run's points."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self._arrays: OrderedDict[tuple, NDArray[np.float64]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key: tuple) -> NDArray[np.float64] | None:
        with self._lock:
            found = self._arrays.get(key)
            if found is not None:
                self._arrays.move_to_end(key)
            return found

    def put(self, key: tuple, points: NDArray[np.float64]) -> None:
        # small tiles only: a search that reads many tiles is slow when they
        # are many and small (sparse points, tiny tiles), while a dense
        # survey's large tiles are few, and would only fill the memory
        if points.nbytes > self.budget // 64:
            return
        with self._lock:
            if key in self._arrays:
                return
            self._arrays[key] = points
            self._bytes += points.nbytes
            while self._bytes > self.budget:
                _, old = self._arrays.popitem(last=False)
                self._bytes -= old.nbytes


_RECENT = _RecentTilePoints(64 * 2**20)


def neighbour_tile_points(
    scratch: Scratch, row: int, col: int, run_id: str, load: Callable[[int, int], NDArray[np.float64]] | None = None
) -> NDArray[np.float64]:
    """:func:`load_tile_points` (read only) for a tile that is not the caller's:
    kept in memory for later calls of the same run (``run_id``; empty: not
    kept).  A tile whose window lies in a data void reads tile after tile
    around it, and so do its neighbours: each file is read once, not once per
    tile and round of the search.  ``load(row, col)`` reads a tile's points
    (default: its spill files)."""
    key = (scratch.root, run_id, row, col)
    points = _RECENT.get(key) if run_id else None
    if points is None:
        points = load(row, col) if load is not None else load_tile_points(scratch, row, col)
        points.flags.writeable = False
        if run_id:
            _RECENT.put(key, points)
    return points


def points_in_box(
    points: NDArray[np.float64], box: tuple[float, float, float, float]
) -> NDArray[np.bool_]:
    """Mask of the points (n, 2 or more: x, y, ...) inside a closed box."""
    # always a read-only view, as the points loaded from the scratch folder
    # are: one compiled kernel, not one per flag
    view = points.view()
    view.flags.writeable = False
    return _in_box(view, float(box[0]), float(box[1]), float(box[2]), float(box[3]))


@meshcore.kernels.kernel
def _in_box(points, x_min, y_min, x_max, y_max):
    """:func:`points_in_box` in one pass (numpy's takes seven over strided columns)."""
    out = empty(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        x = points[i, 0]
        y = points[i, 1]
        out[i] = (x >= x_min) & (x <= x_max) & (y >= y_min) & (y <= y_max)
    return out


def hull_candidates(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The points of ``points`` (n, 3) on their convex hull (exact; collinear ones kept)."""
    if points.shape[0] == 0:
        return points.copy()
    return grow_hull(points[:0], points[:, 0], points[:, 1], points[:, 2])


def grow_hull(
    hull: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The points (n, 3) on the convex hull of ``hull`` and the points x, y, z.

    The hull of a union is the hull of the parts' hulls (points on its edges
    are on their part's hull's edges), so only the new points' hull is
    gathered: a chunk of millions is never copied whole.
    """
    from meshcore import convex_hull

    if x.shape[0] == 0:
        return hull.copy()
    own = convex_hull(x, y)
    merged = np.concatenate([hull, np.column_stack([x[own], y[own], z[own]])])
    return merged[convex_hull(merged[:, 0], merged[:, 1])]
