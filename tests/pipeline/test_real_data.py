"""Runs on the real LAS/LAZ samples beside the project (skipped when they are absent)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import meshcore
from pipeline.store import zarr_store as store
from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.errors import CrsError, PipelineError
from pipeline.runs.runner import run

from .store_checks import face_set

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def sample(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"{path} is not available")
    return path


def _run(path: Path, out: Path, **kw):
    return run(RunConfig(inputs=(str(path),), output=str(out), **{"resolution": 1.0, **kw}), progress=False)


def _check_store(out: Path, report) -> None:
    xy, z, faces = store.read_mesh(out)
    meshcore.validate(meshcore.Mesh(np.asarray(xy), np.asarray(faces), np.arange(len(xy))))
    assert len(xy) == report.vertices
    assert report.tiles_uncertified == 0
    elev = xr.open_zarr(out)["elevation"]
    assert np.isfinite(elev.values).any()


def test_lambert93_laz_14(tmp_path):
    path = sample("ign_semis_lambert93.laz")
    out = tmp_path / "ign.zarr"
    report = _run(path, out, resolution=2.0, tile_size=256.0, workers=2)
    assert report.points_read == 289_055
    assert report.points_kept == 152_678
    assert report.tiles >= 4
    _check_store(out, report)


def test_us_feet_and_info(tmp_path, capsys):
    path = sample("4_6_crop_us_feet.las")
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "23,875" in text or "23875" in text
    out = tmp_path / "feet.zarr"
    report = _run(path, out, resolution=5.0, workers=2)
    assert report.points_kept == 9_003
    _check_store(out, report)
    from pyproj import CRS

    crs = CRS.from_wkt(xr.open_zarr(out)["spatial_ref"].attrs["crs_wkt"])
    assert "foot" in crs.axis_info[0].unit_name.lower()
    # the file declares its heights in US survey feet (VerticalUnitsGeoKey): the store says so
    assert xr.open_zarr(out)["elevation"].attrs["units"] == "0.304800609601219 metre"


def test_geographic_input_is_gridded_in_its_utm_zone(tmp_path, capsys):
    """A survey in degrees is valid input: without --out-crs the run works in
    the WGS 84 UTM zone at its centre, says so, and gives what --out-crs of
    that zone gives; an incremental run keeps the zone the store chose."""
    from pyproj import CRS

    from pipeline.runs.plan import kept_sizes

    path = sample("geographic_epsg4326.las")
    auto, given = tmp_path / "auto.zarr", tmp_path / "given.zarr"
    assert main(["run", str(path), "-o", str(auto), "--resolution", "2", "--no-progress"]) == 0
    assert "are in WGS 84 / UTM zone 15N (EPSG:32615), the UTM zone at their centre" in capsys.readouterr().out
    assert main(["run", str(path), "-o", str(given), "--resolution", "2", "--out-crs", "EPSG:32615", "-q"]) == 0
    a, b = xr.open_zarr(auto), xr.open_zarr(given)
    assert CRS.from_wkt(a["spatial_ref"].attrs["crs_wkt"]).to_epsg() == 32615
    assert np.isfinite(a["elevation"].values).sum() > 1000
    np.testing.assert_array_equal(a["elevation"].values, b["elevation"].values)
    np.testing.assert_array_equal(a["x"].values, b["x"].values)
    assert kept_sizes(RunConfig(inputs=(str(path),), output=str(auto), resolution=2.0))["out_crs"] == "EPSG:32615"
    with pytest.raises(CrsError, match="geographic"):  # an out_crs in degrees is still refused
        _run(path, tmp_path / "g2.zarr", out_crs="EPSG:4326")


def test_info_names_a_crs_record_the_bounds_contradict(capsys):
    """``terrain info`` says what a run would refuse: the record of lone-star
    (UTM metres recorded as degrees) flagged, with the flag to give; a right
    record is not."""
    from pipeline.tools.info import info_json

    wrong, right = sample("lone_star_wrong_crs_degrees.laz"), sample("ign_semis_lambert93.laz")
    assert main(["info", str(wrong), str(right)]) == 0
    text = capsys.readouterr().out
    assert text.count("wrong? it is in degrees, but its header bounds (x 515,368.6") == 1
    assert "give --override-crs the CRS the coordinates are in" in text
    by_path = {e["path"]: e for e in info_json([wrong, right])}
    assert by_path[str(wrong)]["crs_contradiction"].startswith("is in degrees, but its header bounds")
    assert by_path[str(right)]["crs_contradiction"] is None


@pytest.mark.parametrize(
    ("name", "record"),
    [
        ("lone_star_wrong_crs_geocentric.copc.laz", "unnamed (EPSG:4978) is geocentric (earth-centred x, y, z)"),
        ("lone_star_wrong_crs_degrees.laz", "WGS 84 (EPSG:4326) is in degrees"),
    ],
)
def test_records_the_coordinates_contradict_are_refused_and_run_with_the_override(tmp_path, capsys, name, record):
    """PDAL's lone-star survey: UTM zone 12N metres under a geocentric and a
    geographic record. Without the override one line names the
    contradiction; with it the DEM is on UTM zone 12N."""
    from pyproj import CRS

    path = sample(name)
    out = tmp_path / "lone.zarr"
    for flags in ([], ["--out-crs", "EPSG:32612"], ["--in-crs", "EPSG:32612"]):
        assert main(["run", str(path), "-o", str(out), "--resolution", "1", "--no-progress", *flags]) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith(f"terrain: error: {path}: its CRS record {record}, but its header bounds (x 515,368.6")
        assert line.endswith("if the record is wrong, give --override-crs the CRS the coordinates are in")
    assert not out.exists()
    assert main(["run", str(path), "-o", str(out), "--resolution", "1", "--no-progress",
                 "--override-crs", "EPSG:32612"]) == 0
    assert f"note: {path}: its CRS record " in capsys.readouterr().out
    ds = xr.open_zarr(out)
    assert CRS.from_wkt(ds["spatial_ref"].attrs["crs_wkt"]).to_epsg() == 32612
    elevation = ds["elevation"].values
    assert np.isfinite(elevation).mean() > 0.5  # the points' hull fills two thirds of the header's box
    assert 2322.8 < np.nanmin(elevation) and np.nanmax(elevation) < 2338.6
    assert 515_368 <= float(ds["x"].min()) and float(ds["x"].max()) <= 515_402


def test_broken_crs_needs_in_crs(tmp_path, capsys):
    path = sample("warsaw_small_broken_crs.las")
    code = main(["run", str(path), "-o", str(tmp_path / "w.zarr"), "--resolution", "1", "--no-progress"])
    assert code == 2
    assert "warsaw_small_broken_crs.las" in capsys.readouterr().err
    out = tmp_path / "w2.zarr"
    report = _run(path, out, in_crs="EPSG:2180")
    assert report.points_kept == 1_381
    _check_store(out, report)


def test_duplicates_are_counted(tmp_path):
    path = sample("plane_many_duplicates.laz")
    out = tmp_path / "plane.zarr"
    report = _run(path, out, classes=None, in_crs="EPSG:3945")
    assert report.points_read == 28_185
    assert report.duplicates == 12_495
    assert report.vertices == 28_185 - 12_495
    _check_store(out, report)


def test_single_point(tmp_path):
    path = sample("single_point.laz")
    out = tmp_path / "one.zarr"
    # one point makes no surface: a clear error naming the file, never a complete store
    with pytest.raises(PipelineError, match=r"single_point\.laz: no surface: the 1 distinct kept point"):
        _run(path, out, classes=None, in_crs="EPSG:2154")
    assert store.read_attrs(out)["complete"] is False


GROUND_SAMPLES = [
    "ign_semis_lambert93.laz", "extra_byte_blocks_lambert93.laz", "autzen_trim.las",
    "startinpy_small_extrabytes.laz", "4_6_crop_us_feet.las",
]


@pytest.mark.parametrize("tile", [10.0, 20.0, 50.0])
@pytest.mark.parametrize("name", GROUND_SAMPLES)
def test_real_surveys_certify_every_tile_and_tile_into_the_whole_delaunay(tmp_path, name, tile):
    """A box over the survey's south-west corner (its own edges, and the box's
    straight cuts at round coordinates), 60 CRS units across or three tiles,
    whichever is larger."""
    import laspy

    path = sample(name)
    las = laspy.read(path)
    ground = np.asarray(las.classification) == 2
    x, y = np.asarray(las.x)[ground], np.asarray(las.y)[ground]
    corner = int(np.argmin(x + y))  # the south-west-most ground point
    side = max(60.0, 3 * tile)
    x0, y0 = math.floor(x[corner]) - tile, math.floor(y[corner]) - tile
    bbox = (x0, y0, x0 + side, y0 + side)
    out = tmp_path / "d.zarr"
    report = _run(
        path, out, resolution=tile / 8.0, tile_size=tile, bbox=bbox, triangle_measure="delaunay", quad_measure=None
    )
    assert report.tiles_uncertified == 0
    node_xy, _, faces = store.read_mesh(out)
    node_xy, faces = np.asarray(node_xy), np.asarray(faces)
    meshcore.validate(meshcore.Mesh(node_xy, faces, np.arange(len(node_xy))))
    assert len(node_xy) == report.vertices > 50
    whole = meshcore.build_mesh(node_xy, "delaunay", None)
    assert face_set(node_xy, faces) == face_set(whole.vertices, whole.faces)
    if tile == 20.0:  # the combined mesh: flips and merges stay inside the pieces
        combined = _run(path, tmp_path / "c.zarr", resolution=tile / 8.0, tile_size=tile, bbox=bbox)
        _check_store(tmp_path / "c.zarr", combined)
        assert combined.vertices == report.vertices


def test_tiles_without_buffer_certify_in_bounded_memory(tmp_path):
    """With no buffer, tiles of 100 m of a dense survey each load hundreds of
    thousands of points against a thousand or more circles and kriging disks;
    which points lie in a circle is found without a points-by-circles matrix
    (one of 4.4 GiB a tile did not fit), the run stays under a 1.5 GiB data
    segment and every tile certifies."""
    import os
    import resource
    import subprocess
    import sys

    path = sample("extra_byte_blocks_lambert93.laz")
    cap = 1536 * 2**20

    def capped() -> None:
        resource.setrlimit(resource.RLIMIT_DATA, (cap, cap))

    out = tmp_path / "out.zarr"
    code = "import sys; from pipeline.cli import main; sys.exit(main(sys.argv[1:]))"
    args = [sys.executable, "-c", code, "run", str(path), "-o", str(out), "--resolution", "12.5", "--tile-size", "100",
            "--buffer", "0", "--surface", "smooth", "--no-progress"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=300, preexec_fn=capped, env=dict(os.environ))
    assert done.returncode == 0, done.stderr[-2000:]
    report = xr.open_zarr(out).attrs["run_history"][-1]["report"]
    assert report["tile_expansions"] >= 5 and report["tiles_uncertified"] == 0


def test_a_real_survey_keeps_its_grid_and_delaunay_dem_at_any_tile_size(tmp_path):
    """41 x 48 m at 0.25 m cells: tiles of 10 m (40 cells) once padded its
    194 rows to 200; the grid is the survey's at any tile size, and so is the
    Delaunay DEM, bit for bit."""
    path = sample("startinpy_small_extrabytes.laz")
    outs = []
    for tile in (10.0, None):  # None: the size from the density, one tile here
        out = tmp_path / f"tile{tile}.zarr"
        _run(path, out, resolution=0.25, tile_size=tile, triangle_measure="delaunay", quad_measure=None)
        outs.append(out)
    tiled, whole = (xr.open_zarr(out) for out in outs)
    assert tiled["elevation"].shape == whole["elevation"].shape == (194, 165)
    assert tiled["elevation"].chunks == ((40,) * 4 + (34,), (40,) * 4 + (5,))
    for name in ("x", "y"):
        assert np.array_equal(tiled[name].values, whole[name].values)
    assert tiled["spatial_ref"].attrs == whole["spatial_ref"].attrs
    bits = [store.read_layer(out, "elevation").view(np.uint32) for out in outs]
    assert np.array_equal(bits[0], bits[1])
