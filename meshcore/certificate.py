"""What a window piece's faces depend on, and whether it held it (the tile protocol).

A tiled run meshes each tile's points (its window plus a buffer) and keeps the
faces its window owns.  The Delaunay triangles are the global set's where their
circumcircles hold no point the tile lacks; the flips and merges that follow
read the triangles around them, round after round.  :func:`initial_doubt`
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
from numpy.typing import ArrayLike, NDArray

from ._jit import empty, larger, njit, njit_helper, smaller
from .delaunay import Triangulation, circumcenter_terms
from .predicates import cross_rounded

__all__ = ["KnownRegion", "WindowCertificate", "circles_leaving", "disk_box_in", "lens_boxes", "inner_box", "initial_doubt", "open_hull_edges", "circle_in_input_frame", "safe_circle"]

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
    flip_blocks: NDArray[np.int32] = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int32), compare=False)
    """``last_flip_round`` per block of ``flip_blocks_box`` (the window's part
    over the points) cut into :data:`meshcore.flip.WINDOW_BLOCKS` blocks a side,
    row 0 at its lowest y; a flip beyond the box counts in the blocks of its
    edge.  A tile whose held boxes meet only blocks that stopped flipping by
    its assumed round needs no later round of this one."""
    flip_blocks_box: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


def last_flip_round_in(flip_blocks: ArrayLike, flip_blocks_box: tuple[float, float, float, float], boxes) -> int:
    """The last round whose flips touched a window inside the closed ``boxes``,
    from its certificate's :attr:`~WindowCertificate.flip_blocks` and
    :attr:`~WindowCertificate.flip_blocks_box`: the largest of its blocks that
    meet one (each grown by 1e-8 of its coordinates, for rounding; the edge
    blocks stand for everything beyond the box, as the flips mark them)."""
    blocks = np.asarray(flip_blocks, dtype=np.int64)
    n_rows, n_cols = blocks.shape
    x0, y0, x1, y1 = flip_blocks_box
    xs = x0 + (x1 - x0) * np.arange(n_cols + 1) / n_cols
    ys = y0 + (y1 - y0) * np.arange(n_rows + 1) / n_rows
    slack = 1e-8 * (abs(x0) + abs(y0) + 1.0)
    xs[0], xs[-1], ys[0], ys[-1] = -np.inf, np.inf, -np.inf, np.inf
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    # each box meets a run of columns and a run of rows: the first whose far
    # side reaches its near side, to the last whose near side its far side reaches
    c0 = np.searchsorted(xs[1:], b[:, 0] - slack, side="left")
    c1 = np.searchsorted(xs[:-1], b[:, 2] + slack, side="right") - 1
    r0 = np.searchsorted(ys[1:], b[:, 1] - slack, side="left")
    r1 = np.searchsorted(ys[:-1], b[:, 3] + slack, side="right") - 1
    meet = (c0 <= c1) & (r0 <= r1)
    if not meet.any():
        return 0
    c0, c1, r0, r1 = c0[meet], c1[meet] + 1, r0[meet], r1[meet] + 1
    # the blocks any box meets: a summed-area mark of their rectangles
    marks = np.zeros((n_rows + 1, n_cols + 1), dtype=np.int64)
    np.add.at(marks, (r0, c0), 1)
    np.add.at(marks, (r0, c1), -1)
    np.add.at(marks, (r1, c0), -1)
    np.add.at(marks, (r1, c1), 1)
    met = marks.cumsum(axis=0).cumsum(axis=1)[:n_rows, :n_cols] > 0
    return max(0, int(blocks[met].max()))


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


@njit_helper
def _surely_inside(ax, ay, bx, by, cx, cy, x_lo, y_lo, x_hi, y_hi, slack) -> bool:
    """True when :func:`circle_in_input_frame` of the triangle (local
    coordinates) is inside the box (``x_lo - ox`` ...: the box in the local
    frame; ``slack``: more than the rounding of that shift and of the
    circle's to the input frame), decided without divisions or roots; False
    means "compute the circle".

    The circumdisk lies within 2 R of each corner.  When the triangle takes
    :func:`safe_circle`'s direct branch (its cross product keeps its digits)
    and no side is shorter than 1e-10 of another, the computed centre is
    within 1e-4 R of the exact one and the computed radius within 5e-4 R of
    R (each of their errors is at most 16 units of roundoff times R times
    the ratio of two sides), so the computed disk lies within 4 R of corner
    a: inside the box when the box's sides are farther (with 4 R squared as
    4 a^2 b^2 c^2 / cross^2, the rounding of these products is 1e-15)."""
    dx, dy, ex, ey, bl, cl, d = circumcenter_terms(ax, ay, bx, by, cx, cy)
    # safe_circle's test of its direct branch, the same bits
    if not abs(d) > 1e12 * (16.0 * _U * (abs(dx * ey) + abs(dy * ex))):
        return False
    fx = cx - bx
    fy = cy - by
    al = fx * fx + fy * fy
    shortest = smaller(al, smaller(bl, cl))
    longest = larger(al, larger(bl, cl))
    if not (shortest >= 1e-20 * longest and 1e-60 < shortest and longest < 1e60):
        return False
    reach = smaller(smaller(ax - x_lo, x_hi - ax), smaller(ay - y_lo, y_hi - ay))
    reach = reach * (1.0 - 1e-9) - slack - 1e-9 * (abs(ax) + abs(ay))
    if not (0.0 < reach < 1e60):
        return False
    return 4.0 * (al * bl * cl) * (1.0 + 1e-6) < reach * reach * (d * d)


@njit
def _circles_leaving(x, y, tri, ox, oy, x_lo, y_lo, x_hi, y_hi):
    """The triangles whose circumcircle (input frame) is not inside the box, and the circles."""
    nt = tri.shape[0] // 3
    rows = empty(nt, dtype=np.int64)
    out = empty((nt, 3))
    n = 0
    # the box in the local frame, and a bound of the rounding of that shift and of the circles' to the input
    # frame: most circles are settled inside it without computing them
    l_x_lo = x_lo - ox
    l_y_lo = y_lo - oy
    l_x_hi = x_hi - ox
    l_y_hi = y_hi - oy
    slack = 1e-9 * (abs(ox) + abs(oy) + 1.0)
    for t in range(nt):
        a = tri[3 * t]
        b = tri[3 * t + 1]
        c = tri[3 * t + 2]
        if _surely_inside(x[a], y[a], x[b], y[b], x[c], y[c], l_x_lo, l_y_lo, l_x_hi, l_y_hi, slack):
            continue
        ux, uy, r = circle_in_input_frame(x, y, a, b, c, ox, oy)
        if ux - r >= x_lo and ux + r <= x_hi and uy - r >= y_lo and uy + r <= y_hi:
            continue
        rows[n] = t
        out[n, 0] = ux
        out[n, 1] = uy
        out[n, 2] = r
        n += 1
    return rows[:n].copy(), out[:n].copy()


def circles_leaving(triangulation: Triangulation, box) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The triangles whose circumcircle is not inside ``box`` (``x_lo, y_lo,
    x_hi, y_hi``), in order, and those circles ``(x, y, r)`` in the input
    frame (:func:`safe_circle`: they hold the exact circles)."""
    t = triangulation
    if tuple(box) == _EVERYWHERE or t.triangles.shape[0] == 0:
        return np.empty(0, dtype=np.int64), np.empty((0, 3))
    return _circles_leaving(t.x, t.y, t.triangles, float(t.origin[0]), float(t.origin[1]), *box)


