"""Ground points of an unclassified cloud: low outliers, morphological
openings of the lowest surface, and a ground TIN.

The method is the simple morphological filter (SMRF, Pingel, Vincent and
Mitchell 2013, the filter PDAL runs by default) with three changes:

1. **Low outliers first.**  A point with fewer than two other points at most
   ``outlier_depth`` above it in the 3 x 3 block of ``outlier_cell`` cells
   around its own, among at least four others, is a low outlier (multipath, a reflection below the
   ground): never ground and never a seed.  This is the test of LAStools'
   ``lasnoise`` and PDAL's ``filters.elm`` (the lowest point of a cell set
   apart from the points above it).
2. **Openings of the lowest surface, each from that surface.**  The lowest
   point of every ``cell`` (a grid aligned on multiples of ``cell``, so it is
   the same grid in any tile) makes a surface with holes where cells are
   empty; it is opened (a minimum of the data over a square window of
   radius ``r`` cells, then a maximum of that over the cells within
   :data:`GAP_CELLS` of the data: an object on the edge of a void, a tree
   at the rim of a clearing without returns, opens like any other) for
   ``r = 1 ... R`` with ``R = ceil(max_window / cell)``.  A
   cell whose opening drops by more than ``slope * r * cell`` from radius
   ``r - 1`` to ``r`` holds an object (Pingel's test), unless the drop goes
   on over the next radii (:data:`SLOPE_RADII`): the opening cuts a crest
   of steep ground a little more at every radius, an object all at once.
   So does a drop of more than ``wall_height`` that does not go on, at the
   radii up to ``wall_radius``: a wall, where Pingel's threshold, growing
   with the radius, lets a low wide roof through.
   A cell whose opening drops by more than ``object_height`` from one
   radius to the next holds an object whatever follows, and so does one
   whose opening drops by more than
   ``object_height`` over two radii, ``r - 2`` to ``r``
   (:data:`DROP_RADII`): a roof beside a lower annex, a low wall or a tree
   opens down in two steps, each under the cap, that Pingel's one-step
   test lets through.  Each opening is computed from the lowest surface
   itself, not from the previous one, which bounds what a cell's flag
   depends on.  The opening of radius 1 reads no cell beyond the survey's
   convex hull: a window there holds only the rim's own cells, so a hedge
   or a car on the rim would open as its own ground.  Larger radii read
   them, which keeps a slope that rises to the rim whole.
3. **A TIN of the ground cells instead of an inpainted grid.**  The lowest
   points of the cells not flagged (the seeds) are triangulated (Delaunay,
   :func:`meshcore.delaunay.delaunay`), and the triangles of circumradius
   at most ``max_radius`` kept (the live TIN: a wider gap between seeds, a
   roof or a water body, is not bridged).  A point is ground when it lies
   within ``threshold + scalar * s`` of a live triangle containing it, ``s``
   that triangle's slope (Pingel's final test, with the triangle's exact
   slope instead of a gridded one).  A point on an edge or a corner is
   tested against every live triangle there, so the answer does not depend
   on the path that found it.  A point in no live triangle (the survey's
   rim, beyond its edge cells' lowest points, or the edge of a void) is
   tested against the plane of the nearest edge of the live TIN within
   ``sqrt(2) cell``, ties by the edge's corners.  A seed is ground, and so
   is every exact copy of it (x, y and z).  Where return numbers are
   given, only last returns seed the surface (a first of several returns
   is not the ground).

What a point's class depends on
-------------------------------
Everything is computed on grids aligned on multiples of the cell sizes, ties
are broken by coordinates and the arithmetic is done in the caller's
coordinates, so a point's class depends only on the points near it:

* a low-outlier decision on the block of 3 x 3 ``outlier_cell`` cells around
  the point's own;
* a cell's object flag on the lowest points of the cells within ``2 R`` of
  it (an opening of radius ``R`` reads ``2 R`` cells each way, and whether
  a cell's erosion is read, :data:`GAP_CELLS` beyond it, and the
  survey's hull), each of which depends on the outliers as above: so a seed
  depends on the points within :meth:`GroundParameters.margin` of it (a
  square), given the hull;
* a point's class on the seeds of the live triangles containing it, fixed by
  the seeds inside their circumcircles, all within ``2 rho`` of it (``rho``
  the largest of their circumradii); or, in no live triangle, on the seeds
  within ``sqrt(2) cell + 2 max_radius``.

:attr:`GroundResult.reach` adds the two: a subset of the cloud that holds
every point of the square of half-side ``reach`` around one of its points
decides that point as the whole cloud does.  ``reach`` is small wherever
ground cells are dense, and never more than
:meth:`GroundParameters.max_reach`.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> x, y = rng.uniform(0, 100, (2, 5000))
>>> z = 0.02 * x + np.where((abs(x - 50) < 10) & (abs(y - 50) < 10), 8.0, 0.0)
>>> result = classify_ground(x, y, z)
>>> bool(result.ground[z < 0.02 * x + 1].all()), bool(result.ground[z > 0.02 * x + 1].any())
(True, False)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import larger, njit, njit_helper, smaller
from ._order import _merge_sort_ties
from .delaunay import _locate, _next, _prev, _walk, delaunay
from .predicates import orient2d
from .errors import InvalidInputError
from .mesh import point_columns

__all__ = ["GroundParameters", "GroundResult", "classify_ground"]


@dataclass(frozen=True)
class GroundParameters:
    """The parameters of :func:`classify_ground`, in metres (lengths) or
    rise over run (slopes); the defaults suit flat towns, hilly forest and
    steep terrain alike.

    Parameters
    ----------
    cell : float
        Side of the cells of the lowest surface, metres.
    max_window : float
        Radius of the largest opening, metres: half the width of the widest
        object that is not ground (a 100 m building needs 50 m).
    slope : float
        Terrain slope that the openings take for ground (rise over run).
    threshold : float
        Height above or below the ground TIN within which a point is ground,
        metres, on flat ground.
    scalar : float
        Added to ``threshold`` per unit of the TIN's slope, metres.  Pingel's
        1.25 is for the gradient of a smoothed grid; a TIN through the
        ground's own lowest points follows a slope without that allowance,
        and a facet's slope is steepest where one seed is off, so little of
        it is taken.  The defaults of ``threshold``, ``scalar`` and
        ``object_height`` were chosen by ``bench/bench_ground.py`` over five
        surveys (town, fields, forest, steep ground; metres and feet).
    object_height : float
        A drop of the opening larger than this from one radius to the next
        marks an object whatever the radius, metres (Pingel's threshold
        ``slope * r * cell`` alone lets low buildings wider than
        ``2 object_height / slope`` through).
    wall_height : float
        A drop of the opening larger than this from one radius to the next
        that does not go on (a wall, not a slope: :data:`SLOPE_RADII`)
        marks an object at the radii up to ``wall_radius``, metres.  Pingel's
        threshold ``slope * r * cell`` grows with the radius, so a flat roof
        lower than ``slope`` times half its width was ground: 96% of a roof
        60 x 48 m and 3 m high on gentle slopes, 53% with this test, and all
        of it on flat ground.
    wall_radius : float
        The largest radius of the openings at which ``wall_height`` applies,
        metres: half the width of the widest low building it finds (0 turns
        the test off).  A raised field or a terrace wider than twice this
        stays ground (``ign_semis``, whose surveyors called terraces of a few
        metres ground: 0.5536 m RMS of their DTM at 25 m, 0.5546 m at 30 m,
        0.647 m with a ``wall_height`` of 2 m).
    outlier_depth : float
        How far below the points of its neighbourhood a point must lie to be
        a low outlier, metres.
    outlier_cell : float
        Side of the cells of the low-outlier test, metres.
    max_radius : float
        Largest circumradius of a triangle of the ground TIN, metres: wider
        gaps between ground seeds (a roof, a water body) are not bridged, and
        a point there is ground only near the TIN's edge.  It bounds how far a
        decision reads.
    """

    cell: float = 1.0
    max_window: float = 50.0
    slope: float = 0.15
    threshold: float = 0.2
    scalar: float = 0.1
    object_height: float = 4.0
    wall_height: float = 2.5
    wall_radius: float = 25.0
    outlier_depth: float = 1.0
    outlier_cell: float = 5.0
    max_radius: float = 50.0

    def margin(self, unit: float = 1.0) -> float:
        """How far, in the coordinates' units, beyond the seeds a decision
        reads lie the points those seeds depend on: the openings read ``2 R``
        cells around a seed's cell (``R = ceil(max_window / cell)``), and a
        low-outlier test the block of 3 x 3 ``outlier_cell`` cells around a
        point's own."""
        radii = max(1, math.ceil(self.max_window / self.cell))
        reads = max(2 * radii, radii + GAP_CELLS)  # an erosion, or whether a cell is read, within radii
        return ((reads + 1) * self.cell + 2 * self.outlier_cell) / unit

    def max_reach(self, unit: float = 1.0) -> float:
        """The largest :attr:`GroundResult.reach` of any point, in the coordinates' units."""
        return self.margin(unit) + (math.sqrt(2.0) * self.cell + 2 * self.max_radius) / unit

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise InvalidInputError(f"GroundParameters.{f.name} must be a finite number >= 0, not {value!r}")
        for name in ("cell", "max_window", "outlier_cell"):
            if getattr(self, name) <= 0:
                raise InvalidInputError(f"GroundParameters.{name} must be > 0, not {getattr(self, name)!r}")

    def for_spacing(self, spacing: float) -> GroundParameters:
        """These parameters for a cloud whose points lie ``spacing`` metres
        apart (one over the square root of its density): a ``cell`` of at
        least half the spacing and a ``max_window`` of at least four spacings.

        On a cloud sparser than two points a cell, most cells are empty and a
        window of a few cells holds one point or none: the openings see no
        object, and every point is ground (on a 1,065-point sample 120 m apart,
        the DTM's RMS against the survey's own ground was 12.4 m with the
        defaults and 4.7 m so, in a thousandth of the time).  Every
        shared sample denser than that keeps the defaults."""
        if not (math.isfinite(spacing) and spacing > 0):
            return self
        return replace(self, cell=max(self.cell, spacing / 2.0), max_window=max(self.max_window, 4.0 * spacing))

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict) -> GroundParameters:
        unknown = set(values) - {f.name for f in fields(cls)}
        if unknown:
            raise InvalidInputError(f"unknown ground parameters {sorted(unknown)}; valid: {[f.name for f in fields(cls)]}")
        return cls(**values)


