"""Tests of meshcore.quadrature: exactness of the face rules and the L2 errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.polynomial import Polynomial
from numpy.testing import assert_allclose

from meshcore import InvalidInputError, InvalidMeshError, Mesh, build_mesh
from meshcore.quadrature import _quadrature_kernel, face_quadrature, gauss_legendre, l2_errors

TRIANGLE = np.array([[0.2, -0.1], [2.0, 0.3], [0.7, 1.6]])
QUAD = np.array([[0.0, 0.0], [2.0, 0.0], [1.5, 1.5], [0.0, 1.0]])  # convex, not a parallelogram


def single_face(corners: np.ndarray) -> Mesh:
    n = corners.shape[0]
    faces = np.array([list(range(n)) + [-1] * (4 - n)], dtype=np.int64)
    return Mesh(vertices=corners.astype(np.float64), faces=faces, input_to_vertex=np.arange(n))


def polygon_moment(corners: np.ndarray, a: int, b: int) -> float:
    """Exact integral of x^a y^b over a counter-clockwise polygon (Green: x^(a+1) y^b / (a+1) dy)."""
    total = 0.0
    for p, q in zip(corners, np.roll(corners, -1, axis=0)):
        x = Polynomial([p[0], q[0] - p[0]])
        y = Polynomial([p[1], q[1] - p[1]])
        integrand = x ** (a + 1) * y**b * (q[1] - p[1]) / (a + 1)
        antiderivative = integrand.integ()
        total += antiderivative(1.0) - antiderivative(0.0)
    return total


def monomials(degree: int) -> list[tuple[int, int]]:
    return [(a, d - a) for d in range(degree + 1) for a in range(d + 1)]


def integrate_monomial(corners: np.ndarray, order: int, a: int, b: int) -> float:
    q = face_quadrature(single_face(corners), order)
    x, y = q.points[..., 0], q.points[..., 1]
    return q.integrate(x**a * y**b)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


def random_disc(rng: np.random.Generator, n: int) -> np.ndarray:
    r = np.sqrt(rng.random(n))
    t = 2 * np.pi * rng.random(n)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


# -- the 1-D rule -------------------------------------------------------------


def test_gauss_legendre_integrates_degree_2n_minus_1_on_the_unit_interval():
    for n in range(1, 7):
        x, w = gauss_legendre(n)
        for d in range(2 * n):
            assert_allclose(np.sum(w * x**d), 1.0 / (d + 1), rtol=1e-13)
        assert abs(np.sum(w * x ** (2 * n)) - 1.0 / (2 * n + 1)) > 1e-10


@pytest.mark.parametrize("order", [0, -1, 2.0, True])
def test_order_must_be_a_positive_integer(order):
    with pytest.raises(InvalidInputError, match="order"):
        face_quadrature(single_face(TRIANGLE), order)


# -- exactness on single faces -----------------------------------------------


@pytest.mark.parametrize("corners", [TRIANGLE, QUAD], ids=["triangle", "quad"])
@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_polynomials_of_total_degree_2n_minus_2_are_exact(corners, order):
    for a, b in monomials(2 * order - 2):
        exact = polygon_moment(corners, a, b)
        assert_allclose(integrate_monomial(corners, order, a, b), exact, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("corners", [TRIANGLE, QUAD], ids=["triangle", "quad"])
def test_higher_degrees_are_not_exact(corners):
    # The rule is not exact by accident of a trivial integrand: order 2 misses degree 4.
    errors = [abs(integrate_monomial(corners, 2, a, b) - polygon_moment(corners, a, b)) for a, b in monomials(4)]
    assert max(errors) > 1e-6


def test_area_centroid_and_second_moment_of_a_triangle_closed_form():
    q = face_quadrature(single_face(TRIANGLE), 2)
    (x0, y0), (x1, y1), (x2, y2) = TRIANGLE
    area = 0.5 * ((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0))
    x, y = q.points[..., 0], q.points[..., 1]
    assert_allclose(q.integrate(np.ones_like(x)), area, rtol=1e-14)
    assert_allclose(q.integrate(x) / area, TRIANGLE[:, 0].mean(), rtol=1e-14)
    # Degree 2 is integrated exactly by the edge-midpoint rule: area/3 * sum f(midpoints).
    mid = 0.5 * (TRIANGLE + np.roll(TRIANGLE, -1, axis=0))
    assert_allclose(q.integrate(x * y), area / 3 * np.sum(mid[:, 0] * mid[:, 1]), rtol=1e-13)


def test_parallelogram_is_exact_to_degree_2n_minus_1_per_direction():
    corners = np.array([[0.0, 0.0], [2.0, 0.5], [2.5, 2.0], [0.5, 1.5]])
    order = 2
    for a in range(4):
        for b in range(4 - a):
            assert_allclose(
                integrate_monomial(corners, order, a, b), polygon_moment(corners, a, b), rtol=1e-12
            )


def test_shape_functions_are_a_partition_of_unity_and_padding_is_zero(rng):
    mesh = build_mesh(random_disc(rng, 80), "s3", "s4")
    q = face_quadrature(mesh, 3)
    assert q.points.shape == (mesh.faces.shape[0], 9, 2)
    assert q.shape_gradients.shape == (mesh.faces.shape[0], 9, 4, 2)
    assert_allclose(q.shape_values.sum(axis=-1), 1.0, rtol=1e-14)
    assert_allclose(q.shape_gradients.sum(axis=-2), 0.0, atol=1e-10)
    triangles = ~mesh.is_quad
    assert np.all(q.shape_values[triangles, :, 3] == 0.0)
    assert np.all(q.shape_gradients[triangles, :, 3] == 0.0)
    assert np.all(q.weights > 0.0)
    # Every point lies in its face: the shape values are convex weights of the corners.
    assert np.all(q.shape_values >= 0.0)


def test_mesh_area_equals_the_hull_area(rng):
    spatial = pytest.importorskip("scipy.spatial")
    xy = random_disc(rng, 300)
    hull_area = spatial.ConvexHull(xy).volume
    for tm, qm in (("s1", None), ("s1", "s2"), ("s3", "s4")):
        q = face_quadrature(build_mesh(xy, tm, qm), 1)
        assert_allclose(q.weights.sum(), hull_area, rtol=1e-12)


def test_kernel_python_form_matches_compiled(rng):
    mesh = build_mesh(random_disc(rng, 40), "s3", "s4")
    compiled = face_quadrature(mesh, 3)
    nodes, nweights = gauss_legendre(3)
    n_f = mesh.faces.shape[0]
    out = (np.empty((n_f, 9, 2)), np.empty((n_f, 9)), np.empty((n_f, 9, 4)), np.empty((n_f, 9, 4, 2)))
    bad = _quadrature_kernel.py_func(mesh.vertices, mesh.faces, nodes, nweights, *out)
    assert bad == -1
    for mine, theirs in zip(
        out, (compiled.points, compiled.weights, compiled.shape_values, compiled.shape_gradients)
    ):
        assert_allclose(mine, theirs, rtol=1e-14, atol=1e-14)


def test_clockwise_or_degenerate_faces_are_rejected():
    with pytest.raises(InvalidMeshError, match="non-positive Jacobian"):
        face_quadrature(single_face(TRIANGLE[::-1].copy()), 2)
    with pytest.raises(InvalidMeshError, match="non-positive Jacobian"):
        face_quadrature(single_face(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])), 2)
    dart = np.array([[0.0, 0.0], [2.0, 0.0], [0.3, 0.3], [0.0, 2.0]])  # not convex
    with pytest.raises(InvalidMeshError, match="non-positive Jacobian"):
        face_quadrature(single_face(dart), 3)


# -- L2 errors ------------------------------------------------------------------


def errors_of(mesh, order, f, grad_f, z=None):
    q = face_quadrature(mesh, order)
    x, y = q.points[..., 0], q.points[..., 1]
    if z is None:
        z = f(mesh.vertices[:, 0], mesh.vertices[:, 1])
    return l2_errors(mesh, z, f(x, y), np.stack(grad_f(x, y), axis=-1), q)


def test_linear_functions_have_zero_error_on_any_mesh(rng):
    def f(x, y):
        return 0.5 - 1.5 * x + 2.5 * y

    def grad_f(x, y):
        return np.full_like(x, -1.5), np.full_like(x, 2.5)

    xy = random_disc(rng, 150)
    for tm, qm in (("s1", None), ("s1", "s2"), ("s3", None), ("s3", "s4")):
        mesh = build_mesh(xy, tm, qm)
        value, gradient = errors_of(mesh, 3, f, grad_f)
        assert value < 1e-13 and gradient < 1e-11


def test_bilinear_function_is_reproduced_on_rectangles_only():
    def f(x, y):
        return 1.0 + x - 2.0 * y + 3.0 * x * y

    def grad_f(x, y):
        return 1.0 + 3.0 * y, -2.0 + 3.0 * x

    rectangle = single_face(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]))
    assert max(errors_of(rectangle, 3, f, grad_f)) < 1e-13
    # On a general quadrangle the isoparametric patch is not bilinear in (x, y).
    value, gradient = errors_of(single_face(QUAD), 3, f, grad_f)
    assert value > 1e-3 and gradient > 1e-3


def test_constant_offset_gives_c_times_sqrt_area(rng):
    # f linear is reproduced exactly, so the surface through f + c differs from f by c.
    def f(x, y):
        return 0.3 + x - 0.5 * y

    def grad_f(x, y):
        return np.ones_like(x), np.full_like(y, -0.5)

    xy = random_disc(rng, 120)
    c = -0.37
    for tm, qm in (("s1", None), ("s3", "s4")):
        mesh = build_mesh(xy, tm, qm)
        area = face_quadrature(mesh, 1).weights.sum()
        z = f(mesh.vertices[:, 0], mesh.vertices[:, 1]) + c
        value, gradient = errors_of(mesh, 2, f, grad_f, z=z)
        assert_allclose(value, abs(c) * math.sqrt(area), rtol=1e-12)
        assert gradient < 1e-11


def test_x_squared_on_the_unit_triangle_and_square_closed_form():
    def f(x, y):
        return x * x

    def grad_f(x, y):
        return 2.0 * x, np.zeros_like(y)

    triangle = single_face(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
    # g = x;  int (x^2 - x)^2 (1 - x) dx = 1/60,  int (2x - 1)^2 (1 - x) dx = 1/6
    assert_allclose(errors_of(triangle, 3, f, grad_f), [math.sqrt(1 / 60), math.sqrt(1 / 6)], rtol=1e-13)
    square = single_face(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))
    # g = x;  int (x^2 - x)^2 dx = 1/30,  int (2x - 1)^2 dx = 1/3
    assert_allclose(errors_of(square, 3, f, grad_f), [math.sqrt(1 / 30), math.sqrt(1 / 3)], rtol=1e-13)


def test_doubling_the_order_changes_a_smooth_error_very_little(rng):
    def f(x, y):
        return np.exp(-4.0 * ((x - 0.2) ** 2 + y**2))

    def grad_f(x, y):
        e = f(x, y)
        return -8.0 * (x - 0.2) * e, -8.0 * y * e

    mesh = build_mesh(random_disc(rng, 200), "s3", "s4")
    low = np.array(errors_of(mesh, 6, f, grad_f))
    high = np.array(errors_of(mesh, 12, f, grad_f))
    # The value error converges fast; the gradient error on quadrangles has
    # 1 / det J in its integrand and converges more slowly.
    assert_allclose(low[0], high[0], rtol=1e-7)
    assert_allclose(low[1], high[1], rtol=5e-5)
    coarse = np.array(errors_of(mesh, 1, f, grad_f))
    assert np.max(np.abs(coarse - high) / high) > 1e-3  # the check has teeth


def test_l2_errors_checks_shapes(rng):
    mesh = build_mesh(random_disc(rng, 30), "s1", "s2")
    q = face_quadrature(mesh, 2)
    z = np.zeros(mesh.vertices.shape[0])
    good_f, good_g = np.zeros(q.weights.shape), np.zeros(q.weights.shape + (2,))
    with pytest.raises(InvalidInputError, match="z must"):
        l2_errors(mesh, z[:-1], good_f, good_g, q)
    with pytest.raises(InvalidInputError, match="f_values"):
        l2_errors(mesh, z, good_f[:, :1], good_g, q)
    with pytest.raises(InvalidInputError, match="f_gradients"):
        l2_errors(mesh, z, good_f, good_g[..., :1], q)
    other = face_quadrature(build_mesh(random_disc(rng, 50), "s1", None), 2)
    with pytest.raises(InvalidInputError, match="faces"):
        l2_errors(mesh, z, good_f, good_g, other)
    assert l2_errors(mesh, z, good_f, good_g, q) == (0.0, 0.0)
