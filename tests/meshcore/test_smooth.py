"""Tests of the smooth surface: cubic patches (meshcore.patches) and kriged nodes (meshcore.smooth)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

import meshcore
from meshcore.errors import InvalidInputError
from meshcore.interpolate import _surface_at, gradient, interpolate
from meshcore.mesh import Mesh

from .mesh_checks import edge_faces, hand_mesh, python_and_compiled
from meshcore._buckets import _nearest
from meshcore.cells import CELL_PER_SPACING
from meshcore.kriging import _LANES, _dual_systems, _kriging_scratch, _solve_systems
from meshcore.smooth import _layout, smooth_neighbourhoods, smooth_nodes
from meshcore.variogram import MODELS, Variogram, _loo_errors_kernel, fit_variogram

OFFSET = np.array([6.0e5, 6.8e6])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261201)


def _nodes_of(mesh: Mesh, f) -> np.ndarray:
    """Node rows holding ``f`` at every node position (the layout's own positions)."""
    positions, take, _, _ = _layout(mesh.vertices, mesh.faces)
    values = f(positions[:, 0], positions[:, 1])
    rows = np.full(take.shape, np.nan)
    rows[take >= 0] = values[take[take >= 0]]
    return rows


def _inside_points(mesh: Mesh, rng, per_face: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Random points inside every face (convex combinations of its corners)."""
    xs, ys = [], []
    for face in mesh.faces:
        corners = mesh.vertices[face[face >= 0]]
        w = rng.dirichlet(np.ones(len(corners)), per_face)
        p = w @ corners
        xs.append(p[:, 0])
        ys.append(p[:, 1])
    return np.concatenate(xs), np.concatenate(ys)


def _cubic(x, y):
    return 1.0 + 0.3 * x - 0.7 * y + 0.2 * x * x - 0.1 * x * y + 0.05 * y * y + 0.03 * x**3 - 0.02 * x * x * y + 0.01 * y**3


def _cubic_gradient(x, y):
    gx = 0.3 + 0.4 * x - 0.1 * y + 0.09 * x * x - 0.04 * x * y
    gy = -0.7 - 0.1 * x + 0.1 * y - 0.02 * x * x + 0.03 * y * y
    return gx, gy


# --------------------------------------------------------------------------
# The patches
# --------------------------------------------------------------------------


def test_cubic_triangle_and_parallelogram_patches_reproduce_cubics(rng):
    """P3 on triangles and Q3 on parallelograms hold every cubic: value and gradient."""
    mesh = hand_mesh([[0, 0], [3, 0.5], [6, 0], [1, 3], [4, 3.5], [2.5, 6]], [[0, 1, 4, 3], [1, 2, 4, -1], [3, 4, 5, -1]])
    # the quad 0 1 4 3 is a parallelogram: (3, 0.5) - (0, 0) == (4, 3.5) - (1, 3)
    z = _cubic(mesh.vertices[:, 0], mesh.vertices[:, 1])
    nodes = _nodes_of(mesh, _cubic)
    x, y = _inside_points(mesh, rng)
    assert_allclose(interpolate(mesh, z, x, y, surface="smooth", nodes=nodes), _cubic(x, y), rtol=0, atol=1e-12)
    gx, gy = gradient(mesh, z, x, y, surface="smooth", nodes=nodes)
    wx, wy = _cubic_gradient(x, y)
    assert_allclose(gx, wx, atol=1e-11)
    assert_allclose(gy, wy, atol=1e-11)


def test_quad_patch_reproduces_bicubics_in_its_parameters_and_linear_functions(rng):
    """On a general convex quadrangle the patch holds every bicubic in (u, v), so every linear function."""
    corners = np.array([[0.0, 0.0], [5.0, -0.5], [6.0, 4.0], [-0.5, 3.0]])
    mesh = hand_mesh(corners, [[0, 1, 2, 3]])
    lin = lambda x, y: 2.0 - 0.5 * x + 1.25 * y  # noqa: E731
    z = lin(corners[:, 0], corners[:, 1])
    x, y = _inside_points(mesh, rng, 200)
    nodes = _nodes_of(mesh, lin)
    assert_allclose(interpolate(mesh, z, x, y, surface="smooth", nodes=nodes), lin(x, y), atol=1e-12)
    gx, gy = gradient(mesh, z, x, y, surface="smooth", nodes=nodes)
    assert_allclose(gx, -0.5, atol=1e-11)
    assert_allclose(gy, 1.25, atol=1e-11)
    # a bicubic in the patch's own parameters: nodes on the (1/3, 2/3) grid
    from meshcore.interpolate import _bilinear_inverse

    def uv_cubic(u, v):
        return u**3 * v**2 - 2.0 * u * v**3 + 0.5 * u * u + v

    t = np.array([0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0])
    grid = {(i, j): uv_cubic(t[i], t[j]) for i in range(4) for j in range(4)}
    row = np.array([grid[1, 0], grid[2, 0], grid[3, 1], grid[3, 2], grid[2, 3], grid[1, 3], grid[0, 2], grid[0, 1],
                    grid[1, 1], grid[2, 1], grid[2, 2], grid[1, 2]])
    zc = np.array([grid[0, 0], grid[3, 0], grid[3, 3], grid[0, 3]])
    got = interpolate(mesh, zc, x, y, surface="smooth", nodes=row[None, :])
    uv = np.array([_bilinear_inverse(*corners.ravel(), px, py) for px, py in zip(x, y)])
    assert_allclose(got, uv_cubic(uv[:, 0], uv[:, 1]), atol=1e-10)


def test_patches_pass_through_the_corners_at_survey_coordinates(rng):
    xy = rng.random((300, 2)) * 200.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    v = mesh.vertices
    z = 80.0 + np.sin((v[:, 0] - OFFSET[0]) / 17.0) * 4.0 + rng.normal(0.0, 0.2, v.shape[0])
    got = interpolate(mesh, z, v[:, 0], v[:, 1], surface="smooth")
    assert_allclose(got, z, rtol=0, atol=1e-9)


@pytest.mark.parametrize("measures", [("delaunay", None), ("s1", "s2"), ("s3", "s4")])
def test_the_surface_is_continuous_across_every_edge_of_random_meshes(rng, measures):
    """Both faces of every interior edge give the same value along it (checked at random points)."""
    xy = rng.random((400, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, *measures)
    v = mesh.vertices
    z = 10.0 + 0.05 * (v[:, 0] - OFFSET[0]) + 3.0 * np.sin((v[:, 1] - OFFSET[1]) / 9.0) + rng.normal(0, 0.1, len(v))
    nodes = smooth_nodes(mesh, z, Variogram(0.01, 1.0, 20.0))
    faces = mesh.faces
    sides = edge_faces(faces)
    shared = [(e, fs) for e, fs in sides.items() if len(fs) == 2]
    assert len(shared) > 500
    worst = 0.0
    for (a, b), (f, g) in shared:
        for t in rng.random(3):
            p = v[a] + t * (v[b] - v[a])
            one = _surface_at(v, faces, z, nodes, f, p[0], p[1])[0]
            two = _surface_at(v, faces, z, nodes, g, p[0], p[1])[0]
            worst = max(worst, abs(one - two))
    assert worst < 1e-7  # rounding at survey coordinates; a wrong node is off by ~0.1


def test_linear_surface_is_exact_at_survey_coordinates(rng):
    """Kriged nodes and patches reproduce a plane (the clamp never bites on one)."""
    xy = np.round(rng.random((2000, 2)) * 300.0 / 0.01) * 0.01 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    plane = lambda x, y: 250.0 + 0.12 * (x - OFFSET[0]) - 0.31 * (y - OFFSET[1])  # noqa: E731
    z = plane(mesh.vertices[:, 0], mesh.vertices[:, 1])
    x, y = _inside_points(mesh, rng, 3)
    for variogram in (Variogram(0.0, 1.0, 50.0), Variogram(0.2, 1.0, 5.0), None):
        nodes = smooth_nodes(mesh, z, variogram)
        assert_allclose(interpolate(mesh, z, x, y, surface="smooth", nodes=nodes), plane(x, y), rtol=0, atol=1e-7)
        gx, gy = gradient(mesh, z, x, y, surface="smooth", nodes=nodes)
        # a gradient divides by a face's width: the hull's slivers lose digits
        assert_allclose(gx, 0.12, atol=1e-5)
        assert_allclose(gy, -0.31, atol=1e-5)


def test_rasterize_samples_the_smooth_surface_and_keeps_max_edge(rng):
    xy = rng.random((500, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    v = mesh.vertices
    z = np.cos((v[:, 0] - OFFSET[0]) / 8.0) * 2.0 + (v[:, 1] - OFFSET[1]) * 0.01
    nodes = smooth_nodes(mesh, z)
    grid = meshcore.rasterize(mesh, z, *OFFSET, 1.0, 100, 100, surface="smooth", nodes=nodes)
    cx, cy = np.meshgrid(OFFSET[0] + np.arange(100) + 0.5, OFFSET[1] + np.arange(100) + 0.5)
    assert_allclose(grid, interpolate(mesh, z, cx, cy, surface="smooth", nodes=nodes), atol=1e-12)
    linear = meshcore.rasterize(mesh, z, *OFFSET, 1.0, 100, 100)
    assert np.nanmax(np.abs(grid - linear)) > 1e-3  # not the linear surface
    assert_array_equal(np.isnan(grid), np.isnan(linear))
    cut = meshcore.rasterize(mesh, z, *OFFSET, 1.0, 100, 100, max_edge=4.0, surface="smooth", nodes=nodes)
    assert_array_equal(np.isnan(cut), np.isnan(meshcore.rasterize(mesh, z, *OFFSET, 1.0, 100, 100, max_edge=4.0)))
    assert np.isnan(cut).sum() > np.isnan(grid).sum()


def test_bad_surface_arguments_raise():
    mesh = hand_mesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2, -1]])
    with pytest.raises(InvalidInputError, match="surface='cubic' is not valid"):
        interpolate(mesh, [0.0, 1.0, 2.0], 0.2, 0.2, surface="cubic")
    with pytest.raises(InvalidInputError, match=r"nodes must be a real array of shape \(n_faces, 12\)"):
        interpolate(mesh, [0.0, 1.0, 2.0], 0.2, 0.2, surface="smooth", nodes=np.zeros((2, 12)))
    with pytest.raises(InvalidInputError, match="give them with surface='smooth'"):
        interpolate(mesh, [0.0, 1.0, 2.0], 0.2, 0.2, nodes=np.zeros((1, 12)))
    with pytest.raises(InvalidInputError, match="variogram needs nugget >= 0"):
        Variogram(-1.0, 1.0, 1.0)
    with pytest.raises(InvalidInputError, match="neighbours must be an integer from 4 to 64"):
        smooth_nodes(mesh, [0.0, 1.0, 2.0], Variogram(0.0, 1.0, 1.0), neighbours=2)


# --------------------------------------------------------------------------
# The kriged nodes
# --------------------------------------------------------------------------


def test_nearest_neighbours_are_exact_and_break_ties_by_coordinates(rng):
    xy = np.round(rng.random((3000, 2)) * 50.0) + OFFSET  # a lattice: many equal distances
    xy = np.unique(xy, axis=0)
    queries = rng.random((200, 2)) * 50.0 + OFFSET
    index, d2 = _nearest(xy, queries, 12)
    for q, (row, dist) in enumerate(zip(index, d2)):
        full = ((xy - queries[q]) ** 2).sum(axis=1)
        order = np.lexsort((xy[:, 1], xy[:, 0], full))[:12]
        assert_array_equal(row, order)
        assert_array_equal(dist, full[order])


@pytest.mark.parametrize("layout", ["duplicates", "line", "outlier"])
def test_nearest_neighbours_are_exact_on_duplicates_lines_and_outliers(rng, layout):
    """Exact duplicates in their input order; a grid one bucket thick; a point far from the others."""
    xy = np.round(rng.random((2000, 2)) * 20.0) + OFFSET
    if layout == "line":
        xy[:, 1] = OFFSET[1]
    if layout == "outlier":
        xy = np.vstack([xy, OFFSET + 1e5])
    queries = np.vstack([rng.random((150, 2)) * 20.0 + OFFSET, OFFSET + [-30.0, 50.0]])
    for k in (1, 16, 40):
        index, d2 = _nearest(xy, queries, k)
        for q in range(queries.shape[0]):
            full = ((xy - queries[q]) ** 2).sum(axis=1)
            order = np.lexsort((np.arange(xy.shape[0]), xy[:, 1], xy[:, 0], full))[:k]
            assert_array_equal(index[q], order)
            assert_array_equal(d2[q], full[order])


def test_adjacent_window_pieces_get_bit_identical_nodes_on_their_shared_edges(rng):
    """Seamless: each piece krigs from the points it holds, the shared edges agree bit for bit,
    also across a void on the seam, whose nodes take natural neighbours from both pieces' sides."""
    xy = np.round((rng.random((4000, 2)) * [400.0, 200.0]) / 0.01) * 0.01 + OFFSET
    xy = xy[np.hypot(xy[:, 0] - OFFSET[0] - 200.0, xy[:, 1] - OFFSET[1] - 100.0) > 30.0]
    z = 50.0 + 10.0 * np.sin((xy[:, 0] - OFFSET[0]) / 40.0) + rng.normal(0.0, 0.3, xy.shape[0])
    variogram = fit_variogram(xy, z)
    split = OFFSET[0] + 200.0
    pieces = []
    filled = []  # nodes in the void with natural neighbours
    for window in ((OFFSET[0], OFFSET[1], split, OFFSET[1] + 200.0), (split, OFFSET[1], OFFSET[0] + 400.0, OFFSET[1] + 200.0)):
        # each holds its window plus 40 m: the kriging neighbourhoods lie inside
        lo, hi = window[0] - 40.0, window[2] + 40.0
        while True:
            keep = (xy[:, 0] >= lo) & (xy[:, 0] <= hi)
            mesh = meshcore.build_mesh(xy[keep], "delaunay", None, window=window)
            hoods = smooth_neighbourhoods(mesh, spacing=variogram.spacing)
            kriged = np.column_stack([hoods.centres, hoods.radius])
            assert np.all((kriged[:, 0] - kriged[:, 2] >= lo) & (kriged[:, 0] + kriged[:, 2] <= hi))
            # the voids' natural neighbours beside the survey's hull read farther (the pipeline's
            # certificate holds their disks where they meet the survey): held too
            reach = _x_reach(hoods.disks, OFFSET[1], OFFSET[1] + 200.0)
            if reach[0] >= lo and reach[1] <= hi:
                break
            lo, hi = min(lo, reach[0]), max(hi, reach[1])
        filled.append(np.count_nonzero(np.diff(hoods.fill.coordinates.first)))
        zz = np.empty(mesh.vertices.shape[0])
        zz[mesh.input_to_vertex] = z[keep]
        pieces.append((mesh, smooth_nodes(mesh, zz, variogram, neighbourhoods=hoods)))
    assert min(filled) > 3

    def edge_nodes(mesh, nodes):
        out = {}
        for f, face in enumerate(mesh.faces):
            n = 4 if face[3] >= 0 else 3
            for k in range(n):
                a, b = mesh.vertices[face[k]], mesh.vertices[face[(k + 1) % n]]
                pair = (nodes[f, 2 * k], nodes[f, 2 * k + 1])
                key = (tuple(a), tuple(b))
                if key > (tuple(b), tuple(a)):
                    key, pair = (tuple(b), tuple(a)), pair[::-1]
                out[key] = pair
        return out

    left, right = edge_nodes(*pieces[0]), edge_nodes(*pieces[1])
    shared = set(left) & set(right)
    assert len(shared) > 10
    for key in shared:
        assert left[key] == right[key]  # exactly
    # and the same as the whole mesh's
    whole = meshcore.build_mesh(xy, "delaunay", None)
    zz = np.empty(whole.vertices.shape[0])
    zz[whole.input_to_vertex] = z
    every = edge_nodes(whole, smooth_nodes(whole, zz, variogram))
    for key in shared:
        assert every[key] == left[key]


def _x_reach(disks: np.ndarray, y0: float, y1: float) -> tuple[float, float]:
    """The lowest and highest x of the disks ``(x, y, r)`` between ``y0`` and ``y1``."""
    x, y, r = disks.T
    dy = np.maximum(np.maximum(y0 - y, y - y1), 0.0)
    half = np.sqrt(np.maximum(r * r - dy * dy, 0.0))
    meets = dy <= r
    return float(np.min((x - half)[meets])), float(np.max((x + half)[meets]))


def test_nodes_are_clamped_to_their_neighbourhood_and_corners(rng):
    """On a step (a cliff) kriging overshoots; the nodes stay inside the values around them."""
    xy = rng.random((1500, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    v = mesh.vertices
    z = np.where(v[:, 0] - OFFSET[0] > 50.0, 20.0, 0.0)
    nodes = smooth_nodes(mesh, z, Variogram(0.0, 1.0, 100.0))
    used = np.isfinite(nodes)
    assert nodes[used].min() >= 0.0 and nodes[used].max() <= 20.0
    # on flat ground far from the cliff every node is flat
    far = np.all(np.abs(v[mesh.faces[:, :3], 0] - OFFSET[0] - 50.0) > 25.0, axis=1)
    assert_array_equal(nodes[far][np.isfinite(nodes[far])] % 20.0, 0.0)


def _void_survey(rng, ground, radius=25.0, n=6000):
    """Points on 150 x 150 m of ``ground(x, y)`` but in a disk of ``radius`` at the centre, and a grid over the disk."""
    xy = rng.random((n, 2)) * 150.0
    xy = xy[np.hypot(xy[:, 0] - 75.0, xy[:, 1] - 75.0) > radius]
    g = np.arange(75.0 - radius, 75.0 + radius, 0.5) + 0.25
    gx, gy = np.meshgrid(g, g)
    inside = np.hypot(gx - 75.0, gy - 75.0) < radius - 0.5
    return xy + OFFSET, ground(xy[:, 0], xy[:, 1]), np.column_stack([gx[inside], gy[inside]]) + OFFSET


def test_a_void_in_a_plane_is_the_plane(rng):
    """The fill of a void reproduces linear functions, as kriging does: a plane with a hole is the plane."""
    plane = lambda x, y: 12.0 + 0.03 * x - 0.07 * y  # noqa: E731
    xy, z, cells = _void_survey(rng, plane)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    surface = meshcore.smooth_surface(mesh, zz, Variogram(0.01, 1.0, 20.0, "exponential", spacing=150.0 / 6000**0.5))
    assert surface.mesh.vertices.shape[0] > mesh.vertices.shape[0]  # faces across the void were cut
    values = interpolate(mesh, zz, cells[:, 0], cells[:, 1], surface=surface)
    local = cells - OFFSET
    assert_allclose(values, plane(local[:, 0], local[:, 1]), atol=1e-9)


@pytest.mark.parametrize("ground,variogram", [
    # a ridge, smooth and noise-free: crests may rise between points, but not in the void
    (lambda x, y: 20.0 - 0.004 * (y - 75.0) ** 2 + 0.02 * x, Variogram(1e-6, 1.0, 60.0, "matern52")),
    # flat ground with noise (a car park, water): the rim's noise is not carried across
    (lambda x, y: 5.0 + 0.0 * x, Variogram(0.3, 1.0, 2.0, "exponential")),
])
def test_a_void_holds_no_value_outside_its_rim(rng, ground, variogram):
    """Inside a void, no DEM cell leaves the range of the points of the TIN's
    triangles around it (the TIN's own share, which is none): no ring, no bowl."""
    from scipy.spatial import Delaunay

    xy, z, cells = _void_survey(rng, ground)
    if variogram.nugget > 0.1:
        z = z + rng.normal(0.0, 0.05, z.size)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    spacing = 150.0 / 6000**0.5
    v = Variogram(variogram.nugget, variogram.sill, variogram.range, variogram.model, spacing)
    values = interpolate(mesh, zz, cells[:, 0], cells[:, 1], surface=meshcore.smooth_surface(mesh, zz, v))
    tri = Delaunay(xy - OFFSET)
    rim = np.unique(tri.simplices[tri.find_simplex(cells - OFFSET)])
    assert np.all(np.isfinite(values))
    assert z[rim].min() <= values.min() and values.max() <= z[rim].max()


def test_a_void_in_noisy_flat_ground_is_nearer_the_ground_than_the_tin(rng):
    """Where the rim's points are flat ground and noise, the fill averages the rim
    (the TIN follows the three points of each triangle): nearer the ground."""
    from scipy.interpolate import LinearNDInterpolator

    xy, z, cells = _void_survey(rng, lambda x, y: 5.0 + 0.0 * x)
    z = z + rng.normal(0.0, 0.05, z.size)
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z
    v = fit_variogram(xy, z)
    smooth = interpolate(mesh, zz, cells[:, 0], cells[:, 1], surface=meshcore.smooth_surface(mesh, zz, v))
    tin = LinearNDInterpolator(xy - OFFSET, z)(cells - OFFSET)
    rmse = lambda p: float(np.sqrt(np.mean((p - 5.0) ** 2)))  # noqa: E731
    assert rmse(smooth) < rmse(tin)


def test_smooth_ground_keeps_its_crests_and_rough_ground_is_clamped(rng):
    """A dome with no point near its top: with a smooth, noise-free variogram
    nodes there rise above every point (the clamp would flatten the crest); with
    an exponential one, or a noisy Matérn one, no node leaves the range of the
    values around it."""
    xy = rng.random((2000, 2)) * 100.0
    xy = xy[np.hypot(xy[:, 0] - 50.0, xy[:, 1] - 50.0) > 4.0] + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    local = mesh.vertices - OFFSET - 50.0
    z = 30.0 - 0.01 * (local[:, 0] ** 2 + local[:, 1] ** 2)
    top = z.max()
    smooth = smooth_nodes(mesh, z, Variogram(1e-6, 1.0, 40.0, "matern52"))
    assert top + 0.5 * (30.0 - top) < np.nanmax(smooth) < 30.05  # most of the way up to the true top
    for variogram in (Variogram(0.0, 1.0, 40.0, "exponential"), Variogram(0.01, 1.0, 40.0, "matern52")):
        assert np.nanmax(smooth_nodes(mesh, z, variogram)) <= top
    # the hull: the nodes of cells kriged from one side stay clamped, smooth or not
    hoods = smooth_neighbourhoods(mesh, spacing=2.2)
    edge = np.abs(hoods.positions[:, 0] - OFFSET[0] - 50.0) > 49.0
    rows = np.full(hoods.positions.shape[0], np.nan)
    used = hoods.take >= 0
    rows[hoods.take[used]] = smooth_nodes(mesh, z, Variogram(1e-6, 1.0, 40.0, "matern52", 2.2),
                                          neighbourhoods=hoods)[used]
    assert np.all(rows[edge] >= z.min() - 1e-9)


def test_linear_nodes_are_the_plane_and_agree_on_both_sides_of_every_edge(rng):
    """The linear surface's node values (the reference the pipeline stores the
    smooth nodes against): a plane's values at the layout's node positions, the
    same bits from both faces of an edge for any z."""
    xy = rng.random((400, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    v = mesh.vertices - OFFSET
    plane = meshcore.tiles.linear_nodes(mesh.faces, 3.0 * v[:, 0] - 2.0 * v[:, 1] + 7.0)
    expected = _nodes_of(mesh, lambda x, y: 3.0 * (x - OFFSET[0]) - 2.0 * (y - OFFSET[1]) + 7.0)
    assert_array_equal(np.isnan(plane), np.isnan(expected))
    assert_allclose(plane, expected, rtol=0, atol=1e-8)  # the positions round at 6e5
    rough = meshcore.tiles.linear_nodes(mesh.faces, rng.normal(0.0, 100.0, v.shape[0]))
    _, take, _, _ = _layout(mesh.vertices, mesh.faces)
    node = take.ravel()
    value = rough.ravel()
    order = np.argsort(node[node >= 0], kind="stable")
    ids, vals = node[node >= 0][order], value[node >= 0][order]
    shared = ids[1:] == ids[:-1]
    assert shared.sum() > 500 and np.array_equal(vals[1:][shared], vals[:-1][shared])


def test_node_deviations_are_single_precision_and_restore_the_same_bits_on_both_sides(rng):
    xy = rng.random((400, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    z = rng.normal(300.0, 20.0, mesh.vertices.shape[0])
    linear = meshcore.tiles.linear_nodes(mesh.faces, z)
    nodes = linear + rng.normal(0.0, 0.5, linear.shape)  # NaN where a face has no such node
    packed = meshcore.tiles.node_deviations(mesh.faces, z, nodes)
    assert packed.dtype == np.float32
    assert np.array_equal(packed, (nodes - linear).astype(np.float32), equal_nan=True)
    restored = meshcore.tiles.nodes_from_deviations(mesh.faces, z, packed)
    assert np.array_equal(restored, linear + packed, equal_nan=True)
    assert_allclose(restored, nodes, rtol=0, atol=1e-6)
    with pytest.raises(meshcore.InvalidInputError, match="shape"):
        meshcore.tiles.node_deviations(mesh.faces, z, nodes[:, :9])


def test_systems_solved_side_by_side_give_each_system_alone_bit_for_bit(rng):
    """Each lane of the kriging solver does one system's operations: the same
    numbers whatever its neighbours in the batch, singular lanes included."""
    k = 16
    xy = rng.random((400, 2)) * 30.0 + OFFSET
    z = np.sin(xy[:, 0] / 7.0) + 0.01 * rng.standard_normal(400)
    centres = rng.random((3 * _LANES + 3, 2)) * 30.0 + OFFSET
    neighbours, _ = _nearest(xy, centres, k)
    neighbours[4, :] = neighbours[4, 0]  # one point repeated: a singular covariance matrix
    xy[1:3, 1] = xy[0, 1]
    neighbours[_LANES + 1, :3] = [0, 1, 2]  # three neighbours on a line: a singular drift
    neighbours[_LANES + 1, 3:] = -1
    neighbours[2 * _LANES + 2, 12:] = -1  # a shorter row between full ones
    neighbours[2 * _LANES + 3, 1] = neighbours[2 * _LANES + 3, 0]  # a point twice, no nugget: a zero pivot
    ratio, scale, model = 0.0, 1.0 / 9.0, MODELS.index("matern32")

    alone = []
    room = _kriging_scratch(k)
    for s in range(centres.shape[0]):
        count = int(np.count_nonzero(neighbours[s] >= 0))
        _dual_systems(xy, z, centres, neighbours, s, 1, count, ratio, scale, model, room)
        alone.append((room.radius[0], room.coef[0, : count + 3].copy()))

    together = []
    first = 0
    while first < centres.shape[0]:
        lanes, count = _solve_systems(xy, z, centres, neighbours, first, ratio, scale, model, room)
        assert 1 <= lanes <= _LANES and count == int(np.count_nonzero(neighbours[first] >= 0))
        together.extend((room.radius[b], room.coef[b, : count + 3].copy()) for b in range(lanes))
        first += lanes
    assert len(together) == len(alone)
    assert np.isnan(alone[4][0]) and np.isnan(alone[_LANES + 1][0]) and np.isnan(alone[2 * _LANES + 3][0])
    assert np.isfinite([radius for radius, _ in alone]).sum() >= centres.shape[0] - 3
    for (r1, c1), (r2, c2) in zip(alone, together):
        assert_array_equal(r1, r2)
        if np.isfinite(r1):
            assert_array_equal(c1, c2)


def test_collinear_neighbours_fall_back_to_the_linear_surface():
    """A thin strip of points on two lines: no plane fits most neighbourhoods, the nodes are the linear surface's."""
    x = np.linspace(0.0, 100.0, 60)
    xy = np.concatenate([np.column_stack([x, np.zeros(60)]), np.column_stack([x[:3] + 0.5, [1.0, 1.0, 1.0]])]) + OFFSET
    mesh = meshcore.build_mesh(xy, "delaunay", None)
    z = np.sin(mesh.vertices[:, 0] - OFFSET[0])
    nodes = smooth_nodes(mesh, z, Variogram(0.0, 1.0, 10.0), neighbours=4)
    assert np.isfinite(nodes[:, :6]).all()


def test_fit_variogram_is_deterministic_and_finds_the_noise(rng):
    xy = rng.random((6000, 2)) * 300.0 + OFFSET
    smooth = 20.0 * np.sin((xy[:, 0] - OFFSET[0]) / 50.0) * np.cos((xy[:, 1] - OFFSET[1]) / 70.0)
    noisy = smooth + rng.normal(0.0, 0.3, xy.shape[0])
    a = fit_variogram(xy, noisy)
    perm = rng.permutation(xy.shape[0])
    assert fit_variogram(xy[perm], noisy[perm]) == a
    assert a.nugget > 0.0
    clean = fit_variogram(xy, smooth)
    assert clean.nugget / clean.sill < a.nugget / a.sill
    assert Variogram.from_dict(a.to_dict()) == a
    with pytest.raises(InvalidInputError, match="at least 18 finite points"):
        fit_variogram(xy[:10], noisy[:10])


def test_variogram_models_are_correlations_and_round_trip():
    h = np.array([0.0, 0.5, 1.0, 3.0, 30.0])
    previous = None
    for model in MODELS:
        v = Variogram(0.1, 2.0, 1.5, model, spacing=0.7)
        rho = v.correlation(h)
        assert rho[0] == 1.0 and np.all(np.diff(rho) < 0) and rho[-1] < 1e-6
        assert_allclose(v.semivariance(h), np.where(h > 0, 0.1 + 2.0 * (1.0 - rho), 0.0))
        if previous is not None:  # smoother models stay correlated longer at short lags
            assert rho[1] > previous[1]
        previous = rho
        assert Variogram.from_dict(v.to_dict()) == v
    # a record from before the models and cells reads as exponential, with no spacing
    assert Variogram.from_dict({"nugget": 0.0, "sill": 1.0, "range": 2.0}) == Variogram(0.0, 1.0, 2.0, "exponential", None)
    with pytest.raises(InvalidInputError, match="model must be one of exponential, matern32, matern52, got 'gauss'"):
        Variogram(0.0, 1.0, 1.0, "gauss")
    with pytest.raises(InvalidInputError, match="spacing must be > 0"):
        Variogram(0.0, 1.0, 1.0, spacing=0.0)


def test_model_correlations_match_their_closed_forms_to_rounding():
    """The kernels' table-and-series exponential against numpy's, on lags up to and past its cut-off."""
    h = np.concatenate([np.linspace(0.0, 70.0, 200_001), [1e-300, 1e-9, 63.999999, 64.0, 1e3]])
    for model, shape in zip(MODELS, (lambda a: np.exp(-a), lambda a: (1 + a) * np.exp(-a),
                                     lambda a: (1 + a + a * a / 3) * np.exp(-a))):
        a = h * (1.0, np.sqrt(3.0), np.sqrt(5.0))[MODELS.index(model)]
        rho = Variogram(0.0, 1.0, 1.0, model).correlation(h)
        exact = shape(a)
        live = a < 64.0
        assert np.all(np.abs(rho[live] - exact[live]) <= 1e-15 * exact[live] + 1e-300)  # a few ulp
        assert np.all(rho[~live] == 0.0) and np.all(exact[~live] < 1e-24)


def test_nodes_are_kriged_in_cells_of_the_spacing(rng):
    """One system per cell on multiples of the cell's side; every node lies in its cell."""
    xy = rng.random((2000, 2)) * 100.0 + OFFSET
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    hoods = smooth_neighbourhoods(mesh, spacing=2.5)
    cell = 2.5 * CELL_PER_SPACING
    assert hoods.cell == cell
    assert_allclose(hoods.centres / cell - 0.5, np.round(hoods.centres / cell - 0.5), atol=1e-9)
    owner = np.repeat(np.arange(hoods.centres.shape[0]), np.diff(hoods.first))
    assert np.all(np.abs(hoods.positions - hoods.centres[owner]) <= 0.5 * cell * (1 + 1e-12))
    assert len(np.unique(owner)) == hoods.centres.shape[0]  # no empty cell
    # a system for nearly every cell of the hull (100 m x 100 m)
    assert 0.8 * (100.0 / cell) ** 2 < hoods.centres.shape[0] <= (100.0 / cell + 1) ** 2
    z = np.sin((mesh.vertices[:, 0] - OFFSET[0]) / 9.0)
    with pytest.raises(InvalidInputError, match=f"neighbourhoods were computed for cells of {cell!r}"):
        smooth_nodes(mesh, z, Variogram(0.0, 1.0, 10.0, spacing=3.0), neighbourhoods=hoods)
    # the spacing a fit measures is the points' own: 1 / sqrt(density)
    fitted = fit_variogram(mesh.vertices, z)
    assert 0.8 * 100.0 / np.sqrt(2000) < fitted.spacing < 1.25 * 100.0 / np.sqrt(2000)


def test_a_smooth_surface_gets_a_smooth_model_and_a_rough_one_the_exponential(rng):
    """The fit chooses the model by its errors: Matérn on an analytic surface, exponential on a rough one."""
    xy = rng.random((3000, 2)) * 100.0
    smooth = np.sin(xy[:, 0] / 13.0) * np.cos(xy[:, 1] / 17.0) * 5.0
    assert fit_variogram(xy, smooth).model in ("matern32", "matern52")
    # a random walk's increments: a Brownian-like (rough) surface of many tiny steps
    order = np.argsort(xy[:, 0])
    rough = np.empty(3000)
    rough[order] = np.cumsum(rng.standard_normal(3000))
    assert fit_variogram(xy, rough).model == "exponential"


def test_smooth_predicts_withheld_points_better_than_the_tin(rng):
    """On a smooth survey-like surface the cubic patches beat the TIN at withheld points."""
    xy = rng.random((5000, 2)) * 100.0 + OFFSET
    f = lambda p: 0.1 * p[:, 0] + 0.1 * p[:, 1] + np.sin(0.01 * p[:, 0]) - np.sin(0.1 * p[:, 1]) + np.sin(0.003 * p[:, 0] * p[:, 1])  # noqa: E731
    local = xy - OFFSET
    z = np.round(f(local), 3)
    test = np.zeros(5000, dtype=bool)
    test[rng.choice(5000, 500, replace=False)] = True
    mesh = meshcore.build_mesh(xy[~test], "s3", "s4")
    zz = np.empty(mesh.vertices.shape[0])
    zz[mesh.input_to_vertex] = z[~test]
    linear = interpolate(mesh, zz, xy[test, 0], xy[test, 1])
    smooth = interpolate(mesh, zz, xy[test, 0], xy[test, 1], surface="smooth")
    ok = np.isfinite(linear)
    rmse = lambda p: np.sqrt(np.mean((p[ok] - z[test][ok]) ** 2))  # noqa: E731
    assert rmse(smooth) < 0.6 * rmse(linear)


def test_python_form_of_the_smooth_kernels_agrees():
    """The kernels run with NUMBA_DISABLE_JIT=1 give the same numbers."""
    script = (
        "import json, numpy as np, meshcore\n"
        "rng = np.random.default_rng(5)\n"
        "xy = rng.random((120, 2)) * 50.0 + [6.0e5, 6.8e6]\n"
        "mesh = meshcore.build_mesh(xy, 's3', 's4')\n"
        "z = np.sin(mesh.vertices[:, 0] / 7.0) + mesh.vertices[:, 1] * 1e-3\n"
        "v = meshcore.fit_variogram(mesh.vertices, z, sample=60)\n"
        "nodes = meshcore.smooth_nodes(mesh, z, v)\n"
        "x, y = (rng.random((2, 300)) * 50.0 + np.array([[6.0e5], [6.8e6]]))\n"
        "val = meshcore.interpolate(mesh, z, x, y, surface='smooth', nodes=nodes)\n"
        "gx, gy = meshcore.gradient(mesh, z, x, y, surface='smooth', nodes=nodes)\n"
        "out = [nodes, val, gx, gy, [v.nugget, v.sill, v.range]]\n"
        "print(json.dumps([np.where(np.isnan(a), None, a).tolist() for a in map(np.asarray, out)]))\n"
    )
    runs = python_and_compiled(script)
    for a, b in zip(*runs):
        assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    assert np.isfinite(runs[1][1]).sum() > 200


def test_leave_one_out_errors_of_several_nuggets_are_those_of_each_nugget_alone(rng):
    """The fit solves every nugget of a model and range on covariances computed
    once: each nugget's errors are those it gives alone, bit for bit, whatever
    the batch of lanes (a short row and a singular system among them)."""
    k = 12
    xy = rng.random((300, 2)) * 20.0 + OFFSET
    z = np.cos(xy[:, 1] / 5.0) + 0.02 * rng.standard_normal(300)
    sample = np.arange(0, 300, 7)
    neighbours, _ = _nearest(xy, xy[sample], k + 1)
    neighbours = np.ascontiguousarray(neighbours[:, 1:])
    neighbours[3, 9:] = -1  # a shorter row
    neighbours[5, :] = neighbours[5, 0]  # one point repeated: singular without a nugget
    ratios = np.array([0.0, 1e-4, 0.1, 5.0])
    for model in range(len(MODELS)):
        together = np.empty((ratios.size, sample.size))
        _loo_errors_kernel(xy, z, sample, neighbours, ratios, 1.0 / 4.0, model, together)
        for r, ratio in enumerate(ratios):
            alone = np.empty((1, sample.size))
            _loo_errors_kernel(xy, z, sample, neighbours, ratios[r : r + 1], 1.0 / 4.0, model, alone)
            assert_array_equal(together[r], alone[0])
            assert np.isfinite(alone[0]).sum() >= sample.size - 1
        # the nugget matters: the errors differ from one to the next
        assert not np.array_equal(together[1], together[3])


def test_a_voids_fill_takes_the_natural_neighbours_only_where_they_agree_with_the_tin():
    """Where the natural-neighbour interpolant departs from the TIN by several of
    the ground's standard deviations at the node's distance from the points (a
    rim of two grounds: a step, the far side of a bay), the fill is the TIN's;
    where they agree it is the mean of the two."""
    from meshcore.natural import natural_coordinates, natural_values, tin_values
    from meshcore.voids import VOID_AGREEMENT, VOID_NATURAL_SHARE, VoidFill

    angles = np.linspace(0.0, 2.0 * np.pi, 40, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)]) * 10.0
    near = ring[:12] * 0.9  # a dense arc on one side, as a strip along a step
    points = np.vstack([ring, near]) + OFFSET
    z = np.concatenate([np.zeros(40), np.full(12, 2.0)])
    places = np.array([[1.5, -2.0], [-3.0, 1.0]]) + OFFSET
    coords = natural_coordinates(points, places, np.full(2, 30.0), np.full(2, 100.0))
    natural, tin = natural_values(coords, z), tin_values(coords, z)
    departure = np.abs(natural - tin)
    assert np.all(departure > 0.1)
    gap = np.full(2, 7.0)
    fill = VoidFill(np.arange(2), coords)
    for sill, share in ((1e6, VOID_NATURAL_SHARE), (1e-6, 0.0)):
        values = fill.values(z, 2, Variogram(0.0, sill, 5.0, "exponential", spacing=1.0), gap)
        assert_allclose(values[:, 0], tin + share * (natural - tin))
    # in between, the share falls linearly with the departure
    sd = float(np.sqrt(Variogram(0.0, 1.0, 5.0, "exponential").semivariance(7.0)))
    sill = (departure[0] / (1.5 * VOID_AGREEMENT * sd)) ** 2
    values = fill.values(z, 2, Variogram(0.0, sill, 5.0, "exponential", spacing=1.0), gap)
    assert_allclose(values[0, 0], tin[0] + 0.5 * VOID_NATURAL_SHARE * (natural[0] - tin[0]))
