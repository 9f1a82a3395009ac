"""Natural-neighbour (Sibson) coordinates: the smooth surface's fill of voids (meshcore.natural)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from meshcore.natural import join_places, natural_coordinates, natural_values, take_places

from .mesh_checks import python_and_compiled

OFFSET = np.array([6.0e5, 6.8e6])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)


def _coordinates(points, places, cap=1e9):
    places = np.atleast_2d(places)
    return natural_coordinates(points, places, np.full(places.shape[0], 1.0), np.full(places.shape[0], cap))


def _rows(nat):
    return [(nat.index[a:b], nat.weight[a:b]) for a, b in zip(nat.first[:-1], nat.first[1:])]


def test_a_place_at_the_centre_of_a_regular_polygon_takes_equal_shares():
    for n in (4, 6, 9):
        angles = 2.0 * np.pi * np.arange(n) / n + 0.1
        ring = np.column_stack([np.cos(angles), np.sin(angles)]) * 3.0 + OFFSET
        (index, weight), = _rows(_coordinates(ring, OFFSET))
        assert sorted(index.tolist()) == list(range(n))
        assert_allclose(weight, 1.0 / n, rtol=1e-6)  # the rim's triangles are flat: their centres round


def test_sibson_coordinates_are_the_shares_of_the_voronoi_cell_the_place_would_take(rng):
    """Against scipy's Voronoi diagrams of the points without and with the place:
    each neighbour's weight is the area its cell loses to the place's, over the place's cell."""
    from scipy.spatial import ConvexHull, Voronoi

    xy = rng.random((400, 2)) * 100.0
    places = rng.random((30, 2)) * 50.0 + 25.0

    def areas(points):
        vor = Voronoi(points)
        out = np.full(points.shape[0], np.nan)
        for i, region in enumerate(vor.point_region):
            cell = vor.regions[region]
            if cell and -1 not in cell:
                out[i] = ConvexHull(vor.vertices[cell]).volume
        return out

    before = areas(xy)
    nat = _coordinates(xy + OFFSET, places + OFFSET)
    for q, (index, weight) in zip(places, _rows(nat)):
        after = areas(np.vstack([xy, q]))
        stolen = before - after[:-1]
        want = {i: a for i, a in enumerate(stolen) if a > 1e-9 * after[-1]}
        assert set(index.tolist()) <= set(want) | {i for i, a in enumerate(stolen) if abs(a) <= 1e-9 * after[-1]}
        for i, w in zip(index.tolist(), weight.tolist()):
            assert w == pytest.approx(want.get(i, 0.0) / after[-1], rel=1e-6, abs=1e-9)
        assert sum(want.values()) == pytest.approx(after[-1], rel=1e-9)


def test_the_interpolant_reproduces_planes_and_stays_within_its_neighbours(rng):
    xy = rng.random((600, 2)) * 100.0 + OFFSET
    xy = xy[np.hypot(*(xy - OFFSET - 50.0).T) > 20.0]  # a void
    places = rng.random((200, 2)) * 50.0 + 25.0 + OFFSET
    nat = _coordinates(xy, places)
    assert np.all(np.diff(nat.first) > 0) and np.all(nat.weight > 0.0)
    local = xy - OFFSET
    plane = 3.0 - 0.2 * local[:, 0] + 0.05 * local[:, 1]
    q = places - OFFSET
    assert_allclose(natural_values(nat, plane), 3.0 - 0.2 * q[:, 0] + 0.05 * q[:, 1], atol=1e-9)
    z = np.sin(local[:, 0] / 9.0) + np.cos(local[:, 1] / 13.0)
    values = natural_values(nat, z)
    for (index, _), v in zip(_rows(nat), values):
        assert z[index].min() - 1e-12 <= v <= z[index].max() + 1e-12


