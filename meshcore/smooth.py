"""The smooth surface's node values: local kriging in cells of about a point spacing.

The smooth surface (``surface="smooth"``) puts a cubic patch on every face
(:mod:`meshcore.patches`).  Its corners take the points' z; its other nodes
(two per edge, the inner ones of each face) take the value of universal
kriging with a linear drift:

- the nodes are grouped in square cells of 1.4 point spacings
  (:attr:`Variogram.spacing`), aligned on multiples of the cell's side; each
  cell's nodes are kriged from the ``neighbours`` vertices nearest the
  cell's centre: one system per cell, solved once in its dual form
  (Cholesky of the covariances, the drift by its Schur complement), then
  evaluated at each of its nodes.  About one system per two points: a system
  per edge and per face (five per point) gave the same errors at several
  times the cost;
- nearest is exact, with ties broken by coordinates, so a node's value
  depends only on the points inside its cell's disk (the centre and the
  distance to its last neighbour, :attr:`Neighbourhoods.disks`), never on the
  order of the points or on which points a tile happens to hold beyond it;
- an edge's nodes are placed from its end first in coordinate order, so the
  two faces of an edge, in one tile or in two, put them at the same
  positions, in the same cells, and get bit-identical values: the surface is
  continuous (C0 across every edge) and seamless across tiles;
- the kriged value is clamped to the range of the neighbours' values and of
  its edge's (an inner node: its face's) corners.  Kriging with a linear
  drift reproduces linear functions, and a linear function stays inside that
  range, so the surface reproduces linear functions exactly; the clamp
  stops overshoot where the neighbours lie to one side (the hull, voids).
  On ground the variogram calls smooth and nearly noise-free (a Matérn model,
  a nugget under 0.1% of the sill) only those nodes are clamped, so that a
  crest may rise above the points beside it (:func:`_clamps_inside`);
- a system whose neighbours are collinear (no plane fits) gives its nodes
  the linear surface's values;
- a node in a void (farther than :data:`VOID_NEAR` spacings from its
  cell's points) is blended, by its distance from them, into the void's
  fill: the linear surface, then half of it and half the natural-neighbour
  interpolant of the points around the void (:mod:`meshcore.natural`).
  There the cell's points lie on one side of the rim, and kriging carries
  that side's tilt and noise across the void: beyond a few spacings it was
  worse than the TIN; the fill reads the whole rim, stays within its values
  and reproduces linear functions.  The blend depends on the node's
  position and its cell's points alone, so edges stay C0 and tiles seamless;
  a node's natural neighbours are read from disks that :attr:`Neighbourhoods.disks`
  reports with the cells' (:func:`_void_blend`);
- first, faces with an edge longer than a few spacings are cut
  (:func:`smooth_plan`, :mod:`meshcore.refine`): the edge is split into
  equal pieces by its length alone, the new points are kriged from their
  cells' systems as nodes are, and the patches lie on the triangles
  (:func:`smooth_surface`).

The covariance is a :class:`Variogram` of one of :data:`MODELS`;
:func:`fit_variogram` chooses the model, its nugget and range by
leave-one-out cross-validation of this same kriging on a sample, and
measures the spacing.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._buckets import _bounds, _disks_holding, _nearest, _nearest_around
from ._jit import LANES, empty, full, lanes_scale, lanes_subtract_products, larger, njit, njit_helper, smaller, zeros
from .errors import InvalidInputError
from .mesh import Mesh, mesh_arrays, vertex_values
from .natural import (NaturalCoordinates, join_places, natural_coordinates, natural_ranges, natural_values, take_places,
                      tin_values)
from .patches import NODES_PER_FACE
from .refine import Refinement, _first_end, refine_long_faces

__all__ = [
    "MODELS", "CELL_PER_SPACING", "Variogram", "Neighbourhoods", "AddedPoints", "SmoothPlan", "SmoothSurface", "fit_variogram",
    "smooth_nodes", "smooth_neighbourhoods", "smooth_plan", "smooth_surface", "DEFAULT_NEIGHBOURS", "VoidFill",
    "VOID_NEAR", "VOID_FAR", "VOID_NATURAL_SHARE", "VOID_REACH",
]

DEFAULT_NEIGHBOURS = 16
"""Points per kriging neighbourhood (the vertex and its 15 nearest)."""

_PIVOT_TOL = 1e-10
"""A kriging system whose pivot falls below this (relative) is singular."""

MODELS = ("exponential", "matern32", "matern52")
"""The covariance models, from the roughest to the smoothest (Matérn with
smoothness 1/2, 3/2 and 5/2): :func:`fit_variogram` chooses among them."""


@dataclass(frozen=True)
class Variogram:
    """A variogram ``nugget + sill (1 - rho(h))`` (``h > 0``) of one of :data:`MODELS`.

    ``rho`` is the correlation at lag ``h``: ``exp(-h / range)`` for the
    exponential model, ``(1 + a) exp(-a)`` with ``a = sqrt(3) h / range``
    for Matérn 3/2 and ``(1 + a + a^2 / 3) exp(-a)`` with ``a = sqrt(5) h / range``
    for Matérn 5/2.  The rougher the model, the closer kriging stays to a
    TIN; the smoother, the better it follows a smooth surface between
    sparse points.

    Attributes
    ----------
    nugget : float
        The semivariance at zero lag: noise the smoother does not follow (z unit squared).
    sill : float
        The partial sill, ``> 0`` (z unit squared).
    range : float
        The distance scale of the model, ``> 0`` (horizontal unit).
    model : str
        One of :data:`MODELS`.
    spacing : float or None
        The survey's typical point spacing (horizontal unit): the smooth
        surface groups its nodes in square cells of this side, each cell's
        nodes kriged from one system.  :func:`fit_variogram` measures it;
        ``None`` lets each mesh measure its own (pieces of one survey then
        no longer agree on their shared edges).

    Only ``nugget / sill``, ``range`` and ``model`` change the kriging weights.
    """

    nugget: float
    sill: float
    range: float
    model: str = "exponential"
    spacing: float | None = None

    def __post_init__(self) -> None:
        for name in ("nugget", "sill", "range", "spacing"):
            value = getattr(self, name)
            if name == "spacing" and value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InvalidInputError(f"variogram {name} must be a finite number, got {value!r}")
        if self.nugget < 0.0 or not self.sill > 0.0 or not self.range > 0.0:
            raise InvalidInputError(
                f"variogram needs nugget >= 0, sill > 0 and range > 0, got {self.nugget!r}, {self.sill!r}, {self.range!r}"
            )
        if self.model not in MODELS:
            raise InvalidInputError(f"variogram model must be one of {', '.join(MODELS)}, got {self.model!r}")
        if self.spacing is not None and not self.spacing > 0.0:
            raise InvalidInputError(f"variogram spacing must be > 0, got {self.spacing!r}")

    def correlation(self, h: ArrayLike) -> NDArray[np.float64]:
        """``rho(h)``, the model's correlation at lags ``h >= 0`` (1 at 0, without the nugget)."""
        return _correlation(np.abs(np.asarray(h, dtype=np.float64)), self.range, MODELS.index(self.model))

    def semivariance(self, h: ArrayLike) -> NDArray[np.float64]:
        """``gamma(h)``: 0 at ``h == 0``, ``nugget + sill (1 - rho(h))`` beyond."""
        h = np.abs(np.asarray(h, dtype=np.float64))
        return np.where(h > 0.0, self.nugget + self.sill * (1.0 - self.correlation(h)), 0.0)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: float(getattr(self, k)) for k in ("nugget", "sill", "range")}
        out["model"] = self.model
        out["spacing"] = None if self.spacing is None else float(self.spacing)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Variogram":
        try:
            spacing = data.get("spacing")
            return cls(float(data["nugget"]), float(data["sill"]), float(data["range"]),
                       str(data.get("model", "exponential")), None if spacing is None else float(spacing))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise InvalidInputError(f"a variogram needs numbers nugget, sill and range, got {data!r}") from None


def _correlation(h: NDArray[np.float64], range_: float, model: int) -> NDArray[np.float64]:
    """:func:`_covariance` at every lag of ``h`` (1 at 0)."""
    flat = np.ascontiguousarray(h, dtype=np.float64).reshape(-1)
    out = np.empty_like(flat)
    _correlation_kernel(flat, 1.0 / range_, model, out)
    return out.reshape(np.shape(h))


# --------------------------------------------------------------------------
# Kriging: one system per cell, solved in its dual form
# --------------------------------------------------------------------------


_SQRT3 = math.sqrt(3.0)
_SQRT5 = math.sqrt(5.0)
_LAG_SCALE = (1.0, _SQRT3, _SQRT5)
"""``a = scale * h / range``: the argument of each model's exponential."""

_EXP_STEPS = 16
_EXP_TABLE = np.exp(-np.arange(64 * _EXP_STEPS) / _EXP_STEPS)
"""``exp(-n / 16)`` for ``n < 1024``: :func:`_exp_neg` starts from the nearest below."""


@njit_helper
def _exp_neg(a: float) -> float:
    """``exp(-a)`` for ``a >= 0``, within a few ulp; 0 from ``a >= 64`` on (``exp(-64) = 1.6e-28``).

    A table step of 1/16 and the Taylor series of degree 8 of the rest
    (its remainder below ``(1/16)^9 / 9! = 4e-17``): a branch-free loop of
    these vectorises, where one of ``math.exp`` calls the scalar library
    function at every lag.  The covariances are most of the smooth surface's
    cost (about 190 a point).
    """
    t = smaller(a * 16.0, 1023.0)
    n = np.int64(t)
    u = (n * 0.0625) - a
    p = 1.0 + u * (1.0 + u * (0.5 + u * (1.0 / 6.0 + u * (1.0 / 24.0 + u * (1.0 / 120.0 + u * (
        1.0 / 720.0 + u * (1.0 / 5040.0 + u * (1.0 / 40320.0))))))))
    return _EXP_TABLE[n] * p if a < 64.0 else 0.0


@njit_helper
def _model_covariance(a: float, model: int) -> float:
    """The covariance per unit sill of ``MODELS[model]`` at the scaled lag ``a`` (:data:`_LAG_SCALE`)."""
    e = _exp_neg(a)
    if model == 0:
        return e
    if model == 1:
        return (1.0 + a) * e
    return (1.0 + a + a * a * (1.0 / 3.0)) * e


@njit_helper
def _covariance(h: float, inv_range: float, model: int) -> float:
    """The covariance per unit sill at lag ``h > 0`` of model ``MODELS[model]``."""
    return _model_covariance(h * (_LAG_SCALE[model] * inv_range), model)


