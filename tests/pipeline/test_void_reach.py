"""A lake wider than a tile's buffer gives the triangles across it circles as
wide as the lake.  A tile looks for the points in such a circle from near to
far (a few buffers first, twice as far each round), not a tile wide at once:
the few points nearest to what it holds break the circle, so what it reads
beyond its buffer stays small; and the result is the untiled one."""

from __future__ import annotations

from .ground_surveys import ground_with_void, middle_tiles_of_a_delaunay_run


def _survey(path, rng):
    """500 x 500 m of ground at 1.2 points a square metre, cut at the LAS scale, with a round lake of 90 m
    radius centred on the corner that four tiles of 125 m share."""
    return ground_with_void(path, rng, 300_000, 500.0, lambda x, y: (x - 250.0) ** 2 + (y - 250.0) ** 2 <= 90.0**2)


def test_the_circles_across_a_lake_are_searched_from_near_to_far(tmp_path, rng, monkeypatch):
    path = _survey(tmp_path / "survey.laz", rng)
    lake, same = middle_tiles_of_a_delaunay_run(tmp_path, monkeypatch, path, tile_size=125.0, buffer=4.0)
    assert len(lake) >= 4
    # each holds about 133 x 133 m, a fifth of it lake: they read about as many points beyond their buffers
    # as they hold (a search a tile wide at once read 2 to 7.5 times as many, 3.8 times in all)
    loaded, held = sum(s.points_loaded for s in lake), sum(s.points_held for s in lake)
    assert loaded < 1.5 * held, [(s.row, s.col, s.points_loaded, s.points_held) for s in lake]
    assert same
