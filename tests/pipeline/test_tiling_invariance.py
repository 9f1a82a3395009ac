"""Tiling never changes the answer: a tiled run's mesh and DEM are the untiled run's.

Tiles are the run's chunks, and as a dask array's result does not depend on
its chunks, a store does not depend on the tile size or the buffer: the same
faces, and the same grid with the same values, bit for bit.  The surveys are
shaped like real ones (see ``test_seams``): cut on straight lines, stored as
integers of a scale at survey-sized offsets, sparse, with voids, their points
in random order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.store import zarr_store as store

from .store_checks import face_set
from .test_seams import _survey

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"


def _store(path: Path, out: Path, **kw):
    config = RunConfig(inputs=(str(path),), output=str(out), in_crs=kw.pop("in_crs", "EPSG:2154"), workers=2, **kw)
    return run(config, progress=False)


def _assert_same_answer(tiled: Path, untiled: Path, layers=("elevation",)) -> None:
    a, b = xr.open_zarr(tiled), xr.open_zarr(untiled)
    assert a.sizes == b.sizes
    for name in ("x", "y", *layers):
        assert np.array_equal(a[name].values, b[name].values, equal_nan=True), name
    node_a, _, faces_a = store.read_mesh(tiled)
    node_b, _, faces_b = store.read_mesh(untiled)
    got, want = face_set(np.asarray(node_a), faces_a), face_set(np.asarray(node_b), faces_b)
    assert got == want, (len(got - want), len(want - got))


# (seed, width, height, tile size as a share of the width, buffer as a share of the tile, measures, surface)
CASES = [
    (11, 240.0, 90.0, 0.05, 0.0, ("s3", "s4"), "linear"),
    (12, 200.0, 160.0, 0.1, 1.0, ("s1", "s2"), "linear"),
    (13, 300.0, 120.0, 0.25, 0.05, ("s3", None), "linear"),
    (14, 180.0, 150.0, 0.4, 0.5, ("delaunay", "s4"), "linear"),
    (15, 160.0, 140.0, 0.2, 0.3, ("s3", "s4"), "smooth"),
    (16, 220.0, 100.0, 0.2, 0.0, ("s1", "s2"), "smooth"),
]


@pytest.mark.parametrize("seed,width,height,share,buffer_share,measures,surface", CASES)
def test_a_tiled_survey_is_the_untiled_survey_face_for_face_and_bit_for_bit(
    tmp_path, seed, width, height, share, buffer_share, measures, surface
):
    _survey(tmp_path / "ground.las", seed, width, height)
    tile = max(2.0, 2.0 * round(share * width / 2.0))  # whole cells of 2 m
    common = dict(resolution=2.0, triangle_measure=measures[0], quad_measure=measures[1], surface=surface,
                  layers=("elevation", "slope"))
    tiled = _store(tmp_path / "ground.las", tmp_path / "tiled.zarr", tile_size=tile, buffer=buffer_share * tile,
                   **common)
    untiled = _store(tmp_path / "ground.las", tmp_path / "untiled.zarr", tile_size=2.0 * max(width, height), **common)
    assert tiled.tiles_uncertified == untiled.tiles_uncertified == 0
    assert tiled.faces == untiled.faces and tiled.quads == untiled.quads
    _assert_same_answer(tmp_path / "tiled.zarr", tmp_path / "untiled.zarr", layers=("elevation", "slope"))


# (sample, resolution, tile sizes, surface): the issue's own cases
SAMPLES = [
    ("startinpy_small_extrabytes.laz", 0.25, (10.0,), "linear"),
    ("4_6_crop_us_feet.las", 1.0, (50.0,), "linear"),
    ("autzen_trim.las", 1.0, (100.0,), "smooth"),
]


@pytest.mark.skipif(not SHARED.is_dir(), reason="needs ../shared/data")
@pytest.mark.parametrize("name,resolution,sizes,surface", SAMPLES)
def test_real_samples_give_the_same_store_at_every_tile_size(tmp_path, name, resolution, sizes, surface):
    source = SHARED / name
    if not source.exists():
        pytest.skip(f"{name} is not in ../shared/data")
    common = dict(resolution=resolution, surface=surface, in_crs=None)
    _store(source, tmp_path / "untiled.zarr", tile_size=1e4 * resolution, **common)
    for size in sizes:
        _store(source, tmp_path / f"t{size:g}.zarr", tile_size=size, **common)
        _assert_same_answer(tmp_path / f"t{size:g}.zarr", tmp_path / "untiled.zarr")
