"""Tests of meshcore.interpolate: exact on linear/bilinear data, continuous, NaN outside."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import Delaunay

from meshcore.errors import InvalidInputError, InvalidMeshError
from meshcore.interpolate import (
    _bilinear_inverse,
    _surface_at,
    _quadratic_roots,
    gradient,
    interpolate,
)
from meshcore.mesh import Mesh

from .mesh_checks import hand_mesh


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


# --------------------------------------------------------------------------
# Hand-built meshes (fresh arrays on every call)
# --------------------------------------------------------------------------


def unit_square() -> Mesh:
    return hand_mesh([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1, 2, 3]])


def two_triangles() -> Mesh:
    return hand_mesh([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1, 2, -1], [0, 2, 3, -1]])


def hexagon_fan() -> Mesh:
    angles = np.arange(6) * np.pi / 3
    v = np.vstack([[0.0, 0.0], np.column_stack([np.cos(angles), np.sin(angles)])])
    return hand_mesh(v, [[0, 1 + k, 1 + (k + 1) % 6, -1] for k in range(6)])


def parallelogram() -> Mesh:
    return hand_mesh([[0, 0], [2, 0], [3, 1], [1, 1]], [[0, 1, 2, 3]])


def trapezoid_u() -> Mesh:
    """P0P1 parallel to P3P2: the quadratic in u degenerates."""
    return hand_mesh([[0, 0], [3, 0], [2, 1], [1, 1]], [[0, 1, 2, 3]])


def trapezoid_v() -> Mesh:
    """P0P3 parallel to P1P2: the quadratic in v degenerates."""
    return hand_mesh([[0, 0], [2, 0], [2, 3], [0, 1]], [[0, 1, 2, 3]])


def general_quad() -> Mesh:
    return hand_mesh([[0, 0], [4, 0.5], [3.5, 3], [0.5, 2.2]], [[0, 1, 2, 3]])


def mixed() -> Mesh:
    """Two quads and three triangles; quad-quad edge 1-4, quad-triangle edges 3-4 and 4-5."""
    return hand_mesh(
        [[0, 0], [2, 0], [4, 0], [0, 2], [2, 2.3], [4, 2], [1, 4], [3, 4.2]],
        [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 6, -1], [4, 7, 6, -1], [4, 5, 7, -1]],
    )


def grid_mesh(rng: np.random.Generator, nx: int, ny: int, jitter: float = 0.2) -> Mesh:
    """A jittered nx x ny grid, each cell a quad or two triangles (boundary kept straight)."""
    gx, gy = np.meshgrid(np.arange(nx + 1.0), np.arange(ny + 1.0))
    interior = (gx > 0) & (gx < nx) & (gy > 0) & (gy < ny)
    gx = gx + interior * rng.uniform(-jitter, jitter, gx.shape)
    gy = gy + interior * rng.uniform(-jitter, jitter, gy.shape)
    faces = []
    for j in range(ny):
        for i in range(nx):
            a, b = j * (nx + 1) + i, j * (nx + 1) + i + 1
            c, d = b + nx + 1, a + nx + 1
            kind = rng.integers(3)
            if kind == 0:
                faces.append([a, b, c, d])
            elif kind == 1:
                faces += [[a, b, c, -1], [a, c, d, -1]]
            else:
                faces += [[a, b, d, -1], [b, c, d, -1]]
    return hand_mesh(np.column_stack([gx.ravel(), gy.ravel()]), faces)


def delaunay_mesh(points: np.ndarray) -> tuple[Mesh, Delaunay]:
    """scipy's triangulation as a Mesh, every triangle turned counter-clockwise."""
    tri = Delaunay(points)
    s = tri.simplices.astype(np.int64)
    a, b, c = points[s[:, 0]], points[s[:, 1]], points[s[:, 2]]
    cw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    s[cw, 1], s[cw, 2] = s[cw, 2], s[cw, 1]
    return hand_mesh(points, np.column_stack([s, np.full(len(s), -1)])), tri


