import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from meshcore import InvalidInputError, quality_summary, s1, s2, s3, s4

EQUILATERAL = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, math.sqrt(3) / 2]])
SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_optimal_shapes_score_one():
    assert s1(EQUILATERAL) == pytest.approx(1.0, abs=1e-15)
    assert s3(EQUILATERAL) == pytest.approx(1.0, abs=1e-15)
    assert s2(SQUARE) == pytest.approx(1.0, abs=1e-15)
    assert s4(SQUARE) == pytest.approx(1.0, abs=1e-15)


def test_degenerate_shapes_score_zero():
    line = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    repeated = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]])
    assert s1(line) == 0.0 and s3(line) == 0.0
    assert s1(repeated) == 0.0 and s3(repeated) == 0.0
    flat_quad = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, 1.0]])
    reflex_quad = np.array([[0.0, 0.0], [2.0, 0.0], [0.5, 0.5], [0.0, 2.0]])
    bow_tie = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    for q in (flat_quad, reflex_quad, bow_tie):
        assert s2(q) == 0.0 and s4(q) == 0.0


def test_closed_forms():
    right_isoceles = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert s1(right_isoceles) == pytest.approx(2 / math.sqrt(3) * math.sin(math.pi / 4))
    # S3 = 4/sqrt(3) A / (l1 l2 l3)^(2/3), A = 1/2, l = 1, 1, sqrt(2)
    assert s3(right_isoceles) == pytest.approx(4 / math.sqrt(3) * 0.5 / (math.sqrt(2)) ** (2 / 3))
    # obtuse: 120 degrees -> S1 = 2/sqrt(3) * (1 + cos 120) (smaller than sin 30)
    obtuse = np.array([[0.0, 0.0], [1.0, 0.0], [-0.5, math.sqrt(3) / 2]])
    assert s1(obtuse) == pytest.approx(2 / math.sqrt(3) * 0.5)
    rect = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    assert s2(rect) == pytest.approx(1.0)
    # A = 2, R^2 = 5/4 for every triple: S4 = (2 / 2.5) ** (1/3)
    assert s4(rect) == pytest.approx(0.8 ** (1 / 3))


def test_s4_optimum_with_two_fixed_sides_is_not_the_rectangle():
    # the paper's remark: with sides (0,1)-(0,0)-(2,0) fixed, moving the fourth
    # vertex off the rectangle corner (2, 1) increases S4
    grid = np.linspace(0.5, 3.0, 251)
    gx, gy = np.meshgrid(grid, grid)
    quads = np.zeros(gx.shape + (4, 2))
    quads[..., 0, :] = (0.0, 0.0)
    quads[..., 1, :] = (2.0, 0.0)
    quads[..., 2, 0] = gx
    quads[..., 2, 1] = gy
    quads[..., 3, :] = (0.0, 1.0)
    values = s4(quads)
    best = np.unravel_index(np.argmax(values), values.shape)
    corner = s4(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]))
    assert values[best] > corner + 1e-3
    assert not np.allclose((gx[best], gy[best]), (2.0, 1.0), atol=0.02)


@settings(max_examples=200, deadline=None)
@given(
    pts=st.lists(st.floats(-10, 10), min_size=8, max_size=8),
    scale=st.floats(1e-3, 1e3),
    angle=st.floats(0, 2 * math.pi),
    shift=st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)),
)
def test_measures_are_invariant_to_similarity(pts, scale, angle, shift):
    p = np.array(pts).reshape(4, 2)
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    q = scale * p @ rot.T + np.array(shift)
    for f, k in ((s1, 3), (s3, 3), (s2, 4), (s4, 4)):
        a = float(f(p[:k]))
        b = float(f(q[:k]))
        assert 0.0 <= a <= 1.0
        # away from degeneracy (a vanishing edge or turn), where rounding of the
        # transform decides whether a quadrangle is still strictly convex
        corners = p[:k]
        edges = np.roll(corners, -1, axis=0) - corners
        nxt = np.roll(edges, -1, axis=0)
        turns = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
        size = np.abs(edges).max()
        # and its shortest edge must be long next to the rounding of the moved coordinates
        shortest = np.abs(edges).max(axis=1).min()
        well_posed = scale * shortest > 1e-6 * (np.abs(q).max() + 1e-300)
        if (
            well_posed
            and min(a, b) > 1e-3
            and np.abs(edges).max(axis=1).min() > 1e-6 * size
            and np.abs(turns).min() > 1e-6 * size**2
        ):
            # a measure near 0 amplifies the rounding of the moved coordinates
            # roughly as 1 / S, so the tolerance follows the conditioning
            assert b == pytest.approx(a, rel=1e-6 / min(a, b), abs=1e-9)