@njit_helper
def _covariances(xs: np.ndarray, ys: np.ndarray, count: int, px: float, py: float, scale: float, model: int,
                 out: np.ndarray) -> None:
    """``out[j]``: the covariance between ``(xs[j], ys[j])`` and ``p`` for ``j < count``.

    ``scale`` is ``_LAG_SCALE[model] / range``.  One loop per model, free of
    branches and calls, so that the compiler vectorises it.
    """
    if model == 0:
        for j in range(count):
            dx = xs[j] - px
            dy = ys[j] - py
            out[j] = _exp_neg(math.sqrt(dx * dx + dy * dy) * scale)
    elif model == 1:
        for j in range(count):
            dx = xs[j] - px
            dy = ys[j] - py
            a = math.sqrt(dx * dx + dy * dy) * scale
            out[j] = (1.0 + a) * _exp_neg(a)
    else:
        for j in range(count):
            dx = xs[j] - px
            dy = ys[j] - py
            a = math.sqrt(dx * dx + dy * dy) * scale
            out[j] = (1.0 + a + a * a * (1.0 / 3.0)) * _exp_neg(a)


@njit
def _correlation_kernel(h: np.ndarray, inv_range: float, model: int, out: np.ndarray) -> None:
    for i in range(h.shape[0]):
        out[i] = _covariance(h[i], inv_range, model)


_LANES = LANES
"""Kriging systems solved side by side (:class:`_KrigingScratch`), one per lane."""


class _KrigingScratch(NamedTuple):
    """Room for :func:`_dual_systems`: up to :data:`_LANES` systems of ``k`` neighbours."""

    xs: np.ndarray  # (_LANES, k) the neighbours relative to each centre
    ys: np.ndarray
    coef: np.ndarray  # (_LANES, k + 3) each system's dual weights and drift
    radius: np.ndarray  # (_LANES,) each system's radius, NaN when singular
    c: np.ndarray  # (k, k, _LANES) the covariances, then their Cholesky factors
    g: np.ndarray  # (k, 4, _LANES) the right-hand sides
    col: np.ndarray  # (k, _LANES) the back substitution's unknowns
    work: np.ndarray  # (12, _LANES) each lane's 1 / pivot, drift sums, flag and first z
    pairs: np.ndarray  # (2, k * k) the lags of the pairs below the diagonal
    cov: np.ndarray  # (_LANES, k * k) their covariances
    reach: np.ndarray  # (_LANES,) each system's radius


@njit
def _kriging_scratch(k: int) -> _KrigingScratch:
    return _KrigingScratch(
        empty((_LANES, k)), empty((_LANES, k)), empty((_LANES, k + 3)), empty(_LANES),
        empty((k, k, _LANES)), empty((k, 4, _LANES)), empty((k, _LANES)), empty((12, _LANES)),
        empty((2, k * k)), empty((_LANES, k * k)), empty(_LANES),
    )


@njit
def _dual_systems(
    xy: np.ndarray, z: np.ndarray, centres: np.ndarray, neighbours: np.ndarray, first: int, lanes: int, k: int,
    nugget_ratio: float, scale: float, model: int, room: _KrigingScratch,
) -> None:
    """:func:`_dual_setup`, then :func:`_dual_solve`: see the latter."""
    _dual_setup(xy, centres, neighbours, first, lanes, k, scale, model, room)
    _dual_solve(z, neighbours, first, lanes, k, nugget_ratio, room)


@njit_helper
def _dual_setup(
    xy: np.ndarray, centres: np.ndarray, neighbours: np.ndarray, first: int, lanes: int, k: int,
    scale: float, model: int, room: _KrigingScratch,
) -> None:
    """What :func:`_dual_solve` takes of the systems ``first .. first + lanes - 1``
    and is the same for every nugget: ``room.xs``, ``room.ys`` (the neighbours
    relative to each centre), ``room.reach`` (the radius) and ``room.cov`` (the
    covariances of the pairs below the diagonal, row by row)."""
    xs, ys, pairs, cov, reach = room.xs, room.ys, room.pairs, room.cov, room.reach
    for b in range(lanes):
        s = first + b
        cx = centres[s, 0]
        cy = centres[s, 1]
        r = 0.0
        for i in range(k):
            q = neighbours[s, i]
            xs[b, i] = xy[q, 0] - cx
            ys[b, i] = xy[q, 1] - cy
            r = larger(r, math.sqrt(xs[b, i] * xs[b, i] + ys[b, i] * ys[b, i]))
        reach[b] = r
        # the lags of the pairs below the diagonal, then their covariances in
        # one long loop (row by row, the short rows would not vectorise)
        m = 0
        for i in range(k):
            for j in range(i):
                pairs[0, m] = xs[b, j] - xs[b, i]
                pairs[1, m] = ys[b, j] - ys[b, i]
                m += 1
        _covariances(pairs[0], pairs[1], m, 0.0, 0.0, scale, model, cov[b])


@njit_helper
def _dual_solve(
    z: np.ndarray, neighbours: np.ndarray, first: int, lanes: int, k: int, nugget_ratio: float, room: _KrigingScratch,
) -> None:
    """Universal kriging (linear drift) over ``k`` neighbours, solved in its dual
    form, for the systems ``first .. first + lanes - 1`` (neighbours
    ``neighbours[s, :k]``; ``lanes <= _LANES``) that :func:`_dual_setup` set
    up, with the nugget ``nugget_ratio`` of the sill.

    Fills, for lane ``b`` (its neighbours ``room.xs[b]``, ``room.ys[b]``
    relative to the centre ``c``), ``room.coef[b, :k]`` (weights of the
    covariances) and ``room.coef[b, k:k+3]`` (the drift, in coordinates
    relative to ``c`` over the radius ``R``) so that the estimates at other
    points are :func:`_dual_values`, and ``room.radius[b]``: ``R``, or NaN when
    the system is singular (fewer than three points, collinear neighbours).
    The covariance matrix is factored by Cholesky; the drift comes from the
    Schur complement ``F' C^-1 F``.  Everything is relative to the centre, so
    a system depends on its centre and neighbours only.

    The systems are solved side by side, the lane innermost in every loop:
    each lane does the operations of one system alone, in the same order (its
    numbers do not depend on the other lanes), and the loops over lanes
    vectorise where a system's own loops are too short to (a third faster).
    """
    xs, ys, coef, radius, c, g, col, work = room.xs, room.ys, room.coef, room.radius, room.c, room.g, room.col, room.work
    cov, reach = room.cov, room.reach
    for b in range(lanes):
        s = first + b
        r = reach[b]
        # C = L L' in the lower triangle of c (its diagonal keeps 1 / L[j, j]),
        # the covariances with the nugget on the diagonal; the right-hand sides
        # [1, x / R, y / R, z - z0] are carried along into g = L^-1 [...]
        z0 = z[neighbours[s, 0]] if k > 0 else 0.0
        inv_r = 1.0 / r if r > 0.0 else 0.0  # a lane without a radius is singular (and Python divides by no zero)
        m = 0
        for i in range(k):
            for j in range(i):
                c[i, j, b] = cov[b, m]
                m += 1
            c[i, i, b] = 1.0 + nugget_ratio
            g[i, 0, b] = 1.0
            g[i, 1, b] = xs[b, i] * inv_r
            g[i, 2, b] = ys[b, i] * inv_r
            g[i, 3, b] = z[neighbours[s, i]] - z0
        work[11, b] = z0
    ok = work[10]
    for b in range(lanes):
        ok[b] = 1.0 if k >= 3 and reach[b] > 0.0 else 0.0
        radius[b] = reach[b]
    # each column is scaled, then updates the columns right of it: the
    # operations and their order of a dot-product Cholesky.  All the lanes at
    # once (those past ``lanes`` hold an earlier system's numbers, unread)
    inv_d = work[0]
    row = c.shape[1] * _LANES  # c[i, m, :] starts at (i * row + m * _LANES)
    rhs = 4 * _LANES  # g[i, q, :] at i * rhs + q * _LANES
    for j in range(k):
        for b in range(lanes):
            d = c[j, j, b]
            # a pivot this small: the lane is singular, and goes on with NaN (no
            # square root of a negative number when the kernels run as Python)
            ok[b] = ok[b] if d > 1e-14 else 0.0
            v = 1.0 / math.sqrt(d) if d > 1e-14 else math.nan
            inv_d[b] = v
            c[j, j, b] = v
        diagonal = j * row + j * _LANES
        lanes_scale(g, j * rhs, _LANES, inv_d, 0, 4)  # g[j, :, :] *= inv_d
        lanes_scale(c, diagonal + row, row, inv_d, 0, k - j - 1)  # the column below: l[i] = c[i, j] * inv_d
        for i in range(j + 1, k):
            # c[i, m] -= l[i] l[m] for j < m <= i, and g[i, q] -= l[i] g[j, q]
            lanes_subtract_products(c, i * row + (j + 1) * _LANES, _LANES, c, i * row + j * _LANES, c, diagonal + row, row,
                                    i - j)
            lanes_subtract_products(g, i * rhs, _LANES, c, i * row + j * _LANES, g, j * rhs, _LANES, 4)
    # the drift: (F' C^-1 F) beta = F' C^-1 (z - z0), a 3 x 3 system, with
    # F' C^-1 F = A' A and F' C^-1 (z - z0) = A' b for [A b] = g
    s00, s01, s02, s11, s12, s22 = work[1], work[2], work[3], work[4], work[5], work[6]
    r0, r1, r2 = work[7], work[8], work[9]
    for b in range(lanes):
        s00[b] = 0.0
        s01[b] = 0.0
        s02[b] = 0.0
        s11[b] = 0.0
        s12[b] = 0.0
        s22[b] = 0.0
        r0[b] = 0.0
        r1[b] = 0.0
        r2[b] = 0.0
    for i in range(k):
        for b in range(lanes):
            a0 = g[i, 0, b]
            a1 = g[i, 1, b]
            a2 = g[i, 2, b]
            bi = g[i, 3, b]
            s00[b] += a0 * a0
            s01[b] += a0 * a1
            s02[b] += a0 * a2
            s11[b] += a1 * a1
            s12[b] += a1 * a2
            s22[b] += a2 * a2
            r0[b] += a0 * bi
            r1[b] += a1 * bi
            r2[b] += a2 * bi
    for b in range(lanes):
        m00 = s11[b] * s22[b] - s12[b] * s12[b]
        m01 = s02[b] * s12[b] - s01[b] * s22[b]
        m02 = s01[b] * s12[b] - s02[b] * s11[b]
        det = s00[b] * m00 + s01[b] * m01 + s02[b] * m02
        # F' C^-1 F is positive definite unless the neighbours are collinear: its
        # determinant is then small against the product of its diagonal (Hadamard)
        ok[b] = ok[b] if det > _PIVOT_TOL * s00[b] * s11[b] * s22[b] else 0.0
        m11 = s00[b] * s22[b] - s02[b] * s02[b]
        m12 = s01[b] * s02[b] - s00[b] * s12[b]
        m22 = s00[b] * s11[b] - s01[b] * s01[b]
        if det == 0.0:  # singular (ok is 0): nothing to divide
            det = math.nan
        beta0 = (m00 * r0[b] + m01 * r1[b] + m02 * r2[b]) / det
        beta1 = (m01 * r0[b] + m11 * r1[b] + m12 * r2[b]) / det
        beta2 = (m02 * r0[b] + m12 * r1[b] + m22 * r2[b]) / det
        r0[b] = beta0
        r1[b] = beta1
        r2[b] = beta2
    # alpha = C^-1 (z - z0 - F beta) = L^-T (b - A beta): one back
    # substitution, each solved unknown subtracted from those above it
    for i in range(k):
        for b in range(lanes):
            col[i, b] = g[i, 3, b] - r0[b] * g[i, 0, b] - r1[b] * g[i, 1, b] - r2[b] * g[i, 2, b]
    for i in range(k - 1, -1, -1):
        lanes_scale(col, i * _LANES, 0, c, i * row + i * _LANES, 1)  # col[i] *= 1 / L[i, i]
        lanes_subtract_products(col, 0, _LANES, col, i * _LANES, c, i * row, _LANES, i)  # col[m] -= col[i] L[i, m], m < i
    for b in range(lanes):
        for i in range(k):
            coef[b, i] = col[i, b]
        coef[b, k] = r0[b] + work[11, b]
        coef[b, k + 1] = r1[b]
        coef[b, k + 2] = r2[b]
        good = ok[b] > 0.0
        for i in range(k + 3):
            if not math.isfinite(coef[b, i]):
                good = False
        if not good:
            radius[b] = math.nan


