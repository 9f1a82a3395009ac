"""A void over the corner of a tile's window (a building, a pond) makes the
tile look for points around that corner, not a tile wide all around what it
holds: what it reads beyond its buffer stays small, and the result is the
untiled one."""

from __future__ import annotations

import numpy as np

from .ground_surveys import ground_with_void, middle_tiles_of_a_delaunay_run


def _survey(path, rng):
    """400 x 400 m of ground at 2 points a square metre, cut at the LAS scale, with a 36 m square void
    centred on the corner the four middle tiles of 100 m share."""
    return ground_with_void(path, rng, 320_000, 400.0,
                            lambda x, y: (np.abs(x - 200.0) < 18.0) & (np.abs(y - 200.0) < 18.0))


def test_a_void_over_a_window_corner_is_searched_near_that_corner(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    middle, same = middle_tiles_of_a_delaunay_run(tmp_path, monkeypatch, path, tile_size=100.0, buffer=5.0)
    assert len(middle) >= 4
    # each holds about 110 x 110 m; the void reaches 13 m past that (a tile-wide search read seven times as much)
    for s in middle:
        assert s.points_loaded < s.points_held, (s.row, s.col, s.points_loaded, s.points_held)
    assert same
