"""Elimination of diagonals: pairs of triangles become quadrangles (paper, section 2).

For every interior edge e12 that is the diagonal of a strictly convex
quadrangle q, with e34 the other diagonal,

    gain = S_q(q) - max{ S(e12), S(e34) },   S(e) = min of the pair's triangle measures,

where the quad measure S2 is paired with the triangle measure S1, and S4 with
S3.  ``greedy`` (the paper's scheme) sorts the edges by decreasing gain (ties
by the edges' endpoints' coordinates) and deletes a diagonal while both of its
triangles are still triangles and the gain is positive.  That is the locally
dominant matching of the triangles: a diagonal is deleted exactly when no
edge of its triangles that comes first in that order is, so the choice is one
of the geometry alone, and a tile's certificate follows how far it reaches
(:func:`meshcore.build._doubt_reached`).
``optimal`` deletes the set of diagonals with the largest total gain: a
maximum-weight matching of the triangles (networkx's blossom algorithm).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ._jit import empty, full, index, larger, njit, njit_helper, smaller
from .delaunay import Triangulation, _next, _prev
from .flip import edge_before, flippable, triangle_score, triangle_scores
from .predicates import lex_before
from .quality import s2_kernel, s4_cubed_kernel

__all__ = ["merge_candidates", "merge_triangles", "greedy_order"]

_PAIRED_TRIANGLE_MEASURE = {"s2": 1, "s4": 3}
_QUAD_CODE = {"s2": 2, "s4": 4}


@njit_helper
def _quad_score(measure: int, ax, ay, bx, by, cx, cy, dx, dy) -> float:
    """Score of the quadrangle with these corners: S2, or S4 cubed (paired with the
    triangle scores S1, S3 cubed); computed from the corner that comes first by
    coordinates, so any rotation of the same quadrangle gives the same bits."""
    first, fx, fy = 0, ax, ay
    if lex_before(bx, by, fx, fy):
        first, fx, fy = 1, bx, by
    if lex_before(cx, cy, fx, fy):
        first, fx, fy = 2, cx, cy
    if lex_before(dx, dy, fx, fy):
        first = 3
    if first == 1:
        ax, ay, bx, by, cx, cy, dx, dy = bx, by, cx, cy, dx, dy, ax, ay
    elif first == 2:
        ax, ay, bx, by, cx, cy, dx, dy = cx, cy, dx, dy, ax, ay, bx, by
    elif first == 3:
        ax, ay, bx, by, cx, cy, dx, dy = dx, dy, ax, ay, bx, by, cx, cy
    if measure == 2:
        return s2_kernel(ax, ay, bx, by, cx, cy, dx, dy)
    return s4_cubed_kernel(ax, ay, bx, by, cx, cy, dx, dy)


@njit_helper
def _score_to_measure(measure: int, score: float) -> float:
    return score if measure == 2 else np.cbrt(score)


@njit
def _candidates_kernel(x, y, tri, he, active, triangle_measure: int, quad_measure: int, scores):
    q = scores if scores.shape[0] == tri.shape[0] // 3 else triangle_scores(triangle_measure, x, y, tri)
    m = tri.shape[0]
    capacity = m // 8 + 16
    edges = empty(capacity, dtype=np.int32)
    gains = empty(capacity)
    n = 0
    for e in range(m):
        f = he[e]
        if f <= e or not (active[e // 3] and active[f // 3]):
            continue
        a = index(tri[e])
        b = index(tri[_next(e)])
        c = index(tri[_prev(e)])
        d = index(tri[_prev(f)])
        # each corner's coordinates read once (every score and the convexity test share them)
        xa, ya, xb, yb, xc, yc, xd, yd = x[a], y[a], x[b], y[b], x[c], y[c], x[d], y[d]
        sq = _quad_score(quad_measure, xa, ya, xd, yd, xb, yb, xc, yc)
        best = smaller(q[e // 3], q[f // 3])
        if sq <= best:
            continue
        best = larger(
            best,
            smaller(
                triangle_score(triangle_measure, xa, ya, xd, yd, xc, yc),
                triangle_score(triangle_measure, xb, yb, xc, yc, xd, yd),
            ),
        )
        if sq <= best or not flippable(xa, ya, xb, yb, xc, yc, xd, yd):
            continue
        gain = _score_to_measure(quad_measure, sq) - _score_to_measure(quad_measure, best)
        if gain > 0.0:
            if n == capacity:
                capacity *= 2
                grown_edges = empty(capacity, dtype=np.int32)
                grown_gains = empty(capacity)
                for i in range(n):  # element by element: see delaunay._merge_sort_run
                    grown_edges[i] = edges[i]
                    grown_gains[i] = gains[i]
                edges = grown_edges
                gains = grown_gains
            edges[n] = e
            gains[n] = gain
            n += 1
    return edges[:n].copy(), gains[:n].copy()


@njit
def _greedy_kernel(he, edges, gains, order, nt: int) -> np.ndarray:
    partner = full(nt, -1, dtype=np.int32)
    for k in range(order.shape[0]):
        e = edges[order[k]]
        f = he[e]
        t1 = e // 3
        t2 = f // 3
        if partner[t1] == -1 and partner[t2] == -1:
            partner[t1] = e
            partner[t2] = f
    return partner


def greedy_order(triangulation: Triangulation, edges: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """Indices by decreasing gain; equal gains by the edges' endpoints (the one
    first by coordinates, then the other), so the order is the geometry's."""
    order = np.argsort(-gains)  # (not stable: the runs of equal gains are sorted next)
    _order_ties_by_endpoints(order, gains, edges, triangulation.triangles, triangulation.x, triangulation.y)
    return order