@njit_helper
def _dual_values(
    xs: np.ndarray, ys: np.ndarray, k: int, coef: np.ndarray, radius: float, scale: float, model: int,
    qx: np.ndarray, qy: np.ndarray, m: int, block: np.ndarray, out: np.ndarray,
) -> None:
    """``out[:m]``: the kriging estimates at the points ``(qx, qy)[:m]`` (relative to the
    centre) of a system from :func:`_dual_systems`.

    ``block`` is room for three rows of ``m * k``: the lags from every point to
    every neighbour, then their covariances, computed in one long loop (the
    rows of ``k`` alone were too short to vectorise well); each point's row
    is then summed in four interleaved partial sums, in a fixed order.
    """
    lag_x, lag_y, cov = block[0], block[1], block[2]
    for t in range(m):
        for i in range(k):
            lag_x[t * k + i] = xs[i] - qx[t]
            lag_y[t * k + i] = ys[i] - qy[t]
    _covariances(lag_x, lag_y, m * k, 0.0, 0.0, scale, model, cov)
    for t in range(m):
        row = t * k
        s0 = s1 = s2 = s3 = 0.0
        i = 0
        while i + 4 <= k:
            s0 += coef[i] * cov[row + i]
            s1 += coef[i + 1] * cov[row + i + 1]
            s2 += coef[i + 2] * cov[row + i + 2]
            s3 += coef[i + 3] * cov[row + i + 3]
            i += 4
        while i < k:
            s0 += coef[i] * cov[row + i]
            i += 1
        out[t] = coef[k] + (coef[k + 1] * qx[t] + coef[k + 2] * qy[t]) / radius + ((s0 + s1) + (s2 + s3))


@njit_helper
def _one_sided(xs: np.ndarray, ys: np.ndarray, count: int) -> bool:
    """Whether the points ``(xs, ys)[:count]`` leave three neighbouring eighths of
    the plane around the origin empty: a gap of at least 135 degrees, as at the
    hull or beside a void, where kriging extrapolates."""
    mask = 0
    for i in range(count):
        x = xs[i]
        y = ys[i]
        if y >= 0.0:
            sector = (0 if y < x else 1) if x >= 0.0 else (2 if y > -x else 3)
        else:
            sector = (4 if y > x else 5) if x < 0.0 else (6 if -y > x else 7)
        mask |= 1 << sector
    run = 0
    for j in range(16):  # twice round, for a gap across sector 0
        if mask & (1 << (j % 8)):
            run = 0
        else:
            run += 1
            if run >= 3:
                return True
    return False


@njit_helper
def _count(neighbours: np.ndarray) -> int:
    """The neighbours present in a padded row (``-1`` pads the end)."""
    if neighbours.shape[0] == 0 or neighbours[neighbours.shape[0] - 1] >= 0:
        return neighbours.shape[0]
    k = 0
    while k < neighbours.shape[0] and neighbours[k] >= 0:
        k += 1
    return k


@njit_helper
def _lanes(neighbours: np.ndarray, first: int) -> tuple[int, int]:
    """How many systems from ``first`` on (at most :data:`_LANES`) have as many neighbours as it, and that count."""
    k = neighbours.shape[1]
    count = _count(neighbours[first])
    end = smaller(first + _LANES, neighbours.shape[0])
    lanes = 1
    if count == k:  # full rows: their last column is set
        while first + lanes < end and neighbours[first + lanes, k - 1] >= 0:
            lanes += 1
    else:
        while first + lanes < end and _count(neighbours[first + lanes]) == count:
            lanes += 1
    return lanes, count


@njit
def _solve_systems(
    xy: np.ndarray, z: np.ndarray, centres: np.ndarray, neighbours: np.ndarray, first: int,
    nugget_ratio: float, scale: float, model: int, room: _KrigingScratch,
) -> tuple[int, int]:
    """:func:`_dual_systems` for the systems from ``first`` on that have as many
    neighbours as it (at most :data:`_LANES`); returns how many, and that count."""
    lanes, count = _lanes(neighbours, first)
    if lanes == _LANES:  # a constant number of lanes: loops the compiler unrolls and vectorises better
        _dual_systems(xy, z, centres, neighbours, first, _LANES, count, nugget_ratio, scale, model, room)
    else:
        _dual_systems(xy, z, centres, neighbours, first, lanes, count, nugget_ratio, scale, model, room)
    return lanes, count


@njit
def _nodes_kriged_kernel(
    xy: np.ndarray, z: np.ndarray, centres: np.ndarray, neighbours: np.ndarray, first: np.ndarray,
    positions: np.ndarray, corners: np.ndarray, pattern: np.ndarray, pattern_weights: np.ndarray,
    nugget_ratio: float, inv_range: float, model: int, clamp_inside: bool, gap: np.ndarray, fill: np.ndarray,
    near: float, far: float, out: np.ndarray,
) -> None:
    """Krig the nodes of every system (a cell), clamp them, and blend those in voids into the fill.

    System ``s`` (centre ``centres[s]``, its neighbours) gives the nodes
    ``first[s] .. first[s + 1] - 1``.  A node is clamped to the
    range of its neighbours' values widened to its ``corners``' values (in a
    void: to the linear surface's value there, its corners' values by the
    weights of its ``pattern``): every node when ``clamp_inside``, else only
    those of systems whose neighbours lie to one side of the centre
    (:func:`_one_sided`), and those in voids; a
    singular system, or one that meets an unknown z, gives its nodes the
    linear surface's value (the corners' weights, row ``pattern[n]`` of
    ``pattern_weights``).  A node farther than ``near`` from its nearest
    neighbour (``gap[n]``) is clamped to the range of its natural neighbours
    (``fill[n, 1:]``) and blended into the void's fill ``fill[n, 0]`` (NaN:
    none, the linear surface's value then), which alone it is from ``far`` on
    (:func:`_void_blend`).
    """
    k = neighbours.shape[1]
    room = _kriging_scratch(k)
    most = 0
    for s in range(centres.shape[0]):
        most = larger(most, first[s + 1] - first[s])
    qx = empty(most)
    qy = empty(most)
    values = empty(most)
    block = empty((3, most * k))
    scale = _LAG_SCALE[model] * inv_range
    s0 = 0
    while s0 < centres.shape[0]:
        lanes, count = _solve_systems(xy, z, centres, neighbours, s0, nugget_ratio, scale, model, room)
        for b in range(lanes):
            s = s0 + b
            lo = math.inf
            hi = -math.inf
            finite = True
            for i in range(count):
                zi = z[neighbours[s, i]]
                if not math.isfinite(zi):
                    finite = False
                lo = smaller(lo, zi)
                hi = larger(hi, zi)
            radius = room.radius[b] if finite else math.nan
            kriged = math.isfinite(radius)
            clamp = kriged and (clamp_inside or _one_sided(room.xs[b], room.ys[b], count))
            if kriged:
                m = first[s + 1] - first[s]
                for t in range(m):
                    qx[t] = positions[first[s] + t, 0] - centres[s, 0]
                    qy[t] = positions[first[s] + t, 1] - centres[s, 1]
                _dual_values(room.xs[b], room.ys[b], count, room.coef[b], radius, scale, model, qx, qy, m, block, values)
            for n in range(first[s], first[s + 1]):
                linear = _linear_value(z, corners, pattern_weights, pattern[n], n)
                if kriged:
                    value = values[n - first[s]]
                    if gap[n] > near:
                        # in a void always clamped (no crest is known there to keep): to the
                        # neighbours' range and the linear surface's value (a linear function
                        # lies there), not to the far ends of a long edge across the void, then
                        # to the range of its natural neighbours, within which its fill lies
                        low = smaller(lo, linear)
                        high = larger(hi, linear)
                        out[n] = smaller(larger(value, low), high)
                        if math.isfinite(fill[n, 1]):
                            out[n] = smaller(larger(out[n], fill[n, 1]), fill[n, 2])
                    else:
                        # beside its points: the neighbours' range widened to its edge's (face's)
                        # corners, which a crest between them may rise to
                        low = lo
                        high = hi
                        for j in range(4):
                            v = corners[n, j]
                            if v >= 0 and math.isfinite(z[v]):
                                low = smaller(low, z[v])
                                high = larger(high, z[v])
                        out[n] = smaller(larger(value, low), high) if clamp else value
                else:
                    out[n] = linear
                if gap[n] > near:
                    out[n] = _void_blend(out[n], linear, fill[n, 0], gap[n], near, far)
        s0 += lanes


@njit_helper
def _linear_value(z: np.ndarray, corners: np.ndarray, pattern_weights: np.ndarray, row: int, n: int) -> float:
    """The linear surface at node ``n``: its corners' values by the weights of ``pattern_weights[row]``."""
    linear = 0.0
    for j in range(4):
        v = corners[n, j]
        if v >= 0 and math.isfinite(z[v]):
            linear += pattern_weights[row, j] * z[v]
    return linear


@njit_helper
def _void_blend(value: float, linear: float, fill: float, gap: float, near: float, far: float) -> float:
    """A node's value ``gap`` from its nearest point: its kriged ``value`` up to ``near``,
    the void's ``fill`` (:meth:`VoidFill.values`; NaN where a node has none: the
    linear surface then) from ``far`` on, in between a blend linear in the
    distance.  Kriging, the fill and the linear surface reproduce linear
    functions, and the fill stays within the values of the points around the
    void: so does the blend, and it goes from one to the other smoothly."""
    base = fill if math.isfinite(fill) else linear
    if gap >= far:
        return base
    w = (far - gap) / (far - near)
    return base + w * (value - base)


