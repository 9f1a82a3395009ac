"""The global tile grid, and routing points to tiles in one streaming pass.

One grid for the whole run: its south-west corner is snapped to a multiple of
the resolution, tiles are ``tile_cells x tile_cells`` DEM cells.  A point is
*owned* by the tile whose core holds it (half-open boxes; the outer tiles
extend to infinity, so every point has exactly one owner).  Routing sends each
point to every tile whose core grown by ``buffer`` holds it, appending to that
tile's spill files on disk, so memory stays bounded whatever the archive size.
"""

from __future__ import annotations

import math
import numbers
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

import meshcore

from ..errors import UsageError
from .scratch import Scratch

__all__ = [
    "TileGrid", "PointCounts", "POINT_FATES", "RouteResult", "TileSpiller", "drop_source_spill", "load_tile_points", "neighbour_tile_points", "points_in_box",
    "intersect_boxes", "hull_candidates", "grow_hull", "tile_key",
]


@dataclass(frozen=True)
class TileGrid:
    """The DEM grid and its tiles: the one grid of a run, its store and its
    provenance.

    Attributes
    ----------
    x0, y0 : float
        South-west outer corner of cell (0, 0), a multiple of ``resolution``
        in a grid made by :meth:`covering` (CRS units).
    resolution : float
        Cell size (CRS units), > 0.
    tile_cells : int
        Tile (and store chunk) edge in cells.  Tile ``(0, 0)`` is the
        south-west tile; tiles at the east edge may be narrower.
    nx, ny : int
        Cells along x and y.  ``ny`` must be a multiple of ``tile_cells``.

    Why ``ny`` is a whole number of tiles: the store is north-up, so its chunk
    rows are counted from the north, while tiles are counted from the south.
    They line up only if ``ny`` is a multiple of ``tile_cells``; otherwise
    every tile would straddle two chunks and parallel writes would need locks.
    :meth:`covering` rounds ``ny`` up (pads the north edge with no-data rows).

    Two serialisations, with the same entries in two orders that stores have
    always had, so that their bytes do not change: :meth:`to_dict` (the
    provenance's ``grid``, in field order) and :meth:`to_store_attr` (the
    store's ``grid`` attribute).  :meth:`from_dict` reads either.

    Examples
    --------
    >>> g = TileGrid(x0=100.0, y0=200.0, resolution=10.0, nx=3, ny=2, tile_cells=2)
    >>> g.x.tolist(), g.y.tolist()
    ([105.0, 115.0, 125.0], [215.0, 205.0])
    >>> g.geotransform
    (100.0, 10.0, 0.0, 220.0, 0.0, -10.0)
    >>> list(g.to_dict()), list(g.to_store_attr())
    (['x0', 'y0', 'resolution', 'tile_cells', 'nx', 'ny'], ['x0', 'y0', 'resolution', 'nx', 'ny', 'tile_cells'])
    >>> TileGrid.from_dict(g.to_store_attr()) == TileGrid.from_dict(g.to_dict()) == g
    True
    """

    x0: float
    y0: float
    resolution: float
    tile_cells: int
    nx: int
    ny: int

    def __post_init__(self) -> None:
        for name in ("x0", "y0", "resolution"):
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise UsageError(f"TileGrid.{name} must be a finite number, got {value!r}")
        if self.resolution <= 0:
            raise UsageError(f"TileGrid.resolution must be > 0, got {self.resolution!r}")
        for name in ("nx", "ny", "tile_cells"):
            value = getattr(self, name)
            if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 1:
                raise UsageError(f"TileGrid.{name} must be an integer >= 1, got {value!r}")
        if self.ny % self.tile_cells:
            padded = -(-self.ny // self.tile_cells) * self.tile_cells
            raise UsageError(
                f"TileGrid.ny={self.ny} is not a multiple of tile_cells={self.tile_cells}: tiles counted "
                f"from the south would straddle the north-up store's chunks; use ny={padded} "
                "(pad the north edge)"
            )

    @classmethod
    def covering(cls, bounds: tuple[float, float, float, float], resolution: float, tile_cells: int) -> TileGrid:
        """The grid whose cells cover ``bounds`` (xmin, ymin, xmax, ymax), in whole tile rows."""
        xmin, ymin, xmax, ymax = bounds
        x0 = math.floor(xmin / resolution) * resolution
        y0 = math.floor(ymin / resolution) * resolution
        nx = max(1, int(math.floor((xmax - x0) / resolution)) + 1)
        ny = max(1, int(math.floor((ymax - y0) / resolution)) + 1)
        # a tile never outgrows the grid (one tile is the untiled case), and
        # the grid has whole tiles north-south: the store is north-up, so its
        # chunk rows line up with tile rows only when the grid ends on a tile edge
        tile_cells = max(1, min(int(tile_cells), max(nx, ny)))
        ny = -(-ny // tile_cells) * tile_cells
        return cls(float(x0), float(y0), float(resolution), int(tile_cells), nx, ny)

    @property
    def tile_size(self) -> float:
        return self.tile_cells * self.resolution

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """The box its cells cover (xmin, ymin, xmax, ymax)."""
        return (self.x0, self.y0, self.x0 + self.nx * self.resolution, self.y0 + self.ny * self.resolution)

    @property
    def n_cols(self) -> int:
        return -(-self.nx // self.tile_cells)

    @property
    def n_rows(self) -> int:
        return -(-self.ny // self.tile_cells)

    @property
    def n_tiles(self) -> int:
        return self.n_cols * self.n_rows

    def _inner_edges(self, axis: int) -> NDArray[np.float64]:
        origin, count = (self.x0, self.n_cols) if axis == 0 else (self.y0, self.n_rows)
        return origin + np.arange(1, count) * self.tile_size

    def window(self, row: int, col: int) -> tuple[float, float, float, float]:
        """Half-open ownership box of a tile; outer tiles reach to infinity."""
        ex = self._inner_edges(0)
        ey = self._inner_edges(1)
        x_lo = -math.inf if col == 0 else float(ex[col - 1])
        x_hi = math.inf if col == self.n_cols - 1 else float(ex[col])
        y_lo = -math.inf if row == 0 else float(ey[row - 1])
        y_hi = math.inf if row == self.n_rows - 1 else float(ey[row])
        return x_lo, y_lo, x_hi, y_hi

    def box(self, row: int, col: int) -> tuple[float, float, float, float]:
        """Finite box of the tile's cells (clipped to the grid)."""
        r0, r1, c0, c1 = self.cell_slice(row, col)
        return (
            self.x0 + c0 * self.resolution,
            self.y0 + r0 * self.resolution,
            self.x0 + c1 * self.resolution,
            self.y0 + r1 * self.resolution,
        )

    def cell_slice(self, row: int, col: int) -> tuple[int, int, int, int]:
        """Rows ``r0:r1`` (from the south) and columns ``c0:c1`` of the tile's cells."""
        r0 = row * self.tile_cells
        c0 = col * self.tile_cells
        return r0, min(r0 + self.tile_cells, self.ny), c0, min(c0 + self.tile_cells, self.nx)

    def owner(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(row, col) of the tile owning each point (the same edges as :meth:`window`)."""
        return self.bins(y, 1).astype(np.int64), self.bins(x, 0).astype(np.int64)

    def bins(self, values: NDArray[np.float64], axis: int) -> NDArray[np.intp]:
        """Tile column (axis 0, of x) or row (axis 1, of y) of every (finite)
        value: the number of inner tile edges at or below it, as ``np.searchsorted(edges,
        values, side="right")`` counts them, at a fraction of its cost.

        Division by the tile size guesses the bin to within one (the edges are
        rounded sums of the origin and multiples of the size); one comparison
        with each edge of the guessed bin makes it exact.
        """
        flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
        k = _bins(flat, self.x0 if axis == 0 else self.y0, 1.0 / self.tile_size, *self.bin_bounds(axis))
        return k.reshape(np.shape(values))

    def bin_bounds(self, axis: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lower and upper bounds of every tile column (axis 0) or row (axis 1):
        the inner edges, with -inf and +inf at the ends."""
        edges = self._inner_edges(axis)
        return np.concatenate([[-np.inf], edges]), np.concatenate([edges, [np.inf]])

    def tiles(self) -> list[tuple[int, int]]:
        return [(r, c) for r in range(self.n_rows) for c in range(self.n_cols)]

    def tiles_meeting(self, boxes) -> list[tuple[int, int]]:
        """The tiles (row, col), in order, whose windows hold a point of any of
        the closed ``boxes`` (x_min, y_min, x_max, y_max)."""
        corners = np.array(boxes, dtype=np.float64).reshape(-1, 4)
        row_lo, col_lo = self.owner(corners[:, 0], corners[:, 1])
        row_hi, col_hi = self.owner(corners[:, 2], corners[:, 3])
        found = set()
        for r0, c0, r1, c1 in zip(row_lo.tolist(), col_lo.tolist(), row_hi.tolist(), col_hi.tolist()):
            found.update((r, c) for r in range(r0, r1 + 1) for c in range(c0, c1 + 1))
        return sorted(found)

    def extends(self, other: TileGrid) -> bool:
        """Whether this grid is ``other`` grown to the north or east (or equal):
        the same origin, cells and tiles, at least its rows and columns.
        Its tiles then keep their numbers (rows count from the south)."""
        same = (self.x0, self.y0, self.resolution, self.tile_cells) == (other.x0, other.y0, other.resolution, other.tile_cells)
        return same and self.nx >= other.nx and self.ny >= other.ny

    def edge_tiles_moved_by(self, other: TileGrid) -> set[tuple[int, int]]:
        """The tiles of ``other`` (which this grid extends) whose window or
        box this grid changes: its northern row when rows were added (its
        window reached to infinity), its eastern column when columns or cells
        were (likewise, and its box is clipped to the grid).

        The strips along the data extent's edges that a tile holds from the
        start move with the extent too, but they only spare it rounds of
        loading: its piece is what its certificate says, whatever else it holds.
        """
        moved: set[tuple[int, int]] = set()
        if self.n_rows > other.n_rows:
            moved.update((other.n_rows - 1, c) for c in range(other.n_cols))
        if self.nx > other.nx:
            moved.update((r, other.n_cols - 1) for r in range(other.n_rows))
        return moved

    @property
    def x(self) -> NDArray[np.float64]:
        """Cell-centre x coordinates, ascending (west to east)."""
        return self.x0 + (np.arange(self.nx) + 0.5) * self.resolution

    @property
    def y(self) -> NDArray[np.float64]:
        """Cell-centre y coordinates, descending (north to south: the store's row 0 is the northern-most)."""
        return self.y_top - (np.arange(self.ny) + 0.5) * self.resolution

    @property
    def y_top(self) -> float:
        """The northern outer edge of the grid."""
        return self.y0 + self.ny * self.resolution

    @property
    def geotransform(self) -> tuple[float, float, float, float, float, float]:
        """GDAL's affine transform of the north-up grid: ``(x0, res, 0, y_top, 0, -res)``."""
        r = float(self.resolution)
        return (float(self.x0), r, 0.0, float(self.y_top), 0.0, -r)

    def to_dict(self) -> dict[str, float | int]:
        """The provenance's ``grid``: the fields in their order (x0, y0, resolution, tile_cells, nx, ny)."""
        return asdict(self)

    def to_store_attr(self) -> dict[str, float | int]:
        """The store's ``grid`` attribute: the same entries in the store's
        order (x0, y0, resolution, nx, ny, tile_cells), which every store
        written so far has; :meth:`from_dict` reads it too."""
        return {name: getattr(self, name) for name in _STORE_ORDER}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TileGrid:
        """The grid of :meth:`to_dict` or :meth:`to_store_attr` (either order)."""
        try:
            return cls(**data)
        except TypeError as err:
            raise UsageError(f"TileGrid.from_dict: {err}") from None


_STORE_ORDER = ("x0", "y0", "resolution", "nx", "ny", "tile_cells")
"""The key order of the store's ``grid`` attribute (:meth:`TileGrid.to_store_attr`)."""


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
    tile_points: tuple[tuple[int, int, int], ...] = ()
    """(row, col, points) of every tile it spilled to: the tiles' work."""
    sha256: str | None = None
    seconds: float | None = None
    skipped: str | None = None
    window: bool = False
    hull: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)), compare=False, repr=False)

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
        return {"path": self.path, **self.by_fate(), "beyond_grid": self.beyond_grid, **self._bounds(),
                "parts": [list(p) for p in self.parts], "tile_points": [list(t) for t in self.tile_points],
                "sha256": self.sha256, "seconds": self.seconds}

    @classmethod
    def from_record(cls, payload: Mapping[str, Any]) -> RouteResult:
        """The result of a record read by ``WorkDir.recorded("route", key, "hull")``."""
        data = {k: v for k, v in payload.items() if k in _ROUTE_FIELDS}
        if data.get("bounds") is not None:
            data["bounds"] = tuple(data["bounds"])
        data["parts"] = tuple(tuple(p) for p in data.get("parts", ()))
        data["tile_points"] = tuple(tuple(t) for t in data.get("tile_points", ()))
        return cls(**data)

    def to_report(self) -> dict[str, Any]:
        """The file's entry in the run report (``RunReport.files``)."""
        if self.window:
            return {"path": self.path, "sha256": self.sha256, **self._bounds(), **self.by_fate()}
        return {"path": self.path, **self.by_fate(), "beyond_grid": self.beyond_grid, **self._bounds(),
                "sha256": self.sha256, "seconds": self.seconds}


_ROUTE_FIELDS = frozenset(f.name for f in fields(RouteResult))


def tile_key(row: int, col: int) -> str:
    """A tile's name in the work folder and its records: ``RRRRR_CCCCC``."""
    return f"{row:05d}_{col:05d}"


def tile_dir(row: int, col: int) -> str:
    """A tile's folder in the work folder (a :class:`~pipeline.tiling.scratch.Scratch` key)."""
    return f"tiles/{tile_key(row, col)}"


def intersect_boxes(a, b):
    """The intersection of two closed boxes (xmin, ymin, xmax, ymax), or None."""
    out = (max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3]))
    return out if out[0] <= out[2] and out[1] <= out[3] else None


