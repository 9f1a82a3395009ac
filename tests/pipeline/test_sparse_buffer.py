"""A buffer set far below a sparse survey's point spacing (a user's 3 m over
points 40 m apart): each tile's searches grow by what the flips' doubt
spreads over the points it holds, not by the buffer, so a tile meshes a few
times, not dozens, and the mesh is still one tile's."""

from __future__ import annotations

import numpy as np

from pipeline import RunConfig, run

from .ground_surveys import ORIGIN, record_tiles, same_mesh, write_ground


def test_tiles_of_a_sparse_survey_with_a_small_buffer_mesh_a_few_times(tmp_path, monkeypatch, rng):
    n, side = 160, 500.0  # a point every 40 m
    x = np.round(ORIGIN[0] + rng.random(n) * side, 2)
    y = np.round(ORIGIN[1] + rng.random(n) * side, 2)
    path = write_ground(tmp_path / "sparse.las", x, y, 50.0 + 0.02 * (x - ORIGIN[0]) + 3.0 * np.sin(y / 90.0))
    meshed = record_tiles(monkeypatch)
    common = dict(inputs=(str(path),), resolution=5.0, workers=1)
    run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=50.0, buffer=3.0, **common), progress=False)
    run(RunConfig(output=str(tmp_path / "whole.zarr"), tile_size=4096.0, **common), progress=False)
    assert same_mesh(tmp_path / "tiled.zarr", tmp_path / "whole.zarr")
    tiled = [s for job, s in meshed if job.grid.n_tiles > 1]
    assert len(tiled) >= 100
    expansions = np.array([s.expansions for s in tiled])
    # growing by the buffer, half of them expanded 9 times or more, up to 15
    assert np.median(expansions) <= 5 and expansions.max() <= 10, np.bincount(expansions)
