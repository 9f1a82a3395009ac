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
   empty; it is opened (a minimum then a maximum over a square window of
   radius ``r`` cells, ignoring the holes) for ``r = 1 ... R`` with
   ``R = ceil(max_window / cell)``.  A cell whose opening drops by more than
   ``slope * r * cell`` from radius ``r - 1`` to ``r`` holds an object
   (Pingel's test).  Each opening is computed from the lowest surface
   itself, not from the previous opening: for square windows the two are the
   same (openings by nested squares form a granulometry), and it bounds what
   a cell's flag depends on.
3. **A TIN of the ground cells instead of an inpainted grid.**  The lowest
   points of the cells not flagged are triangulated (Delaunay,
   :func:`meshcore.delaunay.delaunay`); a point is ground when it lies within
   ``threshold + scalar * s`` of that TIN, ``s`` the slope of the triangle
   under it (Pingel's final test, with the triangle's exact slope instead of
   a gridded one).  Where return numbers are given, only last returns seed
   the surface (a first of several returns is not the ground).

What a point's class depends on
-------------------------------
Everything is computed on grids aligned on multiples of the cell sizes, so a
point's class depends only on the points near it:

* a low-outlier decision on the points within ``2 sqrt(2) outlier_cell``
  (the block of 3 x 3 cells);
* a cell's object flag on the lowest points within ``sqrt(2) (2 R + 1) cell``
  (an opening of radius ``R`` reads ``2 R`` cells each way), each of which
  depends on the outliers as above;
* a point's class on the three seeds of the TIN triangle under it, a triangle
  of the Delaunay TIN of the seeds, fixed by the seeds inside its
  circumcircle.

So the class of a point ``p`` depends only on points within
``reach(p) = 2 rho(p) + sqrt(2) (2 R + 2) cell + 2 sqrt(2) outlier_cell``,
``rho(p)`` the circumradius of the TIN triangle under ``p``
(:attr:`GroundResult.circumradius`): a tile whose loaded points cover that
disc around each of its own points decided them as an unbounded cloud would
have.  ``rho`` is small wherever ground cells are dense, and long only across
large areas without a ground cell (water, a very large roof).

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
from dataclasses import asdict, dataclass, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import njit
from .delaunay import _locate, _next, _walk, delaunay
from .errors import InvalidInputError

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
        1.25 is for the gradient of a smoothed grid; a TIN facet's slope is
        steeper wherever one seed is off, so less of it is taken.
    object_height : float
        A drop of the opening larger than this from one radius to the next
        marks an object whatever the radius, metres (Pingel's threshold
        ``slope * r * cell`` alone lets low buildings wider than
        ``2 object_height / slope`` through).
    outlier_depth : float
        How far below the points of its neighbourhood a point must lie to be
        a low outlier, metres.
    outlier_cell : float
        Side of the cells of the low-outlier test, metres.
    """

    cell: float = 1.0
    max_window: float = 50.0
    slope: float = 0.15
    threshold: float = 0.5
    scalar: float = 0.5
    object_height: float = 2.0
    outlier_depth: float = 1.0
    outlier_cell: float = 5.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise InvalidInputError(f"GroundParameters.{f.name} must be a finite number >= 0, not {value!r}")
        for name in ("cell", "max_window", "outlier_cell"):
            if getattr(self, name) <= 0:
                raise InvalidInputError(f"GroundParameters.{name} must be > 0, not {getattr(self, name)!r}")

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
    circumradius : (n,) float64
        Circumradius of the ground-TIN triangle under the point, in the
        input's units (infinite outside the TIN): the ``rho`` of the module
        docstring's reach.
    """

    ground: NDArray[np.bool_]
    low_outlier: NDArray[np.bool_]
    circumradius: NDArray[np.float64]

    @property
    def low_outliers(self) -> int:
        """How many low outliers were set apart."""
        return int(self.low_outlier.sum())


# --- grids --------------------------------------------------------------------------------------------------


def _cells(x: np.ndarray, y: np.ndarray, size: float) -> tuple[np.ndarray, int, int]:
    """Cell of each point on the grid aligned on multiples of ``size``, as one id ``row * nx + column``."""
    ix = np.floor(x / size).astype(np.int64)
    iy = np.floor(y / size).astype(np.int64)
    ix -= ix.min()
    iy -= iy.min()
    nx = int(ix.max()) + 1
    ny = int(iy.max()) + 1
    return iy * nx + ix, nx, ny


def _grouped(cell: np.ndarray, z: np.ndarray, ncells: int) -> tuple[np.ndarray, np.ndarray]:
    """Points sorted by cell then height, and where each cell's run starts (``ncells + 1`` entries)."""
    order = np.lexsort((z, cell)).astype(np.int64)
    starts = np.zeros(ncells + 1, dtype=np.int64)
    np.cumsum(np.bincount(cell, minlength=ncells), out=starts[1:])
    return order, starts


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
def _line_min(values, n, stride, start, r, padded, g, h, out_values) -> None:
    """Minimum over a window of radius ``r`` along one line of a raveled grid
    (van Herk / Gil-Werman: three comparisons per cell whatever ``r``).

    The line is ``values[start + i * stride]`` for ``i < n``; beyond its ends
    the values are infinite.
    """
    k = 2 * r + 1
    m = n + 2 * r
    blocks = (m + k - 1) // k
    total = blocks * k
    for j in range(total):
        i = j - r
        padded[j] = values[start + i * stride] if 0 <= i < n else np.inf
    for j in range(total):
        if j % k == 0:
            g[j] = padded[j]
        else:
            g[j] = min(g[j - 1], padded[j])
    for j in range(total - 1, -1, -1):
        if j % k == k - 1 or j == total - 1:
            h[j] = padded[j]
        else:
            h[j] = min(h[j + 1], padded[j])
    for i in range(n):
        out_values[start + i * stride] = min(h[i], g[i + 2 * r])


@njit
def _square_min(grid, r, out) -> None:
    """Minimum of the raveled ``(ny, nx)`` ``grid`` over squares of radius ``r`` cells, into ``out``."""
    ny, nx = grid.shape
    size = max(nx, ny) + 4 * r + 2
    padded = np.empty(size)
    g = np.empty(size)
    h = np.empty(size)
    flat = grid.ravel()
    tmp = np.empty(nx * ny)
    for row in range(ny):
        _line_min(flat, nx, 1, row * nx, r, padded, g, h, tmp)
    o = out.ravel()
    for col in range(nx):
        _line_min(tmp, ny, nx, col, r, padded, g, h, o)


@njit
def _opening(surface, r, scratch, out) -> None:
    """Opening of ``surface`` (NaN: no data) by the square of radius ``r``
    cells, with the holes ignored; NaN where ``surface`` has none."""
    ny, nx = surface.shape
    for i in range(ny):
        for j in range(nx):
            v = surface[i, j]
            scratch[i, j] = np.inf if np.isnan(v) else v
    _square_min(scratch, r, out)  # erosion: +inf where no data lies within r
    for i in range(ny):
        for j in range(nx):
            v = out[i, j]
            scratch[i, j] = np.inf if v == np.inf else -v  # a maximum as the minimum of negatives; holes ignored
    _square_min(scratch, r, out)
    for i in range(ny):
        for j in range(nx):
            out[i, j] = np.nan if np.isnan(surface[i, j]) else -out[i, j]


@njit
def _object_kernel(surface, radii, slope_cell, cap, objects) -> None:
    """Pingel's progressive test: ``objects`` where the opening of radius
    ``r`` lies more than ``slope_cell * r`` below the opening of radius ``r - 1``."""
    ny, nx = surface.shape
    previous = surface.copy()
    current = np.empty_like(surface)
    scratch = np.empty_like(surface)
    for r in range(1, radii + 1):
        _opening(surface, r, scratch, current)
        limit = min(slope_cell * r, cap)
        for i in range(ny):
            for j in range(nx):
                if previous[i, j] - current[i, j] > limit:
                    objects[i, j] = True
        previous, current = current, previous


# --- the ground TIN -----------------------------------------------------------------------------------------


@njit
def _tin_kernel(tri, he, vx, vy, vz, px, py, pz, visit, threshold, scalar, reach, ground, radius) -> None:
    """For each point (in the order ``visit``, neighbours one after another):
    the TIN triangle under it, its height and slope there, and whether it
    lies within ``threshold + scalar * slope`` of it.  A point outside the
    TIN but within ``reach`` of its hull (the rim of the survey, beyond its
    edge cells' lowest points) is tested against the plane of the hull
    triangle it lies beyond."""
    t = 0
    state = 12345
    for k in range(visit.shape[0]):
        p = visit[k]
        found, state, beyond = _walk(tri, he, vx, vy, px[p], py[p], t, state)
        extra = 0.0
        if found == -2:  # a walk too long: a broken triangulation
            found, state = _locate(tri, he, vx, vy, px[p], py[p], t, state)
        if found == -1 and beyond >= 0:
            a = tri[beyond]
            b = tri[_next(beyond)]
            ex = vx[b] - vx[a]
            ey = vy[b] - vy[a]
            length2 = ex * ex + ey * ey
            u = 0.0 if length2 == 0.0 else min(max(((px[p] - vx[a]) * ex + (py[p] - vy[a]) * ey) / length2, 0.0), 1.0)
            dx = px[p] - (vx[a] + u * ex)
            dy = py[p] - (vy[a] + u * ey)
            if dx * dx + dy * dy <= reach * reach:
                found = beyond // 3
                extra = reach  # its decision reads as far as the triangle's, plus its way to it
        if found < 0:
            radius[p] = np.inf
            continue
        t = found
        a = tri[3 * t]
        b = tri[3 * t + 1]
        c = tri[3 * t + 2]
        ax = vx[a]
        ay = vy[a]
        bx = vx[b] - ax
        by = vy[b] - ay
        cx = vx[c] - ax
        cy = vy[c] - ay
        bz = vz[b] - vz[a]
        cz = vz[c] - vz[a]
        det = bx * cy - by * cx
        if det == 0.0:
            radius[p] = np.inf
            continue
        gx = (bz * cy - by * cz) / det
        gy = (bx * cz - bz * cx) / det
        height = vz[a] + gx * (px[p] - ax) + gy * (py[p] - ay)
        s = math.sqrt(gx * gx + gy * gy)
        if abs(pz[p] - height) <= threshold + scalar * s:
            ground[p] = True
        bl = bx * bx + by * by
        cl = cx * cx + cy * cy
        ux = (cy * bl - by * cl) * 0.5 / det
        uy = (bx * cl - cx * bl) * 0.5 / det
        radius[p] = math.sqrt(ux * ux + uy * uy) + extra


# --- public --------------------------------------------------------------------------------------------------


def _checked(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arrays = [np.asarray(a, dtype=np.float64) for a in (x, y, z)]
    if any(a.ndim != 1 for a in arrays) or len({a.shape[0] for a in arrays}) != 1:
        raise InvalidInputError(f"x, y and z must be 1-D arrays of one length, not of shapes {[a.shape for a in arrays]}")
    if not all(np.isfinite(a).all() for a in arrays):
        raise InvalidInputError("x, y and z must be finite")
    return arrays[0], arrays[1], arrays[2]


def classify_ground(
    x: ArrayLike,
    y: ArrayLike,
    z: ArrayLike,
    *,
    unit: float = 1.0,
    parameters: GroundParameters | None = None,
    return_number: ArrayLike | None = None,
    number_of_returns: ArrayLike | None = None,
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

    Returns
    -------
    GroundResult

    Raises
    ------
    InvalidInputError
        When the arrays differ in length, are not finite, or ``unit`` is not
        a positive number.
    """
    x, y, z = _checked(x, y, z)
    if not (isinstance(unit, (int, float)) and math.isfinite(unit) and unit > 0):
        raise InvalidInputError(f"unit must be a positive number of metres, not {unit!r}")
    p = parameters or GroundParameters()
    n = x.shape[0]
    ground = np.zeros(n, dtype=np.bool_)
    outlier = np.zeros(n, dtype=np.bool_)
    radius = np.full(n, np.inf)
    if n == 0:
        return GroundResult(ground, outlier, radius)

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
        if not eligible.any():
            eligible = ~outlier
    size = p.cell / unit
    cell, nx, ny = _cells(x, y, size)
    ids = np.flatnonzero(eligible)
    order = ids[np.lexsort((z[ids], cell[ids]))]
    first = np.ones(order.shape[0], dtype=np.bool_)
    first[1:] = cell[order[1:]] != cell[order[:-1]]
    lowest = order[first]
    surface = np.full(nx * ny, np.nan)
    surface[cell[lowest]] = z[lowest]
    surface = surface.reshape(ny, nx)
    objects = np.zeros((ny, nx), dtype=np.bool_)
    radii = max(1, math.ceil(p.max_window / p.cell))
    _object_kernel(surface, radii, p.slope * size, p.object_height / unit, objects)
    seeds = lowest[~objects.ravel()[cell[lowest]]]

    # 3. the ground TIN
    if seeds.shape[0] >= 3:
        tin = delaunay(np.column_stack([x[seeds], y[seeds]]))
    if seeds.shape[0] >= 3 and tin.triangles.shape[0] > 0:  # collinear seeds make no triangle
        vz = z[seeds][tin.order]
        visit = np.argsort(cell, kind="stable")
        _tin_kernel(
            tin.triangles, tin.halfedges, tin.x, tin.y, vz, x - tin.origin[0], y - tin.origin[1], z, visit,
            p.threshold / unit, p.scalar / unit, math.sqrt(2.0) * size, ground, radius,
        )
    ground[seeds] = True
    ground &= ~outlier
    return GroundResult(ground, outlier, radius)
