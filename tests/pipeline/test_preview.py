"""terrain preview: the pictures, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread

from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SurveySpec(points=60_000, files=2, width=200.0, height=150.0, seed=8))
    out = folder.parent / "preview.zarr"
    run(RunConfig(inputs=(str(folder),), output=str(out), resolution=1.0, tile_size=64.0, workers=2), progress=False)
    return out


def _red(picture) -> int:
    rgb = picture[..., :3]
    return int(((rgb[..., 0] > 0.8) & (rgb[..., 1] < 0.2) & (rgb[..., 2] < 0.2)).sum())


def test_overview_and_mesh_window(store, tmp_path):
    assert main(["preview", str(store), "-o", str(tmp_path / "a.png")]) == 0
    overview = imread(tmp_path / "a.png")
    assert _red(overview) == 0
    window = "651050,6861050,651080,6861080"
    assert main(["preview", str(store), "-o", str(tmp_path / "b.png"), "--window", window]) == 0
    both = imread(tmp_path / "b.png")
    assert both.shape[1] > 1.6 * overview.shape[1]  # a second panel
    assert _red(both) > 50  # the zoom box drawn on the overview
    # the mesh panel holds both face colours
    right = both[:, both.shape[1] // 2 :, :3]
    blue = (np.abs(right - np.array([0x21, 0x66, 0xAC]) / 255) < 0.25).all(axis=2).sum()
    orange = (np.abs(right - np.array([0xF4, 0xA5, 0x16]) / 255) < 0.25).all(axis=2).sum()
    assert blue > 1000 and orange > 1000


def test_refusals_are_one_line_errors(store, tmp_path, capsys):
    assert main(["preview", str(store), "-o", str(tmp_path / "c.png"), "--window", "651000,6861000,651200,6861150"]) == 2
    assert "too many to draw" in capsys.readouterr().err
    assert main(["preview", str(store), "-o", str(tmp_path / "d.png"), "--window", "1,2,3"]) == 2
    assert main(["preview", str(store), "-o", str(tmp_path / "f.png"), "--window", "0,0,10,10"]) == 2
    assert "meets no face of the mesh" in capsys.readouterr().err
    assert not (tmp_path / "f.png").exists()
    assert main(["preview", str(tmp_path / "nothing.zarr"), "-o", str(tmp_path / "e.png")]) == 2


def _coloured(picture) -> float:
    """The share of the picture's pixels that are neither white nor grey (relief, colour bars)."""
    rgb = picture[..., :3]
    return float((rgb.max(axis=2) - rgb.min(axis=2) > 0.1).mean())


def test_an_empty_dem_is_drawn_as_its_extent_not_refused(store, tmp_path):
    """A valid run can write a DEM without a value (every face longer than
    --max-edge); previewing it is not an error: the grid's extent is drawn,
    saying so, and the mesh in a window over it."""
    survey = next(p for p in store.parent.glob("survey*") if p.is_dir())  # the fixture's files
    empty = tmp_path / "empty.zarr"
    report = run(RunConfig(inputs=(str(survey),), output=str(empty), resolution=1.0, max_edge=0.05), progress=False)
    assert report.faces > 0 and any("the DEM is empty" in n for n in report.notes)
    assert main(["preview", str(empty), "-o", str(tmp_path / "e.png")]) == 0
    assert main(["preview", str(store), "-o", str(tmp_path / "s.png")]) == 0
    assert _coloured(imread(tmp_path / "e.png")) < 0.01 < _coloured(imread(tmp_path / "s.png"))
    window = "651050,6861050,651080,6861080"
    assert main(["preview", str(empty), "-o", str(tmp_path / "w.png"), "--window", window]) == 0
    zoom = imread(tmp_path / "w.png")
    assert _red(zoom) > 50  # the window's box on the extent


def _dataset(crs: str, units: str | None):
    import xarray as xr
    from pyproj import CRS

    elevation = xr.DataArray(np.zeros((2, 2), dtype=np.float32), dims=("y", "x"), attrs={} if units is None else {"units": units})
    spatial_ref = xr.DataArray(0, attrs={"crs_wkt": CRS.from_user_input(crs).to_wkt()})
    return xr.Dataset({"elevation": elevation, "spatial_ref": spatial_ref})


@pytest.mark.parametrize(
    "crs, units, expected",
    [
        ("EPSG:2154", "metre", ("m", "m", 1.0)),
        ("EPSG:2154", None, ("m", "m", 1.0)),  # undeclared heights: in the horizontal unit
        ("EPSG:2154", "0.3048 metre", ("m", "ft", 0.3048)),
        ("EPSG:2994", None, ("ft", "ft", 1.0)),  # Oregon Lambert, international feet
        ("EPSG:2994", "metre", ("ft", "m", 1 / 0.3048)),
        ("EPSG:26913+5703", "metre", ("m", "m", 1.0)),
    ],
)
def test_preview_reads_the_units_of_the_store(crs, units, expected):
    from pipeline.tools.preview import _units

    xy, z, scale = _units(_dataset(crs, units))
    assert (xy, z) == expected[:2]
    assert scale == pytest.approx(expected[2])


def test_relief_in_feet_over_metres_is_shaded_as_the_same_relief_in_metres():
    from pipeline.tools.preview import _hillshade

    y, x = np.mgrid[0:60, 0:80].astype(np.float64)
    metres = 100.0 + 10.0 * np.sin(x / 9.0) * np.cos(y / 7.0)
    rgb_m, _, _ = _hillshade(metres, 1.0)
    rgb_ft, _, _ = _hillshade(metres / 0.3048, 1.0, height_scale=0.3048)
    unscaled, _, _ = _hillshade(metres / 0.3048, 1.0)
    assert np.allclose(rgb_ft, rgb_m, atol=1e-6)
    assert not np.allclose(unscaled, rgb_m, atol=1e-2)  # 3.3 times too steep
