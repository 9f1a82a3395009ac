"""``validate``: structural checks of a combined mesh, with a clear error for the first failure."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import empty, full, larger, njit, njit_helper, smaller, zeros
from .delaunay import bbox_origin
from .errors import InvalidInputError, InvalidMeshError
from .mesh import Mesh
from .predicates import orient2d

__all__ = ["validate", "convex_hull"]


@njit
def _face_turns(x, y, faces) -> int:
    """Index of the first face that is not strictly convex and counter-clockwise, or -1."""
    for k in range(faces.shape[0]):
        nv = 4 if faces[k, 3] >= 0 else 3
        for j in range(nv):
            a = faces[k, j]
            b = faces[k, (j + 1) % nv]
            c = faces[k, (j + 2) % nv]
            if orient2d(x[a], y[a], x[b], y[b], x[c], y[c]) <= 0:
                return k
    return -1


@njit
def _hull_kernel(x, y, order) -> np.ndarray:
    """Convex hull (counter-clockwise, collinear boundary points kept) of sorted
    points.  The chain runs over distinct places (two equal points on it would
    make every later turn test zero, so nothing behind them could be popped);
    each place on the hull then lists every point there, side by side."""
    n0 = order.shape[0]
    run = empty(n0 + 1, dtype=np.int64)  # run[j]: where the j-th distinct place starts in ``order``
    n = 0
    for i in range(n0):
        if i == 0 or x[order[i]] != x[order[i - 1]] or y[order[i]] != y[order[i - 1]]:
            run[n] = i
            n += 1
    run[n] = n0
    out = empty(2 * n + 1, dtype=np.int64)  # places, as indices into ``run``
    k = 0
    for j in range(n):  # lower chain
        p = order[run[j]]
        while k >= 2:
            a = order[run[out[k - 2]]]
            b = order[run[out[k - 1]]]
            if orient2d(x[a], y[a], x[b], y[b], x[p], y[p]) >= 0:
                break
            k -= 1
        out[k] = j
        k += 1
    lower = k + 1
    for j in range(n - 2, -1, -1):  # upper chain
        p = order[run[j]]
        while k >= lower:
            a = order[run[out[k - 2]]]
            b = order[run[out[k - 1]]]
            if orient2d(x[a], y[a], x[b], y[b], x[p], y[p]) >= 0:
                break
            k -= 1
        out[k] = j
        k += 1
    m = larger(k - 1, 1)
    total = 0
    for t in range(m):
        total += run[out[t] + 1] - run[out[t]]
    hull = empty(total, dtype=np.int64)
    h = 0
    for t in range(m):
        for i in range(run[out[t]], run[out[t] + 1]):
            hull[h] = order[i]
            h += 1
    return hull


@njit_helper
def _strictly_inside(x, y, poly, m, px, py) -> bool:
    """Whether (px, py) lies strictly inside the convex polygon ``poly[:m]``
    (counter-clockwise, m >= 3; exact)."""
    a = poly[m - 1]
    for k in range(m):
        b = poly[k]
        if orient2d(x[a], y[a], x[b], y[b], px, py) <= 0:
            return False
        a = b
    return True


@njit_helper
def _inner_box(x, y, poly, m):
    """An axis-aligned box strictly inside the convex polygon ``poly[:m]`` (CCW):
    its bounding box shrunk about its centre until all four corners are inside.
    Returns (x_lo, y_lo, x_hi, y_hi); an empty box when none is found (or m < 3)."""
    if m >= 3:
        x_lo = x_hi = x[poly[0]]
        y_lo = y_hi = y[poly[0]]
        for k in range(1, m):
            x_lo = smaller(x_lo, x[poly[k]])
            x_hi = larger(x_hi, x[poly[k]])
            y_lo = smaller(y_lo, y[poly[k]])
            y_hi = larger(y_hi, y[poly[k]])
        cx = 0.5 * (x_lo + x_hi)
        cy = 0.5 * (y_lo + y_hi)
        for shrink in (0.9, 0.75, 0.5, 0.25):
            bx_lo = cx + shrink * (x_lo - cx)
            bx_hi = cx + shrink * (x_hi - cx)
            by_lo = cy + shrink * (y_lo - cy)
            by_hi = cy + shrink * (y_hi - cy)
            if (
                _strictly_inside(x, y, poly, m, bx_lo, by_lo)
                and _strictly_inside(x, y, poly, m, bx_hi, by_lo)
                and _strictly_inside(x, y, poly, m, bx_hi, by_hi)
                and _strictly_inside(x, y, poly, m, bx_lo, by_hi)
            ):
                return bx_lo, by_lo, bx_hi, by_hi
    return math.inf, math.inf, -math.inf, -math.inf


@njit
def _hull_filter(x, y) -> np.ndarray:
    """Indices of the points not strictly inside the polygon of the extreme points
    in eight directions (Akl-Toussaint): a superset of the hull, found in one pass."""
    n = x.shape[0]
    if n == 0:
        return empty(0, dtype=np.int64)
    ext = zeros(8, dtype=np.int64)
    best = full(8, -np.inf)
    for i in range(n):
        xi = x[i]
        yi = y[i]
        # the eight directions: E, NE, N, NW, W, SW, S, SE
        for k, v in enumerate((xi, xi + yi, yi, yi - xi, -xi, -xi - yi, -yi, xi - yi)):
            if v > best[k]:
                best[k] = v
                ext[k] = i
    poly = empty(8, dtype=np.int64)
    m = 0
    for k in range(8):
        if m == 0 or (ext[k] != poly[m - 1] and ext[k] != poly[0]):
            poly[m] = ext[k]
            m += 1
    # a box inside the polygon settles most points with four comparisons
    bx_lo, by_lo, bx_hi, by_hi = _inner_box(x, y, poly, m)
    # and a point farther inside every edge than rounding reaches is inside:
    # the edges' inward unit normals, in coordinates about the first vertex
    ox = x[poly[0]]
    oy = y[poly[0]]
    normal_x = empty(m)
    normal_y = empty(m)
    offset = empty(m)
    size = 0.0
    for k in range(m):
        a = poly[k - 1 if k else m - 1]
        b = poly[k]
        ex = x[b] - x[a]
        ey = y[b] - y[a]
        length = math.hypot(ex, ey)
        size = larger(size, length)
        if length == 0.0:  # never for distinct extremes; then only the exact test decides
            normal_x[k] = normal_y[k] = 0.0
            offset[k] = math.inf
            continue
        normal_x[k] = -ey / length
        normal_y[k] = ex / length
        offset[k] = normal_x[k] * (x[a] - ox) + normal_y[k] * (y[a] - oy)
    margin = 1e-6 * size + 1e-12 * (abs(ox) + abs(oy) + size)
    keep = empty(n, dtype=np.int64)
    count = 0
    for i in range(n):
        if bx_lo <= x[i] <= bx_hi and by_lo <= y[i] <= by_hi:
            continue
        if m >= 3:
            px = x[i] - ox
            py = y[i] - oy
            deep = True
            for k in range(m):
                if normal_x[k] * px + normal_y[k] * py - offset[k] <= margin:
                    deep = False
                    break
            if deep:
                continue
        if not (m >= 3 and _strictly_inside(x, y, poly, m, x[i], y[i])):
            keep[count] = i
            count += 1
    return keep[:count]


def convex_hull(x: ArrayLike, y: ArrayLike) -> NDArray[np.int64]:
    """Indices of the points on the convex hull, counter-clockwise, points on hull
    edges included (exact predicates).

    >>> convex_hull([0.0, 1.0, 0.5, 1.0, 0.0], [0.0, 0.0, 0.5, 1.0, 1.0]).tolist()
    [0, 1, 3, 4]
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape:
        raise InvalidInputError(f"x and y must be 1-D arrays of one length, got shapes {x.shape} and {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InvalidInputError("x and y must be finite (no NaN or inf)")
    if x.shape[0] < 3:
        return np.arange(x.shape[0], dtype=np.int64)
    candidates = _hull_filter(x, y) if x.shape[0] > 64 else np.arange(x.shape[0], dtype=np.int64)
    cx = x[candidates]
    cy = y[candidates]
    order = np.lexsort((cy, cx)).astype(np.int64)
    hull = candidates[_hull_kernel(cx, cy, order)]
    # each index once: the chain closes on a repeated point, and a collinear
    # set's chain runs out and back
    _, first = np.unique(hull, return_index=True)
    return hull[np.sort(first)]


def _fail(message: str) -> None:
    raise InvalidMeshError(message)


@njit
def _off_line(x, y) -> int:
    """A vertex off the line through the first two distinct vertices (exact), or -1."""
    n = x.shape[0]
    b = -1
    for i in range(1, n):
        if x[i] != x[0] or y[i] != y[0]:
            b = i
            break
    if b < 0:
        return -1
    for i in range(n):
        if orient2d(x[0], y[0], x[b], y[b], x[i], y[i]) != 0.0:
            return i
    return -1


def validate(mesh: Mesh) -> None:
    """Raise :class:`InvalidMeshError` unless ``mesh`` is a valid combined mesh.

    Checked: shapes and index ranges; every face counter-clockwise and strictly
    convex (exact predicates); every edge shared by at most two faces, in
    opposite directions; the boundary edges are exactly the convex hull of the
    vertices; the total area equals the hull's; every vertex is used; every
    entry of ``input_to_vertex`` is a vertex and every vertex is some input
    point's.  A mesh without faces is valid only when its vertices are collinear.
    For a window piece (``mesh.window`` set) the checks that concern the whole
    hull (boundary, area, every vertex used) are skipped.
    """
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.faces)
    if v.ndim != 2 or v.shape[1] != 2 or not np.isfinite(v).all():
        _fail(f"vertices must be a finite (n, 2) array, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 4 or not np.issubdtype(f.dtype, np.integer):
        _fail(f"faces must be an integer (m, 4) array, got {f.dtype} {f.shape}")
    f = f.astype(np.int64, copy=False)  # edge keys below exceed 32 bits
    n_v = v.shape[0]
    if f.size and (f[:, :3].min() < 0 or f.max() >= n_v or f[:, 3].min() < -1):
        _fail("faces reference vertices out of range (only column 3 may be -1)")
    is_quad = f[:, 3] >= 0
    ordered = np.sort(f, axis=1)
    same = (ordered[:, 1:] == ordered[:, :-1]) & (ordered[:, :-1] >= 0)
    if same.any():
        _fail(f"face {int(np.flatnonzero(same.any(axis=1))[0])} repeats a vertex")

    origin = bbox_origin(v)
    x = np.ascontiguousarray(v[:, 0] - origin[0])
    y = np.ascontiguousarray(v[:, 1] - origin[1])
    bad = _face_turns(x, y, np.ascontiguousarray(f, dtype=np.int64))
    if bad >= 0:
        kind = "quadrangle" if is_quad[bad] else "triangle"
        _fail(f"face {bad} ({kind} {f[bad].tolist()}) is not strictly convex and counter-clockwise")

    # directed edges
    nxt = np.where(is_quad[:, None], np.roll(f, -1, axis=1), np.column_stack([f[:, 1:3], f[:, 0], f[:, 3]]))
    mask = f >= 0
    src = f[mask]
    dst = nxt[mask]
    key = src * n_v + dst
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(key[order][1:] == key[order][:-1])
    if dup.size:
        k = order[dup[0]]
        _fail(f"edge ({int(src[k])}, {int(dst[k])}) is used twice in the same direction (overlapping faces)")
    twin_key = dst * n_v + src
    has_twin = np.isin(twin_key, key)
    boundary = {(int(a), int(b)) for a, b in zip(src[~has_twin], dst[~has_twin])}

    if getattr(mesh, "window", None) is not None:
        return
    used = np.zeros(n_v, dtype=bool)
    used[src] = True
    hull = convex_hull(x, y)
    if f.shape[0] == 0:
        if n_v >= 3 and _off_line(x, y) >= 0:
            # exact: a float area of collinear points is rarely exactly zero
            _fail("the mesh has no faces but its vertices are not collinear")
    else:
        if not used.all():
            _fail(f"vertex {int(np.flatnonzero(~used)[0])} is not used by any face")
        hull_edges = {(int(a), int(b)) for a, b in zip(hull, np.roll(hull, -1))}
        if boundary != hull_edges:
            extra = sorted(boundary - hull_edges)[:3]
            missing = sorted(hull_edges - boundary)[:3]
            _fail(f"the boundary is not the convex hull: extra edges {extra}, missing hull edges {missing}")
        hull_area = 0.5 * (np.dot(x[hull], np.roll(y[hull], -1)) - np.dot(y[hull], np.roll(x[hull], -1)))
        px = x[f.clip(0)]
        py = y[f.clip(0)]
        tri_area = 0.5 * ((px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (py[:, 1] - py[:, 0]) * (px[:, 2] - px[:, 0]))
        quad_extra = 0.5 * ((px[:, 2] - px[:, 0]) * (py[:, 3] - py[:, 0]) - (py[:, 2] - py[:, 0]) * (px[:, 3] - px[:, 0]))
        total = float(tri_area.sum() + quad_extra[is_quad].sum())
        extent2 = float(np.ptp(x) * np.ptp(y)) if x.size else 0.0
        if abs(total - hull_area) > 1e-9 * abs(hull_area) + 1e-12 * extent2:
            _fail(f"faces cover an area of {total!r}, the convex hull {hull_area!r}")

    itv = np.asarray(mesh.input_to_vertex)
    if itv.size:
        if itv.min() < 0 or itv.max() >= n_v:
            _fail("input_to_vertex references vertices out of range")
        if not np.isin(np.arange(n_v), itv).all():
            _fail("some vertex is not the image of any input point")
