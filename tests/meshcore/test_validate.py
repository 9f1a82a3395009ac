import numpy as np
import pytest

import meshcore
from meshcore import InvalidMeshError, Mesh, build_mesh, validate

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def mesh_of(vertices, faces, input_to_vertex=None):
    vertices = np.asarray(vertices, dtype=float)
    if input_to_vertex is None:
        input_to_vertex = np.arange(len(vertices))
    return Mesh(vertices, np.asarray(faces, dtype=np.int64), np.asarray(input_to_vertex, dtype=np.int64))


def test_valid_meshes_pass(rng):
    validate(mesh_of(SQUARE, [[0, 1, 2, 3]]))
    validate(mesh_of(SQUARE, [[0, 1, 2, -1], [0, 2, 3, -1]]))
    validate(build_mesh(rng.random((300, 2)), "s3", "s4"))


@pytest.mark.parametrize(
    "vertices, faces, match",
    [
        (SQUARE, [[0, 2, 1, -1], [0, 2, 3, -1]], "not strictly convex and counter-clockwise"),
        (SQUARE, [[0, 1, 2, -1]], "vertex 3 is not used"),
        (np.vstack([SQUARE, [[0.5, 0.5]]]), [[0, 1, 2, -1], [0, 2, 3, -1]], "vertex 4 is not used"),
        (SQUARE, [[0, 1, 2, -1], [0, 1, 2, -1], [0, 2, 3, -1]], "same direction"),
        (SQUARE, [[0, 1, 1, -1]], "repeats a vertex"),
        (SQUARE, [[0, 1, 2, 7]], "out of range"),
        (SQUARE, [[0, 1, -1, -1]], "out of range"),
        (np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.2], [1.0, 2.0]]), [[0, 1, 2, 3]], "not strictly convex"),
        (np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [1.0, 1.0]]), [[0, 1, 2, 3]], "not strictly convex"),
    ],
)
def test_broken_meshes_are_named(vertices, faces, match):
    with pytest.raises(InvalidMeshError, match=match):
        validate(mesh_of(vertices, faces))


def test_hole_is_detected():
    # a ring of four quads around a missing centre square
    g = np.array([[x, y] for y in range(4) for x in range(4)], dtype=float)
    idx = lambda x, y: 4 * y + x  # noqa: E731
    faces = []
    for y in range(3):
        for x in range(3):
            if (x, y) != (1, 1):
                faces.append([idx(x, y), idx(x + 1, y), idx(x + 1, y + 1), idx(x, y + 1)])
    validate(mesh_of(g, faces + [[idx(1, 1), idx(2, 1), idx(2, 2), idx(1, 2)]]))
    with pytest.raises(InvalidMeshError, match="boundary is not the convex hull"):
        validate(mesh_of(g, faces))


def test_concave_boundary_is_detected():
    # an L-shaped mesh does not cover the convex hull of its vertices
    v = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2], [0, 1], [1, 0]], dtype=float)
    faces = [[0, 7, 3, 6], [7, 1, 2, 3], [6, 3, 4, 5]]
    with pytest.raises(InvalidMeshError, match="convex hull"):
        validate(mesh_of(v, faces))


def test_bad_input_map_is_detected():
    with pytest.raises(InvalidMeshError, match="input_to_vertex"):
        validate(mesh_of(SQUARE, [[0, 1, 2, 3]], input_to_vertex=[0, 1, 2, 9]))
    with pytest.raises(InvalidMeshError, match="not the image"):
        validate(mesh_of(SQUARE, [[0, 1, 2, 3]], input_to_vertex=[0, 1, 2, 2]))


def test_no_faces_is_valid_only_for_collinear_vertices():
    validate(mesh_of([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]], np.empty((0, 4))))
    with pytest.raises(InvalidMeshError, match="not collinear"):
        validate(mesh_of(SQUARE, np.empty((0, 4))))


def test_int32_faces_of_a_large_mesh_validate(rng):
    # edge keys (a * n + b) wrap around in 32 bits: with 300k vertices many collide
    mesh = build_mesh(rng.random((300_000, 2)), "s3", "s4")
    narrow = Mesh(mesh.vertices, mesh.faces.astype(np.int32), mesh.input_to_vertex)
    validate(narrow)