class Neighbourhoods(NamedTuple):
    """Where the smooth surface's nodes are and which points each is kriged from.

    The nodes are grouped in square cells of side ``cell``, aligned on
    multiples of it: one kriging system per cell that holds a node, over the
    ``neighbours`` vertices nearest the cell's centre.  Computed by
    :func:`smooth_neighbourhoods` and taken by :func:`smooth_nodes`.

    Attributes
    ----------
    centres : (m, 2) the cells' centres
    index : (m, k) their nearest vertices, nearest first (``-1`` pads)
    radius : (m,) the distance from each centre to its last neighbour
    first : (m + 1,) cell ``s`` holds the nodes ``first[s] .. first[s+1]-1``
    positions : (n, 2) the nodes
    take : (n_f, 12) int32, the node in each slot of a face's row (``-1``: unused, or a face left out)
    corners : (n, 4) int32, the vertices whose values bound each node's clamp (``-1`` pads)
    pattern : (n,) uint8, where the node lies in its face: the row of
        :data:`_PATTERN_WEIGHTS` that gives the linear surface's weights of its corners
    cell : float, the side of the cells
    gap : (n,) float64, the distance from each node to the nearest of its cell's neighbours
        (exact beyond :data:`VOID_NEAR` spacings; nearer, any distance up to it)
    fill : VoidFill, the nodes in voids (``gap`` over :data:`VOID_NEAR` spacings) and their natural neighbours
    """

    centres: NDArray[np.float64]
    index: NDArray[np.int64]
    radius: NDArray[np.float64]
    first: NDArray[np.int64]
    positions: NDArray[np.float64]
    take: NDArray[np.int64]
    corners: NDArray[np.int32]
    pattern: NDArray[np.uint8]
    cell: float
    gap: NDArray[np.float64]
    fill: "VoidFill"

    @property
    def weights(self) -> NDArray[np.float64]:
        """``(n, 4)``: the linear surface's weights of each node's corners."""
        return _PATTERN_WEIGHTS[self.pattern]

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(m, 3)`` rows ``(x, y, r)``: the closed disks the node values read points from
        (the cells' neighbourhoods, then the circles of the voids' natural neighbours)."""
        return np.concatenate([np.column_stack([self.centres, self.radius]), self.fill.coordinates.disks])


class VoidFill(NamedTuple):
    """The nodes (or added points) of a smooth surface in voids, and their
    natural-neighbour coordinates (:func:`meshcore.natural.natural_coordinates`).

    Attributes
    ----------
    rows : (q,) int64, the nodes, ascending
    coordinates : NaturalCoordinates, one row for each
    """

    rows: NDArray[np.int64]
    coordinates: NaturalCoordinates

    def values(self, z: NDArray[np.float64], n: int) -> NDArray[np.float64]:
        """``(n, 3)``: for each of ``n`` nodes the void's fill of the points' values ``z``
        (:data:`VOID_NATURAL_SHARE` of the natural-neighbour interpolant, the rest the
        Delaunay TIN's) and the lowest and highest value of its natural neighbours;
        NaN at the nodes not in voids (and where a node has no natural neighbours)."""
        out = np.full((n, 3), np.nan)
        out[self.rows, 0] = (VOID_NATURAL_SHARE * natural_values(self.coordinates, z)
                             + (1.0 - VOID_NATURAL_SHARE) * tin_values(self.coordinates, z))
        out[self.rows, 1], out[self.rows, 2] = natural_ranges(self.coordinates, z)
        return out


_NO_ENDS = np.zeros((0, 2), dtype=np.int64)

_NO_FILL = VoidFill(np.zeros(0, dtype=np.int64), NaturalCoordinates(
    np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.empty((0, 3)),
    np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3))))


_THIRD = 1.0 / 3.0
_QUAD_INNER = ((_THIRD, _THIRD), (2 * _THIRD, _THIRD), (2 * _THIRD, 2 * _THIRD), (_THIRD, 2 * _THIRD))
_PATTERN_WEIGHTS = np.array(
    [[1.0 - _THIRD, _THIRD, 0.0, 0.0], [1.0 - 2.0 * _THIRD, 2.0 * _THIRD, 0.0, 0.0], [_THIRD, _THIRD, _THIRD, 0.0]]
    + [[(1.0 - u) * (1.0 - v), u * (1.0 - v), u * v, (1.0 - u) * v] for u, v in _QUAD_INNER]
)
"""The linear surface's weights of a node's corners, by the node's place: an
edge's node at a third and at two thirds, a triangle's centroid, a
quadrangle's four inner nodes."""


@njit
def _layout_kernel(vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray):
    """:func:`_layout`: every edge found once by bucketing its slots by their first end."""
    n_f = faces.shape[0]
    n_v = vertices.shape[0]
    start = zeros(n_v + 1, dtype=np.int64)
    n_tri = 0
    for f in range(n_f):
        nc = 4 if faces[f, 3] >= 0 else 3
        if nc == 3:
            n_tri += 1
        for k in range(nc):
            s = faces[f, k]
            e = faces[f, (k + 1) % nc]
            start[(s if _first_end(vertices, s, e) else e) + 1] += 1
    for v in range(n_v):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    other = empty(start[n_v], dtype=np.int64)
    slot = empty(start[n_v], dtype=np.int64)
    for f in range(n_f):
        nc = 4 if faces[f, 3] >= 0 else 3
        for k in range(nc):
            s = faces[f, k]
            e = faces[f, (k + 1) % nc]
            forward = _first_end(vertices, s, e)
            a = s if forward else e
            other[fill[a]] = e if forward else s
            slot[fill[a]] = f * 4 + k
            fill[a] += 1
    edge = full(start[n_v], -1, dtype=np.int64)
    n_e = 0
    for v in range(n_v):
        for i in range(start[v], start[v + 1]):
            if edge[i] < 0:
                edge[i] = n_e
                for j in range(i + 1, start[v + 1]):
                    if other[j] == other[i]:
                        edge[j] = n_e
                n_e += 1
    n_quad = n_f - n_tri
    n_nodes = 2 * n_e + n_tri + 4 * n_quad
    positions = empty((n_nodes, 2))
    corners = empty((n_nodes, 4), dtype=np.int32)
    pattern = empty(n_nodes, dtype=np.uint8)
    take = empty((n_f, 12), dtype=np.int32)  # every slot written: a node, or -1 past a triangle's
    third = 1.0 / 3.0
    placed = 0  # the edges numbered below this have their nodes (edges are numbered in slot order)
    for v in range(n_v):
        for i in range(start[v], start[v + 1]):
            f = slot[i] // 4
            k = slot[i] % 4
            b = other[i]
            node = 2 * edge[i]
            forward = faces[f, k] == v
            take[f, 2 * k] = node if forward else node + 1
            take[f, 2 * k + 1] = node + 1 if forward else node
            if edge[i] < placed:
                continue  # the edge's other face placed its nodes
            placed = edge[i] + 1
            for j in range(2):
                t = third if j == 0 else 2.0 * third
                positions[node + j, 0] = vertices[v, 0] + t * (vertices[b, 0] - vertices[v, 0])
                positions[node + j, 1] = vertices[v, 1] + t * (vertices[b, 1] - vertices[v, 1])
                corners[node + j, 0] = v
                corners[node + j, 1] = b
                corners[node + j, 2] = -1
                corners[node + j, 3] = -1
                pattern[node + j] = j
    tri = 2 * n_e
    quad = 2 * n_e + n_tri
    for f in range(n_f):
        if faces[f, 3] < 0:
            positions[tri, 0] = (vertices[faces[f, 0], 0] + vertices[faces[f, 1], 0] + vertices[faces[f, 2], 0]) * third
            positions[tri, 1] = (vertices[faces[f, 0], 1] + vertices[faces[f, 1], 1] + vertices[faces[f, 2], 1]) * third
            for j in range(3):
                corners[tri, j] = faces[f, j]
            corners[tri, 3] = -1
            pattern[tri] = 2
            take[f, 8] = tri
            for j in (6, 7, 9, 10, 11):
                take[f, j] = -1
            tri += 1
        else:
            for m in range(4):
                x = 0.0
                y = 0.0
                for j in range(4):
                    x += weights[3 + m, j] * vertices[faces[f, j], 0]
                    y += weights[3 + m, j] * vertices[faces[f, j], 1]
                    corners[quad, j] = faces[f, j]
                positions[quad, 0] = x
                positions[quad, 1] = y
                pattern[quad] = 3 + m
                take[f, 8 + m] = quad
                quad += 1
    return positions, take, corners, pattern


def _layout(vertices: NDArray[np.float64], faces: NDArray[np.int64]):
    """The nodes of :class:`Neighbourhoods`: ``positions, take, corners, pattern``.

    An edge is listed once, its nodes placed from its end first in
    coordinate order, so that every face (in any tile) computes them from the
    same numbers.
    """
    return _layout_kernel(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64),
                          _PATTERN_WEIGHTS)


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


@njit
def _gather_nodes(order: np.ndarray, positions: np.ndarray, corners: np.ndarray, pattern: np.ndarray, take: np.ndarray):
    """The nodes in ``order`` (their positions, corners and patterns), and ``take`` renumbered to it in place."""
    n = order.shape[0]
    renumber = empty(n, dtype=np.int32)
    out_positions = empty((n, 2))
    out_corners = empty((n, 4), dtype=np.int32)
    out_pattern = empty(n, dtype=np.uint8)
    for t in range(n):
        p = order[t]
        renumber[p] = t
        out_positions[t, 0] = positions[p, 0]
        out_positions[t, 1] = positions[p, 1]
        for j in range(4):
            out_corners[t, j] = corners[p, j]
        out_pattern[t] = pattern[p]
    for f in range(take.shape[0]):
        for j in range(take.shape[1]):
            if take[f, j] >= 0:
                take[f, j] = renumber[take[f, j]]
    return out_positions, out_corners, out_pattern


_SMOOTH_GROUND_NUGGET = 1e-3
"""A Matérn variogram whose nugget is below this share of its sill describes
smooth, nearly noise-free ground (:func:`_clamps_inside`)."""


def _clamps_inside(variogram: Variogram) -> bool:
    """Whether :func:`smooth_nodes` clamps every node, or only those kriged from one side.

    Kriging a smooth surface rises above all its neighbours at a crest, and
    the clamp would cut it off; on rough or noisy ground a value outside the
    neighbours' range is ringing or noise more often than relief.  So every
    node is clamped unless the variogram is a Matérn model (a differentiable
    surface) with a nugget under :data:`_SMOOTH_GROUND_NUGGET` of its sill;
    nodes kriged from one side (the hull, voids) are always clamped.
    Measured (``bench/bench_accuracy.py``, RMSE change against the TIN): on
    lidR's smooth test (its first 10 sets) clamping only the one-sided nodes
    gives -94.9% against -90.6%; on the real surveys, whose variograms keep every node clamped,
    clamping only those would lose up to 0.6 points (ign_semis -7.0% ->
    -6.4%).
    """
    return variogram.model == "exponential" or not variogram.nugget < _SMOOTH_GROUND_NUGGET * variogram.sill


def _check_variogram(variogram: object) -> Variogram:
    if not isinstance(variogram, Variogram):
        raise InvalidInputError(f"variogram must be a Variogram, got {type(variogram).__name__}")
    return variogram