class TileSpiller:
    """Routes points of one source to the tiles' spill files, holding at most
    ``budget`` points in memory (bounded memory whatever the archive size)."""

    def __init__(self, scratch: Scratch, grid: TileGrid, buffer: float, source: int, budget: int = 4_000_000):
        self.scratch = scratch
        self.grid = grid
        self.buffer = float(buffer)
        self.source = int(source)
        self.budget = int(budget)
        self._pending: dict[tuple[int, int], list[NDArray[np.float64]]] = {}
        self._held = 0
        self._parts: dict[tuple[int, int], int] = {}
        self._points: dict[tuple[int, int], int] = {}

    def add(self, x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64]) -> None:
        if x.size == 0:
            return
        g = self.grid
        offsets, pts = _route_kernel(
            x, y, z, g.x0, g.y0, 1.0 / g.tile_size, *g.bin_bounds(0), *g.bin_bounds(1), self.buffer, g.n_cols, g.n_tiles
        )
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
            files[f"{tile_dir(*key)}/{_spill_name(self.source, part)}"] = np.concatenate(chunks)
            self._parts[key] = part + 1
        self.scratch.save_many(files)
        self._pending.clear()
        self._held = 0


_ROUNDOFF = 2.0**-53


@meshcore.kernel
def _bin(v: float, origin: float, inv_size: float, below: NDArray[np.float64], above: NDArray[np.float64]) -> int:
    """:meth:`TileGrid.bins` of one value: bin ``k`` is ``[below[k], above[k])``
    (the inner edges with -inf and +inf at the ends); no branch."""
    k = int(min(max((v - origin) * inv_size, 0.0), float(above.shape[0] - 1)))
    k += v >= above[k]
    k -= v < below[k]
    return k