@dataclass(frozen=True)
class GroundResult:
    """What :func:`classify_ground` found, one entry per input point.

    Attributes
    ----------
    ground : (n,) bool
        Ground points.
    low_outlier : (n,) bool
        Low outliers (never ground).
    reach : (n,) float64
        Half the side of the square around the point, in the coordinates'
        units, that holds every point its decision read: a subset of the
        cloud holding every point of that square gives the point the same
        class (see the module docstring).  At most
        :meth:`GroundParameters.max_reach`.
    """

    ground: NDArray[np.bool_]
    low_outlier: NDArray[np.bool_]
    reach: NDArray[np.float64]

    @property
    def low_outliers(self) -> int:
        """How many low outliers were set apart."""
        return int(self.low_outlier.sum())


# --- grids --------------------------------------------------------------------------------------------------


def _cells(x: np.ndarray, y: np.ndarray, size: float) -> tuple[np.ndarray, int, int]:
    """Cell of each point on the grid aligned on multiples of ``size``, as one id ``row * nx + column``."""
    cell, nx, ny = _cells_kernel(x, y, float(size))
    return cell, int(nx), int(ny)


@njit
def _cells_kernel(x, y, size):
    """:func:`_cells` in two passes, without the five temporary arrays of numpy's
    (``floor(x / size)``: the same division and rounding)."""
    n = x.shape[0]
    cell = np.empty(n, dtype=np.int64)
    x_lo = np.int64(0)
    y_lo = np.int64(0)
    x_hi = np.int64(0)
    y_hi = np.int64(0)
    for i in range(n):
        ix = np.int64(math.floor(x[i] / size))
        iy = np.int64(math.floor(y[i] / size))
        if i == 0 or ix < x_lo:
            x_lo = ix
        if i == 0 or ix > x_hi:
            x_hi = ix
        if i == 0 or iy < y_lo:
            y_lo = iy
        if i == 0 or iy > y_hi:
            y_hi = iy
    nx = x_hi - x_lo + 1
    for i in range(n):
        ix = np.int64(math.floor(x[i] / size))
        iy = np.int64(math.floor(y[i] / size))
        cell[i] = (iy - y_lo) * nx + (ix - x_lo)
    return cell, nx, y_hi - y_lo + 1


