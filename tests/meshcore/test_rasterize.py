"""Tests of meshcore.rasterize: the face scan agrees with point evaluation and with scipy."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.interpolate import LinearNDInterpolator

import meshcore
from meshcore.errors import InvalidInputError
from meshcore.interpolate import interpolate
from meshcore.mesh import Mesh
from meshcore.rasterize import rasterize

from .mesh_checks import hand_mesh
from .test_interpolate import delaunay_mesh, grid_mesh, mixed


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240612)


def cell_centres(x0, y0, resolution, nx, ny):
    """The centres ``x0 + (i + 0.5) * resolution`` (and in y) as (ny, nx) arrays."""
    return np.meshgrid(
        x0 + (np.arange(nx) + 0.5) * resolution, y0 + (np.arange(ny) + 0.5) * resolution
    )


def longest_edges(mesh: Mesh) -> np.ndarray:
    f = mesh.faces
    closed = np.where(f >= 0, f, f[:, :1])  # a triangle's 4th corner repeats its 1st
    p = mesh.vertices[closed]
    return np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2).max(axis=1)


def threshold_between(longest: np.ndarray, q: float) -> float:
    """A max_edge halfway between two distinct longest edges (no face near it)."""
    s = np.unique(longest)
    k = int(q * (len(s) - 1))
    return 0.5 * (s[k] + s[k + 1])


# --------------------------------------------------------------------------
# Agreement with point evaluation and with scipy
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("x0", "y0", "resolution", "nx", "ny"),
    [
        (-0.5, -0.5, 0.1, 50, 52),  # grid larger than the mesh on every side
        (0.3, 0.2, 0.05, 40, 30),  # grid inside the mesh
        (-0.05, -0.05, 0.1, 44, 44),  # centres exactly on vertices, edges and the hull
    ],
)
def test_agrees_with_interpolate_at_cell_centres(x0, y0, resolution, nx, ny, rng):
    mesh = mixed()
    z = rng.normal(size=len(mesh.vertices))
    got = rasterize(mesh, z, x0, y0, resolution, nx, ny)
    assert got.shape == (ny, nx) and got.dtype == np.float64
    x, y = cell_centres(x0, y0, resolution, nx, ny)
    ref = interpolate(mesh, z, x, y)
    assert_array_equal(np.isnan(got), np.isnan(ref))
    assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    assert (~np.isnan(got)).sum() > 100


def test_agrees_with_interpolate_on_jittered_mixed_grid(rng):
    mesh = grid_mesh(rng, 15, 10)
    z = np.sin(mesh.vertices[:, 0]) * np.cos(mesh.vertices[:, 1])
    args = (-1.03, -0.71, 0.07, 250, 180)
    got = rasterize(mesh, z, *args)
    ref = interpolate(mesh, z, *cell_centres(*args))
    assert_array_equal(np.isnan(got), np.isnan(ref))
    assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_every_cell_on_edges_and_hull_of_a_regular_grid_gets_a_value(rng):
    # an unjittered 8 x 6 grid: with these centres whole rows and columns lie on
    # grid lines (shared edges and the hull), others on the triangle diagonals
    mesh = grid_mesh(rng, 8, 6, jitter=0.0)
    z = 1.0 + mesh.vertices[:, 0] - 2.0 * mesh.vertices[:, 1]
    got = rasterize(mesh, z, -0.125, -0.125, 0.25, 33, 25)
    x, y = cell_centres(-0.125, -0.125, 0.25, 33, 25)
    assert not np.isnan(got).any()
    assert_allclose(got, 1.0 + x - 2.0 * y, rtol=1e-12, atol=1e-12)
    # one more cell on each side is outside
    wider = rasterize(mesh, z, -0.375, -0.375, 0.25, 35, 27)
    assert np.isnan(wider[0]).all() and np.isnan(wider[-1]).all()
    assert np.isnan(wider[:, 0]).all() and np.isnan(wider[:, -1]).all()
    assert not np.isnan(wider[1:-1, 1:-1]).any()


def test_agrees_with_scipy_on_delaunay_mesh(rng):
    points = rng.random((3000, 2)) * [100.0, 60.0] + [1000.0, 2000.0]
    mesh, tri = delaunay_mesh(points)
    z = np.sin(points[:, 0] / 9.0) * np.cos(points[:, 1] / 7.0) * 20.0 + 0.1 * points[:, 0]
    args = (995.0, 1995.0, 0.37, 300, 180)
    got = rasterize(mesh, z, *args)
    x, y = cell_centres(*args)
    ref = LinearNDInterpolator(tri, z)(x, y)
    assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got).any() and (~np.isnan(got)).sum() > 20000
    assert_allclose(got, ref, rtol=1e-12, atol=1e-10)


def test_rows_run_south_to_north_and_columns_west_to_east():
    mesh = mixed()
    got_x = rasterize(mesh, mesh.vertices[:, 0], 0.0, 0.0, 0.5, 8, 8)
    got_y = rasterize(mesh, mesh.vertices[:, 1], 0.0, 0.0, 0.5, 8, 8)
    assert_allclose(got_x[0], 0.25 + 0.5 * np.arange(8))
    assert_allclose(got_y[:, 2], 0.25 + 0.5 * np.arange(8))


def test_grid_away_from_the_mesh_is_all_nan():
    mesh = mixed()
    assert np.isnan(rasterize(mesh, np.zeros(8), 10.0, 10.0, 1.0, 5, 5)).all()
    assert np.isnan(rasterize(mesh, np.zeros(8), -100.0, 0.0, 1.0, 50, 5)).all()


def test_nan_z_blanks_its_faces_only():
    mesh = mixed()
    z = np.arange(8, dtype=np.float64)
    z[2] = np.nan  # a corner of quad 1 only
    got = rasterize(mesh, z, 0.0, 0.0, 0.5, 8, 8)
    x, y = cell_centres(0.0, 0.0, 0.5, 8, 8)
    ref = interpolate(mesh, z, x, y)
    assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got[0, 5]) and not np.isnan(got[0, 1])


# --------------------------------------------------------------------------
# max_edge
# --------------------------------------------------------------------------


def test_max_edge_blanks_the_long_triangle():
    # a unit square quad plus a long triangle to its east
    mesh = hand_mesh([[0, 0], [1, 0], [1, 1], [0, 1], [3, 0.5]], [[0, 1, 2, 3], [1, 4, 2, -1]])
    z = np.array([0.0, 1.0, 2.0, 1.0, 5.0])
    full = rasterize(mesh, z, 0.0, 0.0, 0.25, 12, 4)
    cut = rasterize(mesh, z, 0.0, 0.0, 0.25, 12, 4, max_edge=1.5)
    assert not np.isnan(full[:, :4]).any() and not np.isnan(full[1:3, 4:6]).any()
    assert_array_equal(cut[:, :4], full[:, :4])
    assert np.isnan(cut[:, 4:]).all()


def test_max_edge_blanks_exactly_the_faces_with_long_edges(rng):
    points = rng.random((800, 2))
    mesh, tri = delaunay_mesh(points)
    z = points[:, 0] ** 2 - points[:, 1]
    args = (0.0, 0.0, 0.01, 100, 100)
    x, y = cell_centres(*args)
    face = tri.find_simplex(np.column_stack([x.ravel(), y.ravel()])).reshape(x.shape)
    longest = longest_edges(mesh)
    max_edge = threshold_between(longest, 0.8)
    full = rasterize(mesh, z, *args)
    cut = rasterize(mesh, z, *args, max_edge=max_edge)
    inside = face >= 0
    blanked = inside & (longest[face] > max_edge)
    assert blanked.sum() > 100 and (inside & ~blanked).sum() > 1000
    assert np.isnan(cut[blanked]).all()
    assert_array_equal(cut[inside & ~blanked], full[inside & ~blanked])
    assert np.isnan(cut[~inside]).all()
    # bounds: above every edge keeps all, below every edge blanks all
    assert_array_equal(rasterize(mesh, z, *args, max_edge=1.001 * longest.max()), full)
    assert np.isnan(rasterize(mesh, z, *args, max_edge=0.5 * longest.min())).all()


def test_max_edge_on_quads(rng):
    mesh = grid_mesh(rng, 10, 10)
    z = mesh.vertices[:, 0] + mesh.vertices[:, 1]
    args = (0.0, 0.0, 0.1, 100, 100)
    longest = longest_edges(mesh)
    max_edge = threshold_between(longest, 0.5)
    full = rasterize(mesh, z, *args)
    cut = rasterize(mesh, z, *args, max_edge=max_edge)
    # cells covered only by short faces are kept: rasterize the short faces alone
    short = hand_mesh(mesh.vertices, mesh.faces[longest <= max_edge])
    kept = rasterize(short, z, *args)
    assert_array_equal(np.isnan(cut), np.isnan(kept))
    assert_allclose(cut, kept, rtol=1e-12)
    assert np.isnan(cut).sum() > 1000 and not np.isnan(full).any()


# --------------------------------------------------------------------------
# Arguments
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"resolution": 0.0}, r"resolution must be > 0"),
        ({"resolution": -1.0}, r"resolution must be > 0"),
        ({"resolution": np.nan}, r"resolution must be a finite real number"),
        ({"resolution": np.inf}, r"resolution must be a finite real number"),
        ({"resolution": "1"}, r"resolution must be a finite real number"),
        ({"nx": 0}, r"nx must be a positive integer"),
        ({"nx": 2.5}, r"nx must be a positive integer"),
        ({"nx": True}, r"nx must be a positive integer"),
        ({"ny": -3}, r"ny must be a positive integer"),
        ({"x0": np.nan}, r"x0 must be a finite real number"),
        ({"y0": np.inf}, r"y0 must be a finite real number"),
        ({"max_edge": 0.0}, r"max_edge must be None or a number > 0"),
        ({"max_edge": -2.0}, r"max_edge must be None or a number > 0"),
        ({"max_edge": np.nan}, r"max_edge must be None or a number > 0"),
        ({"max_edge": "1"}, r"max_edge must be None or a number > 0"),
        ({"z": np.zeros(7)}, r"z must have shape \(n_vertices,\) = \(8,\)"),
        ({"z": np.full(8, np.inf)}, r"z must be finite or NaN"),
    ],
)
def test_bad_arguments_raise(kwargs, match):
    args = {"z": np.zeros(8), "x0": 0.0, "y0": 0.0, "resolution": 0.5, "nx": 4, "ny": 4}
    args.update(kwargs)
    with pytest.raises(InvalidInputError, match=match):
        rasterize(mixed(), **args)
    with pytest.raises(ValueError, match=match):
        rasterize(mixed(), **args)


def test_numpy_scalars_accepted():
    got = rasterize(mixed(), np.zeros(8), np.float32(0.0), np.int64(0), np.float64(0.5),
                    np.int32(4), np.int64(3), max_edge=np.float64(10.0))
    assert got.shape == (3, 4)
    assert_array_equal(got, 0.0)


def test_inputs_not_modified(rng):
    mesh = mixed()
    before = (mesh.vertices.copy(), mesh.faces.copy())
    z = rng.normal(size=8)
    z0 = z.copy()
    rasterize(mesh, z, 0.0, 0.0, 0.5, 8, 8, max_edge=3.0)
    for a, b in zip((mesh.vertices, mesh.faces, z), (*before, z0)):
        assert_array_equal(a, b)


def test_python_form_of_kernel_agrees():
    """The kernel run with NUMBA_DISABLE_JIT=1 gives the same numbers."""
    script = (
        "import json, numpy as np\n"
        "from meshcore.mesh import Mesh\n"
        "from meshcore.rasterize import rasterize\n"
        "v = np.array([[0, 0], [2, 0], [4, 0], [0, 2], [2, 2.3], [4, 2], [1, 4], [3, 4.2]])\n"
        "f = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 6, -1], [4, 7, 6, -1], [4, 5, 7, -1]])\n"
        "m = Mesh(v.astype(float), f, np.arange(8))\n"
        "out = rasterize(m, np.cos(np.arange(8.0)), -0.3, -0.2, 0.3, 16, 16, max_edge=2.5)\n"
        "print(json.dumps(np.where(np.isnan(out), None, out).tolist()))\n"
        "from meshcore.rasterize import sampled_faces\n"
        "print(json.dumps([sampled_faces(m, x0, -0.2, r, 9, 9).tolist() for x0, r in ((-0.3, 0.3), (0.1, 0.9), (-0.5, 1.0))]))\n"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    result = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
    )
    lines = result.stdout.splitlines()
    py_values = np.array(json.loads(lines[0]), dtype=np.float64)
    jit_values = rasterize(mixed(), np.cos(np.arange(8.0)), -0.3, -0.2, 0.3, 16, 16, max_edge=2.5)
    assert_allclose(py_values, jit_values, rtol=1e-14, atol=1e-14)
    assert np.isnan(jit_values).any() and not np.isnan(jit_values).all()
    from meshcore.rasterize import sampled_faces

    jit_taken = [sampled_faces(mixed(), x0, -0.2, r, 9, 9).tolist() for x0, r in ((-0.3, 0.3), (0.1, 0.9), (-0.5, 1.0))]
    assert json.loads(lines[1]) == jit_taken
    assert any(not all(t) for t in jit_taken) and all(any(t) for t in jit_taken)


def _outside(mesh: Mesh, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """``(n_f, n_p)``: how far each point lies outside each face (its largest
    distance beyond an edge's line; <= 0 inside), and -inf tolerance aside."""
    f = mesh.faces
    closed = np.where(f >= 0, f, f[:, :1])
    a = mesh.vertices[closed]  # (n_f, 4, 2), a triangle's 4th corner its 1st
    b = np.roll(a, -1, axis=1)
    e = b - a
    length = np.hypot(e[..., 0], e[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        turn = e[:, :, None, 0] * (py[None, None, :] - a[:, :, None, 1]) - e[:, :, None, 1] * (px[None, None, :] - a[:, :, None, 0])
        dist = np.where(length[:, :, None] > 0, -turn / length[:, :, None], -np.inf)
    return dist.max(axis=1)


@pytest.mark.parametrize("resolution,shift", [(1.0, -0.5), (0.37, 0.11), (2.5, 0.3)])
def test_sampled_faces_are_those_that_hold_a_cell_centre(rng, resolution, shift):
    """Every face a centre lies in (on its edge, at its corner) is taken; a face taken
    has a centre within a hair of it; and most faces of a mesh finer than the grid are not."""
    from meshcore.rasterize import sampled_faces

    origin = np.array([512345.0, 6789012.0])
    grid = grid_mesh(rng, 14, 11)  # straight outer edges on whole units: centres on edges and corners at res 1
    grid = Mesh(grid.vertices + origin, grid.faces, grid.input_to_vertex)
    fine = meshcore.build_mesh(np.round(rng.random((600, 2)) * [14.0, 11.0] + origin, 2), "s3", "s4")
    for mesh in (grid, fine):
        x0, y0 = origin + shift * resolution
        nx, ny = int(16 / resolution), int(13 / resolution)
        taken = sampled_faces(mesh, x0, y0, resolution, nx, ny)
        cx, cy = cell_centres(x0, y0, resolution, nx, ny)
        outside = _outside(mesh, cx.ravel(), cy.ravel())
        holds = np.any(outside <= 0.0, axis=1)
        assert holds.any()
        assert np.all(taken[holds])
        assert np.all(np.min(outside[taken], axis=1) <= 1e-5 * resolution)
        if mesh is fine and resolution > 1.0:
            assert taken.mean() < 0.6  # the faces between the centres are left out
        # every face rasterize draws is taken (values written only from faces taken)
        value = rasterize(mesh, mesh.vertices[:, 0] * 0.0 + 1.0, x0, y0, resolution, nx, ny)
        kept = Mesh(mesh.vertices, mesh.faces[taken], mesh.input_to_vertex)
        z = np.sin(mesh.vertices[:, 0]) + mesh.vertices[:, 1] - origin[1]
        assert_array_equal(rasterize(kept, z, x0, y0, resolution, nx, ny), rasterize(mesh, z, x0, y0, resolution, nx, ny))
        assert np.isfinite(value).sum() > 10
    with pytest.raises(InvalidInputError, match="resolution"):
        sampled_faces(grid, 0.0, 0.0, -1.0, 3, 3)
    with pytest.raises(InvalidInputError, match="nx"):
        sampled_faces(grid, 0.0, 0.0, 1.0, 0, 3)


@pytest.mark.parametrize("surface", ["linear", "smooth"])
def test_the_grid_does_not_depend_on_the_order_of_the_faces(rng, surface):
    """A centre on an edge two faces share reads the face first by coordinates,
    in rasterize, interpolate and gradient alike: shuffled faces give the same
    bits (a tile holds its neighbours' faces in another order than the whole
    survey does)."""
    mesh = grid_mesh(rng, 8, 6, jitter=0.0)  # centres on grid lines and diagonals
    z = np.sin(3.0 * mesh.vertices[:, 0]) + mesh.vertices[:, 1] ** 2  # faces' slopes differ at every edge
    kw = {} if surface == "linear" else {"surface": meshcore.smooth_surface(mesh, z)}
    x, y = cell_centres(-0.125, -0.125, 0.25, 33, 25)
    grid = rasterize(mesh, z, -0.125, -0.125, 0.25, 33, 25, **kw)
    values = interpolate(mesh, z, x, y, **kw)
    slope = meshcore.gradient(mesh, z, x, y, **kw)
    assert np.isfinite(grid).all()
    for _ in range(3):
        order = rng.permutation(mesh.faces.shape[0])
        shuffled = Mesh(mesh.vertices, mesh.faces[order], mesh.input_to_vertex)
        kw2 = {} if surface == "linear" else {"surface": meshcore.smooth_surface(shuffled, z)}
        assert_array_equal(rasterize(shuffled, z, -0.125, -0.125, 0.25, 33, 25, **kw2), grid)
        assert_array_equal(interpolate(shuffled, z, x, y, **kw2), values)
        for got, want in zip(meshcore.gradient(shuffled, z, x, y, **kw2), slope):
            assert_array_equal(got, want)
    # the rule is the one of meshcore.interpolate: the grid is its values at the centres, bit for bit
    assert_array_equal(grid, values)


def test_bounded_triangles_keep_those_of_short_edges_and_small_circles_from_their_first_corner():
    from meshcore.tiles import bounded_triangles

    rng = np.random.default_rng(5)
    points = np.round(rng.uniform(0.0, 50.0, (400, 2)), 2) + [6.5e5, 6.8e6]
    mesh = meshcore.build_mesh(points, "delaunay", None)
    tri = mesh.faces[:, :3]
    v = mesh.vertices - mesh.vertices.min(axis=0)  # the same lengths, fewer digits for the check
    a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    sides = np.stack([np.hypot(*(b - a).T), np.hypot(*(c - b).T), np.hypot(*(a - c).T)])
    area2 = np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    radius = sides.prod(axis=0) / (2.0 * area2)
    for max_edge in (1.5, 3.0, 6.0):
        kept = bounded_triangles(mesh.vertices, tri, max_edge)
        want = (sides.max(axis=0) <= max_edge) & (radius <= max_edge)
        assert {tuple(sorted(f)) for f in kept[:, :3].tolist()} == {tuple(sorted(f)) for f in tri[want].tolist()}
        assert (kept[:, 3] == -1).all()
        first = mesh.vertices[kept[:, 0]]
        for k in (1, 2):  # each starts at its corner first by x, then y
            other = mesh.vertices[kept[:, k]]
            assert ((first[:, 0] < other[:, 0]) | ((first[:, 0] == other[:, 0]) & (first[:, 1] < other[:, 1]))).all()
        # given from another corner, in another order: the same faces
        shuffled = np.roll(tri, 1, axis=1)[::-1]
        again = bounded_triangles(mesh.vertices, shuffled, max_edge)
        assert sorted(map(tuple, again.tolist())) == sorted(map(tuple, kept.tolist()))


def _highest_by_sorting(x, y, z, x0, y0, cell):
    """The rule of highest_per_cell written with numpy's lexsort: per cell, the highest, then first by x, then y."""
    col = np.floor((x - x0) / cell).astype(np.int64)
    row = np.floor((y - y0) / cell).astype(np.int64)
    order = np.lexsort((np.arange(x.size), y, x, -z, col, row))
    cells = np.column_stack([row, col])[order]
    first = np.ones(order.size, dtype=bool)
    first[1:] = (cells[1:] != cells[:-1]).any(axis=1)
    return np.sort(order[first])


@pytest.mark.parametrize("extent", [20.0, 5e4])  # cells enough for a slot each, and far more cells than points
def test_highest_per_cell_keeps_the_highest_point_of_each_cell_whatever_the_order(rng, extent):
    from meshcore.tiles import highest_per_cell

    n = 4000
    # survey-like: coordinates on a 1 cm lattice at an offset, heights on 1 cm, so that ties happen
    x = 651_000.0 + np.round(rng.uniform(0, extent, n), 2)
    y = 6_862_000.0 + np.round(rng.uniform(0, extent, n), 2)
    z = np.round(rng.uniform(100, 100.2, n), 2)
    x[:200], y[:200] = x[200:400], y[200:400]  # points sharing x and y, some of one height
    z[:100] = z[200:300]
    cell = 0.5 if extent < 100 else 300.0
    x0, y0 = 650_999.75, 6_861_999.25
    kept = highest_per_cell(x, y, z, x0, y0, cell)
    assert_array_equal(kept, _highest_by_sorting(x, y, z, x0, y0, cell))
    assert np.unique(np.column_stack([np.floor((x[kept] - x0) / cell), np.floor((y[kept] - y0) / cell)]), axis=0).shape[0] == kept.size
    # shuffled, the same points (exact copies aside: the same values)
    perm = rng.permutation(n)
    again = perm[highest_per_cell(x[perm], y[perm], z[perm], x0, y0, cell)]
    assert_array_equal(np.sort(np.column_stack([x, y, z])[again], axis=0), np.sort(np.column_stack([x, y, z])[kept], axis=0))
    # a caller holding whole cells only gets their points
    col = np.floor((x - x0) / cell)
    held = col < np.median(col)
    sub = np.flatnonzero(held)[highest_per_cell(x[held], y[held], z[held], x0, y0, cell)]
    assert set(sub.tolist()) == set(kept[held[kept]].tolist())


def test_highest_per_cell_rejects_what_it_cannot_grid():
    from meshcore.tiles import highest_per_cell

    assert highest_per_cell([], [], [], 0.0, 0.0, 1.0).shape == (0,)
    with pytest.raises(InvalidInputError, match="cell"):
        highest_per_cell([0.0], [0.0], [0.0], 0.0, 0.0, 0.0)
    with pytest.raises(InvalidInputError, match="finite"):
        highest_per_cell([np.nan], [0.0], [0.0], 0.0, 0.0, 1.0)
    with pytest.raises(InvalidInputError, match="one length"):
        highest_per_cell([0.0, 1.0], [0.0], [0.0], 0.0, 0.0, 1.0)
