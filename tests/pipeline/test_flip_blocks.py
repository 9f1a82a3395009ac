"""A tile meshes again only when a tile near it flipped later than it assumed
*inside the boxes it held*: each tile tells its last flip round per block of
its window, not for the whole window."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import meshcore
from pipeline.meshing.tiles import HeldBefore, TileJob, TileSummary
from pipeline.runs.runner import _rounds_unchecked
from pipeline.tiling.grid import TileGrid

EVERYWHERE = (-math.inf, -math.inf, math.inf, math.inf)


def _survey(rng, n: int = 6000) -> np.ndarray:
    """Slanted scan lines with a void, rounded to the centimetre at survey offsets (flips in many rounds)."""
    line = rng.integers(0, 60, n)
    x = rng.random(n) * 160.0
    y = line * 2.0 + 0.03 * x + rng.normal(0.0, 0.05, n)
    keep = np.hypot(x - 70.0, y - 60.0) > 18.0
    return np.unique(np.round(np.c_[x[keep], y[keep]] + [651_000.0, 6_861_000.0], 2), axis=0)


def _summary(certificate: meshcore.WindowCertificate, **fields) -> TileSummary:
    return TileSummary(
        row=0, col=0, points_owned=0, vertices_owned=0, duplicates=0, faces=0, quads=0, expansions=0, certified=True,
        seconds=0.0, last_flip_round=certificate.last_flip_round,
        flip_blocks=tuple(tuple(int(v) for v in row) for row in certificate.flip_blocks),
        flip_blocks_box=tuple(float(v) for v in certificate.flip_blocks_box), **fields,
    )


def test_the_blocks_hold_every_flip_round_of_any_part_of_the_window(rng):
    xy = _survey(rng)
    window = (651_020.0, 6_861_010.0, 651_140.0, 6_861_110.0)
    whole = meshcore.build_mesh(xy, "s1", "s2", window=window, known=EVERYWHERE).certificate
    blocks = np.asarray(whole.flip_blocks)
    assert blocks.shape == (16, 16) and blocks.max() == whole.last_flip_round > 0
    assert blocks.min() < whole.last_flip_round  # the late rounds flip in a few places only
    summary = _summary(whole)
    assert summary.last_flip_round_in([window]) == whole.last_flip_round
    # each block: at least the last round of the flips that the window of that block alone sees
    x0, y0, x1, y1 = whole.flip_blocks_box
    xs, ys = np.linspace(x0, x1, 17), np.linspace(y0, y1, 17)
    for j in range(0, 16, 3):
        for i in range(16):
            block = (xs[i], ys[j], xs[i + 1], ys[j + 1])
            seen = meshcore.build_mesh(xy, "s1", "s2", window=block, known=EVERYWHERE).certificate.last_flip_round
            assert blocks[j, i] >= seen, (j, i)
    # the same flips seen by the window of a part: the survey's flips there, in rounds the blocks hold
    for _ in range(40):
        w, h = rng.uniform(3.0, 60.0, 2)
        x0, y0 = rng.uniform(window[0], window[2] - w), rng.uniform(window[1], window[3] - h)
        part = (x0, y0, x0 + w, y0 + h)
        seen = meshcore.build_mesh(xy, "s1", "s2", window=part, known=EVERYWHERE).certificate.last_flip_round
        assert summary.last_flip_round_in([part]) >= seen


def test_an_outer_window_has_blocks_over_its_points(rng):
    xy = _survey(rng)
    certificate = meshcore.build_mesh(xy, "s1", "s2", window=(-math.inf, -math.inf, 651_080.0, math.inf),
                                      known=EVERYWHERE).certificate
    x0, y0, x1, y1 = certificate.flip_blocks_box
    assert (x0, y0, x1, y1) == pytest.approx((*xy.min(axis=0), 651_080.0, xy[:, 1].max()), abs=1e-6)
    # beyond the box, the edge blocks answer
    summary = _summary(certificate)
    assert summary.last_flip_round_in([(0.0, 0.0, 1.0, 1.0)]) == int(np.asarray(certificate.flip_blocks)[0, 0])


@pytest.mark.parametrize("box", [(100.0, 0.0, 200.0, 100.0), (100.0, 0.0, 100.0, 100.0), (100.0, 50.0, 200.0, 50.0)])
def test_a_flip_marked_in_a_block_is_found_by_a_box_at_its_place(box):
    """The flip kernel's block of a coordinate and the summary's block geometry agree, blocks of no
    width (a window that only touches the points) too."""
    from meshcore.flip import _block_of

    block_of = _block_of.py_func  # the kernel's helper, as Python
    x0, y0, x1, y1 = box
    for x, y in [(100.0, 0.0), (150.3, 49.9), (199.99, 100.0), (250.0, 120.0), (60.0, -5.0), (100.0, 50.0)]:
        blocks = np.zeros((16, 16), dtype=int)
        blocks[block_of(y, y0, (y1 - y0) / 16, 16), block_of(x, x0, (x1 - x0) / 16, 16)] = 9
        summary = TileSummary(row=0, col=0, points_owned=0, vertices_owned=0, duplicates=0, faces=0, quads=0,
                              expansions=0, certified=True, seconds=0.0, last_flip_round=9,
                              flip_blocks=tuple(map(tuple, blocks.tolist())), flip_blocks_box=box)
        assert summary.last_flip_round_in([(x, y, x, y)]) == 9, (x, y)


def test_a_late_flip_far_from_a_neighbours_held_box_leaves_it_as_it_is():
    grid = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=100, nx=300, ny=100)
    blocks = np.full((16, 16), 5, dtype=int)
    blocks[8, 8] = 11  # a late round in the middle of tile (0, 1): x 150-156, y 50-56
    late = dict(last_flip_round=11, flip_blocks=tuple(map(tuple, blocks.tolist())), flip_blocks_box=(100.0, 0.0, 200.0, 100.0))
    base = dict(points_owned=1, vertices_owned=1, duplicates=0, faces=1, quads=0, expansions=0, certified=True,
                seconds=0.0, last_flip_round=5, assumed_rounds=8)
    summaries = {
        (0, 0): TileSummary(row=0, col=0, held=((-10.0, -10.0, 110.0, 110.0),), **base),
        (0, 1): TileSummary(row=0, col=1, held=((90.0, -10.0, 210.0, 110.0),), **{**base, **late}),
        (0, 2): TileSummary(row=0, col=2, held=((140.0, -10.0, 310.0, 110.0),), **base),  # grown into the late block
    }
    jobs = [TileJob(0, c, None, grid, 10.0, (0.0, 0.0, 300.0, 100.0), None) for c in range(3)]
    again = {(job.row, job.col): job for job in _rounds_unchecked(grid, jobs, summaries)}
    assert {key: job.assume_rounds for key, job in again.items()} == {(0, 1): 11, (0, 2): 11}
    # each starts from the boxes it held the first time
    assert again[(0, 2)].held_before == HeldBefore(((140.0, -10.0, 310.0, 110.0),), 0.0)
    # a record of an older version, without blocks: its whole window counts, as before
    summaries[(0, 1)] = replace(summaries[(0, 1)], flip_blocks=())
    again = {(job.row, job.col): job.assume_rounds for job in _rounds_unchecked(grid, jobs, summaries)}
    assert again == {(0, 0): 11, (0, 1): 11, (0, 2): 11}
