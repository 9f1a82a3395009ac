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
only a few times slower than the filter.  Every expansion has a fixed largest
length, so the exact path works in one scratch buffer on the stack: it
allocates nothing, and kernels compiled without reference counting can call
it.

As with Shewchuk's predicates, exactness assumes no product of coordinate
differences underflows (differences are either 0 or larger than about 1e-150)
or overflows; meshcore works in a local frame where this always holds for
real coordinates.
"""

from __future__ import annotations

import numpy as np

from ._jit import njit, njit_helper, stack_array

__all__ = ["orient2d", "incircle", "incircle_sos", "cross_rounded"]

_EPS = 2.0**-53
_SPLITTER = 2.0**27 + 1.0
_CCW_ERRBOUND_A = (3.0 + 16.0 * _EPS) * _EPS
_ICC_ERRBOUND_A = (10.0 + 96.0 * _EPS) * _EPS


@njit_helper
def _two_sum(a: float, b: float) -> tuple[float, float]:
    x = a + b
    bv = x - a
    av = x - bv
    return x, (a - av) + (b - bv)


@njit_helper
def _fast_two_sum(a: float, b: float) -> tuple[float, float]:
    x = a + b
    return x, b - (x - a)


@njit_helper
def _two_diff(a: float, b: float) -> tuple[float, float]:
    x = a - b
    bv = a - x
    av = x + bv
    return x, (a - av) + (bv - b)


@njit_helper
def _split(a: float) -> tuple[float, float]:
    c = _SPLITTER * a
    abig = c - a
    hi = c - abig
    return hi, a - hi


@njit_helper
def _two_product(a: float, b: float) -> tuple[float, float]:
    x = a * b
    ahi, alo = _split(a)
    bhi, blo = _split(b)
    err = x - ahi * bhi
    err -= alo * bhi
    err -= ahi * blo
    return x, alo * blo - err


@njit_helper
def _diff_into(a: float, b: float, out: np.ndarray) -> int:
    """``a - b`` exactly, as an expansion in ``out`` (increasing magnitude,
    zeros removed); returns its length (1 or 2)."""
    x, y = _two_diff(a, b)
    if y == 0.0:
        out[0] = x
        return 1
    out[0] = y
    out[1] = x
    return 2


@njit_helper
def _scale_into(e: np.ndarray, elen: int, b: float, h: np.ndarray) -> int:
    """``e[:elen] * b`` exactly into ``h`` (room for ``2 elen``); returns its
    length (Shewchuk's scale_expansion_zeroelim)."""
    q, hh = _two_product(e[0], b)
    n = 0
    if hh != 0.0:
        h[n] = hh
        n += 1
    for i in range(1, elen):
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
    return n


@njit_helper
def _sum_into(e: np.ndarray, elen: int, f: np.ndarray, flen: int, h: np.ndarray) -> int:
    """``e[:elen] + f[:flen]`` exactly into ``h`` (room for ``elen + flen``);
    returns its length (Shewchuk's fast_expansion_sum_zeroelim)."""
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
    return n


@njit_helper
def _product_into(
    e: np.ndarray, elen: int, f: np.ndarray, flen: int, h: np.ndarray, scaled: np.ndarray, acc: np.ndarray
) -> int:
    """``e[:elen] * f[:flen]`` exactly into ``h`` (room for ``2 elen flen``);
    ``scaled`` (``2 elen``) and ``acc`` (``2 elen flen``) are scratch."""
    n = _scale_into(e, elen, f[0], h)
    for i in range(1, flen):
        m = _scale_into(e, elen, f[i], scaled)
        n = _sum_into(h, n, scaled, m, acc)
        for k in range(n):  # (a slice assignment could raise on a size mismatch)
            h[k] = acc[k]
    return n


@njit_helper
def _negate(e: np.ndarray, elen: int) -> None:
    for i in range(elen):
        e[i] = -e[i]


@njit_helper
def _sign(value: float) -> int:
    if value > 0.0:
        return 1
    if value < 0.0:
        return -1
    return 0


@njit_helper
def _two_products_into(a, na, b, nb, c, nc, d, nd, sign, h, small) -> int:
    """``a b + sign c d`` (``sign`` +1 or -1) of expansions of at most 2 terms,
    exactly into ``h`` (room for 16); ``small`` (28) is scratch."""
    left, right, scaled, acc = small[0:8], small[8:16], small[16:20], small[20:28]
    nl = _product_into(a, na, b, nb, left, scaled, acc)
    nr = _product_into(c, nc, d, nd, right, scaled, acc)
    if sign < 0:
        _negate(right, nr)
    return _sum_into(left, nl, right, nr, h)


@njit_helper
def _orient2d_into(ax, ay, bx, by, cx, cy, buf) -> int:
    """The orientation determinant exactly, as an expansion in ``buf[8:24]``
    (``buf``: 52 doubles of scratch); returns its length."""
    acx, acy, bcx, bcy, det, small = buf[0:2], buf[2:4], buf[4:6], buf[6:8], buf[8:24], buf[24:52]
    n_acx = _diff_into(ax, cx, acx)
    n_acy = _diff_into(ay, cy, acy)
    n_bcx = _diff_into(bx, cx, bcx)
    n_bcy = _diff_into(by, cy, bcy)
    return _two_products_into(acx, n_acx, bcy, n_bcy, acy, n_acy, bcx, n_bcx, -1, det, small)


@njit_helper
def _orient2d_exact(ax, ay, bx, by, cx, cy) -> int:
    buf = stack_array(64)
    n = _orient2d_into(ax, ay, bx, by, cx, cy, buf)
    return _sign(buf[8 + n - 1])


@njit
def cross_rounded(ax, ay, bx, by, cx, cy) -> tuple[float, float]:
    """The cross product ``(b - a) x (c - a)`` (twice the signed area of
    ``a, b, c``), evaluated exactly and then rounded, with a bound of that
    rounding: ``|value - exact| <= error``.

    Of a near-collinear triangle's cross product, floating point keeps no
    correct digit; this keeps all but the last few.
    """
    buf = stack_array(64)
    n = _orient2d_into(ax, ay, bx, by, cx, cy, buf)
    value = 0.0
    size = 0.0
    for k in range(8, 8 + n):  # smallest first
        value += buf[k]
        size += abs(buf[k])
    # each of the n sums rounds by at most an ulp of a partial sum <= size
    return value, (n + 1) * _EPS * size


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


#: doubles of scratch the exact in-circle test needs on the stack (38 KB)
_INCIRCLE_WORK = 4800


@njit_helper
def _incircle_exact(ax, ay, bx, by, cx, cy, dx, dy) -> int:
    # every expansion has a fixed largest length (differences 2, lifts and
    # cross products 16, their products 512), so one buffer on the stack
    # holds them all: the test allocates nothing, and kernels compiled
    # without reference counting can run it
    w = stack_array(_INCIRCLE_WORK)
    adx, ady, bdx, bdy, cdx, cdy = w[0:2], w[2:4], w[4:6], w[6:8], w[8:10], w[10:12]
    nadx = _diff_into(ax, dx, adx)
    nady = _diff_into(ay, dy, ady)
    nbdx = _diff_into(bx, dx, bdx)
    nbdy = _diff_into(by, dy, bdy)
    ncdx = _diff_into(cx, dx, cdx)
    ncdy = _diff_into(cy, dy, cdy)
    small = w[12:40]
    alift, blift, clift = w[40:56], w[56:72], w[72:88]
    bc, ca, ab = w[88:104], w[104:120], w[120:136]
    nal = _two_products_into(adx, nadx, adx, nadx, ady, nady, ady, nady, 1, alift, small)
    nbl = _two_products_into(bdx, nbdx, bdx, nbdx, bdy, nbdy, bdy, nbdy, 1, blift, small)
    ncl = _two_products_into(cdx, ncdx, cdx, ncdx, cdy, ncdy, cdy, ncdy, 1, clift, small)
    nbc = _two_products_into(bdx, nbdx, cdy, ncdy, cdx, ncdx, bdy, nbdy, -1, bc, small)
    nca = _two_products_into(cdx, ncdx, ady, nady, adx, nadx, cdy, ncdy, -1, ca, small)
    nab = _two_products_into(adx, nadx, bdy, nbdy, bdx, nbdx, ady, nady, -1, ab, small)
    scaled, acc = w[136:168], w[168:680]
    pa, pb, pc = w[680:1192], w[1192:1704], w[1704:2216]
    npa = _product_into(alift, nal, bc, nbc, pa, scaled, acc)
    npb = _product_into(blift, nbl, ca, nca, pb, scaled, acc)
    npc = _product_into(clift, ncl, ab, nab, pc, scaled, acc)
    pab, det = w[2216:3240], w[3240:4776]
    nab2 = _sum_into(pa, npa, pb, npb, pab)
    n = _sum_into(pab, nab2, pc, npc, det)
    return _sign(det[n - 1])


@njit_helper
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


@njit_helper
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


@njit_helper
def _incircle_sos_exact(ax, ay, bx, by, cx, cy, dx, dy) -> int:
    s = _incircle_exact(ax, ay, bx, by, cx, cy, dx, dy)
    if s != 0:
        return s
    # the points in lexicographic order, equal points in argument order: the
    # rank of each is how many come before it
    ra = (np.int64(lex_before(bx, by, ax, ay)) + np.int64(lex_before(cx, cy, ax, ay))
          + np.int64(lex_before(dx, dy, ax, ay)))
    rb = (np.int64(not lex_before(bx, by, ax, ay)) + np.int64(lex_before(cx, cy, bx, by))
          + np.int64(lex_before(dx, dy, bx, by)))
    rc = (np.int64(not lex_before(cx, cy, ax, ay)) + np.int64(not lex_before(cx, cy, bx, by))
          + np.int64(lex_before(dx, dy, cx, cy)))
    for rank in range(4):
        if rank == ra:
            c = orient2d(bx, by, cx, cy, dx, dy)
        elif rank == rb:
            c = -orient2d(ax, ay, cx, cy, dx, dy)
        elif rank == rc:
            c = orient2d(ax, ay, bx, by, dx, dy)
        else:
            c = -orient2d(ax, ay, bx, by, cx, cy)
        if c != 0:
            return c
    return 0
