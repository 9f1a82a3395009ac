"""The global tile grid: one grid for the whole run, its tiles and their names.

The grid is the data's: its south-west corner is the data extent's snapped
down to a multiple of the resolution, and it holds the cells up to the
extent's north-east corner, whatever the tile size.  Tiles are
``tile_cells x tile_cells`` DEM cells counted from that south-west corner;
those of the northern row and the eastern column may be smaller.  A point is
*owned* by the tile whose core holds it (half-open boxes; the outer tiles
extend to infinity, so every point has exactly one owner).  This module needs
no compiled kernel at import, so that the store and its commands start
without them (:meth:`TileGrid.bins` loads :mod:`.binning` when first asked).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import GridTooLargeError, UsageError

__all__ = ["TileGrid", "tile_key", "tile_dir", "intersect_boxes", "check_cells"]


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
        south-west tile; tiles at the north edge may be lower, those at the
        east edge narrower.
    nx, ny : int
        Cells along x and y: the data's extent, whatever ``tile_cells`` is.

    Tiles and the store's chunks: the store is north-up, so its chunk rows
    are counted from the north edge, while tiles are counted from the south
    (a grid that grows to the north keeps its tiles).  The two line up only
    when ``ny`` is a multiple of ``tile_cells``; otherwise each chunk row
    holds parts of two tile rows (:attr:`rows_share_chunks`), and the DEM of
    tiles in neighbouring rows is not written at the same time.

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

    @classmethod
    def covering(cls, bounds: tuple[float, float, float, float], resolution: float, tile_cells: int) -> TileGrid:
        """The grid whose cells cover ``bounds`` (xmin, ymin, xmax, ymax): the
        same cells for any ``tile_cells``."""
        xmin, ymin, xmax, ymax = bounds
        x0 = math.floor(xmin / resolution) * resolution
        y0 = math.floor(ymin / resolution) * resolution
        nx = max(1, int(math.floor((xmax - x0) / resolution)) + 1)
        ny = max(1, int(math.floor((ymax - y0) / resolution)) + 1)
        # a tile never outgrows the grid (one tile is the untiled case)
        tile_cells = max(1, min(int(tile_cells), max(nx, ny)))
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

    @property
    def rows_share_chunks(self) -> bool:
        """Whether the store's chunk rows, counted from the north edge, hold
        parts of two tile rows, counted from the south: there are several,
        and ``ny`` is not a multiple of ``tile_cells``.  Tiles of neighbouring
        rows then write parts of the same chunks."""
        return self.n_rows > 1 and self.ny % self.tile_cells != 0

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
        from .binning import bins  # the kernel, loaded on first use

        k = bins(flat, self.x0 if axis == 0 else self.y0, 1.0 / self.tile_size, *self.bin_bounds(axis))
        return k.reshape(np.shape(values))

    def bin_bounds(self, axis: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Lower and upper bounds of every tile column (axis 0) or row (axis 1):
        the inner edges, with -inf and +inf at the ends."""
        edges = self._inner_edges(axis)
        return np.concatenate([[-np.inf], edges]), np.concatenate([edges, [np.inf]])

    def tiles(self) -> list[tuple[int, int]]:
        return [(r, c) for r in range(self.n_rows) for c in range(self.n_cols)]

    def tiles_meeting(self, boxes, among: list[tuple[int, int]] | None = None) -> list[tuple[int, int]]:
        """The tiles (row, col), in order, whose windows hold a point of any of
        the closed ``boxes`` (x_min, y_min, x_max, y_max); only those of
        ``among`` when given (without listing every tile the boxes span)."""
        corners = np.array(boxes, dtype=np.float64).reshape(-1, 4)
        row_lo, col_lo = self.owner(corners[:, 0], corners[:, 1])
        row_hi, col_hi = self.owner(corners[:, 2], corners[:, 3])
        # the outer tiles' windows reach to infinity: a box beyond the grid meets them
        row_lo, row_hi = np.clip(row_lo, 0, self.n_rows - 1), np.clip(row_hi, 0, self.n_rows - 1)
        col_lo, col_hi = np.clip(col_lo, 0, self.n_cols - 1), np.clip(col_hi, 0, self.n_cols - 1)
        if among is not None:
            if not among:
                return []
            rc = np.array(among, dtype=np.int64).reshape(-1, 2)
            r, c = rc[:, :1], rc[:, 1:]
            meet = ((r >= row_lo) & (r <= row_hi) & (c >= col_lo) & (c <= col_hi)).any(axis=1)
            return sorted(map(tuple, rc[meet].tolist()))
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
        window reached to infinity, and its box is clipped to the grid), its
        eastern column when columns were (likewise).

        The strips along the data extent's edges that a tile holds from the
        start move with the extent too, but they only spare it rounds of
        loading: its piece is what its certificate says, whatever else it holds.
        """
        moved: set[tuple[int, int]] = set()
        if self.ny > other.ny:
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


def check_cells(grid: TileGrid, max_cells: int) -> None:
    """A DEM larger than ``max_cells`` needs an explicit, larger limit."""
    cells = grid.nx * grid.ny
    if cells > max_cells:
        raise GridTooLargeError(
            f"the DEM would have {grid.nx} x {grid.ny} = {cells:,} cells, above max_cells={max_cells:,}; "
            "check the bounds and resolution, or raise max_cells"
        )
