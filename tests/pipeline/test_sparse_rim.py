"""Where a tile's points along a side of its buffer are sparse (the ground
beside trees and buildings), the flips' doubt from the rim would cross the
buffer into its window: the tile holds a box beyond that side from its first
build.  Where they are as dense as the survey's mean, it holds nothing more."""

from __future__ import annotations

import numpy as np

from pipeline.meshing.tiles import TileJob, _sparse_rim, held_box
from pipeline.tiling.grid import TileGrid

GRID = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=100, nx=300, ny=300)
BUFFER = 4.0  # 12 spacings of a survey of 9 points a square metre


def _points(rng, box, density):
    n = int(density * (box[2] - box[0]) * (box[3] - box[1]))
    return np.column_stack([rng.uniform(box[0], box[2], n), rng.uniform(box[1], box[3], n), np.zeros(n)])


def test_a_sparse_side_is_held_beyond_the_buffer_and_a_dense_one_is_not(rng):
    job = TileJob(1, 1, None, GRID, BUFFER, (0.0, 0.0, 300.0, 300.0), None)
    box = held_box(GRID, 1, 1, BUFFER)  # 96-204 each way
    dense = _points(rng, box, 9.0)
    assert _sparse_rim(job, dense, box) == []
    # the ground beside a building along the west side: a point every 2 m (a quarter of a square metre's worth)
    west = (box[0], 150.0, box[0] + 2 * BUFFER, 170.0)
    keep = ~((dense[:, 0] < west[2]) & (dense[:, 1] > west[1]) & (dense[:, 1] < west[3]))
    sparse = np.concatenate([dense[keep], _points(rng, west, 0.25)])
    boxes = _sparse_rim(job, sparse, box)
    assert boxes, "the sparse stretch is held beyond the rim"
    for b in boxes:
        assert b[2] == box[0] and b[0] < box[0]  # beyond the west side only
        assert b[0] >= box[0] - 3 * BUFFER  # at most four buffers from the window
        assert b[1] >= 146.0 and b[3] <= 174.0  # along the sparse stretch (cells of a buffer)


def test_the_survey_edge_is_not_searched_beyond(rng):
    job = TileJob(0, 0, None, GRID, BUFFER, (0.0, 0.0, 300.0, 300.0), None)
    box = held_box(GRID, 0, 0, BUFFER)
    sparse = _points(rng, (0.0, 0.0, box[2], box[3]), 0.25)  # sparse everywhere, on the survey's corner
    for b in _sparse_rim(job, sparse, box):
        assert b[0] >= box[2] or b[1] >= box[3]  # only beyond the inner (east and north) sides