def _check_neighbours(neighbours: object) -> int:
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)) or not 4 <= neighbours <= 64:
        raise InvalidInputError(f"neighbours must be an integer from 4 to 64, got {neighbours!r}")
    return int(neighbours)


CELL_PER_SPACING = 1.4
"""The side of the smooth surface's cells, in point spacings (:attr:`Variogram.spacing`).

Measured (``bench/bench_accuracy.py``): smaller cells centre each system
better on its nodes but cost one system per cell.  At 1.4 spacings (a system
per two points) the errors are those of 0.7 or 1.0 spacings, or of a system
per edge and face (five per point), within the noise of the test; at 2
spacings they grow."""


VOID_NEAR = 2.0
"""A node (or added point) farther than this many point spacings from the nearest
of its cell's points lies in a void: from here to :data:`VOID_FAR` its kriged
value is blended into the void's fill (:func:`_void_blend`)."""

VOID_FAR = 3.5
"""From this many spacings on a node is the void's fill alone.

Why (``bench/bench_accuracy.py``, block cross-validation): in a void every
cell's 16 nearest points lie on one side of the rim, and the kriged value
carries that side's tilt (its linear drift) and noise across; up to 1-2
spacings from the rim it still beats the TIN, farther it loses to it.
Measured: blends from 1-3 to 2-4 spacings all kept the surface below the
TIN's errors in voids of 5 to 40 units on every sample; the nearer ones
keep less of kriging's gains on smooth, sparse ground (autzen_trim) and more
on flat, dense, noisy ground (extra_byte_blocks, where kriging beside a void
is worse than the TIN); point-CV errors moved by 0.1 point at most.  From 2
spacings, fewer nodes need natural neighbours (a third of ign_semis's against
one in two from 1.5), and none blends into the linear surface of the faces cut
across a void, whose small triangles showed as a waffle in a hillshade."""

VOID_NATURAL_SHARE = 0.5
"""The void's fill: this share of the natural-neighbour (Sibson) interpolant of the
points around it, the rest of their Delaunay TIN (:meth:`VoidFill.values`).

Measured as :data:`VOID_FAR`: the natural-neighbour interpolant alone was
2-25% better than the TIN inside most voids, but worse in a void across
startinpy_small's noisy ground (+2 to +4%); a triangulation of the rim (the
TIN's, the combined mesh's) is as arbitrary as another, and was up to 17%
worse than the TIN in some voids (the combined mesh's, 4_6_crop at 10 ft).
The mean of the natural-neighbour interpolant and a triangulation's was the
steadiest: better than the TIN in every void tested, where either alone was
not.  The TIN's, not the combined mesh's, as its value at a node needs no
more than the natural neighbours do (the triangle holding the node is one of
the cavity's), and the combined mesh's, on the faces cut across a void,
showed their small triangles in a hillshade."""

VOID_REACH = 3.0
"""A node's natural neighbours are read as one disk around it while their circles
reach no farther than this many times the distance to its edge's (its face's,
its cut face's parent's) farthest corner; beyond (beside the hull, where the
circles run far out of it) circle by circle, which a piece of a survey holds
where they meet the hull.  It changes no value, only how the disks are told."""


@njit
def _nearest_points_kernel(vertices: np.ndarray, neighbours: np.ndarray, owner: np.ndarray, positions: np.ndarray,
                           rows: np.ndarray, out: np.ndarray) -> None:
    for t in range(rows.shape[0]):
        n = rows[t]
        s = owner[n]
        best = math.inf
        out[t] = -1
        for i in range(neighbours.shape[1]):
            v = neighbours[s, i]
            if v < 0:
                break
            dx = vertices[v, 0] - positions[n, 0]
            dy = vertices[v, 1] - positions[n, 1]
            if dx * dx + dy * dy < best:
                best = dx * dx + dy * dy
                out[t] = v


def _nearest_points(vertices: NDArray[np.float64], positions: NDArray[np.float64], neighbours: NDArray[np.int64],
                    first: NDArray[np.int64], rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """The nearest of its system's neighbours of each node ``rows`` (-1: none)."""
    owner = np.full(positions.shape[0], -1, dtype=np.int64)
    owner[rows] = np.searchsorted(first, rows, side="right") - 1
    out = np.empty(rows.size, dtype=np.int64)
    _nearest_points_kernel(vertices, neighbours, owner, np.ascontiguousarray(positions), rows, out)
    return out


@njit
def _gaps_kernel(vertices: np.ndarray, neighbours: np.ndarray, first: np.ndarray, positions: np.ndarray, near: float,
                 out: np.ndarray) -> None:
    """``out[n]``: the distance from node ``n`` to the nearest of its system's neighbours
    (system ``s`` holds the nodes ``first[s] .. first[s + 1] - 1``; infinite without
    one), or, once one is found within ``near``, that one's."""
    near2 = near * near
    for s in range(neighbours.shape[0]):
        for n in range(first[s], first[s + 1]):
            px = positions[n, 0]
            py = positions[n, 1]
            best = math.inf
            for i in range(neighbours.shape[1]):
                v = neighbours[s, i]
                if v < 0:
                    break
                dx = vertices[v, 0] - px
                dy = vertices[v, 1] - py
                best = smaller(best, dx * dx + dy * dy)
                if best <= near2:
                    break
            out[n] = math.sqrt(best)


def _gaps(vertices: NDArray[np.float64], neighbours: NDArray[np.int64], first: NDArray[np.int64],
          positions: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """How far each node lies from its system's points: :func:`_gaps_kernel` (the nodes in system
    order), exact beyond :data:`VOID_NEAR` (for cells of side ``cell``)."""
    out = np.empty(positions.shape[0])
    _gaps_kernel(vertices, neighbours, first, positions, _void_distances(cell)[0], out)
    return out


def _void_distances(cell: float) -> tuple[float, float]:
    """:data:`VOID_NEAR` and :data:`VOID_FAR` for nodes in cells of side ``cell``
    (from the cell, which every plan of a survey shares bit for bit)."""
    return cell * (VOID_NEAR / CELL_PER_SPACING), cell * (VOID_FAR / CELL_PER_SPACING)


@njit
def _spans_kernel(positions: np.ndarray, vertices: np.ndarray, corners: np.ndarray, data: int, ends: np.ndarray,
                  out: np.ndarray) -> None:
    for n in range(positions.shape[0]):
        best = 0.0
        for j in range(corners.shape[1]):
            c = corners[n, j]
            if c < 0:
                continue
            for e in range(2):
                v = c if c < data else ends[c - data, e]
                dx = vertices[v, 0] - positions[n, 0]
                dy = vertices[v, 1] - positions[n, 1]
                best = larger(best, dx * dx + dy * dy)
        out[n] = math.sqrt(best)


def _spans(positions: NDArray[np.float64], vertices: NDArray[np.float64], corners: NDArray[np.integer], data: int,
           ends: NDArray[np.int64]) -> NDArray[np.float64]:
    """The distance from each node to the farthest point of its ``corners`` (``-1``
    pads): a corner among the first ``data`` vertices, or else both ends of the
    edge it was added on (``ends[corner - data]``), so that a node of a face cut
    reaches as far as the face's own corners."""
    out = np.empty(positions.shape[0])
    _spans_kernel(np.ascontiguousarray(positions), vertices, np.ascontiguousarray(corners, dtype=np.int64), data,
                  np.ascontiguousarray(ends, dtype=np.int64), out)
    return out


def _void_fills(vertices: NDArray[np.float64], data: int, ends: NDArray[np.int64], cell: float,
                *groups: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64],
                               NDArray[np.integer]], rows: list[NDArray[np.int64]] | None = None) -> list[VoidFill]:
    """For each group ``(positions, gap, index, first, corners)`` of nodes (``index``
    and ``first``: their systems; ``corners``: their edges' or faces' corners, as
    :func:`_spans` takes them): those in voids (or ``rows``) and their natural
    neighbours among the first ``data`` of ``vertices``, each read within
    :data:`VOID_REACH` times the distance to its farthest corner; one
    triangulation for all."""
    near, _ = _void_distances(cell)
    if rows is None:
        rows = [np.flatnonzero(gap > near) for _, gap, *_ in groups]
    if not any(r.size for r in rows):
        return [VoidFill(r, _NO_FILL.coordinates._replace(first=np.zeros(r.size + 1, dtype=np.int64))) for r in rows]
    points = np.ascontiguousarray(vertices[:data])
    places = np.concatenate([positions[r] for (positions, *_), r in zip(groups, rows)])
    reach = np.concatenate([4.0 * gap[r] for (_, gap, *_), r in zip(groups, rows)])
    cap = np.concatenate([VOID_REACH * _spans(positions[r], vertices, corners[r], data, ends)
                          for (positions, _, _, _, corners), r in zip(groups, rows)])
    # each from its nearest point, where the search for its natural neighbours starts
    start = np.concatenate([_nearest_points(points, positions, index, first, r)
                            for (positions, _, index, first, _), r in zip(groups, rows)])
    found = natural_coordinates(points, places, reach, cap, start)
    out = []
    lo = 0
    for r in rows:
        out.append(VoidFill(r, take_places(found, np.arange(lo, lo + r.size))))
        lo += r.size
    return out


def _face_mask(faces: ArrayLike, n_f: int) -> NDArray[np.bool_]:
    mask = np.asarray(faces)
    if mask.dtype != np.bool_ or mask.shape != (n_f,):
        raise InvalidInputError(f"faces must be a boolean mask of the mesh's {n_f} faces, got {mask.dtype} {mask.shape}")
    return mask


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


def smooth_neighbourhoods(mesh: Mesh, neighbours: int = DEFAULT_NEIGHBOURS, spacing: float | None = None,
                          data_vertices: int | None = None, faces: ArrayLike | None = None) -> Neighbourhoods:
    """The smooth surface's kriging systems and nodes for ``mesh`` (see :class:`Neighbourhoods`).

    ``spacing`` is the survey's point spacing (:attr:`Variogram.spacing`);
    the cells are ``CELL_PER_SPACING`` of it.  Without it the mesh's
    vertices give it.  The node values of :func:`smooth_nodes` depend on the
    mesh's vertices inside the (closed) disks ``.disks`` only: a piece of a
    larger point set gets the values of the whole set once every point of the
    set inside each disk is among its vertices, and both use one spacing.
    ``data_vertices``: only the first this many vertices are kriged from (the
    others are points a refined mesh added, :mod:`meshcore.refine`).
    ``faces``: a mask of the faces that get nodes (default: all); the others'
    rows of ``take`` are -1, and no system serves them alone.  The nodes in
    voids get their natural neighbours too (``.fill``), whose circles are
    among the disks.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> mesh = meshcore.build_mesh(np.random.default_rng(1).random((50, 2)))
    >>> hoods = smooth_neighbourhoods(mesh, spacing=0.15)
    >>> bool(np.all(hoods.disks[:, 2] > 0)), hoods.cell == 0.15 * CELL_PER_SPACING
    (True, True)
    """
    return _neighbourhoods(mesh, neighbours, spacing, data_vertices, faces, True)


