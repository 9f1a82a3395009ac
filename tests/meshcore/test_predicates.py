from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from meshcore import incircle, orient2d


def exact_orient(a, b, c):
    ax, ay, bx, by, cx, cy = map(Fraction, (*a, *b, *c))
    d = (ax - cx) * (by - cy) - (ay - cy) * (bx - cx)
    return (d > 0) - (d < 0)


def exact_incircle(a, b, c, d):
    rows = []
    for p in (a, b, c):
        x = Fraction(p[0]) - Fraction(d[0])
        y = Fraction(p[1]) - Fraction(d[1])
        rows.append((x, y, x * x + y * y))
    (a1, a2, a3), (b1, b2, b3), (c1, c2, c3) = rows
    det = a1 * (b2 * c3 - b3 * c2) - a2 * (b1 * c3 - b3 * c1) + a3 * (b1 * c2 - b2 * c1)
    return (det > 0) - (det < 0)


def test_sign_conventions():
    assert orient2d(0.0, 0.0, 1.0, 0.0, 0.0, 1.0) == 1
    assert orient2d(0.0, 0.0, 0.0, 1.0, 1.0, 0.0) == -1
    assert orient2d(0.0, 0.0, 1.0, 1.0, 3.0, 3.0) == 0
    assert incircle(0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.2, 0.2) == 1
    assert incircle(0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 2.0, 2.0) == -1
    assert incircle(0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0) == 0
    # clockwise triangle reverses the in-circle sign
    assert incircle(0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.2, 0.2) == -1


def test_nearly_collinear_points_at_survey_scale():
    # the float determinant of these is dominated by rounding; the exact sign is known
    base = 6.0e5
    a = (base + 0.5, base + 0.5)
    b = (base + 12.0, base + 12.0)
    for k in range(-3, 4):
        c = (base + 24.0, np.nextafter(base + 24.0, np.inf if k > 0 else -np.inf) if k else base + 24.0)
        assert orient2d(*a, *b, *c) == exact_orient(a, b, c)


# exactness holds while no product of coordinate differences underflows
# (|difference| either 0 or above ~1e-150): keep generated values in that range
coords = st.floats(min_value=-1e3, max_value=1e3).filter(lambda v: v == 0.0 or abs(v) > 1e-100)
tiny = st.sampled_from([0.0, 1e-90, 5e-17, 1e-12, -1e-12, -5e-17])


@settings(max_examples=300, deadline=None)
@given(t=st.lists(coords, min_size=3, max_size=3), slope=coords, offset=coords, eps=tiny)
def test_orient2d_matches_rational_on_near_lines(t, slope, offset, eps):
    pts = [(ti, slope * ti + offset) for ti in t]
    pts[2] = (pts[2][0] + eps, pts[2][1])
    assert orient2d(*pts[0], *pts[1], *pts[2]) == exact_orient(*pts)


@settings(max_examples=300, deadline=None)
@given(
    angles=st.lists(st.floats(0, 2 * np.pi).filter(lambda v: v == 0.0 or v > 1e-100), min_size=4, max_size=4),
    radius=st.sampled_from([1e-3, 1.0, 7.5, 1e3]),
    centre=st.sampled_from([0.0, 0.1, 6.0e5, -3.3e6]),
)
def test_incircle_matches_rational_on_near_circles(angles, radius, centre):
    pts = [(centre + radius * np.cos(a), centre + radius * np.sin(a)) for a in angles]
    assert incircle(*pts[0], *pts[1], *pts[2], *pts[3]) == exact_incircle(*pts)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(-3, 3), st.integers(-3, 3)), min_size=4, max_size=4))
def test_grid_points_are_exact(points):
    pts = [(0.25 * x + 1e6, 0.25 * y + 5e6) for x, y in points]
    assert orient2d(*pts[0], *pts[1], *pts[2]) == exact_orient(*pts[:3])
    assert incircle(*pts[0], *pts[1], *pts[2], *pts[3]) == exact_incircle(*pts)


@pytest.mark.parametrize("shift", [0.0, 1024.0, 2.0**20])
def test_translation_by_exact_amounts_keeps_signs(rng, shift):
    p = rng.integers(-50, 50, size=(200, 4, 2)) / 8.0
    for q in p:
        a, b, c, d = q
        assert orient2d(*a, *b, *c) == orient2d(*(a + shift), *(b + shift), *(c + shift))
        assert incircle(*a, *b, *c, *d) == incircle(*(a + shift), *(b + shift), *(c + shift), *(d + shift))


def test_the_exact_path_runs_inside_kernels_without_reference_counting():
    """The exact stage allocates nothing (its scratch is on the stack), so a
    kernel compiled without reference counting can call it; its signs still
    match rational arithmetic where the filter cannot decide (cocircular and
    collinear lattice points far from the origin)."""
    from meshcore._jit import njit, njit_borrowing
    from meshcore.predicates import incircle_sos

    @njit_borrowing
    def signs(p, out):  # an allocating callee would not compile here
        for k in range(p.shape[0]):
            r = p[k]
            out[k, 0] = orient2d(r[0], r[1], r[2], r[3], r[4], r[5])
            out[k, 1] = incircle(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7])
            out[k, 2] = incircle_sos(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7])

    @njit
    def kernel(p, out):  # a helper without reference counting is called from kernels only
        signs(p, out)

    rng = np.random.default_rng(3)
    p = (rng.integers(-2, 3, (3000, 8)) * 0.25 + 6.5e5).astype(np.float64)
    out = np.zeros((3000, 3), dtype=np.int64)
    kernel(p, out)
    rows = p.reshape(-1, 4, 2).tolist()
    expected_orient = [exact_orient(*r[:3]) for r in rows]
    expected_incircle = [exact_incircle(*r) for r in rows]
    assert out[:, 0].tolist() == expected_orient
    assert out[:, 1].tolist() == expected_incircle
    assert sum(e == 0 for e in expected_incircle) > 500  # the exact stage had work to do
    decided = out[:, 1] != 0
    assert np.all(out[decided, 2] == out[decided, 1])


def exact_cross(a, b, c):
    ax, ay, bx, by, cx, cy = map(Fraction, (*a, *b, *c))
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.integers(1, 40000), st.integers(1, 40000),
    st.integers(-3, 3), st.sampled_from([0.01, 0.00025, 1e-7]),
)
def test_cross_rounded_is_within_its_bound_on_near_collinear_lattice_points(x0, y0, i, j, k, scale):
    from meshcore.predicates import cross_rounded

    # three points of a LAS lattice along a slanted line, the middle one
    # nudged by k steps: the float cross product keeps no correct digit
    a = (round(6e5 + x0, 2), round(5e6 + y0, 2))
    b = (a[0] + i * scale * 3, a[1] + i * scale * 7 + k * scale)
    c = (a[0] + (i + j) * scale * 3, a[1] + (i + j) * scale * 7)
    value, error = cross_rounded(*a, *b, *c)
    exact = exact_cross(a, b, c)
    assert abs(Fraction(value) - exact) <= Fraction(error)
    assert error <= 1e-14 * abs(value) or exact == 0