ALL_MESHES = [unit_square, two_triangles, hexagon_fan, parallelogram, trapezoid_u,
              trapezoid_v, general_quad, mixed]
QUADS = [unit_square, parallelogram, trapezoid_u, trapezoid_v, general_quad]


def bilinear_forward(corners: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``sum w_k P_k`` with the bilinear weights; ``corners`` (4, ...) rows P0..P3."""
    w = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v])
    return np.tensordot(w, corners, axes=([0], [0]))


def points_in_faces(mesh: Mesh, rng: np.random.Generator, per_face: int = 16) -> np.ndarray:
    out = []
    for face in mesh.faces:
        if face[3] < 0:
            out.append(rng.dirichlet(np.ones(3), per_face) @ mesh.vertices[face[:3]])
        else:
            u, v = rng.random((2, per_face))
            out.append(bilinear_forward(mesh.vertices[face], u, v))
    return np.concatenate(out)


# --------------------------------------------------------------------------
# The inverse bilinear map
# --------------------------------------------------------------------------


def test_quadratic_roots_are_stable():
    # t^2 + 1e8 t + 1 = 0: the small root -1e-8 is lost to cancellation by the school formula
    small, large = _quadratic_roots(1.0, 1e8, 1.0)
    assert_allclose([small, large], [-1e-8, -1e8], rtol=1e-15)
    # a -> 0: the root of the linear equation, no second root
    small, large = _quadratic_roots(1e-300, 2.0, -1.0)
    assert small == 0.5 and abs(large) > 1e299
    small, large = _quadratic_roots(0.0, 2.0, -1.0)
    assert small == 0.5 and np.isnan(large)
    # a slightly negative discriminant is a double root
    assert_allclose(_quadratic_roots(1.0, -2.0, 1.0 + 1e-15), [1.0, 1.0], rtol=1e-7)


@pytest.mark.parametrize(
    "corners",
    [
        [[0, 0], [1, 0], [1, 1], [0, 1]],
        [[0, 0], [2, 0], [3, 1], [1, 1]],  # parallelogram
        [[0, 0], [3, 0], [2, 1], [1, 1]],  # trapezoid, P0P1 || P3P2
        [[0, 0], [2, 0], [2, 3], [0, 1]],  # trapezoid, P0P3 || P1P2
        [[0, 0], [4, 0.5], [3.5, 3], [0.5, 2.2]],
        [[1, 1], [0, 3], [-2, 1.5], [-1, -0.5]],  # rotated: edges in every direction
        [[0, 0], [1, 0], [1.3, 3], [-0.2, 1]],  # strongly non-affine
        [[0, 0], [1, 0], [1 + 1e-9, 1], [0, 1]],  # a parallelogram up to 1e-9
        [[-2, -1.3], [-0.57, -0.58], [0.6, 0.27], [-1.25, 0.57]],  # the larger root is wanted
    ],
)
def test_bilinear_inverse_round_trip(corners, rng):
    p = np.asarray(corners, dtype=np.float64)
    u = np.concatenate([rng.random(200), [0, 1, 1, 0, 0.5, 0, 1]])
    v = np.concatenate([rng.random(200), [0, 0, 1, 1, 0, 0.5, 0.5]])
    xy = bilinear_forward(p, u, v)
    got = np.array([_bilinear_inverse(*p.ravel(), x, y) for x, y in xy])
    assert_allclose(got[:, 0], u, rtol=0, atol=1e-13)
    assert_allclose(got[:, 1], v, rtol=0, atol=1e-13)


def test_bilinear_inverse_exact_on_parallelogram_and_survey_coordinates():
    # dyadic (u, v) on a parallelogram with integer corners: every step is exact
    p = np.array([[0.0, 0.0], [4.0, 0.0], [6.0, 2.0], [2.0, 2.0]])
    for u, v in [(0.25, 0.5), (0.125, 0.875), (1.0, 0.0)]:
        x, y = bilinear_forward(p, np.array(u), np.array(v))
        assert _bilinear_inverse(*p.ravel(), float(x), float(y)) == (u, v)
    # a 2 m quad at UTM-like coordinates keeps about 1e-10 m of precision
    q = np.array([[0.0, 0.0], [2.0, 0.1], [1.9, 2.2], [0.2, 1.8]]) + [512345.0, 5412345.0]
    u = np.array([0.3, 0.7, 0.05])
    v = np.array([0.6, 0.2, 0.95])
    xy = bilinear_forward(q, u, v)
    got = np.array([_bilinear_inverse(*q.ravel(), x, y) for x, y in xy])
    assert_allclose(got, np.column_stack([u, v]), rtol=0, atol=1e-9)


def test_bilinear_inverse_clamps_to_unit_square():
    u, v = _bilinear_inverse(0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0 + 1e-14, -1e-14)
    assert (u, v) == (1.0, 0.0)


# --------------------------------------------------------------------------
# Reproduction of linear and bilinear data
# --------------------------------------------------------------------------


@pytest.mark.parametrize("make", ALL_MESHES)
def test_linear_function_reproduced_with_constant_gradient(make, rng):
    mesh = make()
    f = lambda x, y: 3.0 + 2.0 * x - 5.0 * y  # noqa: E731
    z = f(mesh.vertices[:, 0], mesh.vertices[:, 1])
    pts = np.vstack([points_in_faces(mesh, rng), mesh.vertices])
    got = interpolate(mesh, z, pts[:, 0], pts[:, 1])
    assert_allclose(got, f(pts[:, 0], pts[:, 1]), rtol=1e-12, atol=1e-12)
    gx, gy = gradient(mesh, z, pts[:, 0], pts[:, 1])
    assert_allclose(gx, 2.0, rtol=1e-12)
    assert_allclose(gy, -5.0, rtol=1e-12)


def test_linear_function_on_jittered_mixed_grid(rng):
    mesh = grid_mesh(rng, 12, 7)
    assert mesh.n_quads > 0 and mesh.n_triangles > 0
    z = -1.5 + 0.25 * mesh.vertices[:, 0] + 4.0 * mesh.vertices[:, 1]
    pts = rng.uniform([0, 0], [12, 7], (3000, 2))
    assert_allclose(
        interpolate(mesh, z, pts[:, 0], pts[:, 1]),
        -1.5 + 0.25 * pts[:, 0] + 4.0 * pts[:, 1],
        rtol=1e-12, atol=1e-12,
    )
    gx, gy = gradient(mesh, z, pts[:, 0], pts[:, 1])
    assert_allclose(gx, 0.25, rtol=1e-11)
    assert_allclose(gy, 4.0, rtol=1e-11)


def test_linear_function_at_survey_coordinates(rng):
    mesh0 = grid_mesh(rng, 6, 6)
    offset = np.array([512345.0, 5412345.0])
    mesh = hand_mesh(mesh0.vertices + offset, mesh0.faces)
    local = points_in_faces(mesh0, rng, 4)
    z = 100.0 + 0.3 * mesh0.vertices[:, 0] - 0.7 * mesh0.vertices[:, 1]
    pts = local + offset
    got = interpolate(mesh, z, pts[:, 0], pts[:, 1])
    assert_allclose(got, 100.0 + 0.3 * local[:, 0] - 0.7 * local[:, 1], rtol=0, atol=1e-8)


@pytest.mark.parametrize("make", QUADS)
def test_bilinear_patch_exact_at_vertices(make, rng):
    mesh = make()
    z = rng.normal(size=4)
    assert_allclose(
        interpolate(mesh, z, mesh.vertices[:, 0], mesh.vertices[:, 1]), z, rtol=1e-13, atol=1e-14
    )


@pytest.mark.parametrize("make", QUADS)
def test_bilinear_function_of_uv_reproduced(make, rng):
    mesh = make()
    z = rng.normal(size=4)
    u, v = rng.random((2, 300))
    xy = bilinear_forward(mesh.vertices, u, v)
    expected = bilinear_forward(z, u, v)
    assert_allclose(interpolate(mesh, z, xy[:, 0], xy[:, 1]), expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("make", [general_quad, trapezoid_u, trapezoid_v])
def test_bilinear_gradient_matches_finite_differences(make, rng):
    mesh = make()
    z = rng.normal(size=4)
    u, v = rng.uniform(0.1, 0.9, (2, 50))
    xy = bilinear_forward(mesh.vertices, u, v)
    h = 1e-6
    x, y = xy[:, 0], xy[:, 1]
    fd_x = (interpolate(mesh, z, x + h, y) - interpolate(mesh, z, x - h, y)) / (2 * h)
    fd_y = (interpolate(mesh, z, x, y + h) - interpolate(mesh, z, x, y - h)) / (2 * h)
    gx, gy = gradient(mesh, z, x, y)
    assert_allclose(gx, fd_x, rtol=1e-6, atol=1e-8)
    assert_allclose(gy, fd_y, rtol=1e-6, atol=1e-8)


def test_matches_scipy_on_delaunay_mesh(rng):
    points = rng.random((500, 2))
    mesh, tri = delaunay_mesh(points)
    z = np.sin(5 * points[:, 0]) + points[:, 1] ** 2
    q = rng.uniform(-0.1, 1.1, (4000, 2))
    got = interpolate(mesh, z, q[:, 0], q[:, 1])
    ref = LinearNDInterpolator(tri, z)(q)
    assert_array_equal(np.isnan(got), np.isnan(ref))
    assert np.isnan(got).any() and (~np.isnan(got)).any()
    assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_long_thin_mesh_is_located(rng):
    mesh = grid_mesh(rng, 300, 1, jitter=0.0)
    z = 2.0 * mesh.vertices[:, 0] + mesh.vertices[:, 1]
    q = rng.uniform([0, 0], [300, 1], (2000, 2))
    assert_allclose(interpolate(mesh, z, q[:, 0], q[:, 1]), 2.0 * q[:, 0] + q[:, 1], rtol=1e-12)


# --------------------------------------------------------------------------
# Continuity, edges, outside
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("edge", "face_a", "face_b"),
    [((1, 4), 0, 1), ((3, 4), 0, 2), ((4, 5), 1, 4), ((4, 6), 2, 3)],
    ids=["quad-quad", "quad-triangle", "quad-triangle-2", "triangle-triangle"],
)
def test_continuous_across_shared_edge(edge, face_a, face_b, rng):
    mesh = mixed()
    z = rng.normal(size=len(mesh.vertices))
    pa, pb = mesh.vertices[list(edge)]
    t = np.linspace(0.0, 1.0, 11)
    on_edge = (1 - t)[:, None] * pa + t[:, None] * pb
    expected = (1 - t) * z[edge[0]] + t * z[edge[1]]
    for f in (face_a, face_b):
        values = [
            _surface_at(mesh.vertices, mesh.faces, z, None, f, x, y)[0] for x, y in on_edge
        ]
        assert_allclose(values, expected, rtol=1e-12, atol=1e-12)
    # approached from both sides the surface tends to the same edge values
    normal = np.array([pa[1] - pb[1], pb[0] - pa[0]]) / np.hypot(*(pb - pa))
    inner = on_edge[1:-1]
    for eps in (1e-4, 1e-8):
        left = interpolate(mesh, z, *(inner + eps * normal).T)
        right = interpolate(mesh, z, *(inner - eps * normal).T)
        assert_allclose(left, expected[1:-1], rtol=0, atol=50 * eps)
        assert_allclose(right, expected[1:-1], rtol=0, atol=50 * eps)


@pytest.mark.parametrize("make", ALL_MESHES)
def test_vertices_and_edge_points_are_inside(make, rng):
    mesh = make()
    z = rng.normal(size=len(mesh.vertices))
    f = mesh.faces
    n = np.where(f[:, 3] >= 0, 4, 3)
    starts = np.concatenate([f[i, :n[i]] for i in range(len(f))])
    ends = np.concatenate([np.roll(f[i, :n[i]], -1) for i in range(len(f))])
    mids = 0.5 * (mesh.vertices[starts] + mesh.vertices[ends])
    pts = np.vstack([mesh.vertices, mids])
    assert not np.isnan(interpolate(mesh, z, pts[:, 0], pts[:, 1])).any()
    assert not np.isnan(gradient(mesh, z, pts[:, 0], pts[:, 1])[0]).any()
    assert_allclose(interpolate(mesh, z, mesh.vertices[:, 0], mesh.vertices[:, 1]), z, rtol=1e-12)


@pytest.mark.parametrize("make", ALL_MESHES)
def test_nan_outside_hull(make):
    mesh = make()
    z = np.arange(len(mesh.vertices), dtype=np.float64)
    lo = mesh.vertices.min(axis=0)
    hi = mesh.vertices.max(axis=0)
    mid = 0.5 * (lo + hi)
    x = np.array([lo[0] - 1e-6, hi[0] + 1e-6, lo[0] - 10.0, mid[0], np.nan, np.inf, 0.0])
    y = np.array([mid[1], mid[1], lo[1], hi[1] + 1e-6, 0.0, 0.0, -np.inf])
    assert np.isnan(interpolate(mesh, z, x, y)).all()
    gx, gy = gradient(mesh, z, x, y)
    assert np.isnan(gx).all() and np.isnan(gy).all()


def test_nan_outside_hull_but_inside_bbox():
    mesh = hexagon_fan()
    z = np.ones(7)
    # the corners of the bounding box of a hexagon are outside it
    x = np.array([0.99, -0.99, 0.99, -0.99])
    y = np.array([0.86, 0.86, -0.86, -0.86])
    assert np.isnan(interpolate(mesh, z, x, y)).all()
    assert_allclose(interpolate(mesh, z, x * 0.5, y * 0.5), 1.0)


def test_nan_z_spreads_to_its_faces_only():
    mesh = mixed()
    z = np.arange(8, dtype=np.float64)
    z[2] = np.nan  # a corner of quad 1 only
    assert np.isnan(interpolate(mesh, z, 3.0, 1.0))
    assert np.isnan(gradient(mesh, z, 3.0, 1.0)[0])
    assert not np.isnan(interpolate(mesh, z, [1.0, 2.0, 3.0], [1.0, 3.0, 3.5])).any()


# --------------------------------------------------------------------------
# Shapes and arguments
# --------------------------------------------------------------------------


def test_output_has_the_shape_of_x():
    mesh = unit_square()
    z = [0.0, 1.0, 2.0, 1.0]
    assert interpolate(mesh, z, 0.5, 0.5).shape == ()
    assert float(interpolate(mesh, z, 0.5, 0.5)) == 1.0
    x = np.full((3, 4, 2), 0.25)
    assert interpolate(mesh, z, x, x).shape == (3, 4, 2)
    gx, gy = gradient(mesh, z, x, x)
    assert gx.shape == gy.shape == (3, 4, 2)
    assert interpolate(mesh, z, np.empty((0, 3)), np.empty((0, 3))).shape == (0, 3)
    assert interpolate(mesh, np.array([0, 1, 2, 1]), [0.5], [0.5]).dtype == np.float64


def test_mesh_without_faces_gives_nan():
    mesh = hand_mesh(np.zeros((0, 2)), np.zeros((0, 4)))
    assert np.isnan(interpolate(mesh, np.zeros(0), [0.0, 1.0], [0.0, 1.0])).all()


def test_inputs_not_modified(rng):
    mesh = mixed()
    before = (mesh.vertices.copy(), mesh.faces.copy())
    z = rng.normal(size=8)
    z0 = z.copy()
    x = rng.uniform(0, 4, 50)
    y = rng.uniform(0, 4, 50)
    x0, y0 = x.copy(), y.copy()
    interpolate(mesh, z, x, y)
    gradient(mesh, z, x, y)
    for a, b in zip((mesh.vertices, mesh.faces, z, x, y), (*before, z0, x0, y0)):
        assert_array_equal(a, b)


@pytest.mark.parametrize("func", [interpolate, gradient])
@pytest.mark.parametrize(
    ("z", "x", "y", "match"),
    [
        (np.zeros(3), 0.5, 0.5, r"z must have shape \(n_vertices,\) = \(4,\)"),
        (np.zeros((4, 1)), 0.5, 0.5, r"z must have shape"),
        (np.array([0.0, 1.0, np.inf, 0.0]), 0.5, 0.5, r"z must be finite or NaN"),
        (np.array(["a", "b", "c", "d"]), 0.5, 0.5, r"z must be a real numeric array"),
        (np.zeros(4), np.zeros(3), np.zeros(2), r"x and y must have the same shape"),
        (np.zeros(4), np.zeros(3), 0.5, r"x and y must have the same shape"),
        (np.zeros(4), ["a"], [0.5], r"x must be a real numeric array"),
    ],
)
def test_bad_arguments_raise(func, z, x, y, match):
    with pytest.raises(InvalidInputError, match=match):
        func(unit_square(), z, x, y)
    with pytest.raises(ValueError, match=match):
        func(unit_square(), z, x, y)


def test_bad_mesh_raises():
    with pytest.raises(InvalidInputError, match=r"faces of shape \(n_f, 4\)"):
        interpolate(hand_mesh([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]]), np.zeros(3), 0.1, 0.1)


def test_python_form_of_kernels_agrees():
    """The kernels run with NUMBA_DISABLE_JIT=1 give the same numbers."""
    script = (
        "import json, numpy as np\n"
        "from meshcore.mesh import Mesh\n"
        "from meshcore.interpolate import interpolate, gradient\n"
        "v = np.array([[0, 0], [2, 0], [4, 0], [0, 2], [2, 2.3], [4, 2], [1, 4], [3, 4.2]])\n"
        "f = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 6, -1], [4, 7, 6, -1], [4, 5, 7, -1]])\n"
        "m = Mesh(v.astype(float), f, np.arange(8))\n"
        "z = np.sin(np.arange(8.0))\n"
        "x, y = np.meshgrid(np.linspace(-0.5, 4.5, 9), np.linspace(-0.5, 4.5, 9))\n"
        "gx, gy = gradient(m, z, x, y)\n"
        "out = [interpolate(m, z, x, y), gx, gy]\n"
        "print(json.dumps([np.where(np.isnan(a), None, a).tolist() for a in out]))\n"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    result = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
    )
    py_values = [np.array(a, dtype=np.float64) for a in json.loads(result.stdout)]
    mesh = mixed()
    z = np.sin(np.arange(8.0))
    x, y = np.meshgrid(np.linspace(-0.5, 4.5, 9), np.linspace(-0.5, 4.5, 9))
    jit_values = [interpolate(mesh, z, x, y), *gradient(mesh, z, x, y)]
    for a, b in zip(py_values, jit_values):
        assert_allclose(a, b, rtol=1e-14, atol=1e-14)
    assert not np.isnan(jit_values[0]).all()


@pytest.mark.parametrize("row, col, value", [(0, 0, -1), (1, 2, -1), (1, 3, -2), (0, 3, 5), (1, 1, 5)])
def test_a_corner_out_of_range_is_refused_before_any_kernel_reads_it(row, col, value):
    vertices = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [2.0, 0.0]])
    faces = np.array([[0, 1, 2, 3], [1, 4, 2, -1]])
    z = vertices[:, 0]
    assert np.allclose(interpolate(Mesh(vertices, faces, np.arange(5)), z, [0.5], [0.5]), 0.5)
    faces[row, col] = value
    with pytest.raises(InvalidMeshError, match="outside 0..4"):
        interpolate(Mesh(vertices, faces, np.arange(5)), z, [0.5], [0.5])