def _grouped(cell: np.ndarray, z: np.ndarray, ncells: int) -> tuple[np.ndarray, np.ndarray]:
    """Points sorted by cell then height (ties by index: ``np.lexsort((z, cell))``),
    and where each cell's run starts (``ncells + 1`` entries)."""
    starts = np.zeros(ncells + 1, dtype=np.int64)
    np.cumsum(np.bincount(cell, minlength=ncells), out=starts[1:])
    return _grouped_kernel(cell, z, starts), starts


@njit
def _grouped_kernel(cell, z, starts):
    """:func:`_grouped`'s order: a counting sort by cell (stable), then each
    cell's run by height, stable (a cell holds a few hundred points at most
    on the outliers' cells: 6x faster than a lexsort over the cloud)."""
    n = cell.shape[0]
    order = np.empty(n, dtype=np.int64)
    at = starts[:-1].copy()
    for i in range(n):
        c = cell[i]
        order[at[c]] = i
        at[c] += 1
    heights = np.empty(n)
    for k in range(n):
        heights[k] = z[order[k]]
    for c in range(starts.shape[0] - 1):
        if starts[c + 1] - starts[c] > 1:
            _merge_sort_ties(order, heights, starts[c], starts[c + 1])  # stable: ties keep the index order
    return order


@njit
def _lowest_per_cell(ids, cell, x, y, z, ncells):
    """The lowest of the points ``ids`` in each cell (ties by x, then y, then
    their order in ``ids``), in the order of the cells: what the first of each
    cell's run of ``ids[np.lexsort((y, x, z, cell))]`` is, in one pass."""
    best = np.full(ncells, -1, dtype=np.int64)
    for k in range(ids.shape[0]):
        i = ids[k]
        c = cell[i]
        b = best[c]
        if b < 0 or z[i] < z[b] or (z[i] == z[b] and (x[i] < x[b] or (x[i] == x[b] and y[i] < y[b]))):
            best[c] = i
    return best[best >= 0]


@njit
def _low_outlier_kernel(z, order, starts, nx, ny, depth, support, out) -> None:
    """Flag in ``out`` the points with fewer than ``support`` other points at
    most ``depth`` above them in the 3 x 3 cells around their own.

    ``order`` lists the points by cell then height, ``starts`` where each
    cell's run begins: in each cell only the lowest points are tested, up to
    the first that is not an outlier.
    """
    for row in range(ny):
        for col in range(nx):
            c = row * nx + col
            for k in range(starts[c], starts[c + 1]):
                p = order[k]
                top = z[p] + depth
                count = 0
                for dr in range(-1, 2):
                    r = row + dr
                    if r < 0 or r >= ny:
                        continue
                    for dc in range(-1, 2):
                        cc = col + dc
                        if cc < 0 or cc >= nx:
                            continue
                        d = r * nx + cc
                        for m in range(starts[d], starts[d + 1]):
                            q = order[m]
                            if z[q] > top:
                                break
                            if q != p:
                                count += 1
                                if count >= support:
                                    break
                        if count >= support:
                            break
                    if count >= support:
                        break
                if count >= support:
                    break  # the points above it in this cell are not outliers either
                # below the others by more than depth, or alone: an outlier only with enough points above to say so
                above = 0
                for dr in range(-1, 2):
                    r = row + dr
                    if 0 <= r < ny:
                        for dc in range(-1, 2):
                            cc = col + dc
                            if 0 <= cc < nx:
                                d = r * nx + cc
                                above += starts[d + 1] - starts[d]
                if above - 1 >= 2 * support:
                    out[p] = True
                else:
                    break


