"""What a window piece's faces depend on, and whether it held it (the tile protocol).

A tiled run meshes each tile's points (its window plus a buffer) and keeps the
faces its window owns.  The Delaunay triangles are the global set's where their
circumcircles hold no point the tile lacks; the flips and merges that follow
read the triangles around them, round after round.  :func:`initial_taint`
flags the triangles whose circles reach beyond what the tile holds,
:func:`open_hull_edges` the hull edges of the tile's points that may not be
hull edges of the survey; the flips spread the flags (see
:func:`meshcore.flip.flip_edges`), and a piece is certified when no face it
owns, nor anything those faces' flips and merges read, was ever flagged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, njit
from .delaunay import Triangulation, circumcenter_terms
from .predicates import cross_rounded

__all__ = ["KnownRegion", "WindowCertificate", "initial_taint", "open_hull_edges", "circle_in_input_frame", "safe_circle"]

_U = 2.0**-53
"""The unit roundoff of float64."""

_EVERYWHERE = (-math.inf, -math.inf, math.inf, math.inf)


@dataclass(frozen=True)
class KnownRegion:
    """Where a point set holds every point of the global set it is part of.

    ``box``: a box it holds whole (sides may be infinite).  ``hull``: the
    global set's convex hull, counter-clockwise ``(h, 2)``, or None when
    unknown.  Subclasses may vouch for more than the box in :meth:`covers`.
    """

    box: tuple[float, float, float, float] = _EVERYWHERE
    hull: NDArray[np.float64] | None = field(default=None, compare=False)

    def covers(self, circles: NDArray[np.float64]) -> NDArray[np.bool_]:
        """For each closed circle ``(x, y, r)`` not inside :attr:`box`: whether
        every global point inside it is held (here: never)."""
        return np.zeros(circles.shape[0], dtype=bool)


@dataclass(frozen=True)
class WindowCertificate:
    """Whether a window piece's faces are the global mesh's.

    ``certified`` holds if the global mesh makes no flip near the window after
    round ``assumed_rounds``; ``last_flip_round`` is the last round whose flips
    touched the window's triangles here (0: none), ``rounds`` the rounds the
    piece's point set flipped in.  A tiled run checks that no tile near this
    one flipped after ``assumed_rounds``.  When not certified, ``blocking``
    and ``open_edges`` say what to hold more of.
    """

    certified: bool
    last_flip_round: int
    assumed_rounds: int
    rounds: int
    blocking: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)), compare=False)
    """Where the doubt that reached the window came from: the circles ``(x, y, r)`` of
    triangles whose points the tile may lack (their points, once held, may clear it)."""
    open_edges: bool = False
    """Whether doubt that reached the window came from a hull edge of the tile's points
    that may not be the survey's (holding a wider box clears it)."""


@njit
def safe_circle(ax, ay, bx, by, cx, cy) -> tuple[float, float, float]:
    """Circumcentre of ``a, b, c`` relative to ``a``, and a radius whose disk
    around that centre holds the exact circumdisk (a forward error bound of
    the floating-point evaluation; infinite when the triangle is too thin to
    bound it).

    A fixed relative margin will not do: the slivers along a straight survey
    edge have circles of thousands of kilometres, where 1e-9 of the radius is
    centimetres, which is the spacing of the points themselves.  Their cross
    product is evaluated exactly (then rounded), so the margin stays ulps of
    the radius however thin the triangle.
    """
    dx, dy, ex, ey, bl, cl, d = circumcenter_terms(ax, ay, bx, by, cx, cy)
    err_d = 16.0 * _U * (abs(dx * ey) + abs(dy * ex))
    if not abs(d) > 1e12 * err_d:
        # a sliver: its cross product has lost most of its digits, and its
        # circle's centre would be known only to within a fraction of its
        # radius (kilometres on the circles along a straight survey edge,
        # which then reach the whole survey); exactly, it is known to ulps
        d, err_d = cross_rounded(ax, ay, bx, by, cx, cy)
        if not abs(d) > 2.0 * err_d:
            return 0.0, 0.0, math.inf
    nx = ey * bl - dy * cl
    ny = dx * cl - ex * bl
    err_nx = 16.0 * _U * (abs(ey) * bl + abs(dy) * cl)
    err_ny = 16.0 * _U * (abs(dx) * cl + abs(ex) * bl)
    ux = nx * 0.5 / d
    uy = ny * 0.5 / d
    # |N/d - N*/d*| <= (err_N + |N| err_d / |d|) / (|d| - err_d), halved, plus the division's rounding
    lo = abs(d) - err_d
    eu = 0.5 * (err_nx + abs(nx) * err_d / abs(d)) / lo + 2.0 * _U * abs(ux)
    eu += 0.5 * (err_ny + abs(ny) * err_d / abs(d)) / lo + 2.0 * _U * abs(uy)
    # the exact disk lies within |u - u*| + r* <= |u| + 2|u - u*| of the computed centre
    r = math.sqrt(ux * ux + uy * uy) * (1.0 + 4.0 * _U) + 2.0 * eu
    return ux, uy, r


