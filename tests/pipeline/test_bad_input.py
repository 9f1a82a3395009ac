"""Bad files in an archive: a one-line error and exit 2, or with --skip-bad-files
the job goes on and the report says which files were left out and why."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest
import xarray as xr

from pipeline.store import zarr_store as store
from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey

SPEC = SurveySpec(points=30_000, files=3, width=240.0, height=120.0, seed=12, duplicate_share=0.0)


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    """A good archive, and the same with a text file named .las, a truncated
    file and one whose LAZ data is corrupt half way."""
    good = tmp_path_factory.mktemp("good")
    paths = write_survey(good, SPEC)
    bad = tmp_path_factory.mktemp("bad")
    for p in paths:
        shutil.copy(p, bad / p.name)
    (bad / "notes.las").write_text("this is not a point cloud\n")
    data = paths[0].read_bytes()
    (bad / "truncated.laz").write_bytes(data[:300])
    corrupt = bytearray(paths[1].read_bytes())
    middle = len(corrupt) // 2
    corrupt[middle : middle + 256] = bytes(b ^ 0xFF for b in corrupt[middle : middle + 256])
    (bad / "corrupt.laz").write_bytes(bytes(corrupt))
    return good, bad


def _args(folder, out, *flags):
    return ["run", str(folder), "-o", str(out), "--resolution", "2", "--tile-size", "60", "--no-progress", *flags]


def test_a_bad_file_stops_the_job_with_one_line_naming_it(archives, tmp_path, capsys):
    _, bad = archives
    assert main(_args(bad, tmp_path / "a.zarr")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("terrain: error:")
    assert "corrupt.laz" in err[0] or "notes.las" in err[0] or "truncated.laz" in err[0]
    attrs = store.read_attrs(tmp_path / "a.zarr")
    assert attrs is None or attrs["complete"] is False  # never a complete store with missing data


def test_skip_bad_files_lists_each_and_keeps_the_rest(archives, tmp_path, capsys):
    good, bad = archives
    assert main(_args(bad, tmp_path / "b.zarr", "--skip-bad-files")) == 0
    out = capsys.readouterr().out
    report = xr.open_zarr(tmp_path / "b.zarr").attrs["report"]
    skipped = {Path(f["path"]).name: f["reason"] for f in report["skipped_files"]}
    assert set(skipped) == {"notes.las", "truncated.laz", "corrupt.laz"}
    assert "not a LAS/LAZ file" in skipped["notes.las"]
    assert all(name in reason for name, reason in skipped.items())  # each reason names its file
    assert out.count("skipped file") == 3
    # the corrupt file was found broken while streaming: none of its points remain
    per_file = SPEC.points // SPEC.files
    assert report["points_read"] == 3 * per_file
    reference = run(RunConfig(inputs=(str(good),), output=str(tmp_path / "ref.zarr"), resolution=2.0,
                              tile_size=60.0), progress=False)
    assert reference.points_read == report["points_read"]
    a = xr.open_zarr(tmp_path / "b.zarr")["elevation"].values
    b = xr.open_zarr(tmp_path / "ref.zarr")["elevation"].values
    np.testing.assert_array_equal(a, b)


def test_only_bad_files_is_an_error_even_when_skipping(archives, tmp_path, capsys):
    _, bad = archives
    only = tmp_path / "only"
    only.mkdir()
    shutil.copy(bad / "notes.las", only / "notes.las")
    assert main(_args(only, tmp_path / "c.zarr", "--skip-bad-files")) == 2
    assert "every input was skipped" in capsys.readouterr().err


def _geographic(path: Path, lat_of_first: float | None = None) -> Path:
    import laspy

    rng = np.random.default_rng(5)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([1e-7, 1e-7, 0.01])
    header.offsets = np.array([2.0, 46.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(4326))
    las = laspy.LasData(header)
    lat = 46.0 + rng.random(2000) * 0.01
    if lat_of_first is not None:
        lat[:3] = lat_of_first
    las.x, las.y, las.z = 2.0 + rng.random(2000) * 0.01, lat, rng.random(2000)
    las.classification = np.full(2000, 2, dtype=np.uint8)
    las.write(path)
    return path


def test_points_that_cannot_be_reprojected_name_their_file_and_can_be_skipped(tmp_path):
    from pipeline.errors import InputFileError

    folder = tmp_path / "geo"
    folder.mkdir()
    _geographic(folder / "good.las")
    bad = _geographic(folder / "polar.las", lat_of_first=95.0)  # beyond the pole
    # the header bounds reach the pole too: a coarse grid keeps the DEM small
    config = dict(inputs=(str(folder),), resolution=50_000.0, tile_size=50_000.0, out_crs="EPSG:2154")
    with pytest.raises(InputFileError, match=r"polar\.las: 3 of 2,000 points could not be transformed"):
        run(RunConfig(output=str(tmp_path / "a.zarr"), **config), progress=False)
    report = run(RunConfig(output=str(tmp_path / "b.zarr"), skip_bad_files=True, **config), progress=False)
    assert [f["path"] for f in report.skipped_files] == [str(bad)]
    assert report.points_kept == 2000
