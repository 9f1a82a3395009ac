"""What a product (a DEM layer) is: the declaration every layer gives once.

A :class:`Product` names its layer, its cell type and nodata, its units, the
points and point attributes it needs (a :class:`Selection` and a tuple of
:class:`Attribute`), the other layers it is computed from, the function that
computes one tile's cells (:class:`TileContext` in, an array out), how its
GeoTIFF is typed and resampled, and how ``terrain preview`` draws it.  The
store, the export, the STAC item, the reader, the router and the tile tasks
all read these declarations; none keeps a table of its own
(:mod:`pipeline.products.registry` holds the one list).

Examples
--------
>>> Selection(returns=Returns.FIRST).allows_class(7)
True
>>> Returns.parse("last")
<Returns.LAST: 'last'>
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .attributes import RETURN_ATTRIBUTES, Attribute, Returns

if TYPE_CHECKING:
    import meshcore

__all__ = [
    "Returns", "Attribute", "Selection", "Product", "Preview", "TileContext", "NOISE_CLASSES", "ALL_BUT_NOISE",
    "HEIGHT_UNITS", "PER_AREA_UNITS",
]

NOISE_CLASSES = (7, 18)
"""ASPRS low point (noise) and high noise."""

ALL_BUT_NOISE = frozenset(c for c in range(256) if c not in NOISE_CLASSES)
"""Every ASPRS class but :data:`NOISE_CLASSES`."""

HEIGHT_UNITS = "<height>"
"""A product's ``units`` that are the store's height unit (as the elevation's)."""

PER_AREA_UNITS = "<per area>"
"""A product's ``units`` that are a count per square horizontal unit of the CRS."""


@dataclass(frozen=True)
class Selection:
    """The points a product (or the DTM) is made of: classes (None: every
    class) and returns.  Withheld points are left out of every selection
    unless the run keeps them (``keep_withheld``)."""

    classes: frozenset[int] | None = None
    returns: Returns = Returns.ALL

    def allows_class(self, code: int) -> bool:
        return self.classes is None or code in self.classes

    def union(self, other: Selection) -> Selection:
        """The smallest selection of this form holding both (it may hold more:
        first returns of class 2 with all returns of class 5 is all returns of 2 and 5)."""
        classes = None if self.classes is None or other.classes is None else self.classes | other.classes
        returns = self.returns if self.returns == other.returns else Returns.ALL
        return Selection(classes, returns)

    def attributes_to_split(self, within: Selection) -> tuple[Attribute, ...]:
        """The attributes that tell this selection's points from the rest of ``within``'s."""
        out: list[Attribute] = []
        if self.classes is not None and self.classes != within.classes:
            out.append(Attribute.CLASSIFICATION)
        if self.returns != within.returns:
            out.extend(RETURN_ATTRIBUTES if self.returns in (Returns.LAST, Returns.SINGLE) else RETURN_ATTRIBUTES[:1])
        return tuple(out)

    def mask(self, n: int, attributes: Mapping[str, NDArray]) -> NDArray[np.bool_]:
        """Which of ``n`` points, with these ``attributes`` (a subset of a wider
        selection's), this selection keeps.  An attribute missing is one the
        wider selection already settled (:meth:`attributes_to_split`)."""
        keep = np.ones(n, dtype=bool)
        if self.classes is not None and Attribute.CLASSIFICATION in attributes:
            table = np.zeros(256, dtype=bool)
            table[sorted(self.classes)] = True
            keep &= table[np.asarray(attributes[Attribute.CLASSIFICATION]).astype(np.uint8)]
        if self.returns is not Returns.ALL and Attribute.RETURN_NUMBER in attributes:
            number = attributes.get(Attribute.NUMBER_OF_RETURNS, np.zeros(n))
            by_return = self.returns.mask(attributes[Attribute.RETURN_NUMBER], number)
            if by_return is not None:
                keep &= by_return
        return keep


@dataclass(frozen=True)
class Preview:
    """How ``terrain preview`` draws a product beside the hillshade: a
    matplotlib colour map, the colour bar's label, and the value range
    (percentiles of the layer's valid cells)."""

    cmap: str
    label: str
    percentiles: tuple[float, float] = (1.0, 99.0)


@dataclass
class TileContext:
    """What a product's tile function reads: the tile's cells, the layers
    already computed for them (its dependencies), the tile's points of a
    selection, the surface's mesh, and the run's product settings."""

    grid: Any
    """The run's :class:`~pipeline.tiling.grid.TileGrid`."""
    row: int
    col: int
    settings: Any
    """The run's :class:`~pipeline.products.settings.ProductSettings`."""
    layers: dict[str, NDArray] = field(default_factory=dict)
    mesh: meshcore.Mesh | None = None
    z: NDArray[np.float64] | None = None
    kinds: NDArray[np.int8] | None = None
    surface: dict[str, Any] = field(default_factory=dict)
    height_scale: float = 1.0
    max_edge: float | None = None
    load_points: Callable[[], Any] | None = None
    """Reads the tile's :class:`~pipeline.products.points.ProductPoints`."""
    load_piece: Callable[[str], NDArray] | None = None
    load_dtm_points: Callable[[], Any] | None = None
    """Reads the tile's points the DTM is made of (its cells plus the buffer), as :class:`~pipeline.products.points.ProductPoints`."""
    _points: Any = None
    _selected: dict[Selection, Any] = field(default_factory=dict)
    _cells: dict[int, tuple[Any, NDArray[np.int64], NDArray[np.bool_]]] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        r0, r1, c0, c1 = self.grid.cell_slice(self.row, self.col)
        return (r1 - r0, c1 - c0)

    @property
    def first_cell(self) -> tuple[int, int]:
        """(column, row) of the tile's first cell on the run's grid.  Cell
        centres are ``grid.x0 + (column + i + 0.5) * resolution`` (and the
        same in y), from the grid's corner: a tile's own corner rounds once
        more at a resolution that is not a power of two, and its centres
        would then differ from another tiling's by an ulp
        (:func:`meshcore.rasterize`'s ``first_cell``)."""
        r0, _, c0, _ = self.grid.cell_slice(self.row, self.col)
        return (c0, r0)

    def points(self, selection: Selection) -> Any:
        """The tile's points (its cells plus the buffer) of ``selection``."""
        if self._points is None:
            if self.load_points is None:
                raise RuntimeError("this tile has no product points: the run declared no product that needs them")
            self._points = self.load_points()
        if selection not in self._selected:  # several products read one selection: select once
            self._selected[selection] = self._points.selected(selection)
        return self._selected[selection]

    def _cell_of(self, points: Any) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """The tile's flat cell index of each of ``points`` in its cells, and
        which are (computed once per point set: products count one set twice)."""
        cached = self._cells.get(id(points))
        if cached is None or cached[0] is not points:
            g = self.grid
            r0, r1, c0, c1 = g.cell_slice(self.row, self.col)
            i = np.floor((points.x - g.x0) / g.resolution).astype(np.int64) - c0
            j = np.floor((points.y - g.y0) / g.resolution).astype(np.int64) - r0
            ok = (i >= 0) & (i < c1 - c0) & (j >= 0) & (j < r1 - r0)
            cached = (points, j[ok] * (c1 - c0) + i[ok], ok)  # the points held: their id stays theirs
            self._cells[id(points)] = cached
        return cached[1], cached[2]

    def cell_counts(self, points: Any, weights: NDArray | None = None) -> NDArray:
        """Per cell of the tile: the number of ``points`` whose cell it is (or
        the sum of ``weights``, int64), by the grid's one rule of a point's
        cell: ``floor((x - x0) / resolution)``, the same at any tiling."""
        r0, r1, c0, c1 = self.grid.cell_slice(self.row, self.col)
        flat, ok = self._cell_of(points)
        size = (r1 - r0) * (c1 - c0)
        if weights is None:
            return np.bincount(flat, minlength=size).reshape(r1 - r0, c1 - c0)
        # whole numbers summed as float64 are exact below 2**53 (1e11 returns of
        # 16-bit intensity a cell): bincount's sums, 10x faster than np.add.at
        sums = np.bincount(flat, weights=np.asarray(weights, dtype=np.float64)[ok], minlength=size)
        return np.rint(sums).astype(np.int64).reshape(r1 - r0, c1 - c0)


@dataclass(frozen=True)
class Product:
    """One DEM layer, declared once.

    Parameters
    ----------
    name
        The layer's name in the store, the CLI (``--layers``) and the export.
    dtype, nodata
        The cells' type and the value of a cell without data (None: every
        value is data, as a count's 0).
    fill
        The store's fill value (the nodata, or 0 for a count).
    units
        CF units, or :data:`HEIGHT_UNITS` / :data:`PER_AREA_UNITS`.
    long_name, description
        For the store's attributes and the STAC item.
    compute
        ``compute(ctx) -> array`` of the tile's cells (south-up).
    points
        ``points(settings) -> Selection`` of the points it reads (or None: none, for
        these settings), or None: it never reads points.
    attributes
        The point attributes it reads beyond x, y, z.
    needs
        Other layers its ``compute`` reads from ``ctx.layers`` (computed
        first, written only when asked for).
    export_dtype, resampling
        The GeoTIFF's sample type and how its overviews summarise cells.
    preview
        How ``terrain preview`` draws it beside the hillshade (None: not drawn).
    warm_up
        Runs the product's compiled kernels once on a tiny input, so a tile
        finds them loaded (None: none of its own).
    attrs
        More CF attributes for the store (``flag_values``, ...).
    """

    name: str
    dtype: np.dtype
    nodata: float | int | None
    units: str | None
    long_name: str
    description: str
    compute: Callable[[TileContext], NDArray]
    points: Callable[[Any], Selection | None] | None = None
    attributes: tuple[Attribute, ...] = ()
    needs: tuple[str, ...] = ()
    export_dtype: str = "float32"
    resampling: str = "AVERAGE"
    preview: Preview | None = None
    warm_up: Callable[[], None] | None = None
    attrs: Mapping[str, Any] = field(default_factory=dict)

    @property
    def fill(self) -> float | int:
        return 0 if self.nodata is None else self.nodata

    @property
    def masked(self) -> bool:
        """Whether the fill value marks missing data (CF ``_FillValue``)."""
        return isinstance(self.nodata, float) and math.isnan(self.nodata)

    def empty(self, shape: tuple[int, int]) -> NDArray:
        """A tile of no data."""
        return np.full(shape, self.fill, dtype=self.dtype)