def test_collinear_points_whose_float_area_is_not_zero_are_collinear():
    # exactly collinear (orient2d is 0 for every triple) although the float
    # shoelace area of their hull is not: found by the adversarial test
    xy = np.array([
        [0.04674148043662851, 1.093482960873257], [0.08053119038818957, 1.1610623807763791],
        [0.10412289585691503, 1.20824579171383], [0.22833551552463582, 1.4566710310492716],
        [0.29013934364158933, 1.5802786872831787], [0.2972145121285025, 1.594429024257005],
        [0.41233497710091194, 1.8246699542018239], [0.6280502591366341, 2.2561005182732683],
        [0.7149367656275474, 2.4298735312550948], [0.9600955699629214, 2.920191139925843],
    ])
    mesh = build_mesh(xy, "s3", None)
    assert mesh.faces.shape[0] == 0
    validate(mesh)
    with pytest.raises(InvalidMeshError, match="not collinear"):
        validate(Mesh(np.vstack([xy, [[0.5, 0.0]]]), np.empty((0, 4), dtype=np.int64), np.arange(len(xy) + 1)))


def test_convex_hull_matches_qhull_and_keeps_points_on_hull_edges():
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(5)
    xy = rng.normal(size=(5000, 2)) + 6.5e5  # survey-sized coordinates
    hull = meshcore.convex_hull(xy[:, 0], xy[:, 1])
    assert sorted(hull.tolist()) == sorted(ConvexHull(xy).vertices.tolist())
    u = xy[np.roll(hull, -1)] - xy[hull]
    v = xy[np.roll(hull, -2)] - xy[np.roll(hull, -1)]
    ccw = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    assert (ccw > 0).all()  # counter-clockwise, strictly convex at the qhull vertices
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0], [1.0, 0.0], [1.0, 1.0]])
    assert sorted(meshcore.convex_hull(square[:, 0], square[:, 1]).tolist()) == [0, 1, 2, 3, 4]


def test_convex_hull_lists_each_point_once():
    # a repeated corner: both indices, once each, side by side
    assert meshcore.convex_hull([0.0, 1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0, 0.0]).tolist() == [0, 4, 1, 2, 3]
    # a collinear set is its segment, from one end to the other
    assert meshcore.convex_hull([0.0, 1.0, 2.0, 3.0], [0.0, 1.0, 2.0, 3.0]).tolist() == [0, 1, 2, 3]
    rng = np.random.default_rng(3)  # many repeats, past the filter's threshold
    xy = np.repeat(rng.integers(0, 5, size=(40, 2)).astype(float), 3, axis=0)
    hull = meshcore.convex_hull(xy[:, 0], xy[:, 1])
    assert len(set(hull.tolist())) == len(hull)


@pytest.mark.parametrize("n", [6, 50, 1000])
def test_convex_hull_with_repeated_points_is_the_hull_of_the_distinct_ones(n):
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(n)
    xy = np.round(rng.uniform(0.0, 100.0, size=(n, 2)), 2) + 6.5e5
    xy = np.vstack([xy, xy[rng.integers(0, n, n // 2 + 1)]])  # repeats, interior ones too
    hull = meshcore.convex_hull(xy[:, 0], xy[:, 1])
    corners = {tuple(p) for p in xy[ConvexHull(xy).vertices]}
    assert {tuple(p) for p in xy[hull]} == corners  # no interior point
    # every point at a hull corner is listed, and the walk stays counter-clockwise
    assert len(hull) == sum(tuple(p) in corners for p in xy)
    distinct = xy[hull][np.r_[True, (np.diff(xy[hull], axis=0) != 0).any(axis=1)]]
    u = np.roll(distinct, -1, axis=0) - distinct
    assert (u[:, 0] * np.roll(u[:, 1], -1) - u[:, 1] * np.roll(u[:, 0], -1) > 0).all()


@pytest.mark.parametrize("x, y, message", [([0.0, np.nan, 1.0], [0.0, 1.0, 1.0], "finite"), ([0.0, 1.0], [0.0], "one length")])
def test_convex_hull_rejects_bad_coordinates(x, y, message):
    with pytest.raises(meshcore.InvalidInputError, match=message):
        meshcore.convex_hull(x, y)


def test_convex_hull_of_a_grid_is_its_boundary_and_of_a_square_cloud_matches_qhull():
    from scipy.spatial import ConvexHull

    gx, gy = np.meshgrid(np.arange(100.0), np.arange(80.0))
    x, y = gx.ravel() + 4.1e5, gy.ravel() + 5.2e6
    on_edge = (gx.ravel() == 0) | (gx.ravel() == 99) | (gy.ravel() == 0) | (gy.ravel() == 79)
    assert sorted(meshcore.convex_hull(x, y).tolist()) == np.flatnonzero(on_edge).tolist()
    xy = np.random.default_rng(8).uniform(0.0, 500.0, size=(50_000, 2)) + 6.5e5
    hull = meshcore.convex_hull(xy[:, 0], xy[:, 1])
    assert sorted(hull.tolist()) == sorted(ConvexHull(xy).vertices.tolist())
