"""Robust geometric predicates (adaptive: a fast filter, then exact arithmetic).

Sign conventions
----------------
``orient2d(a, b, c)``
    ``+1`` when ``a, b, c`` turn counter-clockwise (``c`` left of ``a -> b``),
    ``-1`` clockwise, ``0`` exactly collinear.
``incircle(a, b, c, d)``
    ``+1`` when ``d`` lies strictly inside the circle through ``a, b, c``
    (given counter-clockwise), ``-1`` outside, ``0`` exactly co-circular.
    For a clockwise ``a, b, c`` the sign is reversed.

Both first evaluate the determinant in floating point with Shewchuk's
error bound (stage A of "Adaptive Precision Floating-Point Arithmetic and Fast
Robust Geometric Predicates", 1997).  When the bound cannot certify the sign,
the determinant is evaluated exactly with floating-point expansions: the
differences are formed exactly (``two_diff``), multiplied exactly
(``scale_expansion``) and summed exactly (``fast_expansion_sum``).  The sign
is that of the largest component.  When coordinate differences are exact (the
usual case for survey data), the expansions stay short and the exact path is
only a few times slower than the filter.

As with Shewchuk's predicates, exactness assumes no product of coordinate
differences underflows (differences are either 0 or larger than about 1e-150)
or overflows; meshcore works in a local frame where this always holds for
real coordinates.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit

__all__ = ["orient2d", "incircle", "incircle_sos"]

_EPS = 2.0**-53
_SPLITTER = 2.0**27 + 1.0
_CCW_ERRBOUND_A = (3.0 + 16.0 * _EPS) * _EPS
_ICC_ERRBOUND_A = (10.0 + 96.0 * _EPS) * _EPS


@njit
def _two_sum(a: float, b: float) -> tuple[float, float]:
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit
def _fast_two_sum(a: float, b: float) -> tuple[float, float]:
    x = a + b
    return x, b - (x - a)


@njit
def _two_diff(a: float, b: float) -> tuple[float, float]:
    x = a - b
    bv = a - x
    av = x + bv
    return x, (a - av) + (bv - b)


@njit
def _split(a: float) -> tuple[float, float]:
    c = _SPLITTER * a
    abig = c - a
    hi = c - abig
    return hi, a - hi


@njit
def _two_product(a: float, b: float) -> tuple[float, float]:
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi
    err -= alo * bhi
    err -= ahi * blo
    return x, alo * blo - err


@njit
def _diff_expansion(a: float, b: float) -> np.ndarray:
    """``a - b`` exactly, as an expansion (increasing magnitude, zeros removed)."""
    x, y = _two_diff(a, b)
    if y == 0.0:
        out = np.empty(1)
        out[0] = x
        return out
    out = np.empty(2)
    out[0] = y
    out[1] = x
    return out


@njit
def _scale_expansion(e: np.ndarray, b: float) -> np.ndarray:
    """``e * b`` exactly (Shewchuk's scale_expansion_zeroelim)."""
    h = np.empty(2 * e.shape[0])
    q, hh = _two_product(e[0], b)
    n = 0
    if hh != 0.0:
        h[n] = hh
        n += 1
    for i in range(1, e.shape[0]):
        p1, p0 = _two_product(e[i], b)
        s, hh = _two_sum(q, p0)
        if hh != 0.0:
            h[n] = hh
            n += 1
        q, hh = _fast_two_sum(p1, s)
        if hh != 0.0:
            h[n] = hh
            n += 1
    if q != 0.0 or n == 0:
        h[n] = q
        n += 1
    return h[:n]


@njit
def _sum_expansions(e: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``e + f`` exactly (Shewchuk's fast_expansion_sum_zeroelim)."""
    elen = e.shape[0]
    flen = f.shape[0]
    h = np.empty(elen + flen)
    ei = 0
    fi = 0
    enow = e[0]
    fnow = f[0]
    if (fnow > enow) == (fnow > -enow):
        q = enow
        ei += 1
    else:
        q = fnow
        fi += 1
    n = 0
    if ei < elen and fi < flen:
        enow = e[ei]
        fnow = f[fi]
        if (fnow > enow) == (fnow > -enow):
            q, hh = _fast_two_sum(enow, q)
            ei += 1
        else:
            q, hh = _fast_two_sum(fnow, q)
            fi += 1
        if hh != 0.0:
            h[n] = hh
            n += 1
        while ei < elen and fi < flen:
            enow = e[ei]
            fnow = f[fi]
            if (fnow > enow) == (fnow > -enow):
                q, hh = _two_sum(q, enow)
                ei += 1
            else:
                q, hh = _two_sum(q, fnow)
                fi += 1
            if hh != 0.0:
                h[n] = hh
                n += 1
    while ei < elen:
        q, hh = _two_sum(q, e[ei])
        ei += 1
        if hh != 0.0:
            h[n] = hh
            n += 1
    while fi < flen:
        q, hh = _two_sum(q, f[fi])
        fi += 1
        if hh != 0.0:
            h[n] = hh
            n += 1
    if q != 0.0 or n == 0:
        h[n] = q
        n += 1
    return h[:n]


@njit
def _product_expansions(e: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``e * f`` exactly."""
    acc = _scale_expansion(e, f[0])
    for i in range(1, f.shape[0]):
        acc = _sum_expansions(acc, _scale_expansion(e, f[i]))
    return acc


@njit
def _negate(e: np.ndarray) -> np.ndarray:
    return -e


@njit
def _sign(value: float) -> int:
    if value > 0.0:
        return 1
    if value < 0.0:
        return -1
    return 0


@njit
def _orient2d_exact(ax, ay, bx, by, cx, cy) -> int:
    acx = _diff_expansion(ax, cx)
    acy = _diff_expansion(ay, cy)
    bcx = _diff_expansion(bx, cx)
    bcy = _diff_expansion(by, cy)
    det = _sum_expansions(
        _product_expansions(acx, bcy), _negate(_product_expansions(acy, bcx))
    )
    return _sign(det[det.shape[0] - 1])


@njit
def orient2d(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> int:
    """Orientation of ``a, b, c``: +1 counter-clockwise, -1 clockwise, 0 collinear (exact).

    Examples
    --------
    >>> orient2d(0.0, 0.0, 1.0, 0.0, 0.0, 1.0)
    1
    >>> orient2d(0.0, 0.0, 1.0, 1.0, 2.0, 2.0)
    0
    """
    detleft = (ax - cx) * (by - cy)
    detright = (ay - cy) * (bx - cx)
    det = detleft - detright
    if detleft > 0.0:
        if detright <= 0.0:
            return _sign(det)
        detsum = detleft + detright
    elif detleft < 0.0:
        if detright >= 0.0:
            return _sign(det)
        detsum = -detleft - detright
    else:
        return _sign(det)
    errbound = _CCW_ERRBOUND_A * detsum
    if det >= errbound or -det >= errbound:
        return _sign(det)
    return _orient2d_exact(ax, ay, bx, by, cx, cy)


@njit
def _incircle_exact(ax, ay, bx, by, cx, cy, dx, dy) -> int:
    adx = _diff_expansion(ax, dx)
    ady = _diff_expansion(ay, dy)
    bdx = _diff_expansion(bx, dx)
    bdy = _diff_expansion(by, dy)
    cdx = _diff_expansion(cx, dx)
    cdy = _diff_expansion(cy, dy)
    alift = _sum_expansions(_product_expansions(adx, adx), _product_expansions(ady, ady))
    blift = _sum_expansions(_product_expansions(bdx, bdx), _product_expansions(bdy, bdy))
    clift = _sum_expansions(_product_expansions(cdx, cdx), _product_expansions(cdy, cdy))
    bc = _sum_expansions(_product_expansions(bdx, cdy), _negate(_product_expansions(cdx, bdy)))
    ca = _sum_expansions(_product_expansions(cdx, ady), _negate(_product_expansions(adx, cdy)))
    ab = _sum_expansions(_product_expansions(adx, bdy), _negate(_product_expansions(bdx, ady)))
    det = _sum_expansions(
        _sum_expansions(_product_expansions(alift, bc), _product_expansions(blift, ca)),
        _product_expansions(clift, ab),
    )
    return _sign(det[det.shape[0] - 1])


@njit
def _incircle_estimate(ax, ay, bx, by, cx, cy, dx, dy) -> tuple[float, float]:
    """The in-circle determinant in floating point and its error bound (stage A)."""
    adx = ax - dx
    bdx = bx - dx
    cdx = cx - dx
    ady = ay - dy
    bdy = by - dy
    cdy = cy - dy

    bdxcdy = bdx * cdy
    cdxbdy = cdx * bdy
    alift = adx * adx + ady * ady

    cdxady = cdx * ady
    adxcdy = adx * cdy
    blift = bdx * bdx + bdy * bdy

    adxbdy = adx * bdy
    bdxady = bdx * ady
    clift = cdx * cdx + cdy * cdy

    det = alift * (bdxcdy - cdxbdy) + blift * (cdxady - adxcdy) + clift * (adxbdy - bdxady)
    permanent = (
        (abs(bdxcdy) + abs(cdxbdy)) * alift
        + (abs(cdxady) + abs(adxcdy)) * blift
        + (abs(adxbdy) + abs(bdxady)) * clift
    )
    return det, _ICC_ERRBOUND_A * permanent


@njit
def incircle(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float
) -> int:
    """In-circle test: +1 when ``d`` is inside the circle of CCW ``a, b, c`` (exact).

    Examples
    --------
    >>> incircle(0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.5, 0.5)
    1
    >>> incircle(0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0)
    0
    """
    det, errbound = _incircle_estimate(ax, ay, bx, by, cx, cy, dx, dy)
    if det > errbound or -det > errbound:
        return _sign(det)
    return _incircle_exact(ax, ay, bx, by, cx, cy, dx, dy)


@njit
def lex_before(ax: float, ay: float, bx: float, by: float) -> bool:
    """True when point a comes before point b in lexicographic (x, then y) order."""
    return ax < bx or (ax == bx and ay < by)


@njit
def incircle_sos(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float
) -> int:
    """:func:`incircle` with ties broken by a symbolic perturbation: never 0 for distinct
    points of which no three are collinear.

    The lifted height ``x^2 + y^2`` of every point is raised by ``eps^k``, ``k``
    its rank in lexicographic ``(x, y)`` order (the smallest point is perturbed
    most).  When the exact determinant is 0 its sign is that of the cofactor of
    the first point, in that order, whose cofactor is not 0: ``+orient(b, c, d)``
    for ``a``, ``-orient(a, c, d)`` for ``b``, ``+orient(a, b, d)`` for ``c``,
    ``-orient(a, b, c)`` for ``d``.  The order depends only on coordinates, so
    any two runs over overlapping point sets (tiles) break every tie the same
    way and build the same, unique Delaunay triangulation where they overlap.

    Examples
    --------
    >>> incircle(0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0)
    0
    >>> incircle_sos(0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0)
    1
    """
    # the filter (the hot path of the sweep) inline; the exact and symbolic path out of line
    det, errbound = _incircle_estimate(ax, ay, bx, by, cx, cy, dx, dy)
    if det > errbound:
        return 1
    if -det > errbound:
        return -1
    return _incircle_sos_exact(ax, ay, bx, by, cx, cy, dx, dy)


@njit
def _incircle_sos_exact(ax, ay, bx, by, cx, cy, dx, dy) -> int:
    s = _incircle_exact(ax, ay, bx, by, cx, cy, dx, dy)
    if s != 0:
        return s
    xs = np.array([ax, bx, cx, dx])
    ys = np.array([ay, by, cy, dy])
    done = np.zeros(4, dtype=np.bool_)
    for _ in range(4):
        k = -1
        for j in range(4):
            if not done[j] and (k < 0 or lex_before(xs[j], ys[j], xs[k], ys[k])):
                k = j
        done[k] = True
        if k == 0:
            c = orient2d(bx, by, cx, cy, dx, dy)
        elif k == 1:
            c = -orient2d(ax, ay, cx, cy, dx, dy)
        elif k == 2:
            c = orient2d(ax, ay, bx, by, dx, dy)
        else:
            c = -orient2d(ax, ay, bx, by, cx, cy)
        if c != 0:
            return c
    return 0
