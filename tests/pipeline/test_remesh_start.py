"""A tile meshed again, because a tile near it flipped later than it assumed,
starts from the boxes it held the first time: it holds at least what it held
then from its first build, and the result is still the untiled one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import pipeline.runs.runner as runner
from pipeline import RunConfig, run

from .ground_surveys import ORIGIN, record_tiles, same_mesh, write_ground


def _survey(path, rng):
    """Scan lines 1.5 m apart, slanted, over 240 x 240 m, with a round void of 20 m (flips in many rounds)."""
    n = 60_000
    line = rng.integers(0, 160, n)
    x = 651_000.0 + rng.random(n) * 240.0
    y = 6_861_000.0 + line * 1.5 + 0.03 * (x - 651_000.0) + rng.normal(0.0, 0.05, n)
    keep = np.hypot(x - 651_130.0, y - 6_861_110.0) > 20.0
    x, y = np.round(x[keep], 2), np.round(y[keep], 2)
    return write_ground(path, x, y, 50.0 + 0.02 * (y - ORIGIN[1]) + 0.2 * np.sin(x / 15.0))


def test_a_tile_meshed_again_starts_from_what_it_held(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    # every tile assumes one round: many mesh again
    meshed = record_tiles(monkeypatch, lambda job: replace(job, assume_rounds=1)
                          if job.assume_rounds == runner.TileJob.assume_rounds else job)
    common = dict(inputs=(str(path),), resolution=1.0, workers=1)
    report = run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=60.0, buffer=3.0, **common), progress=False)
    first = {(job.row, job.col): s for job, s in meshed if job.held_before is None}
    again: dict = {}
    for job, s in meshed:
        if job.held_before is not None:
            again.setdefault((job.row, job.col), []).append((job, s))
    assert report.tiles_meshed_again > 0 and again
    for key, attempts in again.items():
        before = first[key]
        for job, summary in attempts:
            assert job.held_before.boxes == before.held and job.held_before.grown == before.grown
            before_box, box = before.held[0], summary.held[0]
            assert box[0] <= before_box[0] and box[1] <= before_box[1]
            assert box[2] >= before_box[2] and box[3] >= before_box[3]
            assert summary.grown >= before.grown
            before = summary
    run(RunConfig(output=str(tmp_path / "whole.zarr"), tile_size=4096.0, **common), progress=False)
    assert same_mesh(tmp_path / "tiled.zarr", tmp_path / "whole.zarr")
