import numpy as np
import pytest
from scipy.spatial import Delaunay

from meshcore.delaunay import _insert_point, _locate, delaunay
from meshcore.predicates import incircle, orient2d


def triangles_in_input_ids(xy):
    t = delaunay(xy)
    tri = t.order[t.triangles.reshape(-1, 3)]
    return t, tri


def canonical(tri):
    """Triangles as a set of vertex triples in a rotation-free form."""
    return {tuple(sorted(row)) for row in np.asarray(tri).tolist()}


def check_structure(t):
    tri = t.triangles.reshape(-1, 3)
    x, y = t.x, t.y
    for a, b, c in tri:
        assert orient2d(x[a], y[a], x[b], y[b], x[c], y[c]) > 0
    he = t.halfedges
    e = np.arange(he.size)
    inner = he >= 0
    assert (he[he[inner]] == e[inner]).all()
    nxt = e - e % 3 + (e % 3 + 1) % 3
    assert (t.triangles[e[inner]] == t.triangles[nxt[he[inner]]]).all()


def locally_delaunay(t):
    """Every interior edge passes the exact empty-circle test (co-circular allowed)."""
    tri, he, x, y = t.triangles, t.halfedges, t.x, t.y
    for e in range(he.size):
        f = he[e]
        if f < e:
            continue
        a, b = tri[e], tri[e - e % 3 + (e % 3 + 1) % 3]
        c = tri[e - e % 3 + (e % 3 + 2) % 3]
        d = tri[f - f % 3 + (f % 3 + 2) % 3]
        if incircle(x[a], y[a], x[b], y[b], x[c], y[c], x[d], y[d]) > 0:
            return False
    return True


@pytest.mark.parametrize("n", [3, 4, 10, 100, 2000])
def test_matches_scipy_on_random_points(rng, n):
    xy = rng.random((n, 2))
    t, tri = triangles_in_input_ids(xy)
    check_structure(t)
    assert canonical(tri) == canonical(Delaunay(xy).simplices)


def test_survey_scale_coordinates_with_cm_spacing(rng):
    xy = np.round(rng.random((3000, 2)) * 500 + [612345.0, 5123456.0], 2)
    t, tri = triangles_in_input_ids(xy)
    check_structure(t)
    assert locally_delaunay(t)
    # Qhull works in its own frame; on rounded survey data both must agree
    # wherever the triangulation is unique, so compare areas and counts
    assert len(tri) == len(Delaunay(xy).simplices)


def test_grid_is_triangulated_with_cocircular_squares():
    g = np.stack(np.meshgrid(np.arange(25.0), np.arange(18.0)), -1).reshape(-1, 2)
    t = delaunay(g)
    check_structure(t)
    assert t.triangles.size // 3 == 2 * 24 * 17
    assert locally_delaunay(t)


def test_points_on_a_circle():
    a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    xy = np.c_[np.cos(a), np.sin(a)]
    t = delaunay(xy)
    check_structure(t)
    assert t.triangles.size // 3 == 62


def test_duplicates_map_to_first_occurrence(rng):
    xy = rng.random((300, 2))
    dup = np.vstack([xy, xy[::3], xy[:5]])
    t = delaunay(dup)
    check_structure(t)
    rep_input = t.order[t.rep]
    first = {}
    for i, p in enumerate(map(tuple, dup)):
        first.setdefault(p, i)
    expected = np.array([first[tuple(p)] for p in dup])
    got = np.empty(len(dup), dtype=np.int64)
    got[t.order] = rep_input
    assert (got == expected).all()
    assert canonical(t.order[t.triangles.reshape(-1, 3)]) == canonical(Delaunay(xy).simplices)


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_points_give_no_triangle(n, rng):
    t = delaunay(rng.random((n, 2)))
    assert t.triangles.size == 0
    assert t.order.size == n


def test_collinear_points_give_no_triangle_but_keep_points():
    xy = np.c_[np.arange(10.0), 2 * np.arange(10.0)]
    xy = np.vstack([xy, xy[3]])
    t = delaunay(xy)
    assert t.triangles.size == 0
    assert (t.rep == np.arange(11)).sum() == 10


