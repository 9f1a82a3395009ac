import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import meshcore
from meshcore import InvalidInputError, MeshError, build_mesh, validate
from meshcore.flip import FLIP_TOLERANCE

from .mesh_checks import pair_scores, quad_gains, strictly_convex, triangle_pairs

OPTIONS = [
    ("delaunay", None),
    ("s1", None),
    ("s3", None),
    ("s1", "s2"),
    ("s3", "s4"),
    ("delaunay", "s2"),
]


def test_square_becomes_one_quad():
    mesh = build_mesh(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    validate(mesh)
    assert mesh.faces.shape == (1, 4)
    assert sorted(mesh.faces[0].tolist()) == [0, 1, 2, 3]
    pure = build_mesh(mesh.vertices, "s1", None)
    assert pure.faces.shape == (2, 4) and (pure.faces[:, 3] == -1).all()


def test_regular_hexagon_with_centre():
    a = np.arange(6) * math.pi / 3
    xy = np.vstack([[0.0, 0.0], np.c_[np.cos(a), np.sin(a)]])
    tri = build_mesh(xy, "s1", None)
    validate(tri)
    # six equilateral triangles: already optimal for S1, nothing to flip
    assert tri.n_triangles == 6
    assert np.allclose(meshcore.s1(tri.vertices[tri.faces[:, :3]]), 1.0)
    combined = build_mesh(xy, "s1", "s2")
    validate(combined)
    # two equilateral triangles make a rhombus with 60/120 degree angles:
    # S2 = min(sin 60, 1 + cos 120) = 0.5 < S1 = 1, so no diagonal is removed
    assert combined.n_quads == 0


def test_four_cocircular_points():
    xy = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    mesh = build_mesh(xy, "delaunay", None)
    validate(mesh)
    assert mesh.n_triangles == 2
    mesh = build_mesh(xy, "s3", "s4")
    validate(mesh)
    assert mesh.n_quads == 1 and mesh.n_triangles == 0


def test_collinear_points_keep_every_point():
    xy = np.c_[np.arange(7) * 0.25, 2.0 + np.arange(7) * 0.5]
    mesh = build_mesh(xy)
    validate(mesh)
    assert mesh.faces.shape == (0, 4)
    assert mesh.vertices.shape == (7, 2)
    assert (mesh.input_to_vertex == np.arange(7)).all()


@pytest.mark.parametrize("n", [0, 1, 2])
def test_tiny_inputs_give_empty_meshes(n):
    xy = np.arange(2 * n, dtype=float).reshape(n, 2)
    mesh = build_mesh(xy)
    validate(mesh)
    assert mesh.faces.shape == (0, 4)
    assert mesh.vertices.shape == (n, 2)
    assert mesh.input_to_vertex.tolist() == list(range(n))


def test_duplicates_share_a_vertex(rng):
    xy = rng.random((100, 2))
    noisy = np.vstack([xy, xy[:10], xy[:10]])
    order = rng.permutation(len(noisy))
    noisy = noisy[order]
    mesh = build_mesh(noisy, "s3", "s4")
    validate(mesh)
    assert mesh.vertices.shape == (100, 2)
    assert (mesh.vertices[mesh.input_to_vertex] == noisy).all()
    # the vertex of a point is its first occurrence in the input
    first = {}
    for i, p in enumerate(map(tuple, noisy)):
        first.setdefault(p, len(first))
    assert mesh.input_to_vertex.tolist() == [first[tuple(p)] for p in noisy]


def test_all_points_identical():
    mesh = build_mesh(np.full((50, 2), 3.25))
    validate(mesh)
    assert mesh.vertices.shape == (1, 2)
    assert (mesh.input_to_vertex == 0).all()


@pytest.mark.parametrize("triangle_measure, quad_measure", OPTIONS)
def test_random_meshes_are_valid_and_keep_every_point(rng, triangle_measure, quad_measure):
    xy = rng.random((1500, 2)) * [300.0, 200.0] + [612000.0, 5120000.0]
    mesh = build_mesh(xy, triangle_measure, quad_measure)
    validate(mesh)
    assert (mesh.vertices[mesh.input_to_vertex] == xy).all()
    if quad_measure is None:
        assert mesh.n_quads == 0
    else:
        assert mesh.n_quads > 0.2 * mesh.faces.shape[0]


def test_delaunay_option_matches_scipy(rng):
    from scipy.spatial import Delaunay

    xy = rng.random((500, 2))
    mesh = build_mesh(xy, "delaunay", None)
    ours = {tuple(sorted(f[:3])) for f in mesh.faces.tolist()}
    theirs = {tuple(sorted(s)) for s in Delaunay(xy).simplices.tolist()}
    assert ours == theirs


@pytest.mark.parametrize("measure", ["s1", "s3"])
def test_no_improving_flip_is_left(rng, measure):
    mesh = build_mesh(rng.random((800, 2)), measure, None)
    pairs = triangle_pairs(mesh)
    current, alternative = pair_scores(mesh, measure, pairs)
    convex = strictly_convex(mesh.vertices, *pairs.T)
    # scores compared by the kernel are S1 and S3**3: allow its tolerance in S3 terms
    slack = 1.0 + 3 * FLIP_TOLERANCE
    assert not np.any(convex & (alternative > current * slack + 1e-12))
    # and flips did happen: the Delaunay triangulation was not already optimal
    delaunay = build_mesh(mesh.vertices, "delaunay", None)
    assert {tuple(sorted(f)) for f in delaunay.faces[:, :3].tolist()} != {
        tuple(sorted(f)) for f in mesh.faces[:, :3].tolist()
    }


@pytest.mark.parametrize("triangle_measure, quad_measure", [("s1", "s2"), ("s3", "s4")])
def test_elimination_rule(rng, triangle_measure, quad_measure):
    mesh = build_mesh(rng.random((800, 2)), triangle_measure, quad_measure)
    quads = mesh.faces[mesh.faces[:, 3] >= 0]
    assert (quad_gains(mesh, quad_measure, quads) > 0).all()
    # no pair of adjacent triangles left with a positive gain
    pairs = triangle_pairs(mesh)
    a, b, c, d = pairs.T
    convex = strictly_convex(mesh.vertices, a, b, c, d)
    left = quad_gains(mesh, quad_measure, np.stack([a, d, b, c], 1)[convex])
    assert (left <= 1e-12).all()


def test_optimal_merge_gains_at_least_as_much_as_greedy(rng):
    xy = rng.random((300, 2))
    totals = {}
    for merge in ("greedy", "optimal"):
        mesh = build_mesh(xy, "s3", "s4", merge=merge)
        validate(mesh)
        quads = mesh.faces[mesh.faces[:, 3] >= 0]
        totals[merge] = quad_gains(mesh, "s4", quads).sum()
    assert totals["optimal"] >= totals["greedy"] - 1e-9


@pytest.mark.parametrize("quad_measure", ["s2", "s4"])
def test_optimal_merge_matches_each_group_of_triangles_as_well_as_the_whole_graph(rng, quad_measure):
    """Matching each connected group of candidate triangles alone gives the
    largest total gain the whole graph's matching gives."""
    import networkx as nx

    from meshcore.delaunay import delaunay
    from meshcore.merge import _optimal_partner, merge_candidates

    xy = np.round(rng.random((700, 2)) * 50.0, 2)
    triangulation = delaunay(xy)
    nt = triangulation.triangles.shape[0] // 3
    edges, gains = merge_candidates(triangulation, quad_measure)
    partner = _optimal_partner(triangulation.halfedges, edges, gains, nt)
    chosen = [e for e in partner.tolist() if e >= 0]
    twins = triangulation.halfedges[chosen]
    # every merged triangle is paired with the triangle across its chosen diagonal, and with it only
    assert all(partner[f // 3] == f for f in twins.tolist())
    gain_of = {min(e, int(f)): g for e, f, g in zip(edges.tolist(), triangulation.halfedges[edges].tolist(), gains.tolist())}
    total = sum(gain_of[min(e, int(f))] for e, f in zip(chosen, twins.tolist()) if e < f)
    graph = nx.Graph()
    for e, f, g in zip(edges.tolist(), triangulation.halfedges[edges].tolist(), gains.tolist()):
        graph.add_edge(e // 3, f // 3, weight=g)
    whole = sum(graph.edges[a, b]["weight"] for a, b in nx.max_weight_matching(graph, maxcardinality=False))
    assert nx.number_connected_components(graph) > 1
    assert total == pytest.approx(whole, rel=1e-12, abs=1e-12)


def test_scale_and_translation_invariance(rng):
    xy = rng.integers(0, 4000, size=(600, 2)) / 16.0
    reference = build_mesh(xy, "s3", "s4")
    for scale, shift in ((4.0, (0.0, 0.0)), (0.125, (0.0, 0.0)), (1.0, (2.0**19, 2.0**22))):
        other = build_mesh(xy * scale + np.array(shift), "s3", "s4")
        assert np.array_equal(other.faces, reference.faces)


def test_input_is_not_modified(rng):
    xy = rng.random((200, 2))
    before = xy.copy()
    build_mesh(xy, "s3", "s4")
    assert np.array_equal(xy, before)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"triangle_measure": "s2"}, r"triangle_measure='s2' is not valid; expected one of 'delaunay', 's1', 's3'"),
        ({"quad_measure": "s3"}, r"quad_measure='s3' is not valid; expected one of 's2', 's4'"),
        ({"merge": "best"}, r"merge='best' is not valid; expected one of 'greedy', 'optimal'"),
    ],
)
def test_unknown_options_are_named(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        build_mesh(np.zeros((3, 2)), **kwargs)


@pytest.mark.parametrize(
    "xy, match",
    [
        (np.zeros((4, 3)), r"shape \(n, 2\)"),
        (np.zeros(4), r"shape \(n, 2\)"),
        (np.array([[0.0, 0.0], [np.nan, 1.0]]), r"NaN or infinite .*index 1"),
        (np.array([[0.0, 0.0], [1.0, np.inf]]), r"NaN or infinite"),
        (np.array([["a", "b"]]), r"numeric"),
    ],
)
def test_bad_points_raise_value_errors(xy, match):
    with pytest.raises(ValueError, match=match) as info:
        build_mesh(xy)
    assert isinstance(info.value, MeshError)


point_sets = st.one_of(
    arrays(np.float64, st.tuples(st.integers(3, 60), st.just(2)), elements=st.floats(-1e3, 1e3, width=32)),
    arrays(np.int64, st.tuples(st.integers(3, 60), st.just(2)), elements=st.integers(-4, 4)).map(
        lambda a: a.astype(np.float64) * 0.5 + 1e6
    ),
)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(xy=point_sets, option=st.sampled_from(OPTIONS))
def test_property_conforming_and_lossless(xy, option):
    mesh = build_mesh(xy, *option)
    validate(mesh)
    assert (mesh.vertices[mesh.input_to_vertex] == xy).all()
    assert len(np.unique(xy, axis=0)) == mesh.vertices.shape[0]


# Survey coordinates are quantized (mm here).  A shape with a feature below
# rounding (a point 1e-22 off a unit edge) has measures that depend on which
# corner the arithmetic starts from, so "no flip or merge would improve it"
# is not decidable there; those shapes are left to the conformity test above.
quantized_point_sets = point_sets.map(lambda a: np.round(a, 3))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(xy=quantized_point_sets, measures=st.sampled_from([("s1", "s2"), ("s3", "s4")]))
def test_property_local_optimality(xy, measures):
    triangle_measure, quad_measure = measures
    mesh = build_mesh(xy, triangle_measure, quad_measure)
    pairs = triangle_pairs(mesh)
    if len(pairs):
        current, alternative = pair_scores(mesh, triangle_measure, pairs)
        convex = strictly_convex(mesh.vertices, *pairs.T)
        assert not np.any(convex & (alternative > current * (1 + 1e-6) + 1e-9))
        a, b, c, d = pairs.T
        left = quad_gains(mesh, quad_measure, np.stack([a, d, b, c], 1)[convex])
        assert (left <= 1e-9).all()
    quads = mesh.faces[mesh.faces[:, 3] >= 0]
    assert (quad_gains(mesh, quad_measure, quads) > -1e-9).all()


@pytest.mark.parametrize("seed", [4, 5])
def test_flips_of_a_window_never_touch_a_triangle_outside_it_on_survey_scan_lines(seed):
    # scan lines of a survey (dense along, sparse across, slanted, mm-rounded):
    # slivers around which flips move edges from slot to slot.  A queued slot
    # whose edge had moved to the window's border was once flipped with a
    # neighbour's triangle, and the tiles' pieces overlapped (seed 4, the last
    # window, did it)
    from meshcore._order import geometric_order
    from meshcore.build import _owned_faces, as_points
    from meshcore.delaunay import delaunay
    from meshcore.flip import flip_edges

    rng = np.random.default_rng(seed)
    line = rng.integers(0, 60, 20_000)
    x = rng.random(20_000) * 40
    y = line * 0.6 + 0.02 * x + rng.normal(0, 0.01, 20_000)
    xy = np.unique(np.round(np.c_[x, y], 3), axis=0)
    for w in range(8):
        t = geometric_order(delaunay(as_points(xy)))
        x0, y0 = rng.random(2) * [30, 25]
        window = (x0, y0, x0 + rng.uniform(3, 15), y0 + rng.uniform(3, 15))
        active = _centroid_rule(_owned_faces, t, window)
        before = t.triangles.reshape(-1, 3).copy()
        assert flip_edges(t, "s3" if w % 2 else "s1", active).flips > 0
        outside = active == 0
        assert (t.triangles.reshape(-1, 3)[outside] == before[outside]).all(), window


@pytest.mark.parametrize("triangle_measure, quad_measure", [("s1", "s2"), ("s3", "s4"), ("delaunay", None)])
def test_window_pieces_stitch_into_one_conforming_mesh(rng, triangle_measure, quad_measure):
    # four windows over a 2 x 2 split, each meshed from its own points plus a
    # buffer: the union of the pieces is one conforming mesh over the hull.
    # The boundary is sampled on the box itself, so no Delaunay triangle has a
    # circumcircle reaching past the buffer (the certificate a tiled run checks)
    side = np.arange(0.0, 100.0, 1.25)
    boundary = np.vstack(
        [np.c_[side, 0 * side], np.c_[side + 1.25, 0 * side + 100], np.c_[0 * side, side + 1.25], np.c_[0 * side + 100, side]]
    )
    inner = np.round(rng.random((6000, 2)) * 98.0 + 1.0, 2)
    xy = np.unique(np.vstack([boundary, inner]), axis=0)
    full = build_mesh(xy, triangle_measure, quad_measure)
    buffer = 12.0
    keys = {tuple(p): i for i, p in enumerate(map(tuple, xy))}
    pieces = []
    for x_lo, x_hi in ((-np.inf, 50.0), (50.0, np.inf)):
        for y_lo, y_hi in ((-np.inf, 50.0), (50.0, np.inf)):
            inside = (xy[:, 0] >= x_lo - buffer) & (xy[:, 0] < x_hi + buffer)
            inside &= (xy[:, 1] >= y_lo - buffer) & (xy[:, 1] < y_hi + buffer)
            piece = build_mesh(xy[inside], triangle_measure, quad_measure, window=(x_lo, y_lo, x_hi, y_hi))
            validate(piece)
            ids = np.array([keys[tuple(p)] for p in map(tuple, piece.vertices)])
            f = piece.faces.copy()
            f[f >= 0] = ids[f[f >= 0]]
            pieces.append(f)
    faces = np.vstack(pieces)
    stitched = meshcore.Mesh(xy, faces, np.arange(len(xy)))
    validate(stitched)

    def as_set(fs):
        out = set()
        for row in fs.tolist():
            row = [v for v in row if v >= 0]
            k = row.index(min(row))
            out.add(tuple(row[k:] + row[:k]))
        return out

    same = len(as_set(faces) & as_set(full.faces)) / len(full.faces)
    print(f"identical faces {same:.4f}")
    assert same > 0.97


def test_window_must_be_a_box():
    with pytest.raises(InvalidInputError, match="x_min < x_max"):
        build_mesh(np.zeros((3, 2)), window=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(InvalidInputError, match="window must be"):
        build_mesh(np.zeros((3, 2)), window=(1.0, 0.0))


def _face_set(mesh):
    """Faces as tuples of corner coordinates (meshcore starts each at its smallest corner)."""
    out = set()
    for row in mesh.faces.tolist():
        out.add(tuple(tuple(mesh.vertices[v]) for v in row if v >= 0))
    return out


@pytest.mark.parametrize("triangle_measure, quad_measure", [("s1", "s2"), ("s3", "s4")])
def test_window_piece_depends_on_geometry_not_on_numbering(rng, triangle_measure, quad_measure):
    # the same window from the same nearby points, once alone and once shuffled
    # among many far points (another sweep, other internal numbers, another
    # local origin): flips and merges must treat every active triangle alike
    near = np.round(rng.random((4000, 2)) * 60.0 + 500_000.0, 2)
    far = np.round(rng.random((6000, 2)) * 200.0 + 499_900.0, 2)
    far = far[(np.abs(far - 500_030.0) > 40.0).any(axis=1)]
    window = (500_010.0, 500_010.0, 500_050.0, 500_050.0)
    alone = build_mesh(near, triangle_measure, quad_measure, window=window)
    mixed = np.vstack([near, far])[rng.permutation(len(near) + len(far))]
    among = build_mesh(mixed, triangle_measure, quad_measure, window=window)
    assert alone.n_quads > 100
    assert _face_set(alone) == _face_set(among)


def test_meets_box_is_exact_up_to_its_slack(rng):
    from meshcore.build import _meets_box

    for _ in range(400):
        a, b, c = rng.random((3, 2)) * 10
        if (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) < 0:
            b, c = c, b
        lo = rng.random(2) * 10
        hi = lo + rng.random(2) * 3
        meets = _meets_box(*a, *b, *c, lo[0], lo[1], hi[0], hi[1], 0.0)
        # dense samples of the triangle: any inside the box proves they meet
        w = rng.dirichlet(np.ones(3), 20000)
        p = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
        hit = np.any((p[:, 0] >= lo[0]) & (p[:, 0] <= hi[0]) & (p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1]))
        if hit:
            assert meets
    # a sliver whose bounding box covers the box but which passes beside it
    assert not _meets_box(0.0, 0.0, 10.0, 9.0, 0.0, 1.0, 8.0, 0.0, 10.0, 2.0, 0.0)
    assert _meets_box(0.0, 0.0, 10.0, 9.0, 0.0, 1.0, -np.inf, -np.inf, np.inf, 0.5, 0.0)


def test_lexicographic_order_sorts_by_x_then_y(rng):
    from meshcore.tiles import lexicographic_order

    # survey-like coordinates on a 1 cm lattice: long runs of equal x, and
    # runs longer than the insertion-sorted ones
    pts = np.round(rng.random((20000, 2)) * [3.0, 50.0] + 651000.0, 2)
    pts = np.vstack([pts, np.column_stack([np.full(100, 651001.5), rng.random(100)])])
    order = lexicographic_order(pts)
    assert np.array_equal(pts[order], pts[np.lexsort((pts[:, 1], pts[:, 0]))])
    assert np.array_equal(np.sort(order), np.arange(len(pts)))


@pytest.mark.parametrize(
    "make",
    [
        lambda rng: rng.normal(size=(5000, 2)) * [1e6, 1e-3],  # both signs, x spanning far more bits than y
        lambda rng: np.column_stack([np.full(3000, 2.5), rng.random(3000)]),  # one x: the key is all y
        lambda rng: np.column_stack([rng.choice([-0.0, 0.0, 1e-300, -1e300, 1e300], 4000), rng.integers(-3, 3, 4000) * 0.5]),
        lambda rng: np.round(rng.random((8000, 2)) * [1e-9, 1.0], 12) - [0.0, 0.5],
    ],
)
def test_lexicographic_order_is_numpys_order_for_any_coordinates(make, rng):
    from meshcore.tiles import lexicographic_order

    pts = make(rng)
    order = lexicographic_order(pts)
    # numpy's order of complex numbers is (real, imaginary), with -0.0 == 0.0
    key = pts[:, 0] + 1j * pts[:, 1]
    assert np.all(key[order][1:] >= key[order][:-1])
    assert np.array_equal(np.sort(order), np.arange(len(pts)))


def _centroid_rule(owned_faces, t, window):
    """The triangles a window owns when no two are merged: those whose centroid lies in it."""
    partner = np.full(t.triangles.shape[0] // 3, -1, dtype=np.int32)
    owned, _ = owned_faces(t.x, t.y, float(t.origin[0]), float(t.origin[1]), t.triangles, t.halfedges, partner,
                           np.array(window, dtype=np.float64))
    return owned


@pytest.mark.parametrize("offset", [0.0, 6.5e5, -3.2e7, 1.0e8])
def test_a_window_owns_the_triangles_whose_centroid_it_holds(offset, rng):
    from meshcore.build import _centroid, _owned_faces
    from meshcore.delaunay import delaunay

    # a lattice puts corners on the window's edges and its centroids on them
    # too; the random points add triangles of every shape near them
    lattice = np.stack(np.meshgrid(np.arange(0.0, 40.0, 0.5), np.arange(0.0, 30.0, 0.5)), -1).reshape(-1, 2)
    xy = np.vstack([lattice, rng.random((3000, 2)) * [40.0, 30.0]]) + offset
    t = delaunay(xy)
    ox, oy = (float(v) for v in t.origin)
    tri = t.triangles.reshape(-1, 3)
    for window in [(offset + 10.0, offset + 5.0, offset + 20.5, offset + 17.0), (-np.inf, offset + 3.0, offset + 7.25, np.inf)]:
        active = _centroid_rule(_owned_faces, t, window)
        expect = []
        for i, j, k in tri:
            cx, cy = _centroid(t.x[i], t.y[i], t.x[j], t.y[j], t.x[k], t.y[k], ox, oy)
            expect.append(window[0] <= cx < window[2] and window[1] <= cy < window[3])
        assert np.array_equal(active.astype(bool), np.array(expect))
        assert 0 < active.sum() < len(tri)


@pytest.mark.parametrize("offset", [(0.0, 0.0), (6e5, 5e6), (484649.36, 6632629.73)])
@pytest.mark.parametrize("bulge", [1, 2, 7])
def test_a_sliver_circle_is_bounded_to_ulps_of_its_radius(offset, bulge):
    """The circles of the slivers along a straight survey edge (thousands of
    kilometres): their bound holds the exact circle and is ulps wider, so a
    tile's certificate reads a thin lens along the edge, not the survey."""
    from fractions import Fraction

    from meshcore.certificate import safe_circle as _safe_circle

    ox, oy = offset
    # cm lattice points along a slanted edge 300 m long; the middle one off the line by 'bulge' cm
    a = (round(ox + 0.0, 2), round(oy + 0.0, 2))
    b = (round(ox + 150.0, 2), round(oy + 90.0 + 0.01 * bulge, 2))
    c = (round(ox + 300.0, 2), round(oy + 180.0, 2))
    ux, uy, r = _safe_circle(*a, *b, *c)
    ax, ay, bx, by, cx, cy = map(Fraction, (*a, *b, *c))
    dx, dy, ex, ey = bx - ax, by - ay, cx - ax, cy - ay
    d = 2 * (dx * ey - dy * ex)
    px = (ey * (dx * dx + dy * dy) - dy * (ex * ex + ey * ey)) / d
    py = (dx * (ex * ex + ey * ey) - ex * (dx * dx + dy * dy)) / d
    exact_r = math.sqrt(float(px * px + py * py))
    assert exact_r > 1e5  # a sliver: more than 100 km
    # the bound's disk holds the exact one ...
    gap = math.hypot(float(px - Fraction(ux)), float(py - Fraction(uy)))
    assert gap + exact_r <= r
    # ... and is no wider than a micrometre per thousand kilometres
    assert r - exact_r <= 4e-12 * exact_r + 1e-9


def test_the_faces_stage_compiles_on_a_grid_it_makes_as_build_mesh_would():
    """load_kernels("faces") runs build_mesh's stages after the sweep on a
    grid's triangulation: a valid windowed mesh, the same as build_mesh
    gives for the grid's points with the same window."""
    mesh = meshcore.tiles.load_kernels("faces", "s3", "s4", "greedy")
    meshcore.validate(mesh)
    assert mesh.window == (1.0, 1.0, 6.0, 6.0) and mesh.faces.shape[0] > 0
    built = meshcore.build_mesh(mesh.vertices, "s3", "s4", "greedy", window=(1.0, 1.0, 6.0, 6.0),
                                known=(-1.0, -1.0, 9.0, 9.0))
    corners = {tuple(sorted(map(tuple, mesh.vertices[f[f >= 0]]))) for f in mesh.faces}
    assert corners == {tuple(sorted(map(tuple, built.vertices[f[f >= 0]]))) for f in built.faces}
    assert meshcore.tiles.load_kernels("triangulation") is None
    with pytest.raises(meshcore.InvalidInputError, match="stage"):
        meshcore.tiles.load_kernels("flips")
