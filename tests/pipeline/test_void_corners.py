"""A void over the corner of a tile's window (a building, a pond) makes the
tile look for points around that corner, not a tile wide all around what it
holds: what it reads beyond its buffer stays small, and the result is the
untiled one."""

from __future__ import annotations

import laspy
import numpy as np
from pyproj import CRS

import pipeline.runs.runner as runner
from pipeline import RunConfig, run
from pipeline.store import zarr_store as store

from .store_checks import face_set


def _survey(path, rng):
    """400 x 400 m of ground at 2 points a square metre, cut at the LAS scale, with a 36 m square void
    centred on the corner the four middle tiles of 100 m share."""
    n = 320_000
    x = np.round(651_000.0 + rng.random(n) * 400.0, 2)
    y = np.round(6_861_000.0 + rng.random(n) * 400.0, 2)
    keep = ~((np.abs(x - 651_200.0) < 18.0) & (np.abs(y - 6_861_200.0) < 18.0))
    x, y = x[keep], y[keep]
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([651_000.0, 6_861_000.0, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.round(50.0 + 0.01 * (x - 651_000.0) + 0.3 * np.sin(y / 40.0), 2)
    las.classification = np.full(x.size, 2, dtype=np.uint8)
    las.write(path)
    return path


def test_a_void_over_a_window_corner_is_searched_near_that_corner(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    summaries = []
    meshed = runner.mesh_tile

    def mesh_tile(job):
        summary = meshed(job)
        summaries.append(summary)
        return summary

    monkeypatch.setattr(runner, "mesh_tile", mesh_tile)
    common = dict(inputs=(str(path),), resolution=1.0, triangle_measure="delaunay", quad_measure="none", workers=1)
    run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=100.0, buffer=5.0, **common), progress=False)
    middle = [s for s in summaries if (s.row, s.col) in {(1, 1), (1, 2), (2, 1), (2, 2)}]
    assert len(middle) >= 4
    # each holds about 110 x 110 m; the void reaches 13 m past that (a tile-wide search read seven times as much)
    for s in middle:
        assert s.points_loaded < s.points_held, (s.row, s.col, s.points_loaded, s.points_held)
    run(RunConfig(output=str(tmp_path / "whole.zarr"), tile_size=4096.0, **common), progress=False)
    tiled, whole = store.read_mesh(tmp_path / "tiled.zarr"), store.read_mesh(tmp_path / "whole.zarr")
    assert face_set(np.asarray(tiled[0]), tiled[2]) == face_set(np.asarray(whole[0]), whole[2])
