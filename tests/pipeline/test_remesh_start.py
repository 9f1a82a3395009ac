"""A tile meshed again, because a tile near it flipped later than it assumed,
starts from the boxes it held the first time: it holds at least what it held
then from its first build, and the result is still the untiled one."""

from __future__ import annotations

from dataclasses import replace

import laspy
import numpy as np
from pyproj import CRS

import pipeline.runs.runner as runner
from pipeline import RunConfig, run
from pipeline.store import zarr_store as store

from .store_checks import face_set


def _survey(path, rng):
    """Scan lines 1.5 m apart, slanted, over 240 x 240 m, with a round void of 20 m (flips in many rounds)."""
    n = 60_000
    line = rng.integers(0, 160, n)
    x = 651_000.0 + rng.random(n) * 240.0
    y = 6_861_000.0 + line * 1.5 + 0.03 * (x - 651_000.0) + rng.normal(0.0, 0.05, n)
    keep = np.hypot(x - 651_130.0, y - 6_861_110.0) > 20.0
    x, y = np.round(x[keep], 2), np.round(y[keep], 2)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([651_000.0, 6_861_000.0, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.round(50.0 + 0.02 * (y - 6_861_000.0) + 0.2 * np.sin(x / 15.0), 2)
    las.classification = np.full(x.size, 2, dtype=np.uint8)
    las.write(path)
    return path


def test_a_tile_meshed_again_starts_from_what_it_held(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    meshed = runner.mesh_tile
    first, again = {}, {}

    def mesh_tile(job):
        if job.assume_rounds == runner.TileJob.assume_rounds:  # every tile assumes one round: many mesh again
            job = replace(job, assume_rounds=1)
        summary = meshed(job)
        if job.held_before is None:
            first[(job.row, job.col)] = summary
        else:
            again.setdefault((job.row, job.col), []).append((job, summary))
        return summary

    monkeypatch.setattr(runner, "mesh_tile", mesh_tile)
    common = dict(inputs=(str(path),), resolution=1.0, workers=1)
    report = run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=60.0, buffer=3.0, **common), progress=False)
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
    tiled, whole = store.read_mesh(tmp_path / "tiled.zarr"), store.read_mesh(tmp_path / "whole.zarr")
    assert face_set(np.asarray(tiled[0]), tiled[2]) == face_set(np.asarray(whole[0]), whole[2])
