"""Local kriging in its dual form: the smooth surface's systems, solved side by side.

Each cell of nodes (:mod:`meshcore.cells`) is kriged from its
:data:`DEFAULT_NEIGHBOURS` (or ``neighbours``) nearest points: universal
kriging with a linear drift, one system per cell, solved once in its dual
form (Cholesky of the covariances, the drift by its Schur complement), then
evaluated at each of the cell's nodes.  :data:`_LANES` systems are solved
side by side, one per vector lane.  The covariance is one of
:data:`meshcore.variogram.MODELS`, by its code.
"""

from __future__ import annotations
import math
from typing import NamedTuple

import numpy as np

from ._jit import LANES, empty, lanes_scale, lanes_subtract_products, larger, njit, njit_helper, smaller
from .errors import InvalidInputError

__all__ = ["DEFAULT_NEIGHBOURS"]


DEFAULT_NEIGHBOURS = 16
"""Points per kriging neighbourhood (the vertex and its 15 nearest)."""


_PIVOT_TOL = 1e-10
"""A kriging system whose pivot falls below this (relative) is singular."""


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

def _check_neighbours(neighbours: object) -> int:
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)) or not 4 <= neighbours <= 64:
        raise InvalidInputError(f"neighbours must be an integer from 4 to 64, got {neighbours!r}")
    return int(neighbours)
