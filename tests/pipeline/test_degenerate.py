"""Archives that hold no surface: empty files, one point, all duplicates, all
collinear, coordinates at the edge of the LAS integer range."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
import xarray as xr
from pyproj import CRS

from pipeline.cli import main


def _write(path, x, y, z, scale=0.01, offset=(500_000.0, 4_000_000.0, 0.0)):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale, scale, scale])
    header.offsets = np.array(offset)
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.full(len(x), 2, dtype=np.uint8)
    las.write(path)
    return path


def _run(path, out, *flags):
    return main(["run", str(path), "-o", str(out), "--resolution", "1", "--no-progress", *flags])


@pytest.mark.parametrize(
    "name, xy",
    [
        ("one", np.array([[500_010.0, 4_000_010.0]])),
        ("duplicates", np.tile([[500_010.0, 4_000_010.0]], (500, 1))),
        # exactly on one line once scaled (binary scale 0.25: X = 2k, Y = k)
        ("collinear", np.c_[500_000 + 0.5 * np.arange(300), 4_000_000 + 0.25 * np.arange(300)]),
    ],
)
def test_no_surface_is_a_clear_error(tmp_path, capsys, name, xy):
    path = _write(tmp_path / f"{name}.laz", xy[:, 0], xy[:, 1], np.full(len(xy), 10.0), scale=0.25)
    assert _run(path, tmp_path / "o.zarr") == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("terrain: error:") and "no surface" in err, err


def test_an_empty_file_beside_a_good_one_is_reported_not_an_error(tmp_path, capsys):
    folder = tmp_path / "a"
    folder.mkdir()
    _write(folder / "empty.laz", np.empty(0), np.empty(0), np.empty(0))
    rng = np.random.default_rng(0)
    _write(folder / "good.laz", 500_000 + rng.random(2000) * 50, 4_000_000 + rng.random(2000) * 50, rng.random(2000))
    assert _run(folder, tmp_path / "o.zarr") == 0
    assert "empty.laz: no points of the chosen classes" in capsys.readouterr().out


def test_coordinates_at_the_int32_limits(tmp_path):
    # integer coordinates near +-2**31 of the LAS record, with a coarse scale
    scale = 0.001
    base = np.array([2**31 - 60_000, -(2**31) + 10]) * scale + np.array([600_000.0, 6_000_000.0])
    rng = np.random.default_rng(1)
    x = base[0] + np.round(rng.random(3000) * 50, 3)
    y = base[1] + np.round(rng.random(3000) * 50, 3)
    path = _write(tmp_path / "edge.laz", x, y, rng.random(3000), scale=scale, offset=(600_000.0, 6_000_000.0, 0.0))
    with laspy.open(path) as f:
        las = f.read()
    assert np.abs(las.X).max() > 2**31 - 70_000 and np.abs(las.Y).max() > 2**31 - 70_000
    assert _run(path, tmp_path / "o.zarr") == 0
    elevation = xr.open_zarr(tmp_path / "o.zarr")["elevation"].values
    assert np.isfinite(elevation).sum() > 2000


def test_a_nan_scale_is_one_readable_line(tmp_path, capsys):
    import struct

    path = _write(tmp_path / "nan.las", np.array([500_000.0, 500_001.0, 500_000.0]),
                  np.array([4_000_000.0, 4_000_000.0, 4_000_001.0]), np.zeros(3))
    data = bytearray(path.read_bytes())
    data[131:139] = struct.pack("<d", float("nan"))  # the x scale
    path.write_bytes(bytes(data))
    assert _run(path, tmp_path / "o.zarr") == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == f"terrain: error: {path}: unusable scale factors (nan, 0.01, 0.01): its coordinates cannot be decoded"