def initial_doubt(known: KnownRegion, leaving: tuple[NDArray[np.int64], NDArray[np.float64]], nt: int,
                  ) -> tuple[NDArray[np.uint8], tuple[NDArray[np.int64], NDArray[np.float64]]]:
    """1 for the Delaunay triangles (of ``nt``) that may not be the global
    set's: their circumcircle leaves ``known.box`` and ``known`` does not
    vouch for it; and the rows of those triangles (ascending) with their
    circles ``(x, y, r)``.  ``leaving``: :func:`circles_leaving` of
    ``known.box`` (ascending rows)."""
    taint = np.zeros(nt, dtype=np.uint8)
    rows, circles = leaving
    if rows.size == 0:
        return taint, (rows, circles)
    vouched = np.asarray(known.covers(circles), dtype=bool)
    rows, circles = rows[~vouched], circles[~vouched]
    taint[rows] = 1
    return taint, (rows, circles)


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


@njit
def disk_box_in(cx: float, cy: float, r: float, x0: float, y0: float, x1: float, y1: float):
    """Bounding box of (disk ``(cx, cy, r)`` ∩ box), rounded outwards; ``(False, ...)``
    when they do not meet.  An infinite radius gives the whole box."""
    if not math.isfinite(r):
        return True, x0, y0, x1, y1
    yc = min(max(cy, y0), y1)
    xc = min(max(cx, x0), x1)
    # r^2 - d^2 loses the digits r and d share: near a tangent the half-chord is
    # far less certain than either
    hx = r * r - (yc - cy) ** 2 + 4 * _U * (r * r + (yc - cy) ** 2)
    hy = r * r - (xc - cx) ** 2 + 4 * _U * (r * r + (xc - cx) ** 2)
    if hx < 0 or hy < 0:
        return False, x0, y0, x1, y1
    grow = 4 * _U * (abs(cx) + abs(cy) + r)
    hx = math.sqrt(hx) + grow
    hy = math.sqrt(hy) + grow
    lo_x, lo_y, hi_x, hi_y = max(x0, cx - hx), max(y0, cy - hy), min(x1, cx + hx), min(y1, cy + hy)
    return not (lo_x > hi_x or lo_y > hi_y), lo_x, lo_y, hi_x, hi_y


