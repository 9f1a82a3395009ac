"""The smooth surface's covariance, :class:`Variogram`, and its fit.

:func:`fit_variogram` chooses the model (one of :data:`MODELS`), its nugget
and range by leave-one-out cross-validation of the surface's own kriging
(:mod:`meshcore.kriging`) on a sample, and measures the point spacing.
"""

from __future__ import annotations
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._buckets import _nearest
from ._jit import empty, njit, zeros
from .errors import InvalidInputError
from .cells import _spacing
from .kriging import (DEFAULT_NEIGHBOURS, _LAG_SCALE, _LANES, _check_neighbours, _correlation_kernel, _dual_setup,
                      _dual_solve, _dual_values, _kriging_scratch, _lanes)

__all__ = ["MODELS", "Variogram", "fit_variogram"]


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
    for i, error in zip(ranked, final):
        if math.isfinite(error) and (best is None or error < best[0] * (1.0 - 1e-9)):
            best = (error, i)
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
