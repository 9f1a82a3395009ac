"""Delaunay triangulation by radial sweep (sweep-hull), with exact predicates.

The kernel follows the sweep-hull scheme popularised by *delaunator*: points
are sorted by distance from the circumcentre of a small seed triangle and added
one by one outside an advancing convex hull, with Lawson flips legalising the
new triangles.  What it adds:

* every decision uses the exact predicates of :mod:`meshcore.predicates`, and
  co-circular ties are broken by a symbolic perturbation that depends only on
  the coordinates (:func:`~meshcore.predicates.incircle_sos`), so the
  triangulation is unique: two runs over overlapping point sets (tiles) agree
  on every triangle whose circumcircle is covered by both;
* exact duplicates (same x and y) are detected in the sorted order (the sort
  key is distance, then x, then y) and mapped to one vertex;
* a point that the sweep cannot place outside the hull (it happens when
  rounding of the sort key puts a point inside the hull, or inside the seed
  triangle) is not dropped: it is inserted afterwards by point location and
  Lawson flips, so every distinct input point becomes a vertex;
* inputs with fewer than three non-collinear points give no triangles rather
  than an error.

Half-edge layout
----------------
``triangles[3 t + k]`` is the k-th vertex of triangle t (counter-clockwise);
half-edge ``3 t + k`` runs from ``triangles[3 t + k]`` to
``triangles[3 t + (k + 1) % 3]``; ``halfedges[e]`` is the opposite half-edge
or ``-1`` on the convex hull.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, full, index, larger, njit, njit_borrowing, njit_helper, smaller
from .predicates import incircle_sos, orient2d

__all__ = ["delaunay", "Triangulation"]


@njit_helper
def _next(e: int) -> int:
    return e - 2 if e % 3 == 2 else e + 1


@njit_helper
def _prev(e: int) -> int:
    return e + 2 if e % 3 == 0 else e - 1


@njit_helper
def _link(halfedges: np.ndarray, a: int, b: int) -> None:
    halfedges[a] = b
    if b != -1:
        halfedges[b] = a


@njit_helper
def circumcenter_terms(ax, ay, bx, by, cx, cy) -> tuple[float, float, float, float, float, float, float]:
    """What the circumcentre of ``a, b, c`` is made of: ``b - a``, ``c - a``,
    their squared lengths and their cross product (twice the signed area)."""
    dx = bx - ax
    dy = by - ay
    ex = cx - ax
    ey = cy - ay
    return dx, dy, ex, ey, dx * dx + dy * dy, ex * ex + ey * ey, dx * ey - dy * ex


@njit_helper
def circumcenter_offset(ax, ay, bx, by, cx, cy) -> tuple[float, float]:
    """Circumcentre of ``a, b, c`` relative to ``a`` (infinite or NaN when collinear)."""
    dx, dy, ex, ey, bl, cl, d = circumcenter_terms(ax, ay, bx, by, cx, cy)
    return (ey * bl - dy * cl) * 0.5 / d, (dx * cl - ex * bl) * 0.5 / d


@njit_helper
def _circumradius2(ax, ay, bx, by, cx, cy) -> float:
    if (ax == bx and ay == by) or (ax == cx and ay == cy) or (bx - ax) * (cy - ay) == (by - ay) * (cx - ax):
        return math.inf
    x, y = circumcenter_offset(ax, ay, bx, by, cx, cy)
    return x * x + y * y


@njit
def _circumcenter(ax, ay, bx, by, cx, cy) -> tuple[float, float]:
    x, y = circumcenter_offset(ax, ay, bx, by, cx, cy)
    return ax + x, ay + y


@njit_helper
def _pseudo_angle_key(dx: float, dy: float, size: int) -> int:
    s = abs(dx) + abs(dy)
    if s == 0.0:
        return 0
    p = dx / s
    a = (3.0 - p) / 4.0 if dy > 0.0 else (1.0 + p) / 4.0
    k = np.int64(math.floor(a * size))
    return k % size


@njit_helper
def _less(i: int, j: int, dist: np.ndarray, x: np.ndarray, y: np.ndarray) -> bool:
    """Sort order of the sweep: distance, then x, then y, then input index."""
    if dist[i] != dist[j]:
        return dist[i] < dist[j]
    if x[i] != x[j]:
        return x[i] < x[j]
    if y[i] != y[j]:
        return y[i] < y[j]
    return i < j


@njit_helper
def _merge_sort_run(ids: np.ndarray, lo: int, hi: int, dist, x, y) -> None:
    """Sort ``ids[lo:hi]`` by ``_less`` (bottom-up merge sort, stable, O(k log k))."""
    n = hi - lo
    if n < 2:
        return
    if n <= 24:
        for i in range(lo + 1, hi):
            v = ids[i]
            j = i - 1
            while j >= lo and _less(v, ids[j], dist, x, y):
                ids[j + 1] = ids[j]
                j -= 1
            ids[j + 1] = v
        return
    buf = empty(n, dtype=ids.dtype)
    src = ids[lo:hi].copy()
    width = 1
    while width < n:
        for start in range(0, n, 2 * width):
            mid = smaller(start + width, n)
            end = smaller(start + 2 * width, n)
            i = start
            j = mid
            k = start
            while i < mid and j < end:
                if _less(src[j], src[i], dist, x, y):
                    buf[k] = src[j]
                    j += 1
                else:
                    buf[k] = src[i]
                    i += 1
                k += 1
            while i < mid:
                buf[k] = src[i]
                i += 1
                k += 1
            while j < end:
                buf[k] = src[j]
                j += 1
                k += 1
        src, buf = buf, src
        width *= 2
    # element by element: a slice assignment compiles numba's shape-mismatch
    # error, with its string formatting, into the kernel (a second of the cold start)
    for i in range(n):
        ids[lo + i] = src[i]


@njit
def _local_distances(xy, ox, oy, cx, cy):
    """Local coordinates of every point and its squared distance to (cx, cy)."""
    n = xy.shape[0]
    dist = empty(n)
    x = empty(n)
    y = empty(n)
    for i in range(n):
        x[i] = xy[i, 0] - ox
        y[i] = xy[i, 1] - oy
        dx = x[i] - cx
        dy = y[i] - cy
        dist[i] = dx * dx + dy * dy
    return x, y, dist


@njit
def _fix_ties(ids, dist, x, y) -> None:
    """Order runs of equal distance by (x, y, index), so duplicates become adjacent."""
    n = ids.shape[0]
    k = 0
    while k < n:
        m = k + 1
        while m < n and dist[ids[m]] == dist[ids[k]]:
            m += 1
        if m - k > 1:
            _merge_sort_run(ids, k, m, dist, x, y)
        k = m


def _sweep_order(xy, ox, oy, cx, cy) -> np.ndarray:
    """Input indices sorted by (distance to (cx, cy), x, y, index), in local coordinates."""
    x, y, dist = _local_distances(xy, ox, oy, cx, cy)
    ids = np.argsort(dist).astype(np.int32)
    _fix_ties(ids, dist, x, y)
    return ids


@njit_borrowing
def _legalize_sweep(a, tri, he, x, y, hull_start, hull_tri, hull_prev, stack) -> int:
    """Lawson flips after adding a triangle during the sweep (clockwise triangles).

    Returns the half-edge that ends up on the hull.  ``stack`` must hold as
    many entries as there are points: each flip raises the new point's degree
    by one and pushes one edge, so no legalization pushes more (a stack that
    could grow would have to be allocated here).
    """
    i = 0
    ar = 0
    while True:
        b = he[a]
        a0 = a - a % 3
        ar = a0 + (a + 2) % 3
        if b == -1:
            if i == 0:
                break
            i -= 1
            a = stack[i]
            continue
        b0 = b - b % 3
        al = a0 + (a + 1) % 3
        bl = b0 + (b + 2) % 3
        p0 = index(tri[ar])
        pr = index(tri[a])
        pl = index(tri[al])
        p1 = index(tri[bl])
        # triangles are clockwise during the sweep: p1 inside <=> incircle < 0
        if incircle_sos(x[p0], y[p0], x[pr], y[pr], x[pl], y[pl], x[p1], y[p1]) < 0:
            tri[a] = np.int32(p1)
            tri[b] = np.int32(p0)
            hbl = he[bl]
            if hbl == -1:
                e = hull_start
                while True:
                    if hull_tri[e] == bl:
                        hull_tri[e] = a
                        break
                    e = hull_prev[e]
                    if e == hull_start:
                        break
            _link(he, a, hbl)
            _link(he, b, he[ar])
            _link(he, ar, bl)
            br = b0 + (b + 1) % 3
            if i == stack.shape[0]:  # unreachable (see above); memory is not written past the end
                raise RuntimeError("Delaunay sweep: legalization stack exhausted")
            stack[i] = br
            i += 1
        else:
            if i == 0:
                break
            i -= 1
            a = stack[i]
    return ar


@njit_helper
def _add_triangle(tri, he, nt, i0, i1, i2, a, b, c) -> int:
    t = 3 * nt
    tri[t] = i0
    tri[t + 1] = i1
    tri[t + 2] = i2
    _link(he, t, a)
    _link(he, t + 1, b)
    _link(he, t + 2, c)
    return t


@njit_borrowing
def _flip(tri: np.ndarray, he: np.ndarray, e: int) -> None:
    """Flip the diagonal ``e`` of the quadrangle formed by its two (CCW) triangles.

    Before: ``e`` runs a->b in (a, b, c), its twin b->a in (b, a, d).
    After: the slot of ``e`` holds (a, d, c) with ``e`` = a->d; the twin's slot
    holds (b, c, d) with the twin = b->c.
    """
    f = he[e]
    ne = _next(e)
    nf = _next(f)
    c = tri[_prev(e)]
    d = tri[_prev(f)]
    out_nf = he[nf]
    out_ne = he[ne]
    tri[ne] = d
    tri[nf] = c
    _link(he, e, out_nf)
    _link(he, f, out_ne)
    _link(he, ne, nf)


@njit_helper
def _push(stack: np.ndarray, n: int, value: int) -> np.ndarray:
    if n == stack.shape[0]:
        grown = empty(2 * stack.shape[0], dtype=stack.dtype)
        for i in range(n):  # element by element: see _merge_sort_run
            grown[i] = stack[i]
        stack = grown
    stack[n] = value
    return stack


@njit_helper
def _legalize_around(tri, he, x, y, stack, n) -> np.ndarray:
    """Lawson flips of the edges on ``stack[:n]``; each edge has the new point opposite."""
    while n > 0:
        n -= 1
        e = stack[n]
        f = he[e]
        if f == -1:
            continue
        a = index(tri[e])
        b = index(tri[_next(e)])
        p = index(tri[_prev(e)])
        d = index(tri[_prev(f)])
        if incircle_sos(x[a], y[a], x[b], y[b], x[p], y[p], x[d], y[d]) > 0:
            _flip(tri, he, e)
            # new triangles (a, d, p) at e and (b, p, d) at f: edges opposite p are e and prev(f)
            stack = _push(stack, n, e)
            n += 1
            stack = _push(stack, n, _prev(f))
            n += 1
    return stack


@njit
def _walk(tri, he, x, y, px, py, start, seed) -> tuple[int, int, int]:
    """Visibility walk from triangle ``start`` to (px, py): ``(t, seed, -1)`` with a
    triangle ``t`` containing it (closed); ``(-1, seed, e)`` when it lies outside,
    beyond the hull's half-edge ``e``; ``(-2, seed, -1)`` after a walk too long (a
    broken triangulation)."""
    t = start
    state = seed
    steps = 0
    limit = 4 * (tri.shape[0] // 3) + 16
    while steps < limit:
        steps += 1
        state = (state * 1103515245 + 12345) & 0x7FFFFFFF
        r = state % 3
        moved = False
        for k in range(3):
            e = 3 * t + (k + r) % 3
            a = tri[e]
            b = tri[_next(e)]
            if orient2d(x[a], y[a], x[b], y[b], px, py) < 0:
                f = he[e]
                if f == -1:
                    return -1, state, e
                t = f // 3
                moved = True
                break
        if not moved:
            return t, state, -1
    return -2, state, -1


@njit
def _locate(tri, he, x, y, px, py, start, seed) -> tuple[int, int]:
    """Visibility walk to a triangle containing (px, py) (closed); -1 when outside."""
    t, state, _ = _walk(tri, he, x, y, px, py, start, seed)
    if t >= -1:
        return t, state
    # a walk this long means a broken triangulation; fall back to a scan
    nt = tri.shape[0] // 3
    for t in range(nt):
        inside = True
        for k in range(3):
            e = 3 * t + k
            a = tri[e]
            b = tri[_next(e)]
            if orient2d(x[a], y[a], x[b], y[b], px, py) < 0:
                inside = False
                break
        if inside:
            return t, state
    return -1, state


@njit
def _insert_point(tri, he, nt, x, y, p, t, stack) -> tuple[int, np.ndarray, int]:
    """Insert vertex ``p`` found in triangle ``t``; returns (triangle count, stack, duplicate-of or -1)."""
    zeros = 0
    edge = -1
    for k in range(3):
        e = 3 * t + k
        a = tri[e]
        b = tri[_next(e)]
        if orient2d(x[a], y[a], x[b], y[b], x[p], y[p]) == 0:
            zeros += 1
            edge = e
    if zeros >= 2:
        # p coincides with a vertex of t: the vertex shared by the two zero edges
        for k in range(3):
            v = tri[3 * t + k]
            if x[v] == x[p] and y[v] == y[p]:
                return nt, stack, v
        return nt, stack, tri[3 * t]
    n = 0
    if zeros == 0:
        e0 = 3 * t
        a = tri[e0]
        b = tri[e0 + 1]
        c = tri[e0 + 2]
        h0 = he[e0]
        h1 = he[e0 + 1]
        h2 = he[e0 + 2]
        u = nt
        v = nt + 1
        tri[e0] = a
        tri[e0 + 1] = b
        tri[e0 + 2] = p
        _link(he, e0, h0)
        _add_triangle(tri, he, u, b, c, p, h1, -1, -1)
        _add_triangle(tri, he, v, c, a, p, h2, -1, -1)
        _link(he, e0 + 1, 3 * u + 2)
        _link(he, 3 * u + 1, 3 * v + 2)
        _link(he, 3 * v + 1, e0 + 2)
        for s in (e0, 3 * u, 3 * v):
            stack = _push(stack, n, s)
            n += 1
        return nt + 2, _legalize_around(tri, he, x, y, stack, n), -1
    e = edge
    f = he[e]
    a = tri[e]
    b = tri[_next(e)]
    c = tri[_prev(e)]
    h_bc = he[_next(e)]
    h_ca = he[_prev(e)]
    t1 = e // 3
    u = nt
    # (c, a, p) in slot t1 and (b, c, p) in slot u
    _add_triangle(tri, he, t1, c, a, p, h_ca, -1, -1)
    _add_triangle(tri, he, u, b, c, p, h_bc, -1, -1)
    _link(he, 3 * t1 + 2, 3 * u + 1)
    stack = _push(stack, n, 3 * t1)
    n += 1
    stack = _push(stack, n, 3 * u)
    n += 1
    if f == -1:
        he[3 * t1 + 1] = -1
        he[3 * u + 2] = -1
        return nt + 1, _legalize_around(tri, he, x, y, stack, n), -1
    d = tri[_prev(f)]
    h_ad = he[_next(f)]
    h_db = he[_prev(f)]
    t2 = f // 3
    w = nt + 1
    # (a, d, p) in slot t2 and (d, b, p) in slot w
    _add_triangle(tri, he, t2, a, d, p, h_ad, -1, -1)
    _add_triangle(tri, he, w, d, b, p, h_db, -1, -1)
    _link(he, 3 * t1 + 1, 3 * t2 + 2)
    _link(he, 3 * t2 + 1, 3 * w + 2)
    _link(he, 3 * w + 1, 3 * u + 2)
    stack = _push(stack, n, 3 * t2)
    n += 1
    stack = _push(stack, n, 3 * w)
    n += 1
    return nt + 2, _legalize_around(tri, he, x, y, stack, n), -1


@njit
def _seed_triangle(xy, ox, oy) -> tuple[int, int, int]:
    """Seed of the sweep: a point near the centre, its nearest neighbour, and the
    point making the smallest circumcircle with them (-1 where none exists)."""
    n = xy.shape[0]
    minx = maxx = xy[0, 0]  # a loop, not xy[:, 0].min(): numba compiles a reduction per array type
    miny = maxy = xy[0, 1]
    for i in range(1, n):
        minx = smaller(minx, xy[i, 0])
        maxx = larger(maxx, xy[i, 0])
        miny = smaller(miny, xy[i, 1])
        maxy = larger(maxy, xy[i, 1])
    minx -= ox
    maxx -= ox
    miny -= oy
    maxy -= oy
    bx = 0.5 * (minx + maxx)
    by = 0.5 * (miny + maxy)
    i0 = 0
    best = math.inf
    for i in range(n):
        d = (xy[i, 0] - ox - bx) ** 2 + (xy[i, 1] - oy - by) ** 2
        if d < best:
            best = d
            i0 = i
    x0 = xy[i0, 0] - ox
    y0 = xy[i0, 1] - oy
    i1 = -1
    best = math.inf
    for i in range(n):
        d = (xy[i, 0] - ox - x0) ** 2 + (xy[i, 1] - oy - y0) ** 2
        if d < best and d > 0.0:
            best = d
            i1 = i
    i2 = -1
    if i1 < 0:
        return i0, i1, i2
    x1 = xy[i1, 0] - ox
    y1 = xy[i1, 1] - oy
    best = math.inf
    for i in range(n):
        xi = xy[i, 0] - ox
        yi = xy[i, 1] - oy
        r = _circumradius2(x0, y0, x1, y1, xi, yi)
        if r < best and orient2d(x0, y0, x1, y1, xi, yi) != 0:
            best = r
            i2 = i
    if i2 < 0:
        # every radius overflowed: take any point off the line
        for i in range(n):
            if orient2d(x0, y0, x1, y1, xy[i, 0] - ox, xy[i, 1] - oy) != 0:
                i2 = i
                break
    return i0, i1, i2


def _delaunay_driver(xy: np.ndarray, ox: float, oy: float):
    """Triangulate ``xy - (ox, oy)``.

    Returns ``(x, y, order, rep, triangles, halfedges)``: the local coordinates
    in sweep order, ``order[k]`` the input index of sorted point k, ``rep[k]``
    the sorted position of its vertex (itself unless a duplicate), and the
    triangulation in terms of sorted positions.
    """
    n = xy.shape[0]
    i0, i1, i2 = _seed_triangle(xy, ox, oy) if n > 0 else (0, -1, -1)
    if i2 < 0:
        # fewer than three non-collinear points: no triangle; duplicates still merged
        cx = xy[i0, 0] - ox if n > 0 else 0.0
        cy = xy[i0, 1] - oy if n > 0 else 0.0
    else:
        cx, cy = _circumcenter(
            xy[i0, 0] - ox, xy[i0, 1] - oy, xy[i1, 0] - ox, xy[i1, 1] - oy, xy[i2, 0] - ox, xy[i2, 1] - oy
        )
    order = _sweep_order(xy, ox, oy, cx, cy)
    return _sweep_kernel(xy, ox, oy, order, i0, i1, i2, cx, cy)


@njit
def _sweep_kernel(xy, ox, oy, order, i0, i1, i2, cx, cy):
    n = xy.shape[0]
    no_faces = empty(0, dtype=np.int32)
    x = empty(n)
    y = empty(n)
    rep = empty(n, dtype=np.int32)
    for k in range(n):
        i = order[k]
        x[k] = xy[i, 0] - ox
        y[k] = xy[i, 1] - oy
        rep[k] = k
        if k > 0 and x[k] == x[k - 1] and y[k] == y[k - 1]:
            rep[k] = rep[k - 1]
    if i2 < 0:
        return x, y, order, rep, no_faces, no_faces

    # seeds in sorted positions (their first duplicate stands for them)
    s0 = -1
    s1 = -1
    s2 = -1
    for k in range(n):
        i = order[k]
        if i == i0:
            s0 = rep[k]
        elif i == i1:
            s1 = rep[k]
        elif i == i2:
            s2 = rep[k]
    # clockwise seed (the sweep's orientation); flipped to CCW at the end
    if orient2d(x[s0], y[s0], x[s1], y[s1], x[s2], y[s2]) > 0:
        s1, s2 = s2, s1

    hash_size = larger(1, np.int64(math.ceil(math.sqrt(n))))
    hull_prev = empty(n, dtype=np.int32)
    hull_next = empty(n, dtype=np.int32)
    hull_tri = empty(n, dtype=np.int32)
    hull_hash = full(hash_size, -1, dtype=np.int32)
    max_tri = larger(2 * n - 5, 1)
    tri = empty(3 * max_tri, dtype=np.int32)
    he = empty(3 * max_tri, dtype=np.int32)
    stack = empty(n + 16, dtype=np.int32)  # see _legalize_sweep
    deferred = empty(16, dtype=np.int32)
    n_deferred = 0

    hull_start = s0
    hull_next[s0] = s1
    hull_prev[s2] = s1
    hull_next[s1] = s2
    hull_prev[s0] = s2
    hull_next[s2] = s0
    hull_prev[s1] = s0
    hull_tri[s0] = 0
    hull_tri[s1] = 1
    hull_tri[s2] = 2
    hull_hash[_pseudo_angle_key(x[s0] - cx, y[s0] - cy, hash_size)] = s0
    hull_hash[_pseudo_angle_key(x[s1] - cx, y[s1] - cy, hash_size)] = s1
    hull_hash[_pseudo_angle_key(x[s2] - cx, y[s2] - cy, hash_size)] = s2
    _add_triangle(tri, he, 0, s0, s1, s2, -1, -1, -1)
    nt = 1

    for i in range(n):
        if rep[i] != i or i == s0 or i == s1 or i == s2:
            continue
        px = x[i]
        py = y[i]
        start = 0
        key = _pseudo_angle_key(px - cx, py - cy, hash_size)
        for j in range(hash_size):
            start = hull_hash[(key + j) % hash_size]
            if start != -1 and start != hull_next[start]:
                break
        start = hull_prev[start]
        e = start
        while True:
            q = hull_next[e]
            if orient2d(px, py, x[index(e)], y[index(e)], x[index(q)], y[index(q)]) > 0:
                break
            e = q
            if e == start:
                e = -1
                break
        if e == -1:
            # not strictly outside the hull: insert after the sweep
            deferred = _push(deferred, n_deferred, i)
            n_deferred += 1
            continue

        t = _add_triangle(tri, he, nt, e, i, hull_next[e], -1, -1, hull_tri[e])
        nt += 1
        ar = _legalize_sweep(t + 2, tri, he, x, y, hull_start, hull_tri, hull_prev, stack)
        hull_tri[i] = ar
        hull_tri[e] = t

        nn = hull_next[e]
        while True:
            q = hull_next[nn]
            if orient2d(px, py, x[index(nn)], y[index(nn)], x[index(q)], y[index(q)]) <= 0:
                break
            t = _add_triangle(tri, he, nt, nn, i, q, hull_tri[i], -1, hull_tri[nn])
            nt += 1
            ar = _legalize_sweep(t + 2, tri, he, x, y, hull_start, hull_tri, hull_prev, stack)
            hull_tri[i] = ar
            hull_next[nn] = nn
            nn = q

        if e == start:
            while True:
                q = hull_prev[e]
                if orient2d(px, py, x[index(q)], y[index(q)], x[index(e)], y[index(e)]) <= 0:
                    break
                t = _add_triangle(tri, he, nt, q, i, e, -1, hull_tri[e], hull_tri[q])
                nt += 1
                ar = _legalize_sweep(t + 2, tri, he, x, y, hull_start, hull_tri, hull_prev, stack)
                hull_tri[q] = t
                hull_next[e] = e
                e = q

        hull_start = e
        hull_prev[i] = e
        hull_next[e] = i
        hull_prev[nn] = i
        hull_next[i] = nn
        hull_hash[_pseudo_angle_key(px - cx, py - cy, hash_size)] = i
        hull_hash[_pseudo_angle_key(x[e] - cx, y[e] - cy, hash_size)] = e

    # to counter-clockwise: (v0, v1, v2) -> (v0, v2, v1); half-edge slot k <- 2 - k
    m = 3 * nt
    for t in range(nt):
        b = 3 * t
        v = tri[b + 1]
        tri[b + 1] = tri[b + 2]
        tri[b + 2] = v
        h0 = he[b]
        he[b] = he[b + 2]
        he[b + 2] = h0
    for e in range(m):
        h = he[e]
        if h != -1:
            he[e] = h - h % 3 + (2 - h % 3)

    if n_deferred > 0:
        grown_tri = empty(3 * (nt + 2 * n_deferred), dtype=np.int32)
        grown_he = empty(3 * (nt + 2 * n_deferred), dtype=np.int32)
        for i in range(m):
            grown_tri[i] = tri[i]
            grown_he[i] = he[i]
        tri = grown_tri
        he = grown_he
        seed = 12345
        last = 0
        for k in range(n_deferred):
            p = deferred[k]
            t, seed = _locate(tri[: 3 * nt], he[: 3 * nt], x, y, x[p], y[p], last, seed)
            if t < 0:
                continue  # unreachable: a deferred point lies inside the final hull
            nt, stack, dup = _insert_point(tri, he, nt, x, y, p, t, stack)
            if dup >= 0:
                rep[p] = dup
            last = t
    return x, y, order, rep, tri[: 3 * nt], he[: 3 * nt]


class Triangulation:
    """A triangulation in half-edge form over points in sweep order.

    Attributes
    ----------
    x, y : (n,) float64
        Local coordinates (input minus ``origin``) of every input point, sorted
        in sweep order.
    origin : (2,) float64
        The lower-left corner of the input's bounding box.
    order : (n,) int32
        ``order[k]`` is the input index of sorted point k.
    rep : (n,) int32
        Sorted position of the point that stands for point k (itself, or its
        first duplicate).
    triangles, halfedges : (3 m,) int32
        Vertex ids (sorted positions) and twin half-edges, counter-clockwise
        (see the module docstring).
    """

    __slots__ = ("x", "y", "origin", "order", "rep", "triangles", "halfedges")

    def __init__(self, x, y, origin, order, rep, triangles, halfedges):
        self.x = x
        self.y = y
        self.origin = origin
        self.order = order
        self.rep = rep
        self.triangles = triangles
        self.halfedges = halfedges


def bbox_origin(xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """The local origin of a point set, chosen so that ``xy - origin`` is exact.

    Per axis: the minimum when all values lie in ``[min, 2 min]`` (positive) or
    the maximum when all lie in ``[2 max, max]`` (negative) -- Sterbenz's lemma
    makes the subtraction exact, and survey coordinates (6e5 with a 1 km tile)
    always qualify -- otherwise 0, where coordinates are already small next to
    their spread.  Exactness means two points are equal in the local frame only
    when they are equal in the input, and the exact predicates decide on the
    true geometry.
    """
    origin = np.zeros(2)
    if xy.shape[0] == 0:
        return origin
    # per column: a reduction along axis 0 of an (n, 2) array is ~15x slower
    lo = np.array([xy[:, 0].min(), xy[:, 1].min()])
    hi = np.array([xy[:, 0].max(), xy[:, 1].max()])
    for k in range(2):
        if lo[k] > 0.0 and hi[k] <= 2.0 * lo[k]:
            origin[k] = lo[k]
        elif hi[k] < 0.0 and lo[k] >= 2.0 * hi[k]:
            origin[k] = hi[k]
    return origin


def delaunay(xy: NDArray[np.float64]) -> Triangulation:
    """Delaunay triangulation of validated ``(n, 2)`` float64 points."""
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    origin = bbox_origin(xy)
    x, y, order, rep, tri, he = _delaunay_driver(xy, float(origin[0]), float(origin[1]))
    return Triangulation(x, y, origin, order, rep, tri, he)


def grid_triangulation(columns: int, rows: int) -> Triangulation:
    """A triangulation of a slightly jittered ``columns`` x ``rows`` grid,
    each square cut on its rising diagonal, made here without the sweep's
    kernels: for compiling the kernels of the stages that follow the sweep
    on their own (see :func:`meshcore.build.load_kernels`).  Not Delaunay
    in general (flips make it so)."""
    k = np.arange(columns * rows)
    x = (k % columns + 0.01 * (k * 7 % 5)).astype(np.float64)
    y = (k // columns + 0.01 * (k * 3 % 7)).astype(np.float64)
    corners = []
    for j in range(rows - 1):
        for i in range(columns - 1):
            a = j * columns + i
            corners += [(a, a + 1, a + columns + 1), (a, a + columns + 1, a + columns)]
    tri = np.array(corners, dtype=np.int32).reshape(-1)
    edge_of = {(int(tri[e]), int(tri[e - e % 3 + (e + 1) % 3])): e for e in range(tri.size)}
    he = np.array([edge_of.get((b, a), -1) for (a, b) in edge_of], dtype=np.int32)
    ids = k.astype(np.int32)
    return Triangulation(x, y, np.zeros(2), ids, ids.copy(), tri, he)