def lens_boxes(circles: np.ndarray, hull: np.ndarray, box: np.ndarray) -> np.ndarray:
    """For each circle ``(cx, cy, r)``: the bounding box of (disk ∩ convex
    polygon ``hull`` (counter-clockwise ``(h, 2)``) ∩ ``box``), rounded
    outwards by a bound of its rounding errors; a row of NaN when they do
    not meet.

    No point lies outside a point set's hull, so the part of a circle beyond
    it needs no points: along a straight survey edge the circles of the
    slivers reach far out of the hull but only a thin lens into it.  The
    box's corners are those of the polygon inside the disk, the crossings of
    its edges with the circle, and the disk's own extreme points inside the
    polygon.  An infinite radius (a triangle too thin to bound its circle)
    gives the whole of ``box``; a hull of fewer than three points, the disk's
    box in ``box``.

    A disk inside a box that lies deep inside the polygon
    (:func:`inner_box`) has no corner or crossing and its four extreme points
    inside: it is settled without reading the polygon's edges, which each
    other circle reads (most circles of a tile inside a survey, whose hull
    may have hundreds of corners).
    """
    hull = np.ascontiguousarray(hull, dtype=np.float64).reshape(-1, 2)
    return _lens_boxes(np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3), hull,
                       np.ascontiguousarray(box, dtype=np.float64), inner_box(hull))


def inner_box(hull: np.ndarray) -> np.ndarray:
    """An axis-aligned box ``(x0, y0, x1, y1)`` inside the convex polygon
    ``hull`` (counter-clockwise ``(h, 2)``), every point of it farther inside
    every edge than 1e-5 of the polygon's size (ten times the farthest
    that rounding moves :func:`lens_boxes`' tests, at a tangent): the polygon's box shrunk about
    the mean of its corners as far as that holds.  An empty box (``x0 >
    x1``) for a polygon too thin, or of fewer than three corners."""
    hull = np.ascontiguousarray(hull, dtype=np.float64).reshape(-1, 2)
    return _inner_box_kernel(hull)


@njit
def _inner_box_kernel(hull: np.ndarray) -> np.ndarray:
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = math.inf, math.inf, -math.inf, -math.inf
    h = hull.shape[0]
    if h < 3:
        return out
    x_lo, y_lo, x_hi, y_hi = math.inf, math.inf, -math.inf, -math.inf
    mx, my = 0.0, 0.0
    for j in range(h):
        x_lo, x_hi = min(x_lo, hull[j, 0]), max(x_hi, hull[j, 0])
        y_lo, y_hi = min(y_lo, hull[j, 1]), max(y_hi, hull[j, 1])
        mx += hull[j, 0]
        my += hull[j, 1]
    mx /= h
    my /= h
    size = max(x_hi - x_lo, y_hi - y_lo)
    margin = 1e-5 * size + 1e-9 * max(abs(x_lo), abs(x_hi), abs(y_lo), abs(y_hi))
    lo, hi = 0.0, 1.0  # the share of the way from the mean to the polygon's box that stays inside
    if not _box_deep_inside(hull, mx, my, mx, my, margin):
        return out
    for _ in range(24):  # to a few millionths of the way
        s = 0.5 * (lo + hi)
        if _box_deep_inside(hull, mx - s * (mx - x_lo), my - s * (my - y_lo), mx + s * (x_hi - mx),
                            my + s * (y_hi - my), margin):
            lo = s
        else:
            hi = s
    out[0], out[1], out[2], out[3] = mx - lo * (mx - x_lo), my - lo * (my - y_lo), mx + lo * (x_hi - mx), my + lo * (y_hi - my)
    return out


@njit_helper
def _box_deep_inside(hull, x0, y0, x1, y1, margin) -> bool:
    """Whether the four corners of the box lie more than ``margin`` inside every edge of ``hull``."""
    h = hull.shape[0]
    for j in range(h):
        k = j + 1 if j + 1 < h else 0
        dx, dy = hull[k, 0] - hull[j, 0], hull[k, 1] - hull[j, 1]
        need = margin * math.hypot(dx, dy)
        for m in range(4):
            qx = x0 if m % 2 == 0 else x1
            qy = y0 if m < 2 else y1
            if not dx * (qy - hull[j, 1]) - dy * (qx - hull[j, 0]) > need:
                return False
    return True


