"""meshcore.tiles.block_order: points near in the plane, near in the order."""

from __future__ import annotations

import numpy as np
import pytest

from meshcore import InvalidInputError
from meshcore.tiles import block_order


def test_a_stable_permutation_cell_by_cell_in_blocks():
    rng = np.random.default_rng(7)
    xy = np.round(rng.random((20000, 2)) * 300.0, 1) + [6.0e5, 6.8e6]
    xy[:500] = xy[500:1000]  # exact duplicates keep their order
    box = (6.0e5, 6.8e6, 6.0e5 + 300.0, 6.8e6 + 300.0)
    order = block_order(xy, 2.0, box)
    assert np.array_equal(np.sort(order), np.arange(xy.shape[0]))
    i = np.floor((xy[:, 0] - xy[:, 0].min()) / 2.0).astype(int)  # cells from the box cut to the points
    j = np.floor((xy[:, 1] - xy[:, 1].min()) / 2.0).astype(int)
    key = ((j // 8) * 1000 + i // 8) * 64 + (j % 8) * 8 + i % 8
    assert np.all(np.diff(key[order]) >= 0)  # cell by cell, blocks of 8 x 8 row by row
    same = np.diff(key[order]) == 0
    assert np.all(np.diff(order)[same] > 0)  # the given order within a cell


def test_far_points_and_open_boxes_stay_small():
    rng = np.random.default_rng(8)
    xy = rng.random((1000, 2)) * 100.0
    far = np.array([[-1.0e7, 5.0], [1.0e7, 5.0], [50.0, 1.0e9]])
    pts = np.concatenate([xy, far])
    # a box open on three sides, and points far outside it: no grid of the far points' span
    order = block_order(pts, 0.01, (0.0, -np.inf, np.inf, np.inf))
    assert np.array_equal(np.sort(order), np.arange(pts.shape[0]))
    assert block_order(np.empty((0, 2)), 1.0, (0.0, 0.0, 1.0, 1.0)).shape == (0,)
    with pytest.raises(InvalidInputError):
        block_order(xy, 0.0, (0.0, 0.0, 1.0, 1.0))
    with pytest.raises(InvalidInputError):
        block_order(xy, 1.0, (1.0, 0.0, 0.0, 1.0))