def test_incremental_insertion_inside_and_on_edges(rng):
    # the path that places points the sweep could not put outside the hull:
    # insert interior points, midpoints of interior edges and of hull edges
    base = rng.random((40, 2))
    t = delaunay(base)
    tri0 = t.triangles.reshape(-1, 3)
    a, b = tri0[:, 0], tri0[:, 1]
    he0 = t.halfedges.reshape(-1, 3)
    hull_slot = np.flatnonzero(he0[:, 0] < 0)[:2]
    inner_slot = np.flatnonzero(he0[:, 0] >= 0)[:2]
    mids = [((t.x[a[k]] + t.x[b[k]]) / 2, (t.y[a[k]] + t.y[b[k]]) / 2) for k in (*hull_slot, *inner_slot)]
    extra = np.array(mids + [tuple(p) for p in (rng.random((30, 2)) * 0.5 + 0.25 - t.origin)])
    x = np.concatenate([t.x, extra[:, 0]])
    y = np.concatenate([t.y, extra[:, 1]])
    n0 = t.x.size
    cap = t.triangles.size + 6 * len(extra)
    tri = np.empty(cap, dtype=np.int32)
    he = np.empty(cap, dtype=np.int32)
    tri[: t.triangles.size] = t.triangles
    he[: t.halfedges.size] = t.halfedges
    nt = t.triangles.size // 3
    stack = np.empty(8, dtype=np.int32)
    seed = 7
    for k in range(len(extra)):
        p = n0 + k
        where, seed = _locate(tri[: 3 * nt], he[: 3 * nt], x, y, x[p], y[p], 0, seed)
        assert where >= 0
        nt, stack, dup = _insert_point(tri, he, nt, x, y, p, where, stack)
        assert dup == -1
    from types import SimpleNamespace

    grown = SimpleNamespace(triangles=tri[: 3 * nt], halfedges=he[: 3 * nt], x=x, y=y)
    check_structure(grown)
    assert locally_delaunay(grown)
    assert np.unique(grown.triangles).size == x.size
    # a Delaunay triangulation has 2n - 2 - h triangles
    assert nt == 2 * x.size - 2 - np.count_nonzero(grown.halfedges < 0)


def test_cocircular_ties_do_not_depend_on_input_order(rng):
    # a grid is all ties; the symbolic perturbation makes the triangulation unique
    g = np.stack(np.meshgrid(np.arange(12.0), np.arange(9.0)), -1).reshape(-1, 2)
    ring = np.c_[np.cos(np.arange(16) * np.pi / 8), np.sin(np.arange(16) * np.pi / 8)] * 3 + 20
    for pts in (g, np.vstack([g, np.round(ring, 0)])):
        pts = np.unique(pts, axis=0)
        reference = None
        for _ in range(4):
            perm = rng.permutation(len(pts))
            t = delaunay(pts[perm])
            check_structure(t)
            triangles = {tuple(sorted(map(tuple, pts[perm][t.order[row]].tolist()))) for row in t.triangles.reshape(-1, 3)}
            reference = reference or triangles
            assert triangles == reference


def test_overlapping_subsets_agree_where_circumcircles_are_covered(rng):
    # two tiles with a shared overlap: triangles whose circumcircle lies inside
    # both point sets' boxes are the same (the certificate a tiled run relies on)
    pts = np.round(rng.random((4000, 2)) * 100, 1)
    pts = np.unique(pts, axis=0)
    left = pts[pts[:, 0] < 60]
    right = pts[pts[:, 0] >= 40]

    def certified(sub, lo, hi):
        t = delaunay(sub)
        p = sub[t.order]
        out = set()
        for a, b, c in t.triangles.reshape(-1, 3):
            (ax, ay), (bx, by), (cx, cy) = p[a], p[b], p[c]
            d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
            ux = ((ax**2 + ay**2) * (by - cy) + (bx**2 + by**2) * (cy - ay) + (cx**2 + cy**2) * (ay - by)) / d
            r = np.hypot(ax - ux, ay - ((ax**2 + ay**2) * (cx - bx) + (bx**2 + by**2) * (ax - cx) + (cx**2 + cy**2) * (bx - ax)) / d)
            if lo <= ux - r and ux + r <= hi:
                out.add(tuple(sorted(map(tuple, (p[a], p[b], p[c])))))
        return out

    a = certified(left, 40, 60)
    b = certified(right, 40, 60)
    assert len(a) > 100
    assert a == b