def _neighbourhoods(mesh: Mesh, neighbours: int, spacing: float | None, data_vertices: int | None,
                    faces: ArrayLike | None, fills: bool) -> Neighbourhoods:
    """:func:`smooth_neighbourhoods`, the voids' natural neighbours left out unless ``fills``."""
    k = _check_neighbours(neighbours)
    vertices, mesh_faces = mesh_arrays(mesh)
    if spacing is None:
        spacing = _mesh_spacing(vertices, k)
    elif isinstance(spacing, bool) or not isinstance(spacing, (int, float)) or not (math.isfinite(spacing) and spacing > 0.0):
        raise InvalidInputError(f"spacing must be a finite number > 0, got {spacing!r}")
    cell = float(spacing) * CELL_PER_SPACING
    if faces is None:
        positions, take, corners, pattern = _layout(vertices, mesh_faces)
    else:
        wanted = _face_mask(faces, mesh_faces.shape[0])
        # a node lies on its edge or face alone: the faces wanted give theirs as all the faces do
        positions, some, corners, pattern = _layout(vertices, mesh_faces[wanted])
        take = np.full((mesh_faces.shape[0], NODES_PER_FACE), -1, dtype=np.int32)
        take[wanted] = some
    order, first, centres = _cells(positions, cell)
    positions, corners, pattern = _gather_nodes(order, positions, corners, pattern, take)
    data = vertices if data_vertices is None else np.ascontiguousarray(vertices[:data_vertices])
    index, d2 = _nearest(data, centres, k)
    gap = _gaps(data, index, first, positions, cell)
    if fills:
        (fill,) = _void_fills(vertices, data.shape[0], _NO_ENDS, cell, (positions, gap, index, first, corners))
    else:
        fill = _NO_FILL
    return Neighbourhoods(np.ascontiguousarray(centres), index, _radii(d2), first, positions, take, corners, pattern, cell,
                          gap, fill)


def smooth_nodes(
    mesh: Mesh,
    z: ArrayLike,
    variogram: Variogram | None = None,
    neighbours: int = DEFAULT_NEIGHBOURS,
    neighbourhoods: Neighbourhoods | None = None,
) -> NDArray[np.float64]:
    """The node values of the smooth surface's patches, one row of twelve per face.

    The nodes are grouped in cells of :data:`CELL_PER_SPACING` point spacings; each cell's
    nodes are kriged (universal kriging, linear drift) from the
    ``neighbours`` vertices nearest the cell's centre.  A node is then
    clamped to the range of its neighbours' values and of its edge's (an
    inner node: its face's) corners: a linear function is within that range,
    so the clamp keeps it exact while stopping overshoot where the neighbours
    lie to one side (the hull, voids).  With a variogram of smooth, nearly
    noise-free ground only the nodes kriged from one side are clamped.

    Parameters
    ----------
    mesh : Mesh
        A conforming mesh; its vertices are the points kriged (every vertex,
        also those no face uses).
    z : (n_v,) array
        The value at every vertex.
    variogram : Variogram, optional
        The covariance model and the point spacing; fitted from the mesh's
        vertices by :func:`fit_variogram` when omitted.
    neighbours : int
        Points per kriging neighbourhood, 4 to 64.
    neighbourhoods : Neighbourhoods, optional
        From :func:`smooth_neighbourhoods` for this mesh and the variogram's
        spacing (computed when omitted).

    Returns
    -------
    (n_f, 12) float64
        Node values in the layout of :mod:`meshcore.patches`; unused columns NaN.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> xy = np.random.default_rng(2).random((60, 2))
    >>> mesh = meshcore.build_mesh(xy, "s3", "s4")
    >>> z = 2.0 * mesh.vertices[:, 0] - mesh.vertices[:, 1]
    >>> nodes = smooth_nodes(mesh, z, Variogram(0.0, 1.0, 0.5))
    >>> nodes.shape == (mesh.faces.shape[0], 12)
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    variogram = fit_variogram(vertices, zv, neighbours=k) if variogram is None else _check_variogram(variogram)
    out = np.empty((faces.shape[0], NODES_PER_FACE))  # every entry written: a node or NaN
    if faces.shape[0] == 0:
        return out
    hoods = smooth_neighbourhoods(mesh, k, variogram.spacing) if neighbourhoods is None else neighbourhoods
    if hoods.take.shape != out.shape:
        raise InvalidInputError("neighbourhoods were computed for another mesh")
    if variogram.spacing is not None and hoods.cell != variogram.spacing * CELL_PER_SPACING:
        raise InvalidInputError(f"neighbourhoods were computed for cells of {hoods.cell!r}, the variogram's spacing gives "
                                f"{variogram.spacing * CELL_PER_SPACING!r}")
    values = np.empty(hoods.positions.shape[0])
    rows = hoods.pattern.astype(np.int32)  # as the added points give theirs: one kernel for both, compiled and loaded once
    near, far = _void_distances(hoods.cell)
    _nodes_kriged_kernel(
        vertices, zv, hoods.centres, hoods.index, hoods.first, hoods.positions, hoods.corners, rows, _PATTERN_WEIGHTS,
        variogram.nugget / variogram.sill, 1.0 / variogram.range, MODELS.index(variogram.model),
        _clamps_inside(variogram), hoods.gap, hoods.fill.values(zv, values.size), near, far, values,
    )
    _scatter_nodes(values, hoods.take, out)
    return out


LONG_EDGE = 12.0
"""Edges longer than this many point spacings are split for the smooth surface (:func:`smooth_plan`)..."""

LONG_EDGE_PIECE = 3.0
"""... into equal pieces of at most this many spacings."""

SMOOTH_GROUND_LONG_EDGE = 4.0
"""On smooth, nearly noise-free ground (:func:`_clamps_inside` false): edges longer than this many spacings are split..."""

SMOOTH_GROUND_PIECE = 2.0
"""... into equal pieces of at most this many spacings."""


def _long_edges(variogram: Variogram) -> tuple[float, float]:
    """``(longer_than, piece)`` in point spacings: which edges the smooth surface splits, and into what.

    A cubic patch spans its face: on a face many spacings long (the slivers
    along the hull, faces across a void) it cannot follow the ground between
    its nodes, however well they are kriged.  Measured
    (``bench/bench_accuracy.py``, RMSE change against the TIN): on lidR's
    smooth test the smooth surface goes from -91.7% to -97.0% with edges over
    4 spacings split (-95.9% at 12); the real surveys gain 0.05-0.4 points at
    12 spacings, but autzen_trim loses 1.9 points at 4 (faces of 5 spacings
    across its sparse patches, where kriging is worse than the patches).  So
    4 spacings on smooth ground, 12 elsewhere.
    """
    if _clamps_inside(variogram):
        return LONG_EDGE, LONG_EDGE_PIECE
    return SMOOTH_GROUND_LONG_EDGE, SMOOTH_GROUND_PIECE


class AddedPoints(NamedTuple):
    """The kriging systems of the points a :class:`Refinement` adds on long edges.

    The points are grouped in the cells of the nodes (``cell``, on the same
    multiples), one system per cell over the ``neighbours`` input vertices
    nearest its centre: a point's value depends only on the input vertices
    inside its cell's disk, whichever piece of a survey computes it.

    Attributes
    ----------
    order : (m,) the added points cell by cell
    first : (c + 1,) cell ``s`` holds the points ``order[first[s] .. first[s+1]-1]``
    centres : (c, 2) the cells' centres
    index : (c, k) their nearest input vertices, nearest first (``-1`` pads)
    radius : (c,) the distance from each centre to its last neighbour
    gap : (m,) the distance from each point (in the order of ``order``) to the nearest of its
        cell's neighbours, as :attr:`Neighbourhoods.gap`
    fill : VoidFill, the points in voids (rows in the order of ``order``) and their natural neighbours
    """

    order: NDArray[np.int64]
    first: NDArray[np.int64]
    centres: NDArray[np.float64]
    index: NDArray[np.int64]
    radius: NDArray[np.float64]
    gap: NDArray[np.float64]
    fill: VoidFill

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(c, 3)`` rows ``(x, y, r)``: the closed disks the added points' values read points from
        (the cells' neighbourhoods, then the circles of the voids' natural neighbours)."""
        return np.concatenate([np.column_stack([self.centres, self.radius]), self.fill.coordinates.disks])


