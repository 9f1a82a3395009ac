"""terrain export: COGs (and row blocks plus a VRT) read back by GDAL's tools and
rasterio, cell for cell against the store; the STAC item beside the store."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import zarr

from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey

rasterio = pytest.importorskip("rasterio")

GDAL_TOOLS = shutil.which("gdalinfo") is not None and shutil.which("gdal_translate") is not None
LAYERS = ("elevation", "slope", "face_kind", "point_count")


@pytest.fixture(scope="module")
def store(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("export")
    write_survey(folder / "survey", SurveySpec(points=90_000, files=2, width=330.0, height=300.0, seed=12))
    out = folder / "dem.zarr"
    run(RunConfig(inputs=(str(folder / "survey"),), output=str(out), resolution=0.5, tile_size=64.0,
                  layers=LAYERS[1:], workers=2), progress=False)
    return out


def _store_layer(store: Path, layer: str) -> np.ndarray:
    with xr.open_zarr(store) as ds:
        return ds[layer].values


def _same_cells(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=np.issubdtype(a.dtype, np.floating)))


def _gdal_cells(path: Path, tmp_path: Path) -> np.ndarray:
    """The raster as GDAL's command-line tools read it: gdal_translate to raw ENVI."""
    info = _gdalinfo(path)
    raw = tmp_path / f"{path.stem}.raw"
    subprocess.run(["gdal_translate", "-q", "-of", "ENVI", str(path), str(raw)], check=True)
    dtype = {"Float32": np.float32, "Byte": np.uint8, "Int32": np.int32}[info["bands"][0]["type"]]
    width, height = info["size"]
    return np.fromfile(raw, dtype=dtype).reshape(height, width)


def _gdalinfo(path: Path) -> dict:
    out = subprocess.run(["gdalinfo", "-json", str(path)], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def test_each_layer_is_a_cog_equal_to_the_store(store, tmp_path):
    assert main(["export", str(store), "-o", str(tmp_path / "dem.tif")]) == 0
    with xr.open_zarr(store) as ds:
        x, y = ds["x"].values, ds["y"].values
    res = x[1] - x[0]
    for layer in LAYERS:
        path = tmp_path / ("dem.tif" if layer == "elevation" else f"dem_{layer}.tif")
        expected = _store_layer(store, layer)
        with rasterio.open(path) as src:
            assert src.crs.to_epsg() == 2154
            assert src.transform.a == res and src.transform.e == -res
            assert src.transform.c == x[0] - res / 2 and src.transform.f == y[0] + res / 2
            assert src.descriptions[0] == layer
            assert src.overviews(1), "no overviews"
            assert src.profile["blockxsize"] == 512 and src.profile["compress"] == "deflate"
            values = src.read(1)
            if layer in ("elevation", "slope"):
                assert np.isnan(src.nodata)
            else:
                assert src.nodata == {"face_kind": 0, "point_count": None}[layer]
        assert _same_cells(values.astype(expected.dtype), expected), layer
        assert np.isfinite(values).any()
        if GDAL_TOOLS:
            info = _gdalinfo(path)
            assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
            assert info["bands"][0]["overviews"]
            assert 'ID["EPSG",2154]' in info["coordinateSystem"]["wkt"]
            assert _same_cells(_gdal_cells(path, tmp_path).astype(expected.dtype), expected), layer


def test_a_large_layer_is_row_blocks_under_a_vrt(store, tmp_path):
    with xr.open_zarr(store) as ds:
        nx = ds.sizes["x"]
    # two tile rows (128 cells each) fit a file: the grid's 640 rows make three files
    assert main(["export", str(store), "-o", str(tmp_path / "dem.tif"), "--layers", "elevation,face_kind",
                 "--max-file-cells", str(nx * 256 + 5)]) == 0
    assert not (tmp_path / "dem.tif").exists()
    for layer, stem in (("elevation", "dem"), ("face_kind", "dem_face_kind")):
        parts = sorted(tmp_path.glob(f"{stem}-*.tif"))
        assert [p.name for p in parts] == [f"{stem}-{k:03d}.tif" for k in range(3)]
        expected = _store_layer(store, layer)
        with rasterio.open(tmp_path / f"{stem}.vrt") as src:
            assert src.crs.to_epsg() == 2154 and src.shape == expected.shape
            assert _same_cells(src.read(1).astype(expected.dtype), expected)
        heights = []
        for part in parts:
            with rasterio.open(part) as src:
                heights.append(src.height)
        assert heights == [256, 256, expected.shape[0] - 512]
        if GDAL_TOOLS:
            assert _same_cells(_gdal_cells(tmp_path / f"{stem}.vrt", tmp_path).astype(expected.dtype), expected)
            assert _gdalinfo(parts[0])["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"


def test_the_stac_item_describes_the_store_and_its_cogs(store, tmp_path):
    pystac = pytest.importorskip("pystac")
    from pystac.extensions.projection import ProjectionExtension
    from pystac.validation import validate_dict
    from pyproj import Transformer

    item_path = store.with_name("dem.stac.json")
    assert item_path.exists()  # the run wrote it
    before = json.loads(item_path.read_text())
    assert set(before["assets"]) >= {"zarr"}
    local = store.parent / "cogs"
    assert main(["export", str(store), "-o", str(local / "dem.tif"), "--layers", "elevation,slope"]) == 0
    item = json.loads(item_path.read_text())
    assert {"zarr", "elevation", "slope"} <= set(item["assets"])
    for asset in item["assets"].values():
        assert (item_path.parent / asset["href"]).exists(), asset["href"]
    assert item["assets"]["elevation"]["type"].startswith("image/tiff; application=geotiff")
    # the core schema (shipped with pystac; the projection extension's schema would need the network)
    validate_dict(item, extensions=[])
    loaded = pystac.Item.from_dict(item)
    proj = ProjectionExtension.ext(loaded)
    with xr.open_zarr(store) as ds:
        shape = [ds.sizes["y"], ds.sizes["x"]]
        x, y = ds["x"].values, ds["y"].values
    assert proj.code == "EPSG:2154" and proj.shape == shape
    lon, lat = Transformer.from_crs("EPSG:2154", "EPSG:4326", always_xy=True).transform(x.mean(), y.mean())
    west, south, east, north = loaded.bbox
    assert west < lon < east and south < lat < north
    assert loaded.datetime is not None
    assert item["properties"]["terrain:provenance"]["parameters"]["resolution"] == 0.5
    # exporting another layer keeps the earlier ones; a new run drops them (they describe the old store)
    assert main(["export", str(store), "-o", str(local / "kinds.tif"), "--layers", "face_kind"]) == 0
    assert {"elevation", "slope", "face_kind"} <= set(json.loads(item_path.read_text())["assets"])


def test_refusals_are_one_line_errors_that_write_nothing(store, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(tmp_path / "missing.zarr"), "-o", str(out / "a.tif")]) == 2
    assert "missing.zarr: is not a Zarr store" in capsys.readouterr().err
    assert main(["export", str(store), "-o", str(out / "a.tif"), "--layers", "heights"]) == 2
    assert "unknown layer 'heights'" in capsys.readouterr().err
    unfinished = tmp_path / "unfinished.zarr"
    shutil.copytree(store, unfinished)
    zarr.open_group(unfinished, mode="r+").attrs["complete"] = False
    assert main(["export", str(unfinished), "-o", str(out / "b.tif")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("not complete (its run did not finish); nothing exported") and "\n" not in err
    assert not out.exists() or not list(out.glob("*.tif"))