@njit
def _line_min(values, n, r, padded, g, h, out) -> None:
    """Minimum over a window of radius ``r`` along the line ``values[:n]``
    into ``out`` (van Herk / Gil-Werman: three comparisons per cell whatever
    ``r``); beyond the line's ends the values are infinite."""
    k = 2 * r + 1
    total = ((n + 2 * r + k - 1) // k) * k
    for j in range(total):
        i = j - r
        padded[j] = values[i] if 0 <= i < n else np.inf
    for b in range(0, total, k):  # running minima forwards and backwards within blocks of k
        g[b] = padded[b]
        for j in range(b + 1, b + k):
            g[j] = min(g[j - 1], padded[j])
        h[b + k - 1] = padded[b + k - 1]
        for j in range(b + k - 2, b - 1, -1):
            h[j] = min(h[j + 1], padded[j])
    for i in range(n):
        out[i] = min(h[i], g[i + 2 * r])


@njit
def _square_work(ny: int, nx: int, radius: int) -> np.ndarray:
    """Room for :func:`_square_min` up to ``radius`` on a grid of ``ny`` x ``nx``."""
    return np.empty((3, ny + 4 * radius + 2, nx))


@njit
def _square_min(grid, r, out, work) -> None:
    """Minimum of the ``(ny, nx)`` ``grid`` over squares of radius ``r`` cells, into ``out``
    (``work``: :func:`_square_work` of at least ``r``).

    Along the rows, :func:`_line_min`; down the columns, the same running
    minima taken a whole row at a time (contiguous rows: a column walked
    alone reads a cache line per cell)."""
    ny, nx = grid.shape
    k = 2 * r + 1
    size = nx + 2 * r + k
    padded = np.empty(size)
    g = np.empty(size)
    h = np.empty(size)
    across = work[0]
    for row in range(ny):
        _line_min(grid[row], nx, r, padded, g, h, across[row])
    total = ((ny + 2 * r + k - 1) // k) * k
    down_g = work[1]
    down_h = work[2]
    for b in range(0, total, k):
        for j in range(b, b + k):
            i = j - r
            if 0 <= i < ny:
                if j == b:
                    down_g[j, :] = across[i, :]
                else:
                    for c in range(nx):
                        down_g[j, c] = min(down_g[j - 1, c], across[i, c])
            elif j == b:
                down_g[j, :] = np.inf
            else:
                down_g[j, :] = down_g[j - 1, :]
        for j in range(b + k - 1, b - 1, -1):
            i = j - r
            if 0 <= i < ny:
                if j == b + k - 1:
                    down_h[j, :] = across[i, :]
                else:
                    for c in range(nx):
                        down_h[j, c] = min(down_h[j + 1, c], across[i, c])
            elif j == b + k - 1:
                down_h[j, :] = np.inf
            else:
                down_h[j, :] = down_h[j + 1, :]
    for i in range(ny):
        for c in range(nx):
            out[i, c] = min(down_h[i, c], down_g[i + 2 * r, c])


GAP_CELLS = 8
"""How far from the nearest data (cells, in rows or columns) an empty cell's
erosion is still read by the dilations: the gaps between returns, and the
survey's rim, but not the inside of a void.  Measured on the shared samples
and the synthetic scene of the tests: 1 leaves a strip of ground between a
channel and the survey's edge for an object; the whole void (the unbounded
plane's opening) leaves a tree on a void's edge as ground."""


def _near_data(surface: np.ndarray, k: int) -> np.ndarray:
    """Cells with data, and the empty cells within ``k`` cells of one: those whose erosion a dilation reads."""
    low = np.empty_like(surface)
    _square_min(np.where(np.isnan(surface), np.inf, surface), k, low, _square_work(surface.shape[0], surface.shape[1], k))
    return np.isfinite(low)


@njit
def _min3(grid, tmp, out) -> None:
    """Minimum of ``grid`` over the 3 x 3 cells around each (the grid's outside infinite)."""
    ny, nx = grid.shape
    for i in range(ny):
        tmp[i, 0] = grid[i, 0] if nx == 1 else min(grid[i, 0], grid[i, 1])
        for j in range(1, nx - 1):
            tmp[i, j] = min(min(grid[i, j - 1], grid[i, j]), grid[i, j + 1])
        if nx > 1:
            tmp[i, nx - 1] = min(grid[i, nx - 2], grid[i, nx - 1])
    for i in range(ny):
        lo = max(i - 1, 0)
        hi = min(i + 1, ny - 1)
        for j in range(nx):
            out[i, j] = min(min(tmp[lo, j], tmp[i, j]), tmp[hi, j])


DROP_RADII = 2
"""Over how many successive radii a drop of the opening larger than
``object_height`` marks an object (Pingel's test compares one radius with
the next only).  A roof beside a lower annex, a low wall or a tree opens
down in steps, each under ``object_height``: on ``ign_semis_lambert93`` two
radii brought the DTM from 0.66 to 0.55 m RMS of the survey's own (three
radii: 0.58 m, four: 0.66 m, five: 0.69 m, cutting the crests of steep
ground).  Terrain drops that far over two radii only where it is steeper
than ``object_height / (2 cell)`` (a slope of 2 with the defaults), and
Pingel's test already flags such ground at the small radii.  On coarse
cells (those of a sparse survey, :meth:`GroundParameters.for_spacing`) the
drop must also exceed ``2 cell``, ground as steep as 45 degrees: on
``no_crs_color``'s cells of 60 m the cap alone took gentle slopes for
objects (4.6 to 5.0 m RMS)."""


SLOPE_RADII = 3
"""Over how many radii after Pingel's test flags a drop it is checked to go
on.  A crest of ground of slope ``s`` opens down by about ``s * cell`` at
every radius until the window spans the hill; Pingel's test flags it at
every radius under ``s / slope`` (a ridge of slope 0.5: 3 cells), so the
seeds stop short of the crest on both sides and the TIN bridges it, up to
3 m low over a sharp ridge of slope 0.5.  An object opens down when the
window outgrows it, and not after: a drop followed, at each of the next
``SLOPE_RADII`` radii, by one of at least :data:`SLOPE_KEPT` of it is the
slope of the ground, not an object.

Screened with ``bench/bench_ground.py`` on the shared surveys and on
synthetic steep terrain (360,000 points over 600 x 600 m, 5 cm noise;
sharp ridges every 120 m, a dike): two radii and 0.35 took ``autzen_trim``
from 0.40 to 0.41 ft; three and 0.5 left 0.35 m of the ridges' 1.4 m at a
slope of 0.84; three and 0.25 took the ridges of slope 0.5 from 0.32 to
0.05 m RMS and those of 0.84 from 1.4 to 0.06 m, while every shared survey
kept its RMS within 0.007 ft (``autzen_trim``, 0.396 to 0.403 ft; ``ign_semis``
0.554 to 0.553 m).  The openings read no farther: the radii checked are
at most ``R``, and the last ones are judged by Pingel's test alone."""

SLOPE_KEPT = 0.25
"""The least share of a flagged drop that each of the next
:data:`SLOPE_RADII` drops must keep for the ground's slope to explain it."""


@njit_helper
def _flagged_drop(drop: float, q: int, slope_cell: float, wall: float, wall_radii: int) -> bool:
    """Whether the opening's drop at radius ``q`` marks an object unless it goes on: over Pingel's
    ``slope_cell * q``, or over ``wall`` at the radii up to ``wall_radii``."""
    return drop > slope_cell * q or (q <= wall_radii and drop > wall)


@njit
def _object_kernel(surface, read, first_read, radii, slope_cell, cap, steps_cap, wall, wall_radii, objects) -> None:
    """Pingel's progressive test: ``objects`` where the opening of radius
    ``r`` lies more than ``slope_cell * r`` below the opening of radius
    ``r - 1`` (or more than ``wall`` at the radii up to ``wall_radii``) and
    the drop does not go on (:data:`SLOPE_RADII`), more than ``cap`` below
    it, or more than ``steps_cap`` below the opening of radius
    ``r - DROP_RADII`` (the surface itself for radius 0 and below).

    The opening of radius ``r`` is the maximum, over the cells ``read``
    within ``r``, of the erosion of radius ``r``: the minimum of the data
    within ``r`` (holes infinite), which is the 3 x 3 minimum of the erosion
    of radius ``r - 1`` (squares add up), so each radius costs one small
    erosion and one dilation."""
    ny, nx = surface.shape
    eroded = np.empty_like(surface)
    for i in range(ny):
        for j in range(nx):
            v = surface[i, j]
            eroded[i, j] = np.inf if np.isnan(v) else v
    # the openings of the last DROP_RADII radii, the oldest at r % DROP_RADII
    recent = np.empty((DROP_RADII, ny, nx))
    for k in range(DROP_RADII):
        recent[k] = surface
    current = np.empty_like(surface)
    scratch = np.empty_like(surface)
    tmp = np.empty_like(surface)
    # each cell's drops at the last SLOPE_RADII + 1 radii, that of radius q at q % (SLOPE_RADII + 1)
    k = SLOPE_RADII + 1
    drops = np.zeros((k, ny, nx))
    work = _square_work(ny, nx, radii)
    for r in range(1, radii + 1):
        _min3(eroded, tmp, scratch)
        eroded, scratch = scratch, eroded
        for i in range(ny):
            for j in range(nx):
                # a maximum as the minimum of negatives, over the cells read
                scratch[i, j] = -eroded[i, j] if (first_read[i, j] if r == 1 else read[i, j]) else np.inf
        _square_min(scratch, r, current, work)
        previous = recent[(r - 1) % DROP_RADII]
        oldest = recent[r % DROP_RADII]
        for i in range(ny):
            for j in range(nx):
                v = surface[i, j]
                if not np.isnan(v):
                    c = -current[i, j]
                    d = max(previous[i, j] - c, 0.0)
                    drops[r % k, i, j] = d
                    if d > cap or oldest[i, j] - c > steps_cap:
                        objects[i, j] = True
                    oldest[i, j] = c
                    # radius q's drop marks an object unless each of the next SLOPE_RADII keeps
                    # SLOPE_KEPT of it (a slope), decided once they are known; at the last radius,
                    # the radii whose next drops are not all known are judged by the drop alone
                    q = r - SLOPE_RADII
                    if q >= 1:
                        dq = drops[q % k, i, j]
                        if _flagged_drop(dq, q, slope_cell, wall, wall_radii):
                            for m in range(q + 1, r + 1):
                                if drops[m % k, i, j] < SLOPE_KEPT * dq:
                                    objects[i, j] = True
                                    break
                    if r == radii:
                        for q in range(max(1, r - SLOPE_RADII + 1), r + 1):
                            if _flagged_drop(drops[q % k, i, j], q, slope_cell, wall, wall_radii):
                                objects[i, j] = True


# --- the ground TIN -----------------------------------------------------------------------------------------


@njit_helper
def _sides(tri, ax, ay, t: int) -> tuple[float, float, float, float]:
    """Triangle ``t``'s second and third corners less its first: ``bx, by, cx, cy``."""
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    return ax[b] - ax[a], ay[b] - ay[a], ax[c] - ax[a], ay[c] - ay[a]


@njit
def _triangle_radii(tri, ax, ay, radius) -> None:
    """Circumradius of every triangle, from the absolute coordinates ``ax, ay``
    (the same arithmetic in any tile, so the same value)."""
    for t in range(tri.shape[0] // 3):
        bx, by, cx, cy = _sides(tri, ax, ay, t)
        det = bx * cy - by * cx
        if det == 0.0:
            radius[t] = np.inf
            continue
        bl = bx * bx + by * by
        cl = cx * cx + cy * cy
        ux = (cy * bl - by * cl) * 0.5 / det
        uy = (bx * cl - cx * bl) * 0.5 / det
        radius[t] = math.sqrt(ux * ux + uy * uy)


@njit_helper
def _plane_test(tri, ax, ay, vz, t, px, py, pz, threshold, scalar) -> bool:
    """Whether ``(px, py, pz)`` lies within ``threshold + scalar * slope`` of triangle ``t``'s plane."""
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    bx, by, cx, cy = _sides(tri, ax, ay, t)
    bz = vz[b] - vz[a]
    cz = vz[c] - vz[a]
    det = bx * cy - by * cx
    if det == 0.0:
        return False
    gx = (bz * cy - by * cz) / det
    gy = (bx * cz - bz * cx) / det
    height = vz[a] + gx * (px - ax[a]) + gy * (py - ay[a])
    return abs(pz - height) <= threshold + scalar * math.sqrt(gx * gx + gy * gy)


@njit_helper
def _edge_key_before(ax, ay, tri, e: int, f: int) -> bool:
    """Whether half-edge ``e`` comes before ``f`` by its corners' coordinates."""
    for k in range(2):
        ve = tri[e] if k == 0 else tri[_next(e)]
        vf = tri[f] if k == 0 else tri[_next(f)]
        if ax[ve] != ax[vf]:
            return ax[ve] < ax[vf]
        if ay[ve] != ay[vf]:
            return ay[ve] < ay[vf]
    return e < f


@njit_helper
def _rim_edge(tri, he, live, e: int) -> bool:
    """Whether half-edge ``e`` bounds the live TIN: its triangle is live, its twin missing or not live."""
    if not live[e // 3]:
        return False
    f = he[e]
    return f == -1 or not live[f // 3]


@njit_helper
def _edge_cells(tri, ax, ay, e: int, x0: float, y0: float, size: float, nx: int, ny: int, reach: float):
    """The range of grid cells that edge ``e``'s box, grown by ``reach``, meets."""
    a = tri[e]
    b = tri[_next(e)]
    i0 = max(int(math.floor((min(ax[a], ax[b]) - reach - x0) / size)), 0)
    i1 = min(int(math.floor((max(ax[a], ax[b]) + reach - x0) / size)), nx - 1)
    j0 = max(int(math.floor((min(ay[a], ay[b]) - reach - y0) / size)), 0)
    j1 = min(int(math.floor((max(ay[a], ay[b]) + reach - y0) / size)), ny - 1)
    return i0, i1, j0, j1


@njit
def _rim_index(tri, he, live, ax, ay, x0, y0, size, nx, ny, reach):
    """The boundary half-edges of the live TIN (a live triangle's edge whose
    twin is missing or not live), bucketed on a grid of ``size`` cells from
    ``(x0, y0)``: each edge in every cell its box grown by ``reach`` meets.
    Returns ``(starts, edges)`` in CSR form."""
    counts = np.zeros(nx * ny + 1, dtype=np.int64)
    for e in range(tri.shape[0]):
        if _rim_edge(tri, he, live, e):
            i0, i1, j0, j1 = _edge_cells(tri, ax, ay, e, x0, y0, size, nx, ny, reach)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    counts[j * nx + i + 1] += 1
    for i in range(nx * ny):
        counts[i + 1] += counts[i]
    edges = np.empty(counts[nx * ny], dtype=np.int64)
    fill = counts[:-1].copy()
    for e in range(tri.shape[0]):
        if _rim_edge(tri, he, live, e):
            i0, i1, j0, j1 = _edge_cells(tri, ax, ay, e, x0, y0, size, nx, ny, reach)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    edges[fill[j * nx + i]] = e
                    fill[j * nx + i] += 1
    return counts, edges


@njit
def _tin_kernel(tri, he, lx, ly, ax, ay, vz, live, tri_radius, plx, ply, px, py, pz, visit, threshold, scalar,
                rim, cap, x0, y0, size, nx, ny, starts, rim_edges, ground, reach) -> None:
    """For each point (in the order ``visit``, neighbours one after another):
    the live triangles of the TIN containing it (every one, where it lies on
    an edge or a corner, so the walk's path does not matter), and whether it
    lies within ``threshold + scalar * slope`` of one of them.  A point in no
    live triangle is tested against the nearest boundary edge of the live
    TIN within ``rim`` (ties by the edge's corners).  ``reach`` gets the
    radius around the point that holds every seed the decision read.

    ``lx, ly`` and ``plx, ply`` are the local exact coordinates of the seeds
    and the points (for the exact orientation tests), ``ax, ay`` and ``px,
    py`` the caller's (for the arithmetic, the same in any tile)."""
    t = 0
    state = 12345
    fan = np.empty(64, dtype=np.int64)
    for k in range(visit.shape[0]):
        p = visit[k]
        found, state, beyond = _walk(tri, he, lx, ly, plx[p], ply[p], t, state)
        if found == -2:  # a walk too long: a broken triangulation
            found, state = _locate(tri, he, lx, ly, plx[p], ply[p], t, state)
        nfan = 0
        if found >= 0:
            t = found
            z0 = -1
            z1 = -1
            for j in range(3):
                e = 3 * found + j
                if orient2d(lx[tri[e]], ly[tri[e]], lx[tri[_next(e)]], ly[tri[_next(e)]], plx[p], ply[p]) == 0:
                    if z0 == -1:
                        z0 = j
                    else:
                        z1 = j
            zero = -1
            zeros = 0
            if z0 >= 0 and z1 == -1:
                zeros = 1
                zero = 3 * found + z0
            elif z1 >= 0:
                zeros = 2  # on the corner the two edges share; half-edge zero leaves it
                zero = 3 * found + (z1 if z1 == z0 + 1 else z0)
            fan[0] = found
            nfan = 1
            if zeros == 1:
                f = he[zero]
                if f != -1:
                    fan[1] = f // 3
                    nfan = 2
            elif zeros >= 2:
                # every triangle around corner tri[zero]: half-edge zero leaves it
                e = zero
                while True:
                    f = he[_prev(e)]
                    if f == -1 or f == zero:
                        break
                    if nfan < fan.shape[0]:
                        fan[nfan] = f // 3
                        nfan += 1
                    e = f
                if f == -1:
                    e = zero
                    while True:
                        f = he[e]
                        if f == -1:
                            break
                        e = _next(f)
                        if nfan < fan.shape[0]:
                            fan[nfan] = e // 3
                            nfan += 1
        decided = False
        far = 0.0
        for j in range(nfan):
            s = fan[j]
            if not live[s]:
                continue
            far = max(far, 2.0 * tri_radius[s])
            decided = True
            if _plane_test(tri, ax, ay, vz, s, px[p], py[p], pz[p], threshold, scalar):
                ground[p] = True
        if decided:
            reach[p] = far
            continue
        # in no live triangle: the nearest boundary edge of the live TIN within rim
        reach[p] = rim + 2.0 * cap
        i = int(math.floor((px[p] - x0) / size))
        j = int(math.floor((py[p] - y0) / size))
        if i < 0 or j < 0 or i >= nx or j >= ny:
            continue
        c = j * nx + i
        best = -1
        best_d2 = 0.0
        for m in range(starts[c], starts[c + 1]):
            e = rim_edges[m]
            a = tri[e]
            b = tri[_next(e)]
            ex = ax[b] - ax[a]
            ey = ay[b] - ay[a]
            length2 = ex * ex + ey * ey
            u = 0.0 if length2 == 0.0 else min(max(((px[p] - ax[a]) * ex + (py[p] - ay[a]) * ey) / length2, 0.0), 1.0)
            dx = px[p] - (ax[a] + u * ex)
            dy = py[p] - (ay[a] + u * ey)
            d2 = dx * dx + dy * dy
            if d2 > rim * rim:
                continue
            if best == -1 or d2 < best_d2 or (d2 == best_d2 and _edge_key_before(ax, ay, tri, e, best)):
                best = e
                best_d2 = d2
        if best >= 0 and _plane_test(tri, ax, ay, vz, best // 3, px[p], py[p], pz[p], threshold, scalar):
            ground[p] = True


# --- public --------------------------------------------------------------------------------------------------


def _survey_hull(x: np.ndarray, y: np.ndarray, hull: ArrayLike | None) -> np.ndarray:
    """The hull given, checked, or the convex hull of the points (counter-clockwise, ``(h, 2)``)."""
    if hull is not None:
        out = np.asarray(hull, dtype=np.float64)
        if out.ndim != 2 or out.shape[1] != 2 or not np.isfinite(out).all():
            raise InvalidInputError(f"hull must be an (h, 2) array of finite coordinates, got shape {out.shape}")
        return out
    from .validate import convex_hull

    return np.column_stack([x, y])[convex_hull(x, y)]  # exact predicates, in the caller's coordinates


def _meets_hull(hull: np.ndarray, x: np.ndarray, y: np.ndarray, size: float, pad: int,
                shape: tuple[int, int]) -> np.ndarray:
    """Which cells of the padded grid (``shape``, ``pad`` cells around the
    points' cells) meet the convex ``hull``: the survey's, and the empty cells
    between its returns; not the cells beyond its rim.

    A window on the rim that reached past it would hold only the rim's own
    cells: a hedge or a parked car along the survey's edge, whose cells hold
    no ground return, would open as its own ground and seed the TIN (0.5 to
    1.4 m above the ground along the southern edge of
    warsaw_small_broken_crs, half that sample's DTM error)."""
    if hull.shape[0] < 3:
        return np.ones(shape, dtype=np.bool_)
    # the cells' sides, as the grid aligned on multiples of ``size`` has them (the same in every part)
    col0 = np.floor(x / size).min() - pad
    row0 = np.floor(y / size).min() - pad
    xs = (col0 + np.arange(shape[1] + 1)) * size
    ys = (row0 + np.arange(shape[0] + 1)) * size
    lo, hi = _hull_rows(np.ascontiguousarray(hull[:, 0]), np.ascontiguousarray(hull[:, 1]), ys)
    # a cell meets the convex hull when its column overlaps the hull's span across its row
    return (xs[None, 1:] >= lo[:, None]) & (xs[None, :-1] <= hi[:, None])


@njit
def _hull_rows(hx, hy, ys):
    """For each strip ``ys[j] <= y <= ys[j + 1]``: the span in x of the convex
    polygon ``hx, hy`` inside it (``inf, -inf`` where it misses the strip)."""
    ny = ys.shape[0] - 1
    h = hx.shape[0]
    lo = np.full(ny, np.inf)
    hi = np.full(ny, -np.inf)
    for j in range(ny):
        y0 = ys[j]
        y1 = ys[j + 1]
        for k in range(h):
            px = hx[k]
            py = hy[k]
            qx = hx[(k + 1) % h]
            qy = hy[(k + 1) % h]
            if (py < y0 and qy < y0) or (py > y1 and qy > y1):
                continue
            # the edge's part inside the strip: its ends, clipped to the strip's sides
            dy = qy - py
            t0 = 0.0
            t1 = 1.0
            if dy != 0.0:
                a = (y0 - py) / dy
                b = (y1 - py) / dy
                t0 = larger(t0, smaller(a, b))
                t1 = smaller(t1, larger(a, b))
                if t0 > t1:
                    continue
            for t in (t0, t1):
                xt = px + t * (qx - px)
                if xt < lo[j]:
                    lo[j] = xt
                if xt > hi[j]:
                    hi[j] = xt
    return lo, hi


def classify_ground(
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    *,
    unit: float = 1.0,
    parameters: GroundParameters | None = None,
    return_number: ArrayLike | None = None,
    number_of_returns: ArrayLike | None = None,
    hull: ArrayLike | None = None,
    threads: int = 1,
) -> GroundResult:
    """The ground points of a cloud (see the module docstring for the method).

    Parameters
    ----------
    x, y, z : (n,) arrays
        Coordinates, in one unit of length (``unit`` metres).
    unit : float
        Metres in one unit of the coordinates (0.3048 for feet, 1200/3937
        for US survey feet): the parameters, in metres, are scaled by it.
    parameters : GroundParameters, optional
        The defaults when omitted.
    return_number, number_of_returns : (n,) integer arrays, optional
        When both are given, only last returns seed the ground surface.
    hull : (h, 2) array, optional
        The survey's convex hull, counter-clockwise: the openings read no
        cell outside it.  By default the hull of the points given; a caller
        that classifies a survey in parts gives every part the whole
        survey's hull, so that each part reads the same cells.
    threads : int
        How many threads the openings and the TIN's test may use (their
        kernels run without the GIL): the answer is the same with any.

    Returns
    -------
    GroundResult

    Raises
    ------
    InvalidInputError
        When the arrays differ in length, are not finite, or ``unit`` is not
        a positive number.
    """
    x, y, z = point_columns(x, y, z)
    if not (isinstance(unit, (int, float)) and math.isfinite(unit) and unit > 0):
        raise InvalidInputError(f"unit must be a positive number of metres, not {unit!r}")
    p = parameters or GroundParameters()
    n = x.shape[0]
    ground = np.zeros(n, dtype=np.bool_)
    outlier = np.zeros(n, dtype=np.bool_)
    margin = p.margin(unit)
    reach = np.full(n, p.max_reach(unit))
    if n == 0:
        return GroundResult(ground, outlier, reach)

    # 1. low outliers
    cell, nx, ny = _cells(x, y, p.outlier_cell / unit)
    order, starts = _grouped(cell, z, nx * ny)
    _low_outlier_kernel(z, order, starts, nx, ny, p.outlier_depth / unit, 2, outlier)

    # 2. the lowest surface and its objects
    eligible = ~outlier
    if return_number is not None and number_of_returns is not None:
        rn = np.asarray(return_number)
        nr = np.asarray(number_of_returns)
        if rn.shape != (n,) or nr.shape != (n,):
            raise InvalidInputError("return_number and number_of_returns must have one entry per point")
        eligible &= rn >= nr
    size = p.cell / unit
    cell, nx, ny = _cells(x, y, size)
    lowest = _lowest_per_cell(np.flatnonzero(eligible), cell, x, y, z, nx * ny)  # ties by coordinates
    surface = np.full(nx * ny, np.nan)
    surface[cell[lowest]] = z[lowest]
    surface = surface.reshape(ny, nx)
    radii = max(1, math.ceil(p.max_window / p.cell))
    pad = min(radii, GAP_CELLS)  # the cells beyond the data that a dilation reads
    padded = np.pad(surface, pad, constant_values=np.nan)
    objects = np.zeros(padded.shape, dtype=np.bool_)
    read = _near_data(padded, GAP_CELLS)
    first_read = read & _meets_hull(_survey_hull(x, y, hull), x, y, size, pad, padded.shape)
    cap = p.object_height / unit
    # over DROP_RADII radii: the cap, or ground as steep as 45 degrees on coarse cells (a sparse survey's)
    wall_radii = min(radii, math.floor(p.wall_radius / p.cell))
    _objects(padded, read, first_read, radii, p.slope * size, cap, max(cap, DROP_RADII * size), p.wall_height / unit,
             wall_radii, objects, threads)
    objects = objects[pad:-pad, pad:-pad]
    seeds = lowest[~objects.ravel()[cell[lowest]]]

    # 3. the ground TIN
    tin = delaunay(np.column_stack([x[seeds], y[seeds]])) if seeds.shape[0] >= 3 else None
    if tin is not None and tin.triangles.shape[0] > 0:  # collinear seeds make no triangle
        _tin_pass(tin, x[seeds], y[seeds], z[seeds], x, y, z, p, unit, ground, reach, threads)
    reach += margin
    # a seed is ground, and so is each of its exact copies (one class per position, whichever copy is the seed)
    seed_of = np.full(nx * ny, -1, dtype=np.int64)
    seed_of[cell[seeds]] = seeds
    mate = seed_of[cell]
    has = mate >= 0
    twin = np.zeros(n, dtype=np.bool_)
    twin[has] = (x[has] == x[mate[has]]) & (y[has] == y[mate[has]]) & (z[has] == z[mate[has]])
    ground |= twin
    ground &= ~outlier
    return GroundResult(ground, outlier, reach)


def _in_threads(threads: int, calls: list) -> None:
    """Run the argument-free ``calls`` (kernels without the GIL) on up to ``threads`` threads."""
    if threads <= 1 or len(calls) <= 1:
        for call in calls:
            call()
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(min(threads, len(calls))) as pool:
        for future in [pool.submit(call) for call in calls]:
            future.result()


_BAND_ROWS = 64
"""The fewest rows of cells a band of the openings computes for itself (and never fewer than the rows it
reads on either side: a band narrower than that would mostly compute its neighbours' rows again)."""


def _objects(padded, read, first_read, radii: int, slope_cell: float, cap: float, steps_cap: float, wall: float,
             wall_radii: int, objects, threads: int) -> None:
    """:func:`_object_kernel` over ``padded``, in bands of rows on ``threads``
    threads.  A cell's flag reads the cells within ``2 radii`` rows of it (an
    erosion of ``radii``, then a dilation as wide), so each band computes its
    rows with that many more on each side, and keeps its own: the flags are
    the whole grid's, bit for bit."""
    rows = padded.shape[0]
    halo = 2 * radii + 1
    bands = max(1, min(threads, rows // max(_BAND_ROWS, halo)))
    if bands == 1:
        _object_kernel(padded, read, first_read, radii, slope_cell, cap, steps_cap, wall, wall_radii, objects)
        return
    cuts = np.linspace(0, rows, bands + 1).round().astype(np.int64)

    def band(lo: int, hi: int):
        def call() -> None:
            a, b = max(lo - halo, 0), min(hi + halo, rows)
            flags = np.zeros((b - a, padded.shape[1]), dtype=np.bool_)
            _object_kernel(padded[a:b], read[a:b], first_read[a:b], radii, slope_cell, cap, steps_cap, wall, wall_radii,
                           flags)
            objects[lo:hi] = flags[lo - a:hi - a]
        return call

    _in_threads(threads, [band(int(lo), int(hi)) for lo, hi in zip(cuts[:-1], cuts[1:])])


def _tin_pass(tin, sx, sy, sz, x, y, z, p: GroundParameters, unit: float, ground, reach, threads: int = 1) -> None:
    """Step 3 of :func:`classify_ground` over the seeds' triangulation ``tin``,
    the points in ``threads`` runs of their visit order (a point's answer is
    its own, whatever walk found its triangles)."""
    tri, he = tin.triangles, tin.halfedges
    ax, ay, vz = sx[tin.order], sy[tin.order], sz[tin.order]
    tri_radius = np.empty(tri.shape[0] // 3)
    _triangle_radii(tri, ax, ay, tri_radius)
    cap = p.max_radius / unit
    live = tri_radius <= cap
    rim = math.sqrt(2.0) * p.cell / unit
    x0, y0 = float(x.min()), float(y.min())
    size = max(rim, (float(x.max()) - x0) / 2048, (float(y.max()) - y0) / 2048)
    nx = int((float(x.max()) - x0) // size) + 1
    ny = int((float(y.max()) - y0) // size) + 1
    starts, rim_edges = _rim_index(tri, he, live, ax, ay, x0, y0, size, nx, ny, rim)
    visit = np.lexsort((np.floor((y - y0) / rim), np.floor((x - x0) / rim)))  # neighbours one after another
    plx, ply = x - tin.origin[0], y - tin.origin[1]

    def run(part):
        def call() -> None:
            _tin_kernel(tri, he, tin.x, tin.y, ax, ay, vz, live, tri_radius, plx, ply, x, y, z, part,
                        p.threshold / unit, p.scalar / unit, rim, cap, x0, y0, size, nx, ny, starts, rim_edges,
                        ground, reach)
        return call

    _in_threads(threads, [run(part) for part in np.array_split(visit, max(1, threads))])