@njit
def circle_in_input_frame(x, y, a: int, b: int, c: int, ox: float, oy: float) -> tuple[float, float, float]:
    """:func:`safe_circle` of the triangle ``a, b, c`` of local coordinates
    ``x, y``, its centre in the input frame (plus ``ox, oy``)."""
    ux, uy, r = safe_circle(x[a], y[a], x[b], y[b], x[c], y[c])
    ux += x[a] + ox
    uy += y[a] + oy
    # the sums' rounding moves the centre by at most an ulp of each coordinate
    r += _U * 4.0 * (abs(ux) + abs(uy))
    return ux, uy, r


@njit
def _circles_leaving(x, y, tri, ox, oy, x_lo, y_lo, x_hi, y_hi):
    """The triangles whose circumcircle (input frame) is not inside the box, and the circles."""
    nt = tri.shape[0] // 3
    rows = empty(nt, dtype=np.int64)
    out = empty((nt, 3))
    n = 0
    for t in range(nt):
        a = tri[3 * t]
        b = tri[3 * t + 1]
        c = tri[3 * t + 2]
        ux, uy, r = circle_in_input_frame(x, y, a, b, c, ox, oy)
        if ux - r >= x_lo and ux + r <= x_hi and uy - r >= y_lo and uy + r <= y_hi:
            continue
        rows[n] = t
        out[n, 0] = ux
        out[n, 1] = uy
        out[n, 2] = r
        n += 1
    return rows[:n].copy(), out[:n].copy()


def initial_taint(triangulation: Triangulation, known: KnownRegion) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
    """1 for the Delaunay triangles that may not be the global set's: their
    circumcircle leaves ``known.box`` and ``known`` does not vouch for it; and
    those circles ``(x, y, r)``, one row per triangle (NaN for the others)."""
    t = triangulation
    nt = t.triangles.shape[0] // 3
    taint = np.zeros(nt, dtype=np.uint8)
    circle_of = np.full((nt, 3), np.nan)
    if known.box == _EVERYWHERE or nt == 0:
        return taint, circle_of
    rows, circles = _circles_leaving(t.x, t.y, t.triangles, float(t.origin[0]), float(t.origin[1]), *known.box)
    if rows.size:
        vouched = np.asarray(known.covers(circles), dtype=bool)
        taint[rows[~vouched]] = 1
        circle_of[rows[~vouched]] = circles[~vouched]
    return taint, circle_of


def open_hull_edges(triangulation: Triangulation, known: KnownRegion) -> NDArray[np.uint8]:
    """Per half-edge: 1 for the hull edges of the point set that may not be
    hull edges of the global set (whose hull ``known.hull`` gives; None:
    unknown, every hull edge but where ``known`` holds everything)."""
    t = triangulation
    out = np.zeros(t.triangles.shape[0], dtype=np.uint8)
    hull_edges = np.flatnonzero(t.halfedges < 0)
    if hull_edges.size == 0 or known.box == _EVERYWHERE:
        return out
    if known.hull is None or known.hull.shape[0] < 3:
        out[hull_edges] = 1
        return out
    index = {(float(px), float(py)): i for i, (px, py) in enumerate(np.asarray(known.hull)[:, :2].tolist())}
    h = len(index)
    nxt = np.where(hull_edges % 3 == 2, hull_edges - 2, hull_edges + 1)
    a, b = t.triangles[hull_edges], t.triangles[nxt]
    ox, oy = float(t.origin[0]), float(t.origin[1])
    # the local shift is exact: these are the input coordinates
    ax, ay = (t.x[a] + ox).tolist(), (t.y[a] + oy).tolist()
    bx, by = (t.x[b] + ox).tolist(), (t.y[b] + oy).tolist()
    for k, e in enumerate(hull_edges.tolist()):
        i = index.get((ax[k], ay[k]))
        j = index.get((bx[k], by[k]))
        if i is None or j is None or j != (i + 1) % h:
            out[e] = 1
    return out
