"""Flips in rounds and the greedy elimination are rules of the geometry: a
window's piece is the whole mesh's, and its certificate says when a point set
holding only part of the survey is enough."""

from __future__ import annotations

import math

import numpy as np
import pytest

import meshcore

EVERYWHERE = (-math.inf, -math.inf, math.inf, math.inf)


def _faces(mesh: meshcore.Mesh) -> set:
    v = mesh.vertices
    return {tuple(sorted(tuple(v[i]) for i in row if i >= 0)) for row in mesh.faces.tolist()}


def _survey(rng, n: int = 3000) -> np.ndarray:
    """Scan lines (dense along, sparse across, slanted) with a void, rounded to the
    centimetre at survey offsets: slivers, ties and long faces."""
    line = rng.integers(0, 40, n)
    x = rng.random(n) * 120.0
    y = line * 2.0 + 0.03 * x + rng.normal(0.0, 0.05, n)
    keep = np.hypot(x - 60.0, y - 40.0) > 15.0
    return np.unique(np.round(np.c_[x[keep], y[keep]] + [651_000.0, 6_861_000.0], 2), axis=0)


@pytest.mark.parametrize("measures", [("s3", "s4"), ("s1", "s2"), ("s3", None), ("delaunay", "s4")])
def test_the_mesh_does_not_depend_on_the_order_of_the_points(rng, measures):
    xy = _survey(rng)
    one = meshcore.build_mesh(xy, *measures)
    other = meshcore.build_mesh(xy[rng.permutation(len(xy))], *measures)
    assert _faces(one) == _faces(other)


@pytest.mark.parametrize("measures", [("s3", "s4"), ("s1", "s2")])
def test_window_pieces_of_the_whole_point_set_partition_the_whole_mesh(rng, measures):
    xy = _survey(rng)
    whole = _faces(meshcore.build_mesh(xy, *measures))
    lo, hi = xy.min(axis=0), xy.max(axis=0) + 1e-6
    xs, ys = np.linspace(lo[0], hi[0], 4), np.linspace(lo[1], hi[1], 3)
    union: set = set()
    for i in range(3):
        for j in range(2):
            piece = meshcore.build_mesh(xy, *measures, window=(xs[i], ys[j], xs[i + 1], ys[j + 1]), known=EVERYWHERE)
            faces = _faces(piece)
            assert not faces & union  # no face owned twice
            union |= faces
            assert piece.certificate.certified
    assert union == whole


@pytest.mark.parametrize("measures", [("s3", "s4"), ("s1", "s2"), ("s3", None)])
def test_a_certified_piece_of_part_of_the_points_is_the_whole_meshs(rng, measures):
    xy = _survey(rng)
    whole = meshcore.build_mesh(xy, *measures)
    faces_whole = _faces(whole)
    # the survey's last flip round near any window: the most any piece of the whole set saw
    window = (651_030.0, 6_861_020.0, 651_070.0, 6_861_060.0)
    whole_rounds = meshcore.build_mesh(xy, *measures, window=window, known=EVERYWHERE).certificate.last_flip_round
    certified = 0
    for buffer in (2.0, 5.0, 10.0, 20.0, 40.0):
        box = (window[0] - buffer, window[1] - buffer, window[2] + buffer, window[3] + buffer)
        inside = (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[2]) & (xy[:, 1] >= box[1]) & (xy[:, 1] <= box[3])
        for rounds in range(whole_rounds, whole_rounds + 3):
            piece = meshcore.build_mesh(xy[inside], *measures, window=window, known=box, assume_rounds=rounds)
            if piece.certificate.certified:
                certified += 1
                assert _faces(piece) <= faces_whole
            else:  # what to hold more of
                assert piece.certificate.blocking.shape[0] > 0 or piece.certificate.open_edges
    assert certified > 0  # a wide enough buffer proves the piece
    strip = (xy[:, 0] >= 651_029.0) & (xy[:, 0] <= 651_071.0)
    tight = meshcore.build_mesh(xy[strip], *measures, window=window,
                                known=(651_029.0, -math.inf, 651_071.0, math.inf), assume_rounds=whole_rounds)
    assert tight.certificate.certified is False or _faces(tight) <= faces_whole


def _last_flip_round_block_by_block(blocks, box, boxes) -> int:
    """The rule of ``last_flip_round_in`` block by block: the largest block that a closed box meets, the
    outer blocks reaching to infinity, every edge given 1e-8 of the box's coordinates."""
    n_rows, n_cols = blocks.shape
    slack = 1e-8 * (abs(box[0]) + abs(box[1]) + 1.0)
    width, height = (box[2] - box[0]) / n_cols, (box[3] - box[1]) / n_rows
    last = 0
    for row in range(n_rows):
        low = -math.inf if row == 0 else box[1] + height * row
        high = math.inf if row == n_rows - 1 else box[1] + height * (row + 1)
        for col in range(n_cols):
            left = -math.inf if col == 0 else box[0] + width * col
            right = math.inf if col == n_cols - 1 else box[0] + width * (col + 1)
            if any(b[0] - slack <= right and left <= b[2] + slack and b[1] - slack <= high and low <= b[3] + slack
                   for b in boxes):
                last = max(last, int(blocks[row, col]))
    return last


