"""Edge flipping to local optimality under a triangle quality measure (paper, section 2).

A diagonal of a strictly convex quadrangle is flipped when the smaller measure
of the two alternative triangles exceeds the smaller measure of the current two
by more than a relative tolerance.  Kernels compare *scores*, a monotone
transform of the measure that needs no root: S1 itself, and S3 cubed.  Every flip raises the sorted vector of
triangle measures, so the procedure terminates; the tolerance keeps rounding
noise from flipping back and forth between equivalent diagonals.
"""

from __future__ import annotations

import numpy as np

from ._jit import empty, njit, njit_helper, smaller, zeros
from .delaunay import Triangulation, _flip, _next, _prev
from .predicates import orient2d
from .quality import s1_kernel, s3_cubed_below, s3_cubed_kernel

__all__ = ["flip_edges", "FLIP_TOLERANCE"]

FLIP_TOLERANCE = 1e-9
"""Relative improvement a flip must bring to the score: alt > current * (1 + FLIP_TOLERANCE)."""

_S1 = 1
_S3 = 3


@njit_helper
def triangle_score(measure: int, ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """Score of the triangle with these corners: S1, or S3 cubed."""
    if measure == _S1:
        return s1_kernel(ax, ay, bx, by, cx, cy)
    return s3_cubed_kernel(ax, ay, bx, by, cx, cy)


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


@njit
def _flip_kernel(x, y, tri, he, active, measure: int, tolerance: float) -> int:
    q = triangle_scores(measure, x, y, tri)
    m = tri.shape[0]
    queued = zeros(m, dtype=np.uint8)
    stack = empty(m, dtype=np.int32)
    n = 0
    for e in range(m - 1, -1, -1):  # the stack pops the first edge first
        if he[e] > e and active[e // 3] and active[he[e] // 3]:
            stack[n] = e
            n += 1
            queued[e] = 1
    flips = 0
    while n > 0:
        n -= 1
        e = np.int64(stack[n])
        queued[e] = 0
        f = he[e]
        # a queued slot may hold another edge by now (flips around it move
        # edges between slots), one whose twin lies outside the active region
        if f < 0 or not (active[e // 3] and active[f // 3]):
            continue
        t1 = e // 3
        t2 = f // 3
        current = smaller(q[t1], q[t2])
        a = tri[e]
        b = tri[_next(e)]
        c = tri[_prev(e)]
        d = tri[_prev(f)]
        # each corner's coordinates read once (scores and the convexity test share them)
        xa, ya, xb, yb, xc, yc, xd, yd = x[a], y[a], x[b], y[b], x[c], y[c], x[d], y[d]
        limit = current * (1.0 + tolerance)
        # most edges stay: a quick estimate of S3 settles them without divisions
        if measure == _S3 and s3_cubed_below(xa, ya, xd, yd, xc, yc, limit):
            continue
        qa = triangle_score(measure, xa, ya, xd, yd, xc, yc)
        if qa <= limit:
            continue
        if measure == _S3 and s3_cubed_below(xb, yb, xc, yc, xd, yd, limit):
            continue
        qb = triangle_score(measure, xb, yb, xc, yc, xd, yd)
        if qb <= limit:
            continue
        if not flippable(xa, ya, xb, yb, xc, yc, xd, yd):
            continue
        _flip(tri, he, e)
        q[t1] = qa
        q[t2] = qb
        flips += 1
        for j in range(4):
            g = e if j == 0 else (_prev(e) if j == 1 else (f if j == 2 else _prev(f)))
            h = he[g]
            if h < 0 or not (active[g // 3] and active[h // 3]):
                continue
            k = smaller(g, h)
            if queued[k] == 0:
                queued[k] = 1
                stack[n] = k
                n += 1
    return flips


def flip_edges(
    triangulation: Triangulation,
    measure: str,
    active: np.ndarray | None = None,
    tolerance: float = FLIP_TOLERANCE,
) -> int:
    """Flip diagonals in place until no flip improves ``measure`` ("s1" or "s3").

    With ``active`` (one flag per triangle), only diagonals between two active
    triangles are considered, so the region the active triangles cover stays
    the same.  Edges are visited in the triangulation's own order, so two
    triangulations numbered in the same geometric order (see
    :func:`meshcore._order.geometric_order`) flip the edges they share the
    same way.  Returns the number of flips made.
    """
    code = {"s1": _S1, "s3": _S3}[measure]
    if active is None:
        active = np.ones(triangulation.triangles.shape[0] // 3, dtype=np.uint8)
    return int(
        _flip_kernel(
            triangulation.x,
            triangulation.y,
            triangulation.triangles,
            triangulation.halfedges,
            active,
            code,
            float(tolerance),
        )
    )
