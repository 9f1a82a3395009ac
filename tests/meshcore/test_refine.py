"""Tests of the smooth surface's long faces: long edges split, their faces cut, the new points kriged."""

from __future__ import annotations

import numpy as np
import pytest

import meshcore
from meshcore.errors import InvalidInputError
from meshcore.interpolate import _surface_at
from meshcore.refine import refine_long_faces
from meshcore.smooth import smooth_plan, smooth_surface
from meshcore.variogram import Variogram, fit_variogram

from .mesh_checks import edge_faces

OFFSET = np.array([6.0e5, 6.8e6])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261203)


def _with_void(rng, n=1500):
    xy = rng.random((n, 2)) * 100.0
    xy = xy[np.hypot(xy[:, 0] - 50.0, xy[:, 1] - 50.0) > 20.0]  # a void of 40 m across
    return xy + OFFSET


def _area(v, face):
    pts = v[face[face >= 0]] - v[face[0]]
    x, y = pts[:, 0], pts[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def test_long_faces_are_cut_into_triangles_that_tile_them(rng):
    xy = _with_void(rng)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    refined, parent, ends, t = refine_long_faces(mesh, 2.5, 4.0, 2.0)
    assert refined.vertices.shape[0] > mesh.vertices.shape[0]
    v = refined.vertices
    # conforming: every edge between one or two faces, two of them in opposite directions
    # (validate() would find the split points on the hull slightly off its straight edges)
    directed = {}
    for face in refined.faces:
        n = 4 if face[3] >= 0 else 3
        for k in range(n):
            key = (int(face[k]), int(face[(k + 1) % n]))
            assert key not in directed
            directed[key] = True
    hull_edges = sum((b, a) not in directed for a, b in directed)
    original = sum(1 for face in mesh.faces for k in range(4 if face[3] >= 0 else 3))
    assert hull_edges < 0.2 * original
    areas = np.array([_area(v, f) for f in refined.faces])
    assert np.all(areas > 0.0)
    whole = np.zeros(mesh.faces.shape[0])
    np.add.at(whole, parent, areas)
    expected = np.array([_area(mesh.vertices, f) for f in mesh.faces])
    np.testing.assert_allclose(whole, expected, rtol=1e-9, atol=1e-6)  # split points rounded at survey coordinates
    # every new point on its edge, at its place, and its edge long
    new = v[mesh.vertices.shape[0]:]
    a, b = mesh.vertices[ends[:, 0]], mesh.vertices[ends[:, 1]]
    np.testing.assert_array_equal(new, a + t[:, None] * (b - a))
    assert np.all(np.hypot(*(b - a).T) > 4.0 * 2.5)
    # untouched where no edge is long
    same, parent2, _, _ = refine_long_faces(mesh, 1e6, 4.0, 2.0)
    assert same is mesh and np.array_equal(parent2, np.arange(mesh.faces.shape[0]))
    with pytest.raises(InvalidInputError):
        refine_long_faces(mesh, 0.0, 4.0, 2.0)
    with pytest.raises(InvalidInputError):
        refine_long_faces(mesh, 1.0, 2.0, 4.0)


def test_refined_smooth_surface_is_continuous_and_through_the_points(rng):
    xy = _with_void(rng)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    z = np.sin((mesh.vertices[:, 0] - OFFSET[0]) / 9.0) + 0.02 * (mesh.vertices[:, 1] - OFFSET[1])
    variogram = Variogram(1e-5, 1.0, 20.0, "matern52", 2.5)  # smooth ground: edges over 4 spacings split
    surface = smooth_surface(mesh, z, variogram)
    refined, zr, nodes = surface.mesh, surface.z, surface.nodes
    assert refined.vertices.shape[0] > mesh.vertices.shape[0]
    assert np.all(np.isfinite(zr)) and np.array_equal(zr[: z.size], z)
    v, faces = refined.vertices, refined.faces
    sides = edge_faces(faces)
    worst = 0.0
    for (a, b), fs in sides.items():
        if len(fs) == 2:
            for s in rng.random(2):
                p = v[a] + s * (v[b] - v[a])
                worst = max(worst, abs(_surface_at(v, faces, zr, nodes, fs[0], p[0], p[1])[0]
                                       - _surface_at(v, faces, zr, nodes, fs[1], p[0], p[1])[0]))
    assert worst < 1e-7
    at = meshcore.interpolate(mesh, z, mesh.vertices[:, 0], mesh.vertices[:, 1], surface=surface)
    np.testing.assert_allclose(at, z, atol=1e-7)
    # on rough ground the added points are clamped as nodes are: within their neighbours' and edge's ends' values
    rough = smooth_surface(mesh, z, Variogram(0.01, 1.0, 20.0, "exponential", 2.5))
    added = rough.z[z.size:]
    assert added.size and np.all(added >= z.min()) and np.all(added <= z.max())


def test_window_pieces_split_their_shared_long_edges_alike(rng):
    """Seamless: the new points of an edge two pieces share are bit-identical in place and value."""
    xy = _with_void(rng, 3000)
    z = 5.0 + np.sin((xy[:, 0] - OFFSET[0]) / 15.0) + rng.normal(0.0, 0.01, xy.shape[0])
    variogram = fit_variogram(xy, z)
    split = OFFSET[0] + 50.0
    found = []
    for window in ((OFFSET[0], OFFSET[1], split, OFFSET[1] + 100.0), (split, OFFSET[1], OFFSET[0] + 100.0, OFFSET[1] + 100.0)):
        lo, hi = window[0] - 40.0, window[2] + 40.0
        keep = (xy[:, 0] >= lo) & (xy[:, 0] <= hi)
        mesh = meshcore.build_mesh(xy[keep], "s3", "s4", window=window)
        zz = np.empty(mesh.vertices.shape[0])
        zz[mesh.input_to_vertex] = z[keep]
        plan = smooth_plan(mesh, variogram)
        surface = smooth_surface(mesh, zz, variogram, plan=plan)
        n = mesh.vertices.shape[0]
        found.append({(tuple(mesh.vertices[e0]), tuple(mesh.vertices[e1]), tuple(p)): value
                      for (e0, e1), p, value in zip(plan.refinement.ends, surface.mesh.vertices[n:], surface.z[n:])})
    shared = set(found[0]) & set(found[1])
    assert len(shared) >= 2
    for key in shared:
        assert found[0][key] == found[1][key]  # exactly


def test_nearest_around_a_few_centres_is_the_exact_nearest(rng):
    from meshcore._buckets import _nearest, _nearest_around

    xy = rng.random((5000, 2)) * 100.0 + OFFSET
    xy[:50] = xy[50:100]  # ties
    centres = np.concatenate([rng.random((40, 2)) * 100.0 + OFFSET, [[OFFSET[0] - 30.0, OFFSET[1]]]])
    sparse = xy[::400]  # fewer points around the centres than neighbours asked for
    for points in (xy, sparse):
        for side in (0.5, 3.0, 20.0):
            index, d2 = _nearest_around(points, centres, 16, side)
            want, want_d2 = _nearest(points, centres, 16)
            np.testing.assert_array_equal(index, want)
            np.testing.assert_array_equal(d2, want_d2)
    for side in (0.5, 3.0, 20.0):
        index, d2 = _nearest_around(xy, centres, 16, side)
        want, want_d2 = _nearest(xy, centres, 16)
        np.testing.assert_array_equal(index, want)
        np.testing.assert_array_equal(d2, want_d2)


def test_disks_holding_a_point_are_all_found(rng):
    """Every closed disk that holds a point is found, a point on its circle too; the
    others only when a point comes within a billionth of the radius."""
    from meshcore._buckets import _disks_holding

    points = rng.random((300, 2)) * 100.0 + OFFSET
    centres = rng.random((2000, 2)) * 140.0 + OFFSET - 20.0
    radius = rng.random(2000) * 6.0
    radius[:50] = np.sqrt(((points[:50] - centres[:50]) ** 2).sum(axis=1))  # a point on the circle, to rounding
    radius[50:60] = np.inf
    radius[60:70] = 80.0  # wide
    d2 = ((centres[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    holds = np.any(d2 <= radius[:, None] ** 2, axis=1)
    near = np.any(d2 <= (radius[:, None] * (1.0 + 1e-9)) ** 2, axis=1)
    found = _disks_holding(centres, radius, points)
    assert 100 < holds.sum() < 1900
    assert found[:70].all() and np.all(found[holds]) and not np.any(found & ~near)
    assert not _disks_holding(centres, radius, points[:0]).any()


def test_linear_ground_is_reproduced_on_the_cut_faces_too(rng):
    xy = _with_void(rng)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    local = mesh.vertices - OFFSET
    z = 3.0 + 0.2 * local[:, 0] - 0.05 * local[:, 1]
    surface = smooth_surface(mesh, z, Variogram(0.0, 1.0, 20.0, "matern52", 2.5))
    assert surface.mesh.faces.shape[0] > mesh.faces.shape[0]
    q = rng.random((4000, 2)) * 100.0 + OFFSET
    got = meshcore.interpolate(mesh, z, q[:, 0], q[:, 1], surface=surface)
    want = 3.0 + 0.2 * (q[:, 0] - OFFSET[0]) - 0.05 * (q[:, 1] - OFFSET[1])
    inside = np.isfinite(got)
    assert inside.mean() > 0.9
    np.testing.assert_allclose(got[inside], want[inside], atol=1e-8)
    gx, gy = meshcore.gradient(mesh, z, q[inside, 0], q[inside, 1], surface=surface)
    np.testing.assert_allclose(gx, 0.2, atol=1e-7)
    np.testing.assert_allclose(gy, -0.05, atol=1e-7)


def test_max_edge_leaves_out_the_cells_of_the_faces_cut_with_their_face(rng):
    xy = _with_void(rng)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    z = np.sin((mesh.vertices[:, 0] - OFFSET[0]) / 9.0)
    surface = smooth_surface(mesh, z, Variogram(1e-5, 1.0, 20.0, "matern52", 2.5))
    for max_edge in (6.0, 12.0, None):
        smooth = meshcore.rasterize(mesh, z, *OFFSET, 0.5, 200, 200, max_edge=max_edge, surface=surface)
        linear = meshcore.rasterize(mesh, z, *OFFSET, 0.5, 200, 200, max_edge=max_edge)
        np.testing.assert_array_equal(np.isnan(smooth), np.isnan(linear))
    computed = meshcore.rasterize(mesh, z, *OFFSET, 0.5, 200, 200, surface="smooth",
                                  variogram=Variogram(1e-5, 1.0, 20.0, "matern52", 2.5))
    np.testing.assert_array_equal(computed, meshcore.rasterize(mesh, z, *OFFSET, 0.5, 200, 200, surface=surface))
    with pytest.raises(InvalidInputError, match="another mesh"):
        meshcore.rasterize(mesh, z + 1.0, *OFFSET, 0.5, 20, 20, surface=surface)


def test_the_surface_reads_no_point_outside_its_plan_disks(rng):
    """A point outside every disk of the plan changes nothing: the certificate's promise."""
    xy = _with_void(rng, 2500)
    z = 5.0 + np.sin((xy[:, 0] - OFFSET[0]) / 15.0) + rng.normal(0.0, 0.01, xy.shape[0])
    variogram = fit_variogram(xy, z)
    window = (OFFSET[0] + 20.0, OFFSET[1] + 20.0, OFFSET[0] + 60.0, OFFSET[1] + 60.0)
    known = (window[0] - 8.0, window[1] - 8.0, window[2] + 8.0, window[3] + 8.0)
    mesh = meshcore.build_mesh(xy, "s3", "s4", window=window, known=known)
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    plan = smooth_plan(mesh, variogram)
    assert plan.refinement.ends.shape[0] > 0  # faces across the void are cut
    # the disks the surface reads, and the circles the Delaunay piece depends on
    disks = np.concatenate([plan.disks, mesh.window_escapes]) if mesh.window_escapes is not None else plan.disks
    assert np.all(np.isfinite(disks))
    d2 = (xy[:, 0, None] - disks[None, :, 0]) ** 2 + (xy[:, 1, None] - disks[None, :, 1]) ** 2
    far = ~np.any(d2 <= (disks[None, :, 2] * (1 + 1e-9)) ** 2, axis=1)
    used = np.zeros(mesh.vertices.shape[0], dtype=bool)
    used[mesh.faces[mesh.faces >= 0]] = True
    outside = (xy[:, 0] < known[0]) | (xy[:, 1] < known[1]) | (xy[:, 0] > known[2]) | (xy[:, 1] > known[3])
    drop = far & outside & ~used[mesh.input_to_vertex]
    assert drop.sum() > 100
    whole = smooth_surface(mesh, zz, variogram, plan=plan)
    part_mesh = meshcore.build_mesh(xy[~drop], "s3", "s4", window=window, known=known)
    part_z = np.empty(part_mesh.vertices.shape[0])
    part_z[part_mesh.input_to_vertex] = z[~drop]
    part = smooth_surface(part_mesh, part_z, variogram)
    q = rng.random((3000, 2)) * 40.0 + OFFSET + 20.0
    a = meshcore.interpolate(mesh, zz, q[:, 0], q[:, 1], surface=whole)
    b = meshcore.interpolate(part_mesh, part_z, q[:, 0], q[:, 1], surface=part)
    np.testing.assert_array_equal(a, b)


def test_an_outlier_far_away_costs_little(rng):
    """Two clusters six thousand kilometres apart (a header's offset lied): edges to the far
    one are split into a bounded number of pieces, and the nearest search crosses the empty
    rings between them quickly and exactly."""
    import time

    from meshcore._buckets import _nearest

    near = rng.random((3000, 2)) * [70.0, 80.0] + [6.51e5, 6.861e6]
    far = rng.random((3000, 2)) * [70.0, 80.0] + [6.51e5, 0.0]
    xy = np.round(np.concatenate([near, far]), 2)
    z = np.sin(xy[:, 0] / 9.0) + 1e-3 * rng.normal(size=xy.shape[0])
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    variogram = Variogram(1e-5, 1.0, 20.0, "matern52", 1.0)
    t0 = time.perf_counter()
    surface = smooth_surface(mesh, zz, variogram)
    assert time.perf_counter() - t0 < 60.0  # it took hours, and gigabytes, with no bound on the pieces
    ends = smooth_plan(mesh, variogram).refinement.ends
    assert 0 < ends.shape[0] <= 63 * 3 * mesh.faces.shape[0]
    assert np.all(np.isfinite(surface.z))
    queries = np.column_stack([np.full(200, 6.51e5 + 35.0), np.linspace(-1e5, 7e6, 200)])
    index, d2 = _nearest(xy, queries, 16)
    want = np.sort(((xy[None, :, 0] - queries[:, None, 0]) ** 2 + (xy[None, :, 1] - queries[:, None, 1]) ** 2), axis=1)[:, :16]
    np.testing.assert_array_equal(d2, want)


def test_a_plan_grown_by_points_in_its_disks_is_the_plan_of_the_grown_mesh(rng):
    """A window piece whose faces are certified gets the points its kriging disks
    still need as vertices no face uses: the plan grown from the previous one is
    the grown mesh's own plan, and the surface is that of the piece built again
    with those points."""
    xy = _with_void(rng, 3000)
    z = 5.0 + np.sin((xy[:, 0] - OFFSET[0]) / 15.0) + rng.normal(0.0, 0.01, xy.shape[0])
    variogram = fit_variogram(xy, z)
    window = (OFFSET[0] + 20.0, OFFSET[1] + 20.0, OFFSET[0] + 80.0, OFFSET[1] + 80.0)  # around the void
    known = (window[0] - 4.0, window[1] - 4.0, window[2] + 4.0, window[3] + 4.0)
    inside = (xy[:, 0] >= known[0]) & (xy[:, 1] >= known[1]) & (xy[:, 0] <= known[2]) & (xy[:, 1] <= known[3])
    mesh = meshcore.build_mesh(xy[inside], "s3", "s4", window=window, known=known)
    plan = smooth_plan(mesh, variogram)
    assert plan.refinement.ends.shape[0] > 0  # faces across the void are cut: their new points are renumbered

    def within(points, disks):
        d2 = (points[:, 0, None] - disks[None, :, 0]) ** 2 + (points[:, 1, None] - disks[None, :, 1]) ** 2
        return np.any(d2 <= disks[None, :, 2] ** 2, axis=1)

    outside = xy[~inside]
    wanted = within(outside, plan.disks) & ~within(outside, mesh.window_escapes)
    assert wanted.sum() > 20
    added = np.concatenate([outside[wanted], outside[wanted][:3], xy[inside][:2]])  # and points already there
    grown = meshcore.tiles.with_vertices(mesh, added)
    assert grown.vertices.shape[0] == mesh.vertices.shape[0] + wanted.sum()
    np.testing.assert_array_equal(grown.vertices[grown.input_to_vertex[-5:]], added[-5:])

    again = smooth_plan(grown, variogram, previous=plan)
    fresh = smooth_plan(grown, variogram)
    changed = np.any(again.nodes.index != plan.nodes.index, axis=1)
    assert 0 < changed.sum() < changed.size  # some systems searched again, not all
    def assert_same(a, b):
        for x, y in zip(a, b):
            if isinstance(x, meshcore.Mesh):
                np.testing.assert_array_equal(x.vertices, y.vertices)
                np.testing.assert_array_equal(x.faces, y.faces)
            elif isinstance(x, tuple):  # the voids' fills and their natural neighbours
                assert_same(x, y)
            else:
                np.testing.assert_array_equal(x, y)

    for a, b in ((again.refinement, fresh.refinement), (again.nodes, fresh.nodes), (again.added, fresh.added)):
        assert_same(a, b)

    # the same surface as the piece built again with the points
    values = np.concatenate([z[inside], z[~inside][wanted]])
    zz = np.empty(grown.vertices.shape[0])
    zz[grown.input_to_vertex[: values.size]] = values
    rebuilt = meshcore.build_mesh(np.concatenate([xy[inside], outside[wanted]]), "s3", "s4", window=window, known=known)
    rz = np.empty(rebuilt.vertices.shape[0])
    rz[rebuilt.input_to_vertex] = values
    q = rng.random((3000, 2)) * 56.0 + OFFSET + 22.0  # inside the window (its piece may stop short of its edges)
    a = meshcore.interpolate(grown, zz, q[:, 0], q[:, 1], surface=smooth_surface(grown, zz, variogram, plan=again))
    b = meshcore.interpolate(rebuilt, rz, q[:, 0], q[:, 1], surface=smooth_surface(rebuilt, rz, variogram))
    assert np.isfinite(a).all()
    np.testing.assert_array_equal(a, b)

    with pytest.raises(InvalidInputError, match="previous"):
        smooth_plan(meshcore.build_mesh(xy[:500]), variogram, previous=plan)


def test_a_plan_for_the_sampled_faces_gives_their_nodes_bit_for_bit(rng):
    """The faces a grid samples get the nodes the whole plan gives them, the others
    none; the grid (and any part of it moved by whole cells) reads the same surface,
    for fewer nodes kriged."""
    xy = _with_void(rng, 6000)
    z = 5.0 + np.sin((xy[:, 0] - OFFSET[0]) / 15.0) + rng.normal(0.0, 0.01, xy.shape[0])
    variogram = fit_variogram(xy, z)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    whole_plan = smooth_plan(mesh, variogram)
    assert whole_plan.refinement.ends.shape[0] > 0  # faces across the void are cut
    whole = smooth_surface(mesh, zz, variogram, plan=whole_plan)
    x0, y0, res, n = OFFSET[0] - 0.35, OFFSET[1] - 0.35, 2.0, 51
    taken = meshcore.tiles.sampled_faces(mesh, x0, y0, res, n, n)
    assert 0.1 < taken.mean() < 0.6
    plan = smooth_plan(mesh, variogram, faces=taken)
    assert plan.nodes.positions.shape[0] < 0.7 * whole_plan.nodes.positions.shape[0]
    assert plan.nodes.centres.shape[0] <= whole_plan.nodes.centres.shape[0]
    part = smooth_surface(mesh, zz, variogram, plan=plan)
    rows = taken[part.parent]
    np.testing.assert_array_equal(part.nodes[rows], whole.nodes[rows])
    assert np.all(np.isnan(part.nodes[~rows]))
    np.testing.assert_array_equal(part.z, whole.z)
    for c in (0, 7):  # the grid, and a tile of it
        args = (x0 + c * res, y0 + c * res, res, n - c, n - c)
        a = meshcore.rasterize(mesh, zz, *args, surface=whole)
        np.testing.assert_array_equal(meshcore.rasterize(mesh, zz, *args, surface=part), a)
        jj, ii = np.nonzero(np.isfinite(a))
        qx, qy = args[0] + (ii + 0.5) * res, args[1] + (jj + 0.5) * res
        for g, h in zip(meshcore.gradient(mesh, zz, qx, qy, surface=whole), meshcore.gradient(mesh, zz, qx, qy, surface=part)):
            np.testing.assert_array_equal(h, g)
    with pytest.raises(InvalidInputError, match="boolean mask"):
        smooth_plan(mesh, variogram, faces=taken[1:])
    with pytest.raises(InvalidInputError, match="boolean mask"):
        smooth_plan(mesh, variogram, faces=taken.astype(int))