@meshcore.kernel
def _bins(values, origin, inv_size, below, above):
    out = np.empty(values.shape, dtype=np.intp)
    for i in range(values.shape[0]):
        out[i] = _bin(values[i], origin, inv_size, below, above)
    return out


@meshcore.kernel
def _route_kernel(x, y, z, x0, y0, inv_size, below_x, above_x, below_y, above_y, buffer, n_cols, n_tiles):
    """Every point copied to each tile whose core grown by ``buffer`` holds it: ``pts[offsets[t]:offsets[t + 1]]`` goes to
    tile ``t``.  Within a tile, points for which it is the lowest row and
    column of their reach come first, then the next column, row, ...; each
    group in input order (a counting sort, stable)."""
    n = x.shape[0]
    c_lo = np.empty(n, dtype=np.int32)
    r_lo = np.empty(n, dtype=np.int32)
    c_span = np.empty(n, dtype=np.int32)
    r_span = np.empty(n, dtype=np.int32)
    span_c = 1
    span_r = 1
    for i in range(n):
        xi = x[i]
        yi = y[i]
        # a tile claims every point of its closed window grown by the buffer
        # (``held_box``): a point on that box's edge, or a rounding away from
        # it, goes to the tile too (to both tiles, on a shared edge)
        mx = 8.0 * _ROUNDOFF * (abs(xi) + buffer)
        my = 8.0 * _ROUNDOFF * (abs(yi) + buffer)
        c0 = _bin(xi - buffer - mx, x0, inv_size, below_x, above_x)
        r0 = _bin(yi - buffer - my, y0, inv_size, below_y, above_y)
        sc = _bin(xi + buffer + mx, x0, inv_size, below_x, above_x) - c0 + 1
        sr = _bin(yi + buffer + my, y0, inv_size, below_y, above_y) - r0 + 1
        c_lo[i] = c0
        r_lo[i] = r0
        c_span[i] = sc
        r_span[i] = sr
        span_c = max(span_c, sc)
        span_r = max(span_r, sr)
    groups = span_r * span_c
    start = np.zeros(n_tiles * groups + 1, dtype=np.int64)
    for i in range(n):
        if r_span[i] == 1 and c_span[i] == 1:  # most points: one tile
            start[(r_lo[i] * n_cols + c_lo[i]) * groups + 1] += 1
            continue
        for dr in range(r_span[i]):
            for dc in range(c_span[i]):
                start[((r_lo[i] + dr) * n_cols + c_lo[i] + dc) * groups + dr * span_c + dc + 1] += 1
    for k in range(n_tiles * groups):
        start[k + 1] += start[k]
    pts = np.empty((start[n_tiles * groups], 3))
    offsets = np.empty(n_tiles + 1, dtype=np.int64)
    for t in range(n_tiles + 1):
        offsets[t] = start[t * groups]
    for i in range(n):
        if r_span[i] == 1 and c_span[i] == 1:
            slot = (r_lo[i] * n_cols + c_lo[i]) * groups
            at = start[slot]
            start[slot] = at + 1
            pts[at, 0] = x[i]
            pts[at, 1] = y[i]
            pts[at, 2] = z[i]
            continue
        for dr in range(r_span[i]):
            for dc in range(c_span[i]):
                slot = ((r_lo[i] + dr) * n_cols + c_lo[i] + dc) * groups + dr * span_c + dc
                at = start[slot]
                start[slot] = at + 1
                pts[at, 0] = x[i]
                pts[at, 1] = y[i]
                pts[at, 2] = z[i]
    return offsets, pts