@njit
def _order_ties_by_endpoints(order, gains, edges, tri, x, y) -> None:
    """Sort each run of equal gains in ``order`` by its edges' endpoints, in place
    (such runs are short: the gains of symmetric configurations)."""
    n = order.shape[0]
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and gains[order[stop]] == gains[order[start]]:
            stop += 1
        for i in range(start + 1, stop):  # insertion sort of the run
            k = order[i]
            j = i
            while j > start and edge_before(x, y, tri, edges[k], edges[order[j - 1]]):
                order[j] = order[j - 1]
                j -= 1
            order[j] = k
        start = stop


def merge_candidates(
    triangulation: Triangulation, quad_measure: str, active: NDArray[np.uint8] | None = None,
    scores: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    """Half-edges (one per edge) whose elimination has a positive gain, and the gains.

    With ``active`` (one flag per triangle), only diagonals between two active
    triangles are candidates.  ``scores``: every triangle's score under the
    triangle measure paired with ``quad_measure``, when the caller has them
    (:attr:`meshcore.flip.FlipRounds.scores` of flips under that measure).
    """
    if active is None:
        active = np.ones(triangulation.triangles.shape[0] // 3, dtype=np.uint8)
    return _candidates_kernel(
        triangulation.x,
        triangulation.y,
        triangulation.triangles,
        triangulation.halfedges,
        active,
        _PAIRED_TRIANGLE_MEASURE[quad_measure],
        _QUAD_CODE[quad_measure],
        np.empty(0) if scores is None else scores,
    )


def paired_triangle_measure(quad_measure: str) -> str:
    """The triangle measure a quad measure's gains compare with ("s1" for "s2", "s3" for "s4")."""
    return f"s{_PAIRED_TRIANGLE_MEASURE[quad_measure]}"


def _optimal_partner(he: NDArray[np.int32], edges: NDArray[np.int32], gains, nt: int) -> NDArray[np.int32]:
    """A maximum-weight matching of the triangles joined by candidate diagonals.

    The candidates fall apart into many small groups of triangles (on a real
    survey of 18,000 triangles, 5,500 groups of at most 140): each is matched
    alone, which is as optimal as matching them all at once and takes
    seconds where the whole graph took minutes (the blossom algorithm grows
    with the cube of its nodes).  A group of two triangles is their pair.
    """
    import networkx as nx

    graph = nx.Graph()
    twins = he[edges]
    for e, f, g in zip(edges.tolist(), twins.tolist(), gains.tolist()):
        graph.add_edge(e // 3, f // 3, weight=g, halfedges=(e, f))
    partner = np.full(nt, -1, dtype=np.int32)
    for group in nx.connected_components(graph):
        if len(group) == 2:
            pairs = [tuple(group)]
        else:
            pairs = nx.max_weight_matching(graph.subgraph(group), maxcardinality=False)
        for t1, t2 in pairs:
            e, f = graph.edges[t1, t2]["halfedges"]
            partner[e // 3] = e
            partner[f // 3] = f
    return partner


def merge_triangles(
    triangulation: Triangulation,
    quad_measure: str,
    merge: str = "greedy",
    active: NDArray[np.uint8] | None = None,
    candidates: tuple[NDArray[np.int32], NDArray[np.float64]] | None = None,
    order: NDArray[np.int64] | None = None,
) -> NDArray[np.int32]:
    """Choose the diagonals to delete; returns, per triangle, the half-edge of its
    deleted diagonal or -1 when it stays a triangle.  ``candidates``: what
    :func:`merge_candidates` returned for these arguments, when known, and
    ``order`` the greedy order of its edges (:func:`greedy_order`)."""
    nt = triangulation.triangles.shape[0] // 3
    edges, gains = merge_candidates(triangulation, quad_measure, active) if candidates is None else candidates
    if merge == "optimal":
        return _optimal_partner(triangulation.halfedges, edges, gains, nt)
    if order is None:
        order = greedy_order(triangulation, edges, gains)
    return _greedy_kernel(triangulation.halfedges, edges, gains, order, nt)