@njit
def _lens_boxes(circles: np.ndarray, hull: np.ndarray, box: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """:func:`lens_boxes`, with the polygon's :func:`inner_box` (an empty one: every circle reads the edges)."""
    n = circles.shape[0]
    h = hull.shape[0]
    out = empty((n, 4))
    big = 0.0
    for j in range(h):
        big = max(big, max(abs(hull[j, 0]), abs(hull[j, 1])))
    for i in range(n):
        cx, cy, r = circles[i, 0], circles[i, 1], circles[i, 2]
        ok, fx0, fy0, fx1, fy1 = disk_box_in(cx, cy, r, box[0], box[1], box[2], box[3])
        if not ok:
            out[i, :] = np.nan
            continue
        if h < 3 or not math.isfinite(r):
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = fx0, fy0, fx1, fy1
            continue
        # centred: rounding relative to r; the centring's rounding, as a larger circle
        r = r + 4 * _U * (abs(cx) + abs(cy) + r + big)
        lo_x, lo_y, hi_x, hi_y = math.inf, math.inf, -math.inf, -math.inf
        grow = 0.0
        if cx - r > inner[0] and cx + r < inner[2] and cy - r > inner[1] and cy + r < inner[3]:
            lo_x, lo_y, hi_x, hi_y = -r, -r, r, r  # deep inside: what the edges below would give
        else:
            reach = 2.0 * r  # an edge whose box lies farther from the centre has no corner or crossing in the disk
            for j in range(h):
                k = j + 1 if j + 1 < h else 0
                if (min(hull[j, 0], hull[k, 0]) > cx + reach or max(hull[j, 0], hull[k, 0]) < cx - reach
                        or min(hull[j, 1], hull[k, 1]) > cy + reach or max(hull[j, 1], hull[k, 1]) < cy - reach):
                    continue
                px, py = hull[j, 0] - cx, hull[j, 1] - cy
                dx, dy = (hull[k, 0] - cx) - px, (hull[k, 1] - cy) - py
                a = dx * dx + dy * dy
                b = px * dx + py * dy
                c = px * px + py * py - r * r  # <= 0: the corner is in the disk
                err_c = 4 * _U * (px * px + py * py + r * r)
                if c <= err_c:
                    lo_x, hi_x, lo_y, hi_y = min(lo_x, px), max(hi_x, px), min(lo_y, py), max(hi_y, py)
                disc = b * b - a * c
                err_disc = 8 * _U * ((abs(px * dx) + abs(py * dy)) ** 2 + a * abs(c)) + a * err_c
                if not (a > 0 and disc + err_disc >= 0):
                    continue
                root = math.sqrt(max(disc, 0.0))
                # how far a crossing may be from where it is computed, along its edge
                spread = math.sqrt(max(disc + err_disc, 0.0)) - math.sqrt(max(disc - err_disc, 0.0))
                dt = (spread + 8 * _U * (abs(b) + root)) / a
                for sign in (-1.0, 1.0):
                    t = (-b + sign * root) / a
                    if t >= -dt and t <= 1.0 + dt:
                        tc = min(max(t, 0.0), 1.0)
                        qx, qy = px + tc * dx, py + tc * dy
                        lo_x, hi_x, lo_y, hi_y = min(lo_x, qx), max(hi_x, qx), min(lo_y, qy), max(hi_y, qy)
                        grow = max(grow, dt * math.sqrt(a))
            # the disk's extreme points (east, west, north, south) inside the polygon; the rounding's
            # bound takes 1-norms for the 2-norms (larger: a point on an edge counts as inside)
            for m in range(4):
                ex = r if m == 0 else (-r if m == 1 else 0.0)
                ey = r if m == 2 else (-r if m == 3 else 0.0)
                inside = True
                for j in range(h):
                    k = j + 1 if j + 1 < h else 0
                    px, py = hull[j, 0] - cx, hull[j, 1] - cy
                    dx, dy = (hull[k, 0] - cx) - px, (hull[k, 1] - cy) - py
                    side = dx * (ey - py) - dy * (ex - px)
                    if side < -8 * _U * (abs(dx) + abs(dy)) * (r + abs(px) + abs(py)):
                        inside = False
                        break
                if inside:
                    lo_x, hi_x, lo_y, hi_y = min(lo_x, ex), max(hi_x, ex), min(lo_y, ey), max(hi_y, ey)
        if not math.isfinite(lo_x):  # no part of the polygon in the disk
            out[i, :] = np.nan
            continue
        grow += 8 * _U * (abs(cx) + abs(cy) + 2 * r)
        x0, y0 = max(fx0, cx + lo_x - grow), max(fy0, cy + lo_y - grow)
        x1, y1 = min(fx1, cx + hi_x + grow), min(fy1, cy + hi_y + grow)
        if x0 > x1 or y0 > y1:
            out[i, :] = np.nan
        else:
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x0, y0, x1, y1
    return out
