"""``build_mesh``: Delaunay triangulation, quality flips, elimination of diagonals."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import empty, full, larger, njit, njit_borrowing, njit_helper, smaller, zeros
from ._order import geometric_order
from .delaunay import Triangulation, _next, _prev, delaunay, grid_triangulation
from .errors import InvalidInputError
from .certificate import KnownRegion, WindowCertificate, circles_leaving, initial_doubt, open_hull_edges
from .flip import _centroid, _meets_box, flip_edges
from .merge import greedy_order, merge_candidates, merge_triangles, paired_triangle_measure
from .mesh import Mesh
from .options import MergeMethod, QuadMeasure, TriangleMeasure, parse_option
from .predicates import lex_before

__all__ = ["build_mesh", "as_points", "load_kernels", "KERNEL_STAGES"]


def as_points(xy: ArrayLike, name: str = "xy") -> NDArray[np.float64]:
    """Check and cast an ``(n, 2)`` array of finite coordinates to float64."""
    arr = np.asarray(xy)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InvalidInputError(f"{name} must have shape (n, 2), got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InvalidInputError(f"{name} must be numeric, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        finite = np.isfinite(arr).all(axis=1)
        bad = int(np.flatnonzero(~finite)[0])
        raise InvalidInputError(
            f"{name} has {int((~finite).sum())} point(s) with NaN or infinite coordinates "
            f"(first at index {bad})"
        )
    return arr


@njit_helper
def _inner_window(x, y, ox, oy, x_lo, y_lo, x_hi, y_hi) -> tuple[float, float, float, float]:
    """The window shrunk, in the local frame, by more than the rounding of a
    centroid and of the shift: a triangle whose corners lie inside it has its
    centroid in the window (see :func:`_in_window`)."""
    largest = 0.0
    for i in range(x.shape[0]):
        largest = larger(largest, larger(abs(x[i]), abs(y[i])))
    margin = 1e-12 * (largest + abs(ox) + abs(oy) + 1.0)
    return x_lo - ox + margin, y_lo - oy + margin, x_hi - ox - margin, y_hi - oy - margin


@njit_helper
def _in_window(x, y, ox, oy, tri, t, inner, x_lo, y_lo, x_hi, y_hi) -> bool:
    """Whether triangle ``t``'s centroid lies in ``[x_lo, x_hi) x [y_lo, y_hi)``
    (``inner``: :func:`_inner_window` of them)."""
    i = tri[3 * t]
    j = tri[3 * t + 1]
    k = tri[3 * t + 2]
    ax, ay, bx, by, cx, cy = x[i], y[i], x[j], y[j], x[k], y[k]
    # a triangle well inside the window (its corners farther from the edges
    # than the rounding of the centroid and of the shift) is in it; the
    # others take the exact test
    if (
        smaller(ax, smaller(bx, cx)) > inner[0] and larger(ax, larger(bx, cx)) < inner[2]
        and smaller(ay, smaller(by, cy)) > inner[1] and larger(ay, larger(by, cy)) < inner[3]
    ):
        return True
    gx, gy = _centroid(ax, ay, bx, by, cx, cy, ox, oy)
    return x_lo <= gx < x_hi and y_lo <= gy < y_hi


@njit
def _meeting_window(x, y, tri, rows, window, ox, oy) -> np.ndarray:
    """Which of the triangles ``rows`` meet the window (or nearly: see :func:`_meets_box`)."""
    out = empty(rows.shape[0], dtype=np.bool_)
    slack = 1e-9 * (abs(ox) + abs(oy) + 1.0)
    for k in range(rows.shape[0]):
        t = rows[k]
        a = tri[3 * t]
        b = tri[3 * t + 1]
        c = tri[3 * t + 2]
        out[k] = _meets_box(
            x[a], y[a], x[b], y[b], x[c], y[c], window[0] - ox, window[1] - oy, window[2] - ox, window[3] - oy, slack
        )
    return out


@njit_borrowing
def _emit(faces, k, x, y, vertex_of, a, b, c, d) -> None:
    """Write a face (``d < 0``: a triangle) starting at its lexicographically
    smallest vertex (by coordinates).

    The rotation is then a property of the geometry, not of internal numbering,
    so the same face gets bit-identical values in every run (tiled or not).
    The local coordinates order points as the input does (the shift is exact).
    Each corner's coordinates are read once: comparing through a helper that
    indexes the arrays for every comparison made this pass 3.5x slower.
    """
    corners = 3 if d < 0 else 4
    first = 0
    xm = x[a]
    ym = y[a]
    for i in range(1, corners):
        v = b if i == 1 else (c if i == 2 else d)
        xv = x[v]
        yv = y[v]
        if lex_before(xv, yv, xm, ym):
            first = i
            xm = xv
            ym = yv
    for _ in range(first):
        if corners == 3:
            a, b, c = b, c, a
        else:
            a, b, c, d = b, c, d, a
    faces[k, 0] = vertex_of[a]
    faces[k, 1] = vertex_of[b]
    faces[k, 2] = vertex_of[c]
    faces[k, 3] = -1 if corners == 3 else vertex_of[d]


@njit
def _faces_kernel(tri, he, partner, vertex_of, active, x, y) -> np.ndarray:
    """The faces of the ``active`` triangles: a lone one, or the first (lower
    slot) of a quadrangle's two."""
    nt = tri.shape[0] // 3
    count = 0
    for t in range(nt):
        e = partner[t]
        if active[t] and (e == -1 or t < he[e] // 3):
            count += 1
    faces = empty((count, 4), dtype=np.int64)
    k = 0
    for t in range(nt):
        if not active[t]:
            continue
        e = partner[t]
        if e == -1:
            _emit(faces, k, x, y, vertex_of, tri[3 * t], tri[3 * t + 1], tri[3 * t + 2], -1)
            k += 1
        else:
            f = he[e]
            if t < f // 3:
                # (a, b, c) + (b, a, d) -> quadrangle a, d, b, c (counter-clockwise)
                _emit(faces, k, x, y, vertex_of, tri[e], tri[_prev(f)], tri[_next(e)], tri[_prev(e)])
                k += 1
    return faces


@njit
def _vertex_numbering(order, rep):
    """Vertices are the distinct points in order of first occurrence in the input.

    Returns (vertex id of every sorted point, input index of every vertex,
    vertex of every input point).
    """
    n = order.shape[0]
    is_vertex = zeros(n, dtype=np.bool_)
    for k in range(n):
        r = rep[k]
        while rep[r] != r:  # chains appear only through points merged after the sweep
            r = rep[r]
        rep[k] = r
        if r == k:
            is_vertex[order[k]] = True
    input_to_vertex = empty(n, dtype=np.int64)  # first holds the vertex id of each vertex input
    count = 0
    for i in range(n):
        if is_vertex[i]:
            input_to_vertex[i] = count
            count += 1
    vertex_input = empty(count, dtype=np.int64)
    for i in range(n):
        if is_vertex[i]:
            vertex_input[input_to_vertex[i]] = i
    vertex_of_sorted = empty(n, dtype=np.int32)
    for k in range(n):
        vertex_of_sorted[k] = input_to_vertex[order[rep[k]]]
    for k in range(n):
        input_to_vertex[order[k]] = vertex_of_sorted[k]
    return vertex_of_sorted, vertex_input, input_to_vertex


def _check_window(window: object) -> tuple[float, float, float, float]:
    try:
        x_lo, y_lo, x_hi, y_hi = (float(v) for v in window)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InvalidInputError(f"window must be (x_min, y_min, x_max, y_max), got {window!r}") from None
    if any(np.isnan((x_lo, y_lo, x_hi, y_hi))) or not (x_lo < x_hi and y_lo < y_hi):
        raise InvalidInputError(f"window must have x_min < x_max and y_min < y_max, got {window!r}")
    return x_lo, y_lo, x_hi, y_hi


def build_mesh(
    xy: ArrayLike,
    triangle_measure: str = "s1",
    quad_measure: str | None = "s2",
    merge: str = "greedy",
    window: tuple[float, float, float, float] | None = None,
    known: tuple[float, float, float, float] | KnownRegion | None = None,
    assume_rounds: int = 0,
) -> Mesh:
    """Build the combined triangle/quadrangle mesh of a planar point set.

    1. Delaunay triangulation (exact predicates; duplicates merged);
    2. flips to local optimality under ``triangle_measure`` ("s1" or "s3";
       "delaunay" keeps the Delaunay triangulation), in rounds decided by the
       geometry alone (see :mod:`meshcore.flip`);
    3. elimination of diagonals under ``quad_measure`` ("s2" or "s4"; None keeps
       a pure triangulation), ``merge="greedy"`` (the paper's queue, ties
       broken by coordinates) or ``"optimal"`` (maximum total gain).

    Parameters
    ----------
    xy : (n, 2) array of finite coordinates
    window : (x_min, y_min, x_max, y_max), optional
        Return only the faces the half-open box ``[x_min, x_max) x [y_min,
        y_max)`` owns: a triangle whose centroid lies in it, a quadrangle
        whose deleted diagonal's midpoint does.  The whole point set is
        flipped and merged; pieces built for adjacent windows from enough of
        the global set's points are the global mesh's faces, without gaps or
        overlaps: this is how a tiled run stitches its tiles.
        ``mesh.certificate`` says whether the points passed were enough.
    known : (x_min, y_min, x_max, y_max) or KnownRegion, optional
        With ``window``: where ``xy`` holds every point of the global set (a
        box, or a :class:`meshcore.certificate.KnownRegion` that also knows
        the global hull and vouches for circles beyond its box).  The
        circumcircles of the window's Delaunay triangles that are not inside
        its box are returned as ``mesh.window_escapes`` ``(k, 3)`` (centre x,
        centre y, radius), for every Delaunay triangle that meets the window.
        Beyond the convex hull of ``xy`` there are no triangles and so no
        circles: where the window reaches past that hull, ``xy`` must also
        hold the points of the global convex hull there (a tiled run adds
        them to every tile).
    assume_rounds : int
        With ``window``: the certificate assumes that the global mesh makes no
        flip near the window after this round (a tiled run checks it against
        the neighbouring tiles' ``certificate.last_flip_round``).

    Returns
    -------
    Mesh

    Examples
    --------
    >>> import numpy as np
    >>> mesh = build_mesh(np.array([[0., 0.], [1., 0.], [1., 1.], [0., 1.]]))
    >>> mesh.faces.tolist()
    [[0, 1, 2, 3]]
    """
    tm = parse_option(TriangleMeasure, triangle_measure, "triangle_measure")
    qm = None if quad_measure is None else parse_option(QuadMeasure, quad_measure, "quad_measure")
    mm = parse_option(MergeMethod, merge, "merge")
    bounds = None if window is None else _check_window(window)
    points = as_points(xy)
    region = None
    if known is not None and bounds is not None:
        region = known if isinstance(known, KnownRegion) else KnownRegion(box=_check_window(known))
    if not (isinstance(assume_rounds, (int, np.integer)) and assume_rounds >= 0):
        raise InvalidInputError(f"assume_rounds must be a whole number >= 0, got {assume_rounds!r}")
    return _combined_mesh(points, delaunay(points), tm, qm, mm, bounds, region, int(assume_rounds))


def _combined_mesh(
    points: NDArray[np.float64],
    triangulation: Triangulation,
    tm: TriangleMeasure,
    qm: QuadMeasure | None,
    mm: MergeMethod,
    bounds: tuple[float, float, float, float] | None,
    known: KnownRegion | None,
    rounds: int = 0,
) -> Mesh:
    """:func:`build_mesh` after the Delaunay triangulation of ``points``."""
    if bounds is not None:
        # near in the plane, near in memory (the results do not depend on the numbering)
        triangulation = geometric_order(triangulation)
    nt = triangulation.triangles.shape[0] // 3
    escapes = None
    taint = None
    source = None
    doubted = None
    open_edges = None
    active = np.ones(nt, dtype=np.uint8)
    window = None if bounds is None else np.array(bounds, dtype=np.float64)
    o = triangulation.origin
    if bounds is not None:
        region = known if known is not None else KnownRegion()
        # the circles that leave the box held whole, computed once: those of the triangles that meet the
        # window are the Delaunay certificate's, and those the tile does not vouch for start the doubt
        leaving = circles_leaving(triangulation, region.box)
        escapes = leaving[1][_meeting_window(
            triangulation.x, triangulation.y, triangulation.triangles, leaving[0], window, float(o[0]), float(o[1])
        )]
        taint, doubted = initial_doubt(region, leaving, nt)
        # each doubted triangle is where its doubt came from
        source = np.full(nt, -1, dtype=np.int64)
        source[doubted[0]] = doubted[0]
        open_edges = open_hull_edges(triangulation, region)
    flipped = None
    if tm is not TriangleMeasure.DELAUNAY:
        flipped = flip_edges(
            triangulation, tm.value, active, taint=taint, source=source, open_edges=open_edges, assume_rounds=rounds,
            window=bounds,
        )
    if qm is None:
        partner = np.full(nt, -1, dtype=np.int32)
        candidates = None
    else:
        # the flips' scores, when they flipped under the measure the gains compare with
        paired = flipped is not None and tm.value == paired_triangle_measure(qm.value)
        candidates = merge_candidates(triangulation, qm.value, active, scores=flipped.scores if paired else None)
        order = None if mm is MergeMethod.OPTIMAL else greedy_order(triangulation, *candidates)
        partner = merge_triangles(triangulation, qm.value, mm.value, active, candidates=candidates, order=order)
        candidates = (*candidates, order)

    certificate = None
    if bounds is None:
        owned = active
    else:
        owned, start = _owned_faces(triangulation.x, triangulation.y, float(o[0]), float(o[1]),
                                    triangulation.triangles, triangulation.halfedges, partner, window)
        certificate = _certificate(triangulation, taint, source, doubted, start, candidates, flipped, mm, rounds)
    vertex_of_sorted, vertex_input, input_to_vertex = _vertex_numbering(triangulation.order, triangulation.rep)
    faces = _faces_kernel(
        triangulation.triangles, triangulation.halfedges, partner, vertex_of_sorted, owned,
        triangulation.x, triangulation.y,
    )
    del triangulation, partner, vertex_of_sorted, active
    return Mesh(
        vertices=np.take(points, vertex_input, axis=0),  # 10x faster than points[vertex_input]
        faces=faces,
        input_to_vertex=input_to_vertex,
        triangle_measure=tm.value,
        quad_measure=None if qm is None else qm.value,
        merge=mm.value,
        window=bounds,
        window_escapes=escapes,
        certificate=certificate,
    )


def _certificate(triangulation: Triangulation, taint, source, doubted, start, candidates, flipped,
                 mm: MergeMethod, rounds: int) -> WindowCertificate:
    """Whether a window piece's faces are the global mesh's, given that the
    global mesh makes no flip near the window after round ``rounds``
    (``start``: the triangles of the faces the window owns; ``doubted``: the
    triangles doubted at the start, ascending, and their circles)."""
    greedy = candidates is not None and mm is MergeMethod.GREEDY
    no_edges = np.empty(0, dtype=np.int32)
    reached = _doubt_reached(
        triangulation.halfedges, taint, start, np.zeros(0, dtype=np.uint8) if flipped is None else flipped.zone,
        candidates is not None, candidates[0] if greedy else no_edges,
        candidates[2] if greedy else np.empty(0, dtype=np.int64),
    )
    causes = np.unique(source[reached])
    last = 0 if flipped is None else flipped.last_window_round
    return WindowCertificate(
        certified=reached.size == 0, last_flip_round=last, assumed_rounds=int(rounds),
        rounds=0 if flipped is None else flipped.rounds,
        blocking=doubted[1][np.searchsorted(doubted[0], causes[causes >= 0])], open_edges=bool(np.any(causes == -2)),
        **({} if flipped is None else {"flip_blocks": flipped.window_blocks, "flip_blocks_box": flipped.blocks_box}),
    )


@njit
def _owned_faces(x, y, ox, oy, tri, he, partner, window):
    """1 for the triangles that start a face the window owns: a lone triangle
    whose centroid lies in it, or the first triangle of a quadrangle whose
    deleted diagonal's midpoint does (input frame, the same bits in every run);
    and 1 for every triangle of those faces (a quadrangle's two).

    A triangle of a quadrangle takes only the midpoint's test: the centroid's
    would be overwritten (two thirds of the triangles of a merged mesh)."""
    nt = tri.shape[0] // 3
    owned = zeros(nt, dtype=np.uint8)
    start = zeros(nt, dtype=np.uint8)
    x_lo, y_lo, x_hi, y_hi = window[0], window[1], window[2], window[3]
    inner = _inner_window(x, y, ox, oy, x_lo, y_lo, x_hi, y_hi)
    for t in range(nt):
        e = partner[t]
        if e == -1:
            if _in_window(x, y, ox, oy, tri, t, inner, x_lo, y_lo, x_hi, y_hi):
                owned[t] = 1
                start[t] = 1
            continue
        f = he[e]
        if t > f // 3:
            continue
        a = tri[e]
        b = tri[f]
        mx = ((x[a] + ox) + (x[b] + ox)) / 2.0
        my = ((y[a] + oy) + (y[b] + oy)) / 2.0
        if x_lo <= mx < x_hi and y_lo <= my < y_hi:
            owned[t] = 1
            start[t] = 1
            start[f // 3] = 1
    return owned, start


@njit
def _doubt_reached(he, taint, start, zone, ring: bool, edges, order) -> np.ndarray:
    """The tainted triangles (ascending) that the faces of the triangles ``start``
    flags depend on: ``start`` itself, with ``ring`` the triangles beside it
    (whether an edge is a merge candidate reads the triangle beyond it), the
    flips' ``zone`` (empty: none), and the triangles the greedy merge's choice
    for ``start`` reads (``edges`` in the greedy ``order``, empty: none), as
    the greedy queue reads them: an edge's gain reads its two triangles and,
    whether it is a candidate at all, the triangles beyond their edges; and a
    candidate of a triangle outside ``start`` that comes earlier in the order
    is read in turn.

    Only the tainted triangles are asked for, and only the chains through the
    triangles outside ``start`` are followed: a candidate with both triangles
    in ``start`` reads nothing outside ``start`` and the ring beside it, and a
    chain reaches a candidate outside through a triangle outside, whose
    candidates in ``start`` are where the chains start anyway.
    """
    nt = he.shape[0] // 3
    n = edges.shape[0]
    hit = zeros(nt, dtype=np.uint8)
    if n > 0:
        # per half-edge: the rank of its candidate when no triangle of it is in start and it was not
        # reached yet, else -1
        rank_of = empty(n, dtype=np.int64)
        for k in range(n):
            rank_of[order[k]] = k
        rank = full(he.shape[0], -1, dtype=np.int32)
        stack_e = empty(n, dtype=np.int64)
        stack_k = empty(n, dtype=np.int64)
        top = 0
        # in the edges' order, near in memory (the greedy order is all over it)
        for i in range(n):
            k = rank_of[i]
            e = np.int64(edges[i])
            f = np.int64(he[e])
            s1 = start[e // 3] != 0
            s2 = start[f // 3] != 0
            if s1 and s2:
                continue
            if s1 or s2:  # a candidate of a triangle of start, with a triangle outside
                stack_e[top] = e
                stack_k[top] = k
                top += 1
            else:
                rank[e] = k
                rank[f] = k
        while top > 0:
            top -= 1
            e = stack_e[top]
            k = stack_k[top]
            f = np.int64(he[e])
            # the edge's gain reads its two triangles; whether it is a candidate at
            # all, each edge around them reads the triangle beyond it
            for g in (e, f, _next(e), _prev(e), _next(f), _prev(f)):
                hit[g // 3] = 1
                h = he[g]
                if h >= 0:
                    hit[h // 3] = 1
            for t in (e // 3, f // 3):
                if start[t]:
                    continue
                for j in range(3):
                    g = 3 * t + j
                    r = rank[g]
                    if r >= 0 and r < k:
                        h = he[g]
                        rank[g] = -1
                        rank[h] = -1
                        stack_e[top] = g
                        stack_k[top] = r
                        top += 1
    zoned = zone.shape[0] == nt
    out = empty(nt, dtype=np.int64)
    count = 0
    for t in range(nt):
        if not taint[t]:
            continue
        need = start[t] != 0 or hit[t] != 0 or (zoned and zone[t] != 0)
        if not need and ring:
            for j in range(3):
                h = he[3 * t + j]
                if h >= 0 and start[h // 3]:
                    need = True
        if need:
            out[count] = t
            count += 1
    return out[:count].copy()


KERNEL_STAGES = ("triangulation", "faces")
"""The stages of :func:`build_mesh` whose kernels :func:`load_kernels` compiles apart."""


def load_kernels(stage: str, triangle_measure: str = "s1", quad_measure: str | None = "s2",
                 merge: str = "greedy") -> Mesh | None:
    """Compile (or load from the kernel cache) the kernels of one stage of
    :func:`build_mesh` with a window, as it runs them, on a small example.

    ``stage`` is ``"triangulation"`` (the Delaunay sweep) or ``"faces"``
    (everything after it: the geometric order, the window, flips, merges and
    faces, run on a triangulation of a grid made without the sweep's
    kernels; the measures as ``build_mesh`` takes them).  Each takes about
    6-8 s to compile on one core, so two processes compile a machine's first
    mesh kernels in half the time of one.  Returns the example's mesh
    (``"faces"``) or None.
    """
    tm = parse_option(TriangleMeasure, triangle_measure, "triangle_measure")
    qm = None if quad_measure is None else parse_option(QuadMeasure, quad_measure, "quad_measure")
    mm = parse_option(MergeMethod, merge, "merge")
    triangulation = grid_triangulation(8, 8)
    points = np.column_stack([triangulation.x, triangulation.y])
    if stage == "triangulation":
        delaunay(points)
        return None
    if stage != "faces":
        raise InvalidInputError(f"stage must be one of {', '.join(KERNEL_STAGES)}, got {stage!r}")
    return _combined_mesh(points, triangulation, tm, qm, mm, (1.0, 1.0, 6.0, 6.0),
                          KnownRegion(box=(-1.0, -1.0, 9.0, 9.0)), 2)