def test_the_last_flip_round_of_many_boxes_is_the_largest_block_any_of_them_meets(rng):
    """Hundreds of boxes (a void's circles) at once, at survey offsets: boxes of no width on block
    edges, boxes beyond the blocks, unbounded and inverted ones."""
    box = (651_000.0, 6_861_000.0, 651_160.0, 6_861_100.0)
    edges_x = np.linspace(box[0], box[2], 17)
    edges_y = np.linspace(box[1], box[3], 17)
    for _ in range(60):
        blocks = rng.integers(0, 12, (16, 16)) * (rng.random((16, 16)) < 0.3)
        n = int(rng.integers(0, 300))
        lo = np.c_[rng.uniform(box[0] - 40, box[2] + 40, n), rng.uniform(box[1] - 40, box[3] + 40, n)]
        size = rng.exponential(8.0, (n, 2)) * (rng.random((n, 1)) < 0.8)
        boxes = np.c_[lo, lo + size]
        on_edge = rng.random(n) < 0.2  # a box of no width on a block's edge
        boxes[on_edge, 0] = boxes[on_edge, 2] = rng.choice(edges_x, int(on_edge.sum()))
        on_edge = rng.random(n) < 0.2
        boxes[on_edge, 1] = boxes[on_edge, 3] = rng.choice(edges_y, int(on_edge.sum()))
        boxes[rng.random(n) < 0.05, 0] = -math.inf
        boxes[rng.random(n) < 0.05, 3] = math.inf
        boxes[rng.random(n) < 0.05, 2] -= 30.0  # inverted
        boxes = [tuple(b) for b in boxes.tolist()]
        expected = _last_flip_round_block_by_block(blocks, box, boxes)
        assert meshcore.tiles.last_flip_round_in(blocks, box, boxes) == expected
        assert meshcore.tiles.last_flip_round_in(blocks, box, boxes[:1]) == _last_flip_round_block_by_block(blocks, box, boxes[:1])


@pytest.mark.parametrize("offset", [0.0, 6.8e6])
def test_lens_boxes_settle_disks_deep_inside_the_hull_as_the_edges_would(rng, offset):
    """The shortcut for disks inside the hull's inner box gives every bit the
    edge-by-edge computation gives, also for disks touching that box and on
    thin polygons, at survey-sized offsets; and the box lies inside the hull."""
    from meshcore.certificate import _lens_boxes, inner_box, lens_boxes

    no_box = np.array([math.inf, math.inf, -math.inf, -math.inf])
    settled = 0
    for trial in range(40):
        size = 10.0 ** rng.uniform(0, 4)
        points = rng.random((int(rng.integers(3, 300)), 2)) * size + offset
        if trial % 4 == 0:  # a thin strip
            points[:, 1] = offset + (points[:, 1] - offset) * 1e-3
        hull = points[meshcore.convex_hull(points[:, 0], points[:, 1])]
        if hull.shape[0] < 3:
            continue
        inner = inner_box(hull)
        circles = np.column_stack([offset + size * (1.4 * rng.random(500) - 0.2),
                                   offset + size * (1.4 * rng.random(500) - 0.2), size * 10.0 ** rng.uniform(-3, 0.3, 500)])
        if inner[0] < inner[2] and inner[1] < inner[3]:
            corners = np.array([[inner[0], inner[1]], [inner[2], inner[1]], [inner[2], inner[3]], [inner[0], inner[3]]])
            for k in range(hull.shape[0]):  # every corner of the box strictly inside every edge
                a, b = hull[k - 1], hull[k]
                assert all(meshcore.orient2d(a[0], a[1], b[0], b[1], x, y) > 0 for x, y in corners)
            # disks touching the inner box's west side from inside, and just past it
            r = rng.random(100) * (inner[2] - inner[0]) / 3
            circles[:100] = np.column_stack([inner[0] + r * (1.0 + rng.choice([0.0, 1e-12, -1e-12], 100)),
                                             np.clip(rng.uniform(inner[1], inner[3], 100), inner[1] + r, inner[3] - r), r])
        box = np.array([offset + 0.3 * size * rng.random(), offset + 0.3 * size * rng.random(),
                        offset + size * rng.uniform(0.6, 1.2), offset + size * rng.uniform(0.6, 1.2)])
        fast = lens_boxes(circles, hull, box)
        np.testing.assert_array_equal(fast, _lens_boxes(circles, hull, box, no_box))
        c = circles
        settled += int(np.count_nonzero((c[:, 0] - c[:, 2] > inner[0]) & (c[:, 0] + c[:, 2] < inner[2])
                                        & (c[:, 1] - c[:, 2] > inner[1]) & (c[:, 1] + c[:, 2] < inner[3])))
    assert settled > 1000  # the shortcut was taken
