"""A lake wider than a tile's buffer gives the triangles across it circles as
wide as the lake.  A tile looks for the points in such a circle from near to
far (a few buffers first, twice as far each round), not a tile wide at once:
the few points nearest to what it holds break the circle, so what it reads
beyond its buffer stays small; and the result is the untiled one."""

from __future__ import annotations

import laspy
import numpy as np
from pyproj import CRS

import pipeline.runs.runner as runner
from pipeline import RunConfig, run
from pipeline.store import zarr_store as store

from .store_checks import face_set


def _survey(path, rng):
    """500 x 500 m of ground at 1.2 points a square metre, cut at the LAS scale, with a round lake of 90 m
    radius centred on the corner that four tiles of 125 m share."""
    n = 300_000
    x = np.round(651_000.0 + rng.random(n) * 500.0, 2)
    y = np.round(6_861_000.0 + rng.random(n) * 500.0, 2)
    keep = (x - 651_250.0) ** 2 + (y - 6_861_250.0) ** 2 > 90.0**2
    x, y = x[keep], y[keep]
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([651_000.0, 6_861_000.0, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.round(50.0 + 0.01 * (x - 651_000.0) + 0.3 * np.sin(y / 40.0), 2)
    las.classification = np.full(x.size, 2, dtype=np.uint8)
    las.write(path)
    return path


def test_the_circles_across_a_lake_are_searched_from_near_to_far(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    summaries = []
    meshed = runner.mesh_tile

    def mesh_tile(job):
        summary = meshed(job)
        summaries.append(summary)
        return summary

    monkeypatch.setattr(runner, "mesh_tile", mesh_tile)
    common = dict(inputs=(str(path),), resolution=1.0, triangle_measure="delaunay", quad_measure="none", workers=1)
    run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=125.0, buffer=4.0, **common), progress=False)
    lake = [s for s in summaries if (s.row, s.col) in {(1, 1), (1, 2), (2, 1), (2, 2)}]
    assert len(lake) >= 4
    # each holds about 133 x 133 m, a fifth of it lake: they read about as many points beyond their buffers
    # as they hold (a search a tile wide at once read 2 to 7.5 times as many, 3.8 times in all)
    loaded, held = sum(s.points_loaded for s in lake), sum(s.points_held for s in lake)
    assert loaded < 1.5 * held, [(s.row, s.col, s.points_loaded, s.points_held) for s in lake]
    run(RunConfig(output=str(tmp_path / "whole.zarr"), tile_size=4096.0, **common), progress=False)
    tiled, whole = store.read_mesh(tmp_path / "tiled.zarr"), store.read_mesh(tmp_path / "whole.zarr")
    assert face_set(np.asarray(tiled[0]), tiled[2]) == face_set(np.asarray(whole[0]), whole[2])