def test_vectorised_shapes_and_errors():
    batch = np.broadcast_to(EQUILATERAL, (5, 7, 3, 2))
    assert s1(batch).shape == (5, 7)
    with pytest.raises(InvalidInputError, match=r"\(\.\.\., 4, 2\)"):
        s2(EQUILATERAL)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 2\)"):
        s3(np.zeros((3, 3)))


def test_quality_summary_counts_and_ranges():
    vertices = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [2.0, 0.5]])
    faces = np.array([[0, 1, 2, 3], [1, 4, 2, -1]])
    summary = quality_summary(vertices, faces)
    assert (summary.n_triangles, summary.n_quads) == (1, 1)
    by_name = {m.measure: m for m in summary.measures}
    assert by_name["s2"].minimum == pytest.approx(1.0)
    assert by_name["s1"].count == 1 and sum(by_name["s1"].histogram) == 1
    assert "1 triangles, 1 quadrangles" in str(summary)


def test_s3_quick_estimate_says_below_only_when_the_kernel_agrees():
    from meshcore.quality import s3_cubed_below, s3_cubed_kernel

    rng = np.random.default_rng(11)
    said_below = 0
    for k in range(4000):
        scale = 10.0 ** rng.uniform(-3, 4)
        shift = rng.choice([0.0, 6.5e5, -4e6])
        tri = rng.random(6) * scale + shift
        if k % 4 == 0:  # slivers: the third corner near the line of the first two
            t = rng.random()
            tri[4] = tri[0] + t * (tri[2] - tri[0]) + scale * 1e-7 * rng.normal()
            tri[5] = tri[1] + t * (tri[3] - tri[1])
        exact = s3_cubed_kernel(*tri)
        # at the kernel's own value it is not below; just above it, it is
        # (when the limit is in range), and far above it always is
        assert not s3_cubed_below(*tri, exact)
        for limit in (exact * (1 + 1e-6), exact + 0.05, 0.5, 1.0):
            below = s3_cubed_below(*tri, limit)
            assert not below or exact < limit
            said_below += below and limit == exact * (1 + 1e-6)
    assert said_below > 1000  # the quick test settles the common case


@pytest.mark.parametrize("h", [1e-3, 1e-6, 1e-9, 1e-12])
def test_angles_near_180_degrees_keep_their_precision(h):
    # the apex angle is pi - 2 atan(2h): 1 + cos = 2 sin^2(atan 2h) = 8h^2 / (1 + 4h^2),
    # which 1 + cos(theta) computed directly loses to cancellation from about 179.99 deg
    exact = 2 / math.sqrt(3) * 8 * h * h / (1 + 4 * h * h)
    assert float(s1([[0.0, 0.0], [1.0, 0.0], [0.5, h]])) == pytest.approx(exact, rel=1e-9, abs=0.0)
    # a quadrangle with a near-straight corner at (1, h): pi - 2 atan(h), S2 = 1 + cos there
    quad = [[0.0, 0.0], [1.0, -1.0], [2.0, 0.0], [1.0, h]]
    assert float(s2(quad)) == pytest.approx(2 * h * h / (1 + h * h), rel=1e-9, abs=0.0)
