"""Edge flipping to local optimality under a triangle quality measure (paper, section 2).

A diagonal of a strictly convex quadrangle may flip when the smaller measure of
the two alternative triangles exceeds the smaller measure of the current two
by more than a relative tolerance; its *improvement* is the difference.
Kernels compare *scores*, a monotone transform of the measure that needs no
root: S1 itself, and S3 cubed.

The flips are made in rounds, by a rule of the geometry alone: in each round,
every diagonal whose improvement is the largest among the edges of its two
triangles flips (ties go to the edge whose endpoints come first by
coordinates), all at once.  Two such edges never share a triangle, so the
order in which a round applies them does not matter, and the result is the
same whatever the numbering of the triangles: a tile computes the faces the
whole survey has (see :func:`flip_edges`'s ``taint``).  Every round flips at
least the edge of largest improvement, and every flip raises the sorted vector
of triangle measures, so the rounds end; the tolerance keeps rounding noise
from flipping back and forth between equivalent diagonals.  Every score is
computed from the triangle's corners in one order, starting at the corner
that comes first by coordinates, so the same triangle scores the same bits in
every run.
"""

from __future__ import annotations

import llvmlite.ir as llvmir
import numba
import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic

from ._jit import _compiler, empty, full, index, larger, njit, njit_helper, smaller, zeros
from .delaunay import Triangulation, _flip, _next, _prev
from .predicates import lex_before, orient2d
from .quality import s1_kernel, s3_cubed_below, s3_cubed_kernel

__all__ = ["flip_edges", "FlipRounds", "FLIP_TOLERANCE"]

FLIP_TOLERANCE = 1e-9
"""Relative improvement a flip must bring to the score: alt > current * (1 + FLIP_TOLERANCE)."""

_S1 = 1
_S3 = 3
_FOUR_THIRDS = 4.0 / 3.0

_njit_inline = _compiler(helper=True, inline="always")
"""For the helpers the rounds call per edge: inlined where called (a call
passes every array as a structure: 15% of the time of the loop over every
edge went there)."""


@intrinsic
def _prefetch_intrinsic(typingctx, array, index):
    """Ask the processor to load the cache line of ``array[index]`` (a hint:
    no effect on any value, nor a fault on any index)."""
    if not isinstance(array, types.Array) or not isinstance(index, types.Integer):
        return None
    signature = types.void(array, types.intp)

    def codegen(context, builder, sig, args):
        arr = context.make_array(sig.args[0])(context, builder, args[0])
        where = cgutils.get_item_pointer(context, builder, sig.args[0], arr, [args[1]], wraparound=False)
        byte = llvmir.IntType(8).as_pointer()
        word = llvmir.IntType(32)
        hint = builder.module.declare_intrinsic(
            "llvm.prefetch", [byte], llvmir.FunctionType(llvmir.VoidType(), [byte, word, word, word]))
        # a read, kept in every cache level, of data
        builder.call(hint, [builder.bitcast(where, byte), word(0), word(3), word(1)])
        return context.get_dummy_value()

    return signature, codegen


def _no_prefetch(array, index) -> None:
    pass


#: the rounds visit the candidates and winners in the triangles' order, but
#: each one's other triangle, neighbours and corners lie anywhere in memory:
#: they are asked for a few iterations ahead (a third of the rounds' time
#: went to waiting for them)
_prefetch = _no_prefetch if numba.config.DISABLE_JIT else _prefetch_intrinsic

_AHEAD = 8
"""How many candidates or winners ahead the rounds ask for the memory they will read."""