def route_points(grid: TileGrid, buffer: float, points: NDArray[np.float64], row: int, col: int) -> NDArray[np.float64]:
    """The points of ``points`` (n, 3) that routing sends to tile (row, col),
    in the order routing gives them (:class:`TileSpiller`)."""
    g = grid
    x, y, z = (np.ascontiguousarray(points[:, k]) for k in range(3))
    offsets, pts = _route_kernel(
        x, y, z, g.x0, g.y0, 1.0 / g.tile_size, *g.bin_bounds(0), *g.bin_bounds(1), float(buffer), g.n_cols, g.n_tiles
    )
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
    """Delete every spill file of one source (it is routed again, or left out)."""
    scratch.remove(source_spill(scratch, f"{source:06d}"))


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


def load_tile_points(scratch: Scratch, row: int, col: int) -> NDArray[np.float64]:
    """All points routed to a tile, ``(n, 3)``, in source then reading order."""
    folder = tile_dir(row, col)
    parts = [f"{folder}/{name}" for name in scratch.names(folder) if name.endswith(".npy")]
    if not parts:
        return np.empty((0, 3))
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
    return _in_box(points, float(box[0]), float(box[1]), float(box[2]), float(box[3]))


@meshcore.kernel
def _in_box(points, x_min, y_min, x_max, y_max):
    """:func:`points_in_box` in one pass (numpy's takes seven over strided columns)."""
    out = np.empty(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        x = points[i, 0]
        y = points[i, 1]
        out[i] = (x >= x_min) & (x <= x_max) & (y >= y_min) & (y <= y_max)
    return out


def check_cells(grid: TileGrid, max_cells: int) -> None:
    """A DEM larger than ``max_cells`` needs an explicit, larger limit."""
    cells = grid.nx * grid.ny
    if cells > max_cells:
        raise UsageError(
            f"the DEM would have {grid.nx} x {grid.ny} = {cells:,} cells, above max_cells={max_cells:,}; "
            "check the bounds and resolution, or raise max_cells"
        )


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