def test_coordinates_depend_on_the_points_in_their_disks_alone_and_not_on_their_order(rng):
    """Any set of points that holds every point inside the disks returned gives
    the same coordinates, bit for bit, in any order: a piece of a survey gets the survey's."""
    xy = np.round(rng.random((3000, 2)) * 200.0, 2) + OFFSET
    xy = xy[np.hypot(*(xy - OFFSET - [100.0, 100.0]).T) > 30.0]  # a void
    places = np.round(rng.random((300, 2)) * 100.0, 3) + 50.0 + OFFSET
    cap = np.full(places.shape[0], 60.0)
    whole = natural_coordinates(xy, places, np.full(places.shape[0], 2.0), cap)
    # every point in a disk, and some others
    inside = np.zeros(xy.shape[0], dtype=bool)
    for cx, cy, r in whole.disks:
        inside |= np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) <= r
    inside |= rng.random(xy.shape[0]) < 0.1
    assert 0 < inside.sum() < xy.shape[0]
    piece = np.flatnonzero(inside)
    order = rng.permutation(piece.size)
    part = natural_coordinates(xy[piece[order]], places, np.full(places.shape[0], 5.0), cap)
    assert_array_equal(part.first, whole.first)
    assert_array_equal(piece[order][part.index], whole.index)
    assert_array_equal(part.weight, whole.weight)
    assert_array_equal(part.disks, whole.disks)
    assert_array_equal(part.owner, whole.owner)


def test_beside_the_hull_a_place_reads_its_circles_and_on_a_hull_edge_none():
    """A place near an edge of the hull has coordinates, close to the edge's linear
    interpolation, and reads its circles one by one (most of them lies beyond the
    hull); a place on the edge's line has none."""
    grid = np.array([[x, y] for x in range(0, 11) for y in range(0, 11)], dtype=float) * 10.0 + OFFSET
    places = np.array([[55.0, 1e-3], [55.0, 0.0], [53.0, 46.0]]) + OFFSET
    nat = natural_coordinates(grid, places, np.full(3, 20.0), np.full(3, 40.0))
    counts = np.diff(nat.first)
    assert counts[0] > 0 and counts[1] == 0 and counts[2] > 0
    z = (grid[:, 0] - OFFSET[0]) * 0.1
    assert natural_values(nat, z)[0] == pytest.approx(5.5, abs=1e-6)
    near_hull = nat.disks[nat.owner == 0]
    assert near_hull.shape[0] > 1 and near_hull[:, 2].max() > 1e3  # the circles, one huge
    around = nat.disks[nat.owner == 2]
    assert around.shape[0] == 1 and around[0, 2] < 40.0  # one disk around a place in the open


def test_places_can_be_taken_apart_and_joined_again(rng):
    xy = rng.random((300, 2)) * 50.0 + OFFSET
    places = rng.random((40, 2)) * 30.0 + 10.0 + OFFSET
    nat = _coordinates(xy, places)
    odd, even = np.arange(1, 40, 2), np.arange(0, 40, 2)
    both = join_places(take_places(nat, even), take_places(nat, odd))
    back = take_places(both, np.argsort(np.concatenate([even, odd])))
    for a, b in zip(back, nat):
        assert_array_equal(a, b)


def test_python_form_of_the_natural_kernels_agrees():
    """The kernels run with NUMBA_DISABLE_JIT=1 give the same numbers."""
    script = (
        "import json, numpy as np\n"
        "from meshcore.natural import natural_coordinates\n"
        "rng = np.random.default_rng(5)\n"
        "xy = rng.random((150, 2)) * 50.0 + [6.0e5, 6.8e6]\n"
        "xy = xy[np.hypot(xy[:, 0] - 6.0e5 - 25.0, xy[:, 1] - 6.8e6 - 25.0) > 10.0]\n"
        "q = rng.random((40, 2)) * 50.0 + [6.0e5, 6.8e6]\n"
        "nat = natural_coordinates(xy, q, np.full(40, 3.0), np.full(40, 20.0))\n"
        "print(json.dumps([a.tolist() for a in nat]))\n"
    )
    runs = python_and_compiled(script)
    for a, b in zip(*runs):
        assert_array_equal(a, b)
    assert runs[1][0][-1] > 40