@_njit_inline
def _prefetch_across(tri, he, q, touched, imp, e: int) -> None:
    """Ask for what the rounds read of the triangles across the other two edges of half-edge ``e``'s."""
    for g in (_next(e), _prev(e)):
        h = he[g]
        if h >= 0:
            _prefetch(tri, h)
            _prefetch(he, h)
            _prefetch(q, h // 3)
            _prefetch(touched, h // 3)
            _prefetch(imp, h)

_NO_SOURCE = -1
_OPEN_EDGE = -2
"""A triangle's doubt came from a hull edge of the point set that may not be one of the global set's."""


@njit_helper
def triangle_score(measure: int, ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """Score of the triangle with these corners: S1, or S3 cubed; computed from
    the corner that comes first by coordinates, so any rotation of the same
    triangle gives the same bits."""
    if lex_before(bx, by, ax, ay) and lex_before(bx, by, cx, cy):
        ax, ay, bx, by, cx, cy = bx, by, cx, cy, ax, ay
    elif lex_before(cx, cy, ax, ay) and lex_before(cx, cy, bx, by):
        ax, ay, bx, by, cx, cy = cx, cy, ax, ay, bx, by
    if measure == _S1:
        return s1_kernel(ax, ay, bx, by, cx, cy)
    return s3_cubed_kernel(ax, ay, bx, by, cx, cy)


@njit_helper
def _s1_below(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, limit: float) -> bool:
    """True when :func:`s1_kernel` of the triangle is surely below ``limit``
    (``limit >= 1e-3``), decided on raw coordinates without square roots or
    divisions; False means "compute it".

    S1 is at most 2/sqrt(3) times the sine of the smallest angle (the score of
    an angle is its sine, or below it past 90 degrees), the angle between the
    two longest sides: sin^2 = cross^2 * shortest^2 / (product of the squared
    sides).  That sine's rounding error, here and in the kernel, is a few
    units of 1e-16 whatever the shape: a cross product's error is relative to
    the product of the two sides it is computed from, at most that of the two
    longest.  The estimate must be below the limit by 1e-7 relative to count.
    Out-of-range magnitudes (products outside 1e-250..1e250) say False.
    """
    if limit < 1e-3:
        return False
    ux = bx - ax
    uy = by - ay
    vx = cx - ax
    vy = cy - ay
    wx = cx - bx
    wy = cy - by
    lu = ux * ux + uy * uy
    lv = vx * vx + vy * vy
    lw = wx * wx + wy * wy
    sides = lu * lv * lw
    if not 1e-250 < sides < 1e250:
        return False
    cross = ux * vy - uy * vx
    return _FOUR_THIRDS * cross * cross * smaller(lu, smaller(lv, lw)) < limit * limit * (1.0 - 1e-7) * sides


@njit_helper
def flippable(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float) -> bool:
    """True when the triangles (a, b, c) and (b, a, d) sharing the diagonal ab
    form a strictly convex quadrangle: a and b lie strictly on either side of cd."""
    return orient2d(cx, cy, dx, dy, ax, ay) < 0 and orient2d(cx, cy, dx, dy, bx, by) > 0


@njit_helper
def triangle_scores(measure: int, x, y, tri) -> np.ndarray:
    """Score of every triangle of a half-edge triangulation."""
    nt = tri.shape[0] // 3
    q = empty(nt)
    for t in range(nt):
        a = tri[3 * t]
        b = tri[3 * t + 1]
        c = tri[3 * t + 2]
        q[t] = triangle_score(measure, x[a], y[a], x[b], y[b], x[c], y[c])
    return q


@njit_helper
def edge_before(x, y, tri, e: int, g: int) -> bool:
    """Whether edge ``e`` comes before edge ``g`` by its endpoints' coordinates
    (the first endpoints compared, then the second): a tie-break of the geometry."""
    a = tri[e]
    b = tri[_next(e)]
    if lex_before(x[b], y[b], x[a], y[a]):
        a, b = b, a
    c = tri[g]
    d = tri[_next(g)]
    if lex_before(x[d], y[d], x[c], y[c]):
        c, d = d, c
    if a != c:
        return lex_before(x[a], y[a], x[c], y[c])
    return lex_before(x[b], y[b], x[d], y[d])


@_njit_inline
def _improvement(measure: int, tolerance: float, x, y, tri, he, q, e: int) -> float:
    """How much flipping the diagonal ``e`` raises the smaller score of its two
    triangles, or -1 when it may not flip."""
    f = he[e]
    t1 = e // 3
    t2 = f // 3
    current = smaller(q[t1], q[t2])
    a = index(tri[e])
    b = index(tri[_next(e)])
    c = index(tri[_prev(e)])
    d = index(tri[_prev(f)])
    # each corner's coordinates read once (scores and the convexity test share them)
    xa, ya, xb, yb, xc, yc, xd, yd = x[a], y[a], x[b], y[b], x[c], y[c], x[d], y[d]
    limit = current * (1.0 + tolerance)
    # most edges stay: a quick estimate of the score settles them without divisions
    if measure == _S3 and s3_cubed_below(xa, ya, xd, yd, xc, yc, limit):
        return -1.0
    if measure == _S1 and _s1_below(xa, ya, xd, yd, xc, yc, limit):
        return -1.0
    qa = triangle_score(measure, xa, ya, xd, yd, xc, yc)
    if qa <= limit:
        return -1.0
    if measure == _S3 and s3_cubed_below(xb, yb, xc, yc, xd, yd, limit):
        return -1.0
    if measure == _S1 and _s1_below(xb, yb, xc, yc, xd, yd, limit):
        return -1.0
    qb = triangle_score(measure, xb, yb, xc, yc, xd, yd)
    if qb <= limit:
        return -1.0
    if not flippable(xa, ya, xb, yb, xc, yc, xd, yd):
        return -1.0
    return smaller(qa, qb) - current


@njit_helper
def _beats(x, y, tri, imp, g: int, e: int) -> bool:
    """Whether edge ``g`` takes precedence over edge ``e`` in a round."""
    return imp[g] > imp[e] or (imp[g] == imp[e] and edge_before(x, y, tri, g, e))


@_njit_inline
def _wins(x, y, tri, he, imp, e: int) -> bool:
    """Whether the candidate ``e`` beats every other edge of its two triangles."""
    f = np.int64(he[e])
    for g in (_next(e), _prev(e), _next(f), _prev(f)):
        if imp[g] > 0.0 and _beats(x, y, tri, imp, g, e):
            return False
    return True


@njit_helper
def _unknown(he, taint, open_edge, g: int) -> bool:
    """Whether the far side of edge ``g`` may differ from the global mesh's:
    its other triangle is tainted, or it is a hull edge of this point set that
    need not be one of the global set."""
    h = he[g]
    if h < 0:
        return open_edge[g] != 0
    return taint[h // 3] != 0


@njit_helper
def _known_beaten(x, y, tri, he, imp, taint, open_edge, e: int) -> bool:
    """Whether an edge of ``e``'s triangles whose improvement is known beats it."""
    f = np.int64(he[e])
    for g in (_next(e), _prev(e), _next(f), _prev(f)):
        if imp[g] > 0.0 and not _unknown(he, taint, open_edge, g) and _beats(x, y, tri, imp, g, e):
            return True
    return False


@njit
def _centroid(ax, ay, bx, by, cx, cy, ox, oy) -> tuple[float, float]:
    """Centroid of three points, in the input frame (local + origin, which is
    exact), summed in lexicographic point order.

    The order of the sum is fixed by the points themselves, so every run that
    holds the same three points computes the same floats, whatever its vertex
    numbering or local origin: tiles decide ownership of a shared triangle
    identically.
    """
    if lex_before(bx, by, ax, ay):
        ax, ay, bx, by = bx, by, ax, ay
    if lex_before(cx, cy, bx, by):
        bx, by, cx, cy = cx, cy, bx, by
        if lex_before(bx, by, ax, ay):
            ax, ay, bx, by = bx, by, ax, ay
    return ((ax + ox) + (bx + ox) + (cx + ox)) / 3.0, ((ay + oy) + (by + oy) + (cy + oy)) / 3.0


@njit_helper
def _outside_edge(px, py, qx, qy, x_lo, y_lo, x_hi, y_hi, slack) -> bool:
    """True when the whole box lies clearly right of the directed line p -> q."""
    dx = qx - px
    dy = qy - py
    tol = slack * (abs(dx) + abs(dy))
    for cx, cy in ((x_lo, y_lo), (x_hi, y_lo), (x_hi, y_hi), (x_lo, y_hi)):
        if dx * (cy - py) - dy * (cx - px) >= -tol:
            return False
    return True


@njit
def _meets_box(ax, ay, bx, by, cx, cy, x_lo, y_lo, x_hi, y_hi, slack) -> bool:
    """Whether the counter-clockwise triangle abc meets the closed box (conservative:
    near misses within ``slack`` count as meeting).  Infinite box sides are fine."""
    tx_lo = smaller(ax, smaller(bx, cx))
    tx_hi = larger(ax, larger(bx, cx))
    ty_lo = smaller(ay, smaller(by, cy))
    ty_hi = larger(ay, larger(by, cy))
    if tx_lo >= x_lo and tx_hi <= x_hi and ty_lo >= y_lo and ty_hi <= y_hi:
        return True  # inside the box: most triangles of a window
    x_lo = larger(x_lo, tx_lo - slack)
    x_hi = smaller(x_hi, tx_hi + slack)
    y_lo = larger(y_lo, ty_lo - slack)
    y_hi = smaller(y_hi, ty_hi + slack)
    if x_lo > x_hi or y_lo > y_hi:
        return False
    # the box is now finite: separated only when it lies right of an edge
    return not (
        _outside_edge(ax, ay, bx, by, x_lo, y_lo, x_hi, y_hi, slack)
        or _outside_edge(bx, by, cx, cy, x_lo, y_lo, x_hi, y_hi, slack)
        or _outside_edge(cx, cy, ax, ay, x_lo, y_lo, x_hi, y_hi, slack)
    )


@njit_helper
def _block_of(v: float, lo: float, size: float, n: int) -> int:
    """The block ``floor((v - lo) / size)`` of ``n``, clamped to the first and the last (blocks of no
    width: the first up to ``lo``, the last beyond it)."""
    if not size > 0.0:
        return 0 if v <= lo else n - 1
    i = (v - lo) / size
    if i <= 0.0:
        return 0
    if i >= n - 1:
        return n - 1
    return int(i)


@njit_helper
def _mark_blocks(blocks, k: int, x, y, a, b, c, d, x_lo: float, y_lo: float, block_w: float, block_h: float,
                 slack: float) -> None:
    """Round ``k`` in every block that the bounding box of corners ``a, b, c, d`` (grown by ``slack``) meets."""
    n = blocks.shape[0]
    i0 = _block_of(smaller(smaller(x[a], x[b]), smaller(x[c], x[d])) - slack, x_lo, block_w, n)
    i1 = _block_of(larger(larger(x[a], x[b]), larger(x[c], x[d])) + slack, x_lo, block_w, n)
    j0 = _block_of(smaller(smaller(y[a], y[b]), smaller(y[c], y[d])) - slack, y_lo, block_h, n)
    j1 = _block_of(larger(larger(y[a], y[b]), larger(y[c], y[d])) + slack, y_lo, block_h, n)
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            blocks[j, i] = k


@njit_helper
def _meets_window(x, y, tri, t: int, ox: float, oy: float, window, slack: float) -> bool:
    """Whether triangle ``t`` meets the closed window, or nearly (see :func:`_meets_box`)."""
    a = tri[3 * t]
    b = tri[3 * t + 1]
    c = tri[3 * t + 2]
    return _meets_box(x[a], y[a], x[b], y[b], x[c], y[c], window[0] - ox, window[1] - oy, window[2] - ox,
                      window[3] - oy, slack)


@njit
def _flip_rounds_kernel(x, y, tri, he, active, measure: int, tolerance: float, taint, source, open_edge,
                        assume: int, ox: float, oy: float, window, blocks, block_box):
    """The rounds; returns (flips, rounds with a flip, last round whose flips
    touch the window, per triangle slot: whether it ever held a triangle that
    meets the window).  With a window, ``blocks`` (n x n, zeros) is set to the
    last round whose flips touch the window in each block of ``block_box``
    (the window's part over the points, local frame): a flip counts in every
    block that the bounding box of its two triangles meets (a box beyond
    ``block_box``, in the blocks of its edge next to it).

    Every triangle of the global mesh whose centroid lies in the window lies
    on a triangle of this set that meets the window: when those are never
    tainted, they are the global mesh's, and so are the window's faces.

    With ``taint`` (one flag per triangle; empty: not tracked), the flags
    grow each round over the triangles whose state may differ from the global
    mesh's, as explained in :func:`flip_edges`; ``source`` says for each
    flagged slot where its doubt came from: the slot of a triangle flagged at
    the start, or :data:`_OPEN_EDGE`.

    Only the candidates (edges of positive improvement) are visited each
    round, and a flip rescores the edges of its two new triangles right away,
    while they are in cache, but for an edge whose other triangle a later
    winner of the round flips: that one rescores it.  The edges rescored in a
    round join the candidates in the order they were first reached, so the
    rounds visit them (and spread the doubt) in the same order whatever the
    rescoring's timing.
    """
    nt = tri.shape[0] // 3
    m = tri.shape[0]
    track = taint.shape[0] == nt and nt > 0
    windowed = window.shape[0] == 4
    slack = 1e-9 * (abs(ox) + abs(oy) + 1.0)
    # each triangle's corners read once, for its score and whether it meets the window
    q = empty(nt)
    zone = zeros(nt, dtype=np.uint8)
    if windowed:
        w_x_lo = window[0] - ox
        w_y_lo = window[1] - oy
        w_x_hi = window[2] - ox
        w_y_hi = window[3] - oy
    else:
        w_x_lo = w_y_lo = w_x_hi = w_y_hi = 0.0
    n_blocks = blocks.shape[0] if windowed else 0
    block_w = (block_box[2] - block_box[0]) / n_blocks if n_blocks else 1.0
    block_h = (block_box[3] - block_box[1]) / n_blocks if n_blocks else 1.0
    for t in range(nt):
        a = index(tri[3 * t])
        b = index(tri[3 * t + 1])
        c = index(tri[3 * t + 2])
        ax, ay, bx, by, cx, cy = x[a], y[a], x[b], y[b], x[c], y[c]
        q[t] = triangle_score(measure, ax, ay, bx, by, cx, cy)
        if windowed and _meets_box(ax, ay, bx, by, cx, cy, w_x_lo, w_y_lo, w_x_hi, w_y_hi, slack):
            zone[t] = 1
    # per half-edge; an edge's two halves hold the same value, which is -1 (no flip) or positive
    imp = full(m, -1.0)
    cand = empty(m // 2 + 1, dtype=np.int32)
    nc = 0
    for e in range(m):
        f = he[e]
        if f > e and active[e // 3] and active[f // 3]:
            v = _improvement(measure, tolerance, x, y, tri, he, q, e)
            if v > 0.0:
                imp[e] = v
                imp[f] = v
                cand[nc] = e
                nc += 1
    # per triangle: k once round k flipped it; before, -(4 k + j) when its edge j is a winner of round k
    touched = zeros(nt, dtype=np.int32)
    marked = zeros(nt if track else 0, dtype=np.int32)  # the round a triangle was tainted
    winners = empty(nt // 2 + 1, dtype=np.int32)
    # the half-edges rescored in a round, in the order first reached: the next round's candidates after
    # those of this round that stayed
    reached = empty(m // 2 + 1, dtype=np.int32)
    nr = 0
    frontier = empty(nt if track else 0, dtype=np.int32)
    nf = 0
    fresh = empty(nt if track else 0, dtype=np.int32)
    if track:
        for t in range(nt):
            if taint[t]:
                frontier[nf] = t
                nf += 1
    flips = 0
    rounds = 0
    last_window = 0
    k = 0
    while True:
        k += 1
        # the candidates: those of the last round whose triangles it did not flip (it left the others in
        # the list), then those its flips rescored to a positive improvement; whether each wins
        nw = 0
        kept = 0
        for i in range(nc + nr):
            if i + 2 * _AHEAD < nc:
                e = cand[i + 2 * _AHEAD]
                _prefetch(he, e)
                _prefetch(imp, e)
            if i + _AHEAD < nc:
                f = he[cand[i + _AHEAD]]
                _prefetch(imp, f)
                _prefetch(touched, f // 3)
            if i < nc:
                e = cand[i]
                f = he[e]
                if k > 1 and (touched[e // 3] == k - 1 or (f >= 0 and touched[f // 3] == k - 1)):
                    continue
            else:
                g = reached[i - nc]
                if imp[g] <= 0.0:
                    continue
                h = he[g]
                e = g if g < h else h
            cand[kept] = e
            kept += 1
            if _wins(x, y, tri, he, imp, e):
                f = he[e]
                winners[nw] = e
                nw += 1
                touched[e // 3] = -(4 * k + e % 3)
                touched[f // 3] = -(4 * k + f % 3)
        nc = kept
        nr = 0
        if nc == 0 and not (track and k <= assume and (nf > 0 or k == 1)):
            break
        if track:
            nn = 0
            if k <= assume:
                # the global mesh may flip any edge with a tainted side this round
                for i in range(nf if k > 1 else nt):
                    t = frontier[i] if k > 1 else i
                    if k == 1 and not taint[t]:
                        # first round: triangles on a hull edge that may be no hull edge of the global set
                        if (open_edge[3 * t] or open_edge[3 * t + 1] or open_edge[3 * t + 2]) and marked[t] != k:
                            marked[t] = k
                            source[t] = _OPEN_EDGE
                            fresh[nn] = t
                            nn += 1
                        continue
                    for j in range(3):
                        h = he[3 * t + j]
                        if h >= 0 and not taint[h // 3] and marked[h // 3] != k:
                            marked[h // 3] = k
                            source[h // 3] = source[t]
                            fresh[nn] = h // 3
                            nn += 1
                # one ring more across the candidates of those triangles whose decision a tainted edge may change
                spread = nn
                for i in range(spread):
                    t = fresh[i]
                    for j in range(3):
                        e = 3 * t + j
                        f = he[e]
                        if f < 0 or taint[f // 3] or marked[f // 3] == k or imp[e] <= 0.0:
                            continue
                        if touched[t] != -(4 * k + j) and _known_beaten(x, y, tri, he, imp, taint, open_edge, e):
                            continue
                        marked[f // 3] = k
                        source[f // 3] = source[t]
                        fresh[nn] = f // 3
                        nn += 1
            # a flip whose decision read a tainted triangle may differ from the global mesh's
            for i in range(nw):
                e = np.int64(winners[i])
                f = np.int64(he[e])
                t1 = e // 3
                t2 = f // 3
                cause = source[t1] if taint[t1] else (source[t2] if taint[t2] else _NO_SOURCE)
                for g in (_next(e), _prev(e), _next(f), _prev(f)):
                    if cause == _NO_SOURCE and _unknown(he, taint, open_edge, g):
                        cause = _OPEN_EDGE if he[g] < 0 else source[he[g] // 3]
                if cause != _NO_SOURCE:
                    for t in (t1, t2):
                        if not taint[t] and marked[t] != k:
                            marked[t] = k
                            source[t] = cause
                            fresh[nn] = t
                            nn += 1
            for i in range(nn):
                taint[fresh[i]] = 1
                frontier[i] = fresh[i]
            nf = nn
        if nw == 0:
            continue
        rounds = k
        for i in range(nw):
            # what the flip and the rescoring read, asked for ahead: the winner's triangles, then its other
            # triangle's, the neighbours and the corners
            if i + 2 * _AHEAD < nw:
                e = winners[i + 2 * _AHEAD]
                _prefetch(he, e)
                _prefetch(tri, e)
            if i + _AHEAD < nw:
                e = np.int64(winners[i + _AHEAD])
                f = np.int64(he[e])
                _prefetch(tri, f)
                _prefetch(he, f)
                _prefetch(q, f // 3)
                _prefetch(q, e // 3)
                _prefetch(touched, f // 3)
                for g in (e, _next(e), _prev(e)):
                    _prefetch(x, tri[g])
                    _prefetch(y, tri[g])
                _prefetch_across(tri, he, q, touched, imp, e)
            if i + _AHEAD // 2 < nw:
                e = np.int64(winners[i + _AHEAD // 2])
                f = np.int64(he[e])
                d = tri[_prev(f)]
                _prefetch(x, d)
                _prefetch(y, d)
                _prefetch_across(tri, he, q, touched, imp, f)
                for g in (_next(e), _prev(e)):
                    h = he[g]
                    if h >= 0:
                        d = tri[_prev(h)]
                        _prefetch(x, d)
                        _prefetch(y, d)
            e = np.int64(winners[i])
            f = np.int64(he[e])
            t1 = e // 3
            t2 = f // 3
            # a slot that ever held a triangle of the window (a few flips counted too many: only later rounds asked of the rest)
            near = windowed and (zone[t1] != 0 or zone[t2] != 0)
            a = index(tri[e])
            b = index(tri[_next(e)])
            c = index(tri[_prev(e)])
            d = index(tri[_prev(f)])
            _flip(tri, he, e)
            q[t1] = triangle_score(measure, x[a], y[a], x[d], y[d], x[c], y[c])
            q[t2] = triangle_score(measure, x[b], y[b], x[c], y[c], x[d], y[d])
            touched[t1] = k
            touched[t2] = k
            flips += 1
            if windowed:
                for t in (t1, t2):
                    if _meets_window(x, y, tri, t, ox, oy, window, slack):
                        zone[t] = 1
                        near = True
                if near:
                    last_window = k
                    if n_blocks:
                        _mark_blocks(blocks, k, x, y, a, b, c, d, block_box[0], block_box[1], block_w, block_h, slack)
            # the new diagonal (next(e), its twin next(f)) would flip back to the two triangles it replaced,
            # which score below the new ones: it is no candidate
            ne = _next(e)
            nf2 = _next(f)
            imp[ne] = -1.0
            imp[nf2] = -1.0
            # the other edges of the new triangles: rescored now when their far triangle is final for the
            # round; when a later winner of the round flips it, by that one (the edge is reached here first)
            for t in (t1, t2):
                for j in range(3):
                    g = 3 * t + j
                    if g == ne or g == nf2:
                        continue
                    h = he[g]
                    if h < 0 or not (active[g // 3] and active[h // 3]):
                        imp[g] = -1.0
                        continue
                    far = touched[h // 3]
                    if far != k:  # else an earlier winner flipped the far triangle, reached the edge and left it
                        reached[nr] = g
                        nr += 1
                        if -4 * k - 2 <= far <= -4 * k:
                            continue
                    cg = g if g < h else h
                    v = _improvement(measure, tolerance, x, y, tri, he, q, cg)
                    imp[g] = v
                    imp[h] = v
    return flips, rounds, last_window, zone, q


class FlipRounds:
    """What :func:`flip_edges` did: ``flips`` made in ``rounds`` rounds; with a
    window, ``last_window_round`` (the last round whose flips touched a
    triangle meeting the window, 0 for none), ``window_blocks`` (the same per
    block of ``blocks_box``, the window's part over the points, cut into
    :data:`WINDOW_BLOCKS` x :data:`WINDOW_BLOCKS`, row 0 at its lowest y; a
    flip beyond the box counts in the blocks of its edge) and ``zone`` (per triangle slot: it held such a
    triangle at some round); ``scores``, every triangle's score after the flips
    (:func:`triangle_scores`, the same bits)."""

    __slots__ = ("flips", "rounds", "last_window_round", "window_blocks", "blocks_box", "zone", "scores")

    def __init__(self, flips: int, rounds: int, last_window_round: int, zone: np.ndarray,
                 scores: np.ndarray, window_blocks: np.ndarray | None = None,
                 blocks_box: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)) -> None:
        self.flips = flips
        self.rounds = rounds
        self.last_window_round = last_window_round
        self.window_blocks = np.zeros((0, 0), dtype=np.int32) if window_blocks is None else window_blocks
        self.blocks_box = blocks_box
        self.zone = zone
        self.scores = scores


WINDOW_BLOCKS = 16
"""The blocks per side of a window in which :func:`flip_edges` tells the last
round of flips apart (:attr:`FlipRounds.window_blocks`): a tiled run asks
how long the survey flipped inside the boxes a tile held, not in the whole
windows they meet."""


def flip_edges(
    triangulation: Triangulation,
    measure: str,
    active: np.ndarray | None = None,
    tolerance: float = FLIP_TOLERANCE,
    *,
    taint: np.ndarray | None = None,
    source: np.ndarray | None = None,
    open_edges: np.ndarray | None = None,
    assume_rounds: int = 0,
    window: tuple[float, float, float, float] | None = None,
) -> FlipRounds:
    """Flip diagonals in place, in rounds, until no flip improves ``measure`` ("s1" or "s3").

    With ``active`` (one flag per triangle), only diagonals between two active
    triangles are considered, so the region the active triangles cover stays
    the same.  The result does not depend on the triangles' numbering.

    ``taint`` (one flag per triangle, updated in place) serves a point set
    that is part of a larger one (a tile): it marks the triangles that may
    not be the larger set's (their circumcircle reaches points not held).
    ``open_edges`` (per half-edge) marks the hull edges of this set that may
    not be hull edges of the larger set.  Each round, the flags spread to
    every triangle whose state after the round may differ from the larger
    set's: the far triangle of an edge whose flip is decided from a tainted
    triangle, and for the first ``assume_rounds`` rounds, every neighbour of a
    tainted triangle (the larger set may flip the edge between them in any
    round it still flips near here).  Past ``assume_rounds``, only this set's
    own flips spread them: when the larger set makes no flip near here after
    that round, an untainted triangle is the larger set's final one.
    ``source`` (per triangle, updated in place; by default each flagged
    triangle's own slot) tells where each flag came from.
    """
    code = {"s1": _S1, "s3": _S3}[measure]
    nt = triangulation.triangles.shape[0] // 3
    if active is None:
        active = np.ones(nt, dtype=np.uint8)
    flags = np.zeros(0, dtype=np.uint8) if taint is None else taint
    if source is None:
        source = np.where(flags != 0, np.arange(flags.shape[0]), _NO_SOURCE).astype(np.int64)
    opened = np.zeros(triangulation.triangles.shape[0], dtype=np.uint8) if open_edges is None else open_edges
    o = triangulation.origin
    blocks = np.zeros((WINDOW_BLOCKS, WINDOW_BLOCKS) if window is not None else (0, 0), dtype=np.int32)
    # the blocks cut the window where it meets the points (an outer tile's window is infinite)
    block_box = np.zeros(4)
    if window is not None and triangulation.x.shape[0]:
        w = np.asarray(window, dtype=np.float64) - np.array([o[0], o[1], o[0], o[1]])
        block_box = np.array([max(w[0], 0.0), max(w[1], 0.0), min(w[2], float(triangulation.x.max())),
                              min(w[3], float(triangulation.y.max()))])
        block_box[2:] = np.maximum(block_box[2:], block_box[:2])
    flips, rounds, last, zone, scores = _flip_rounds_kernel(
        triangulation.x,
        triangulation.y,
        triangulation.triangles,
        triangulation.halfedges,
        active,
        code,
        float(tolerance),
        flags,
        source,
        opened,
        int(assume_rounds),
        float(o[0]),
        float(o[1]),
        np.zeros(0) if window is None else np.asarray(window, dtype=np.float64),
        blocks,
        block_box,
    )
    box = tuple(float(v) for v in block_box + np.array([o[0], o[1], o[0], o[1]]))
    return FlipRounds(int(flips), int(rounds), int(last), zone, scores, blocks, box)