class SmoothPlan(NamedTuple):
    """Everything the smooth surface of a mesh reads, known before any value.

    Computed by :func:`smooth_plan`, taken by :func:`smooth_surface`.

    Attributes
    ----------
    refinement : Refinement
        The mesh with its long edges split and their faces cut into triangles
        (:func:`meshcore.refine.refine_long_faces`); the input mesh itself when no edge is long.
    nodes : Neighbourhoods
        The refined mesh's nodes and their systems, over the input vertices only.
    added : AddedPoints
        The systems of the points the refinement added.
    """

    refinement: Refinement
    nodes: Neighbourhoods
    added: AddedPoints

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(m, 3)`` rows ``(x, y, r)``: every closed disk the surface reads points from
        (a piece of a survey gets the whole survey's surface once it holds every point inside them)."""
        return np.concatenate([self.nodes.disks, self.added.disks])


class SmoothSurface(NamedTuple):
    """A mesh's smooth surface: cubic patches over its faces, its long faces cut first.

    Evaluated by :func:`meshcore.interpolate`, :func:`meshcore.gradient` and
    :func:`meshcore.rasterize` given as their ``surface`` with the mesh it was computed for.

    Attributes
    ----------
    mesh : Mesh
        The faces the patches lie on: the input mesh's faces, those with a
        long edge cut into triangles (:class:`meshcore.refine.Refinement`: a
        face cut keeps its row for its first triangle, the others follow);
        its vertices are the input mesh's, then the points added on long edges.
    z : (n_v + m,) the values at its vertices (the added points' kriged)
    nodes : (n_f', 12) the patches' node values, one row per face of ``mesh``
    parent : (n_f',) the input mesh's face each face lies in
    """

    mesh: Mesh
    z: NDArray[np.float64]
    nodes: NDArray[np.float64]
    parent: NDArray[np.int64]


def _radii(d2: NDArray[np.float64]) -> NDArray[np.float64]:
    """The distance from each centre to its last neighbour (squared distances of :func:`_nearest`)."""
    return np.sqrt(d2[:, -1]) if d2.shape[1] else np.zeros(d2.shape[0])


def _added_points(data: NDArray[np.float64], positions: NDArray[np.float64], cell: float, k: int) -> AddedPoints:
    """The systems of the points added at ``positions`` (their fill left to :func:`_void_fills`)."""
    order, first, centres = _cells(positions, cell)
    if centres.shape[0] == 0:
        return AddedPoints(order, first, centres, np.empty((0, k), dtype=np.int64), np.empty(0), np.empty(0), _NO_FILL)
    # the cells of the added points are few and scattered: searched around each, not over a grid of every vertex
    index, d2 = _nearest_around(data, centres, k, 6.0 * cell)
    gap = _gaps(data, index, first, np.ascontiguousarray(positions[order]), cell)
    return AddedPoints(order, first, np.ascontiguousarray(centres), index, _radii(d2), gap, _NO_FILL)


def _with_fills(vertices: NDArray[np.float64], data: int, nodes: Neighbourhoods, added: AddedPoints,
                ends: NDArray[np.int64], new: NDArray[np.float64] | None = None) -> tuple[Neighbourhoods, AddedPoints]:
    """``nodes`` and ``added`` with the natural neighbours of those in voids, found together
    (``vertices``: the refined mesh's, its first ``data`` the points; ``ends``: the added points' edges).

    With ``new`` (points added to the vertices since ``nodes.fill`` and
    ``added.fill`` were found), only the nodes in voids whose disks hold one
    of them are found again (no node joins the voids: a gap only shrinks as
    points are added)."""
    where = np.ascontiguousarray(vertices[data:][added.order])
    groups = ((nodes.positions, nodes.gap, nodes.index, nodes.first, nodes.corners),
              (where, added.gap, added.index, added.first, ends[added.order]))
    if new is None:
        fills = _void_fills(vertices, data, ends, nodes.cell, *groups)
        return nodes._replace(fill=fills[0]), added._replace(fill=fills[1])
    near, _ = _void_distances(nodes.cell)
    old = (nodes.fill, added.fill)
    rows = [np.flatnonzero(gap > near) for _, gap, *_ in groups]
    # each kept node's place among the old ones, and those whose disks hold a new point
    kept = [np.searchsorted(f.rows, r) for f, r in zip(old, rows)]
    again = []
    for f, k in zip(old, kept):
        holds = np.zeros(f.rows.size, dtype=bool)
        hit = _disks_holding(f.coordinates.disks[:, :2], f.coordinates.disks[:, 2], new)
        holds[f.coordinates.owner[hit]] = True
        again.append(holds[k])
    if not any(a.any() for a in again) and all(k.size == f.rows.size for f, k in zip(old, kept)):
        return nodes, added
    found = _void_fills(vertices, data, ends, nodes.cell, *groups, rows=[r[a] for r, a in zip(rows, again)])
    fills = []
    for f, r, k, a, fresh in zip(old, rows, kept, again, found):
        # the old rows of the nodes kept as they were, then the new ones, put back in order
        both = join_places(take_places(f.coordinates, k[~a]), fresh.coordinates)
        order = np.argsort(np.concatenate([np.flatnonzero(~a), np.flatnonzero(a)]), kind="stable")
        fills.append(VoidFill(r, take_places(both, order)))
    return nodes._replace(fill=fills[0]), added._replace(fill=fills[1])


def smooth_plan(mesh: Mesh, variogram: Variogram, neighbours: int = DEFAULT_NEIGHBOURS,
                previous: SmoothPlan | None = None, faces: ArrayLike | None = None) -> SmoothPlan:
    """The long faces cut and every kriging system of ``mesh``'s smooth surface (see :class:`SmoothPlan`).

    Edges longer than a few point spacings (:func:`_long_edges`, by the
    variogram) are split into equal pieces, decided and placed by the edge
    alone, so two pieces of a survey split a shared edge alike.  ``.disks``
    are the points the values will read.

    ``previous``: the plan, with the same variogram and ``neighbours``, of a
    mesh with the same faces whose vertices are the first of ``mesh``'s (as
    :func:`meshcore.mesh.with_vertices` adds points).  Only the systems whose
    disks hold one of the other vertices are searched again: the plan is
    the one ``mesh`` gets, in a fraction of the time (for the faces
    ``previous`` was made for).

    ``faces``: a mask of the faces whose patches are wanted (default: all),
    such as those a grid samples (:func:`meshcore.sampled_faces`).  The
    others get no nodes: their rows of the surface's nodes are NaN, so the
    surface is unknown inside them, and the systems only they would read are
    neither searched nor solved.  The nodes computed are those of the whole
    mesh's plan, bit for bit.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> mesh = meshcore.build_mesh(np.random.default_rng(1).random((50, 2)))
    >>> plan = smooth_plan(mesh, Variogram(0.0, 1.0, 0.5, spacing=0.15))
    >>> plan.refinement.mesh.faces.shape[0] >= mesh.faces.shape[0], bool(np.all(plan.disks[:, 2] > 0))
    (True, True)
    """
    k = _check_neighbours(neighbours)
    variogram = _check_variogram(variogram)
    vertices, mesh_faces = mesh_arrays(mesh)
    if previous is not None:
        extended = _extended_plan(previous, mesh, vertices, mesh_faces, k)
        if extended is not None:
            return extended
    spacing = _mesh_spacing(vertices, k) if variogram.spacing is None else variogram.spacing
    longer_than, piece = _long_edges(variogram)
    refinement = refine_long_faces(mesh, spacing, longer_than, piece)
    n = vertices.shape[0]
    wanted = None if faces is None else _face_mask(faces, mesh_faces.shape[0])[refinement.parent]
    nodes = _neighbourhoods(refinement.mesh, k, spacing, n, wanted, False)
    added_positions = np.ascontiguousarray(refinement.mesh.vertices[n:])
    added = _added_points(vertices, added_positions, nodes.cell, k)
    nodes, added = _with_fills(refinement.mesh.vertices, n, nodes, added, refinement.ends)
    return SmoothPlan(refinement, nodes, added)


def _extended_plan(previous: SmoothPlan, mesh: Mesh, vertices: NDArray[np.float64], faces: NDArray[np.int64],
                   k: int) -> SmoothPlan | None:
    """:func:`smooth_plan` of ``mesh`` from ``previous`` (see there); None when
    its systems have fewer than ``k`` neighbours, all searched again then."""
    refinement, nodes, added = previous
    refined = refinement.mesh
    m = refinement.t.shape[0]
    n_old = refined.vertices.shape[0] - m
    n = vertices.shape[0]
    n_f = faces.shape[0]
    if (n < n_old or refinement.parent.shape[0] < n_f or nodes.take.shape[0] != refinement.parent.shape[0]
            or not np.array_equal(refinement.parent[:n_f], np.arange(n_f))
            or not np.array_equal(refined.vertices[:n_old], vertices[:n_old])):
        raise InvalidInputError("previous must be the plan of a mesh with these faces and the first of these vertices")
    if nodes.index.shape[1] != min(k, n_old) or min(k, n_old) != min(k, n):
        return None
    if n == n_old:
        return previous
    grown = n - n_old
    new = vertices[n_old:]

    def shifted(index: NDArray) -> NDArray:
        """Indices of the refined mesh's vertices, its new points moved past the vertices added."""
        if not m:
            return index
        out = index.copy()
        out[out >= n_old] += grown
        return out

    def searched_again(centres, index, radius, search):
        """``index`` and ``radius`` with the systems whose disks hold a new vertex found again by ``search``."""
        again = _disks_holding(centres, radius, new)
        if not again.any():
            return index, radius
        index, radius = index.copy(), radius.copy()
        found, d2 = search(np.ascontiguousarray(centres[again]))
        index[again], radius[again] = found, _radii(d2)
        return index, radius

    if m:
        refined = Mesh(np.concatenate([vertices, refined.vertices[n_old:]]), shifted(refined.faces), mesh.input_to_vertex,
                       mesh.triangle_measure, mesh.quad_measure, mesh.merge, mesh.window, mesh.window_escapes)
    else:
        refined = mesh
    index, radius = searched_again(nodes.centres, nodes.index, nodes.radius, lambda c: _nearest(vertices, c, k))
    gap = nodes.gap if index is nodes.index else _gaps(vertices, index, nodes.first, nodes.positions, nodes.cell)
    nodes = nodes._replace(index=index, radius=radius, corners=shifted(nodes.corners), gap=gap)
    # as _added_points searches them
    index, radius = searched_again(added.centres, added.index, added.radius,
                                   lambda c: _nearest_around(vertices, c, k, 6.0 * nodes.cell))
    if index is not added.index:
        added_positions = np.ascontiguousarray(refined.vertices[n:][added.order])
        gap = _gaps(vertices, index, added.first, added_positions, nodes.cell)
        added = added._replace(index=index, radius=radius, gap=gap)
    # the voids' natural neighbours again, of the nodes whose disks hold a new vertex
    nodes, added = _with_fills(refined.vertices, n, nodes, added, refinement.ends, new)
    return SmoothPlan(refinement._replace(mesh=refined), nodes, added)


def smooth_surface(
    mesh: Mesh,
    z: ArrayLike,
    variogram: Variogram | None = None,
    neighbours: int = DEFAULT_NEIGHBOURS,
    plan: SmoothPlan | None = None,
) -> SmoothSurface:
    """The smooth surface of ``mesh``: its long faces cut, the points added there
    kriged, and the patches' nodes of the faces that gives (:func:`smooth_nodes`).

    The added points are kriged from their cells' systems, as the nodes are,
    and clamped to their edge's ends and neighbours; every system reads the
    input vertices only.  The surface passes through every vertex, is
    continuous across every edge and reproduces linear functions.

    Parameters
    ----------
    mesh : Mesh
    z : (n_v,) the value at every vertex
    variogram : Variogram, optional
        Fitted from the mesh's vertices when omitted.
    neighbours : int
        Points per kriging neighbourhood, 4 to 64.
    plan : SmoothPlan, optional
        From :func:`smooth_plan` for this mesh, variogram and ``neighbours``.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> xy = np.random.default_rng(2).random((60, 2))
    >>> mesh = meshcore.build_mesh(xy, "s3", "s4")
    >>> surface = smooth_surface(mesh, 2.0 * mesh.vertices[:, 0], Variogram(0.0, 1.0, 0.5))
    >>> surface.nodes.shape == (surface.mesh.faces.shape[0], 12)
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    variogram = fit_variogram(vertices, zv, neighbours=k) if variogram is None else _check_variogram(variogram)
    plan = smooth_plan(mesh, variogram, k) if plan is None else plan
    refinement = plan.refinement
    n = vertices.shape[0]
    refined = refinement.mesh
    if refinement.parent.shape[0] != refined.faces.shape[0] or (refined is not mesh and refined.vertices.shape[0] < n) or (
        refinement.parent.size and refinement.parent.max() >= faces.shape[0]
    ):
        raise InvalidInputError("plan was computed for another mesh")
    m = refined.vertices.shape[0] - n
    z_all = np.empty(n + m)
    z_all[:n] = zv
    if m:
        z_all[n:] = _krige_added(vertices, zv, variogram, plan.added, refined.vertices[n:], refinement.ends, refinement.t,
                                 plan.nodes.cell)
    nodes = smooth_nodes(refined, z_all, variogram, k, neighbourhoods=plan.nodes)
    return SmoothSurface(refined, z_all, nodes, refinement.parent)


def _krige_added(
    vertices: NDArray[np.float64], z: NDArray[np.float64], variogram: Variogram, added: AddedPoints,
    positions: NDArray[np.float64], ends: NDArray[np.int64], t: NDArray[np.float64], cell: float,
) -> NDArray[np.float64]:
    """The added points' values, kriged as the nodes are: each from its cell's system,
    clamped as they are (to the neighbours' and its edge's ends' range), those
    in voids blended into the fill; a singular system gives the linear value
    ``(1 - t) z[first] + t z[second]``."""
    n = positions.shape[0]
    order = added.order
    corners = np.full((n, 4), -1, dtype=np.int32)
    corners[:, :2] = ends[order]
    weights = np.zeros((n, 4))
    weights[:, 0] = 1.0 - t[order]
    weights[:, 1] = t[order]
    values = np.empty(n)
    near, far = _void_distances(cell)
    _nodes_kriged_kernel(
        vertices, z, added.centres, added.index, added.first, np.ascontiguousarray(positions[order]), corners,
        np.arange(n, dtype=np.int32), weights, variogram.nugget / variogram.sill, 1.0 / variogram.range,
        MODELS.index(variogram.model), _clamps_inside(variogram), added.gap, added.fill.values(z, n), near, far, values,
    )
    out = np.empty(n)
    out[order] = values
    return out


@njit
def _scatter_nodes(values: np.ndarray, take: np.ndarray, out: np.ndarray) -> None:
    """``out[f, j] = values[take[f, j]]`` where ``take[f, j] >= 0``, else NaN (six times faster than a mask in numpy)."""
    for f in range(take.shape[0]):
        for j in range(take.shape[1]):
            t = take[f, j]
            out[f, j] = values[t] if t >= 0 else np.nan


# --------------------------------------------------------------------------
# Fitting the variogram
# --------------------------------------------------------------------------


@njit
def _loo_errors_kernel(
    xy: np.ndarray, z: np.ndarray, sample: np.ndarray, neighbours: np.ndarray,
    nugget_ratios: np.ndarray, inv_range: float, model: int, out: np.ndarray,
) -> None:
    """Leave-one-out errors: each sample point kriged from its neighbours (itself
    left out), in row ``r`` of ``out`` with the nugget ``nugget_ratios[r]``.

    A system's covariances do not depend on the nugget: they are computed once
    for every nugget (:func:`_dual_setup`), and each nugget solves the system
    as the smooth surface does (:func:`_dual_solve`)."""
    k = neighbours.shape[1]
    room = _kriging_scratch(k)
    centres = empty((sample.shape[0], 2))
    for s in range(sample.shape[0]):
        centres[s, 0] = xy[sample[s], 0]
        centres[s, 1] = xy[sample[s], 1]
    origin = zeros(1)
    value = empty(1)
    block = empty((3, k))
    scale = _LAG_SCALE[model] * inv_range
    s0 = 0
    while s0 < sample.shape[0]:
        lanes, count = _lanes(neighbours, s0)
        if lanes == _LANES:  # a constant number of lanes, as in _solve_systems
            _dual_setup(xy, centres, neighbours, s0, _LANES, count, scale, model, room)
        else:
            _dual_setup(xy, centres, neighbours, s0, lanes, count, scale, model, room)
        for r in range(nugget_ratios.shape[0]):
            if lanes == _LANES:
                _dual_solve(z, neighbours, s0, _LANES, count, nugget_ratios[r], room)
            else:
                _dual_solve(z, neighbours, s0, lanes, count, nugget_ratios[r], room)
            for b in range(lanes):
                radius = room.radius[b]
                if math.isfinite(radius):
                    _dual_values(room.xs[b], room.ys[b], count, room.coef[b], radius, scale, model, origin, origin, 1,
                                 block, value)
                    out[r, s0 + b] = value[0] - z[sample[s0 + b]]
                else:
                    out[r, s0 + b] = math.nan
        s0 += lanes


def _in_order(pts: NDArray[np.float64], z: NDArray[np.float64]) -> bool:
    """Whether the points are sorted by x, then y, then z (``np.lexsort((z, y, x))``'s order)."""
    if pts.shape[0] < 2:
        return True
    x, y = pts[:, 0], pts[:, 1]
    dx, dy, dz = x[1:] - x[:-1], y[1:] - y[:-1], z[1:] - z[:-1]
    return bool(np.all((dx > 0) | ((dx == 0) & ((dy > 0) | ((dy == 0) & (dz >= 0))))))


_RANGES = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
"""The ranges tried, in median neighbour distances."""

_NUGGETS = (0.0, 1e-6, 1e-4, 0.01, 0.03, 0.1, 0.3, 1.0, 5.0)
"""The nugget / sill ratios tried (Matérn models start at 1e-6: with none their systems are near singular)."""

_SCREEN = 500
"""Every candidate is first scored on this many of the sample's points; the best :data:`_FINALISTS` on all."""

_FINALISTS = 6


def fit_variogram(
    xy: ArrayLike, z: ArrayLike, neighbours: int = DEFAULT_NEIGHBOURS, sample: int = 2000, seed: int = 0
) -> Variogram:
    """The variogram that best predicts left-out points of ``(xy, z)``, and the points' spacing.

    ``sample`` points (drawn with ``seed``) are each kriged, left out, from
    their ``neighbours`` nearest others, for each of :data:`MODELS`, ranges
    from a tenth to a hundred times the median neighbour distance and nuggets
    from none to five times the sill: every candidate on a quarter of the
    sample first, the best few on all of it.  The candidate with the smallest
    root mean square error wins (ties: the first in the order models,
    ranges, nuggets).  A candidate whose systems are singular at more than
    one point in a thousand is not taken.  The sill is then scaled to the
    empirical semivariance of the neighbour pairs, so that ``nugget`` reads
    as the noise variance in z units squared.  ``spacing`` is
    ``1 / sqrt(density)``, the density measured by the distance to each
    sample point's ``neighbours``-th nearest.

    Deterministic: the same points (in any order) give the same variogram.

    Raises
    ------
    InvalidInputError
        When fewer than ``neighbours + 2`` finite points are given.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(3)
    >>> xy = rng.random((800, 2)) * 100.0
    >>> z = np.sin(xy[:, 0] / 15.0) + 0.01 * rng.standard_normal(800)
    >>> v = fit_variogram(xy, z)
    >>> v.range > 0 and v.nugget < v.sill and 2.0 < v.spacing < 5.0
    True
    """
    k = _check_neighbours(neighbours)
    pts = np.asarray(xy, dtype=np.float64)
    zz = np.asarray(z, dtype=np.float64).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] < 2 or pts.shape[0] != zz.shape[0]:
        raise InvalidInputError(f"xy must be (n, 2) and z (n,), got {pts.shape} and {zz.shape}")
    keep = np.isfinite(zz) & np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1])
    pts = np.ascontiguousarray(pts[keep, :2])
    zz = np.ascontiguousarray(zz[keep])
    if pts.shape[0] < k + 2:
        raise InvalidInputError(f"fitting a variogram needs at least {k + 2} finite points, got {pts.shape[0]}")
    # a canonical order, so that the sample does not depend on the input order
    # (points already in it, as a run's merged sample is, are not sorted again)
    if not _in_order(pts, zz):
        order = np.lexsort((zz, pts[:, 1], pts[:, 0]))
        pts = np.ascontiguousarray(pts[order])
        zz = np.ascontiguousarray(zz[order])
    rng = np.random.default_rng(seed)
    m = min(sample, pts.shape[0])
    chosen = np.sort(rng.choice(pts.shape[0], size=m, replace=False))
    index, d2 = _nearest(pts, pts[chosen], k + 1)
    index = np.ascontiguousarray(index[:, 1:])  # leave the point itself out
    d2 = d2[:, 1:]
    nearest = float(np.median(np.sqrt(d2[:, 0])))
    if not nearest > 0.0:
        nearest = float(np.median(np.sqrt(d2[np.isfinite(d2)]))) or 1.0
    screen = np.sort(np.random.default_rng(seed + 1).permutation(m)[: min(_SCREEN, m)])

    candidates = [(model, factor, ratio) for model in range(len(MODELS)) for factor in _RANGES
                  for ratio in _NUGGETS if model == 0 or ratio > 0.0]
    every = np.arange(m)

    def errors(rows: NDArray[np.int64], which: list[int]) -> NDArray[np.float64]:
        """``(len(which), rows.size)``: the errors of candidates ``which`` at ``rows``,
        the nuggets of one model and range on the same covariances."""
        out = np.empty((len(which), rows.size))
        groups: dict[tuple[int, float], list[int]] = {}
        for slot, i in enumerate(which):
            groups.setdefault(candidates[i][:2], []).append(slot)
        sample, hoods = chosen[rows], np.ascontiguousarray(index[rows])
        for (model, factor), slots in groups.items():
            ratios = np.array([candidates[which[slot]][2] for slot in slots])
            found = np.empty((len(slots), rows.size))
            _loo_errors_kernel(pts, zz, sample, hoods, ratios, 1.0 / (factor * nearest), model, found)
            out[slots] = found
        return out

    def rmse(values: NDArray[np.float64]) -> float:
        ok = np.isfinite(values)
        if np.count_nonzero(~ok) > 1e-3 * values.size or not ok.any():
            return math.inf
        return float(np.sqrt(np.mean(values[ok] ** 2)))

    # the sample in two halves on two threads (the kernel releases the GIL):
    # every candidate on the screen, then the finalists on all of the sample
    with ThreadPoolExecutor(2) as pool:

        def scores(rows: NDArray[np.int64], which: list[int]) -> list[float]:
            half = (rows.size + 1) // 2
            found = np.concatenate(list(pool.map(lambda part: errors(part, which), (rows[:half], rows[half:]))), axis=1)
            return [rmse(row) for row in found]

        screened = scores(screen, list(range(len(candidates))))
        ranked = sorted(sorted(range(len(candidates)), key=lambda i: (screened[i], i))[:_FINALISTS])
        final = scores(every, ranked) if screen.size < m else [screened[i] for i in ranked]
    best: tuple[float, int] | None = None
    for i, rmse in zip(ranked, final):
        if math.isfinite(rmse) and (best is None or rmse < best[0] * (1.0 - 1e-9)):
            best = (rmse, i)
    model, factor, ratio = candidates[best[1]] if best is not None else (0, 10.0, 0.1)
    rng_best = factor * nearest
    # the sill: semivariances of neighbour pairs against the model's shape
    first = index[:, :4]
    h = np.sqrt(d2[:, :4]).ravel()
    gamma = 0.5 * (zz[chosen][:, None] - zz[first]).ravel() ** 2
    shape = ratio + 1.0 - _correlation(h, rng_best, model)
    good = np.isfinite(gamma) & (shape > 0)
    sill = float(np.sum(gamma[good] * shape[good]) / np.sum(shape[good] ** 2)) if good.any() else 1.0
    if not sill > 0.0:
        sill = float(np.finfo(float).tiny) * 1e10
    return Variogram(nugget=ratio * sill, sill=sill, range=rng_best, model=MODELS[model], spacing=_spacing(d2[:, -1], k))
