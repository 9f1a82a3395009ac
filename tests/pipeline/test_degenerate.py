"""Archives that hold no surface: empty files, one point, all duplicates, all
collinear, coordinates at the edge of the LAS integer range."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
import xarray as xr
from pyproj import CRS

from pipeline.cli import main


UTM_31N = 32631
"""The record of these surveys: near (500 000, 4 000 000) its coordinates lie
in Algeria, inside its band (a run refuses a record its coordinates contradict)."""


def _write(path, x, y, z, scale=0.01, offset=(500_000.0, 4_000_000.0, 0.0), epsg=UTM_31N):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale, scale, scale])
    header.offsets = np.array(offset)
    header.add_crs(CRS.from_epsg(epsg))
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
    # in ETRS89-LAEA Europe (EPSG:3035), whose false origin makes them a place west of Ireland
    path = _write(tmp_path / "edge.laz", x, y, rng.random(3000), scale=scale, offset=(600_000.0, 6_000_000.0, 0.0),
                  epsg=3035)
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


def _lying_min_y(path, value: float) -> None:
    """Overwrite the header's minimum y (a double at byte 203 of every LAS/LAZ header)."""
    import struct

    with open(path, "r+b") as handle:
        handle.seek(203)
        handle.write(struct.pack("<d", value))


def test_a_header_spanning_far_beyond_its_points_gets_tiles_of_bounded_chunks(tmp_path, capsys):
    # a fuzzed header once said min y = -1 for points near y = 6.86e6: the
    # grid spans 3.4 million rows, and tiles sized from the density were
    # 41,344 cells wide, chunks of 6.8 GB that no codec writes
    from pipeline.runs.plan import LARGEST_TILE_CELLS, MAX_AUTO_TILE_CELLS, plan_run
    from pipeline.config import RunConfig
    from pipeline.errors import UsageError
    from pipeline.tools.synthetic import SurveySpec, write_survey

    paths = write_survey(tmp_path / "survey", SurveySpec(points=12_000, files=2, width=120.0, height=80.0, seed=3))
    for path in paths:  # every header: one file's lie alone is measured from its points (test_cli)
        _lying_min_y(path, -1.0)
    config = RunConfig(inputs=(str(tmp_path / "survey"),), output=str(tmp_path / "o.zarr"), resolution=2.0)
    plan = plan_run(config)
    assert plan.grid.ny > 3_000_000 and plan.grid.tile_cells == MAX_AUTO_TILE_CELLS
    # a tile size asked for: refused when a chunk could not be written, in the words of each interface
    too_big = (LARGEST_TILE_CELLS + 16) * 2.0
    with pytest.raises(UsageError, match="tile_size .* at most"):
        plan_run(RunConfig(inputs=config.inputs, output=config.output, resolution=2.0, tile_size=too_big))
    assert main(["run", str(tmp_path / "survey"), "-o", str(tmp_path / "o.zarr"), "--resolution", "2",
                 "--tile-size", str(too_big), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--tile-size" in err and not (tmp_path / "o.zarr").exists()


def test_a_tile_size_far_too_small_for_the_points_gets_a_note_in_the_words_of_each_interface(tmp_path):
    from pipeline.cli import as_flags
    from pipeline.config import RunConfig
    from pipeline.runs.plan import SMALL_TILE_POINTS, plan_run
    from pipeline.tools.synthetic import SurveySpec, write_survey

    write_survey(tmp_path / "survey", SurveySpec(points=12_000, files=2, width=120.0, height=80.0, seed=3))

    def notes(tile_size):
        config = RunConfig(inputs=(str(tmp_path / "survey"),), output=str(tmp_path / "o.zarr"), resolution=0.5,
                           tile_size=tile_size)
        plan = plan_run(config)
        return plan.grid.n_tiles, [n for n in plan.notes if "tiles of about" in n]

    tiles, small = notes(5.0)  # 16 x 24 tiles of about 30 points
    assert tiles >= 300 and len(small) == 1
    assert small[0].startswith(f"tile_size=5 cuts the survey into {tiles:,} tiles of about ")
    assert as_flags(small[0]).startswith("--tile-size 5 cuts the survey")
    tiles, small = notes(60.0)  # 2 x 2 tiles of 3,000 points
    assert 12_000 / tiles >= SMALL_TILE_POINTS and small == []
    assert notes(None)[1] == []  # a size chosen from the density is never too small


def test_a_tile_size_that_is_no_whole_multiple_of_the_resolution_is_rounded_with_a_note(tmp_path):
    from pipeline.cli import as_flags
    from pipeline.config import RunConfig
    from pipeline.runs.plan import plan_run
    from pipeline.tools.synthetic import SurveySpec, write_survey

    write_survey(tmp_path / "survey", SurveySpec(points=12_000, files=2, width=120.0, height=80.0, seed=3))

    def planned(tile_size):
        plan = plan_run(RunConfig(inputs=(str(tmp_path / "survey"),), output=str(tmp_path / "o.zarr"), resolution=2.0,
                                  tile_size=tile_size))
        return plan.grid.tile_cells, [n for n in plan.notes if "whole multiple" in n]

    cells, notes = planned(37.0)  # 18.5 cells: 19
    assert cells == 19 and len(notes) == 1
    assert notes[0] == ("tile_size=37 is not a whole multiple of resolution=2: the tiles are 19 cells (38) a side "
                        "(the results do not depend on the tiles)")
    assert as_flags(notes[0]).startswith("--tile-size 37 is not a whole multiple of --resolution 2: ")
    assert planned(0.4) == (1, [planned(0.4)[1][0]]) and "1 cells (2)" in planned(0.4)[1][0]  # at least one cell
    assert planned(38.0) == (19, [])  # a whole multiple: no note


def _classed(path, n, classes, seed=0):
    """``n`` points of a gentle slope on 40 x 40 m, cut at the LAS scale, of ``classes`` drawn in turn."""
    rng = np.random.default_rng(seed)
    x = np.round(500_000 + rng.random(n) * 40, 2)
    y = np.round(4_000_000 + rng.random(n) * 40, 2)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 4_000_000.0, 0.0])
    header.add_crs(CRS.from_epsg(UTM_31N))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.round(100.0 + 0.05 * (x - 500_000) + 0.02 * (y - 4_000_000), 2)
    las.classification = np.resize(np.asarray(classes, dtype=np.uint8), n)
    las.write(path)
    return path


def test_a_survey_never_classified_gives_a_surface_of_its_classified_ground(tmp_path, capsys):
    from pipeline import RunConfig, run
    from pipeline.store import zarr_store as store

    # classes 0 and 1 (never classified, unassigned) and noise: no ground anywhere
    folder = tmp_path / "survey"
    folder.mkdir()
    _classed(folder / "a.laz", 3000, [0, 1, 1, 0, 7])
    _classed(folder / "b.laz", 2000, [1, 18, 1, 1], seed=1)
    out = tmp_path / "o.zarr"
    assert _run(folder, out) == 0
    said = capsys.readouterr().out
    assert "no input point(s) of the default classes (2, ground)" in said and "every point but noise" in said
    report = store.read_attrs(out)["report"]
    noise = 3000 // 5 + 2000 // 4
    assert report["points_read"] == 5000 and report["filtered_class"] == noise
    # a gentle plane: the ground stage takes nearly every point for ground, and counts the others
    assert report["points_kept"] + report["not_ground"] == 5000 - noise
    assert report["points_kept"] > 0.95 * (5000 - noise)
    attrs = store.read_attrs(out)
    assert attrs["provenance"]["ground_classification"]["method"] == "smrf-tin"
    assert attrs["provenance"]["ground_classification"]["parameters"]["max_window"] == 50.0
    assert attrs["complete"] is True
    assert 7 not in attrs["provenance"]["classes_kept"]["classes"] and 1 in attrs["provenance"]["classes_kept"]["classes"]
    elevation = xr.open_zarr(out)["elevation"].values
    assert np.isfinite(elevation).sum() > 1000
    # the same job again: the store is complete, nothing is routed again
    again = run(RunConfig(inputs=(str(folder),), output=str(out), resolution=1.0))
    assert "the store was already complete: nothing was recomputed" in again.notes
    assert again.points_kept == report["points_kept"]


def test_the_fallback_note_counts_the_ground_points_that_returns_left_out(tmp_path, capsys):
    from pipeline.store import zarr_store as store

    # ground only as the last of two returns, low vegetation (on the plane) as single returns:
    # --returns first keeps no point of class 2, and the ground is classified from the others
    path = _classed(tmp_path / "a.laz", 3000, [2, 3])
    las = laspy.read(path)
    ground = np.asarray(las.classification) == 2
    las.number_of_returns = np.where(ground, 2, 1).astype(np.uint8)
    las.return_number = np.where(ground, 2, 1).astype(np.uint8)
    las.write(path)
    out = tmp_path / "o.zarr"
    assert _run(path, out, "--returns", "first") == 0
    said = capsys.readouterr().out
    assert ("no input point(s) of the default classes (2, ground) kept, 1,500 more left out by --returns first: "
            "the ground was classified") in said, said
    why = store.read_attrs(out)["provenance"]["classes_kept"]["why"]
    assert why == "no input point(s) of the default classes (2, ground) kept, 1,500 more left out by returns=first"


def test_a_survey_never_classified_with_layers_gives_a_surface_of_its_classified_ground(tmp_path, capsys):
    from pipeline.store import zarr_store as store

    # no noise, so no point is left out by class: the DSM reads every one, and there is still no ground
    path = _classed(tmp_path / "a.laz", 3000, [0, 1, 1])
    out = tmp_path / "o.zarr"
    assert _run(path, out, "--layers", "dsm,chm") == 0
    assert "no input point(s) of the default classes (2, ground)" in capsys.readouterr().out
    report = store.read_attrs(out)["report"]
    assert report["filtered_class"] == 0 and report["points_kept"] + report["not_ground"] == 3000
    chm = xr.open_zarr(out)["chm"].values
    assert np.isfinite(chm).sum() > 1000 and np.nanmax(np.abs(chm)) < 0.5  # a bare plane: nothing stands on it


def test_ground_anywhere_keeps_only_ground_and_other_chosen_classes_stay_an_error(tmp_path, capsys):
    from pipeline.store import zarr_store as store

    folder = tmp_path / "survey"
    folder.mkdir()
    _classed(folder / "ground.laz", 3000, [2, 1, 5])
    _classed(folder / "unclassified.laz", 3000, [1], seed=1)
    out = tmp_path / "o.zarr"
    assert _run(folder, out) == 0
    assert "every point but noise" not in capsys.readouterr().out
    report = store.read_attrs(out)["report"]
    assert report["points_kept"] == 1000 and report["filtered_class"] == 5000
    assert "classes_kept" not in store.read_attrs(out)["provenance"]
    # classes chosen by the user are kept to, even when none of them is there
    assert _run(folder / "unclassified.laz", tmp_path / "b.zarr", "--classes", "6") == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("unclassified.laz: no surface: none of the 3,000 point(s) read is kept: 3,000 not of the "
                        "classes kept (6)"), err


def test_a_run_stopped_while_routing_a_survey_without_ground_again_resumes_with_every_class(tmp_path, monkeypatch):
    from pipeline import RunConfig, run
    from pipeline.runs import runner

    folder = tmp_path / "survey"
    folder.mkdir()
    _classed(folder / "a.laz", 3000, [1, 1, 7])
    _classed(folder / "b.laz", 3000, [0], seed=1)
    real = runner.route_source

    def stopped(job):
        if job.classes != (2,) and job.path.endswith("b.laz"):  # routing again, every class but noise
            raise RuntimeError("power cut")
        return real(job)

    monkeypatch.setattr(runner, "route_source", stopped)
    config = RunConfig(inputs=(str(folder),), output=str(tmp_path / "o.zarr"), resolution=1.0, workers=1)
    with pytest.raises(Exception, match="power cut"):
        run(config, progress=False)
    monkeypatch.setattr(runner, "route_source", real)
    resumed = run(config, progress=False)
    assert any("resum" in n for n in resumed.notes), resumed.notes
    assert resumed.points_kept + resumed.not_ground == 6000 - 1000 and resumed.filtered_class == 1000
    whole = run(RunConfig(inputs=(str(folder),), output=str(tmp_path / "w.zarr"), resolution=1.0), progress=False)
    assert whole.points_kept == resumed.points_kept
    a, b = (xr.open_zarr(tmp_path / name)["elevation"].values for name in ("o.zarr", "w.zarr"))
    np.testing.assert_array_equal(a, b)


def test_two_ground_points_in_an_unclassified_survey_are_too_few_and_every_class_is_meshed(tmp_path, capsys):
    from pipeline.store import zarr_store as store

    path = _classed(tmp_path / "a.laz", 4000, [2, 2] + [1] * 3998)
    out = tmp_path / "o.zarr"
    assert _run(path, out) == 0
    said = capsys.readouterr().out
    assert "only 2 input point(s) of the default classes (2, ground), too few or all on one line" in said, said
    report = store.read_attrs(out)["report"]
    assert report["points_kept"] + report["not_ground"] == 4000 and report["filtered_class"] == 0
    assert store.read_attrs(out)["provenance"]["classes_kept"]["why"].startswith("only 2 input point(s)")


@pytest.mark.parametrize("policy", ["lowest", "highest", "mean", "first"])
def test_each_duplicate_policy_gives_float_heights_for_no_point_and_for_duplicates(policy):
    from pipeline.meshing.tiles import vertex_z

    empty = vertex_z(np.empty(0, dtype=np.int64), 0, np.empty(0), policy)
    assert empty.dtype == np.float64 and empty.shape == (0,)
    z = vertex_z(np.array([0, 1, 1, 2, 1]), 3, np.array([5.0, 1.0, 4.0, 2.0, 7.0]), policy)
    expected = {"lowest": [5.0, 1.0, 2.0], "highest": [5.0, 7.0, 2.0], "mean": [5.0, 4.0, 2.0], "first": [5.0, 1.0, 2.0]}
    np.testing.assert_array_equal(z, expected[policy])


def test_mean_of_duplicates_in_a_survey_whose_first_pass_has_empty_tiles(tmp_path):
    # no ground: the first pass meshes empty tiles, then every class but noise
    path = _classed(tmp_path / "a.laz", 3000, [1, 0])
    assert _run(path, tmp_path / "o.zarr", "--duplicates", "mean", "--tile-size", "10") == 0
    assert np.isfinite(xr.open_zarr(tmp_path / "o.zarr")["elevation"].values).sum() > 1000


def test_a_bbox_over_a_file_without_any_vlr_reads_it_as_plain_las(tmp_path):
    from pipeline import RunConfig, run

    rng = np.random.default_rng(5)
    header = laspy.LasHeader(point_format=3, version="1.2")  # no CRS: not a single VLR
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([500_000.0, 4_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y = 500_000 + rng.random(2000) * 40, 4_000_000 + rng.random(2000) * 40
    las.z, las.classification = rng.random(2000), np.full(2000, 2, dtype=np.uint8)
    las.write(tmp_path / "bare.las")
    assert not laspy.read(tmp_path / "bare.las").header.vlrs
    report = run(RunConfig(inputs=(str(tmp_path / "bare.las"),), output=str(tmp_path / "o.zarr"), resolution=1.0,
                           in_crs="EPSG:2154", bbox=(500_000.0, 4_000_000.0, 500_020.0, 4_000_040.0)), progress=False)
    assert report.points_read == 2000 and 0 < report.points_kept < 2000
    assert report.points_kept + report.outside_bbox == 2000


def test_a_max_edge_shorter_than_every_face_says_why_the_dem_is_empty(tmp_path, capsys):
    from pipeline import RunConfig, run

    path = _classed(tmp_path / "a.laz", 300, [2])  # 300 points on 40 x 40 m: faces of about 2 m
    report = run(RunConfig(inputs=(str(path),), output=str(tmp_path / "o.zarr"), resolution=1.0, max_edge=0.05),
                 progress=False)
    assert report.faces > 0
    assert not np.isfinite(xr.open_zarr(tmp_path / "o.zarr")["elevation"].values).any()
    assert any("the DEM is empty: no cell centre lies under a face no longer than max_edge=0.05" in n for n in report.notes)
    assert _run(path, tmp_path / "c.zarr", "--max-edge", "0.05") == 0
    assert "no longer than --max-edge 0.05; finer cells, or a larger --max-edge, give some" in capsys.readouterr().out
    # with a larger one, cells have values and no such note is given
    report = run(RunConfig(inputs=(str(path),), output=str(tmp_path / "p.zarr"), resolution=1.0, max_edge=10.0),
                 progress=False)
    assert not any("the DEM is empty" in n for n in report.notes)


def test_a_bbox_holding_no_ground_of_a_survey_with_some_says_so_in_its_note(tmp_path):
    from pipeline import RunConfig, run

    folder = tmp_path / "survey"
    folder.mkdir()
    _classed(folder / "ground.laz", 2000, [2])  # ground on 40 x 40 m
    far = _classed(folder / "roofs.laz", 2000, [6], seed=1)  # buildings, 1 km east
    las = laspy.read(far)
    las.x = np.asarray(las.x) + 1000.0
    las.write(far)
    report = run(RunConfig(inputs=(str(folder),), output=str(tmp_path / "o.zarr"), resolution=1.0,
                           bbox=(500_990.0, 3_999_990.0, 501_050.0, 4_000_050.0)), progress=False)
    assert report.points_kept + report.not_ground == 2000 and report.outside_bbox == 2000
    assert any(n.startswith("no input point(s) of the default classes (2, ground) inside the bbox:") for n in report.notes)


@pytest.mark.parametrize("classify", [False, True])
def test_a_survey_of_noise_or_withheld_points_names_why_nothing_was_kept(tmp_path, capsys, classify):
    noise = _classed(tmp_path / "noise.laz", 2000, [7, 18])
    withheld = _classed(tmp_path / "withheld.laz", 2000, [2, 1], seed=1)
    las = laspy.read(withheld)
    las.withheld = np.ones(len(las.points), dtype=bool)
    las.write(withheld)
    flags = ("--classify-ground",) if classify else ()
    assert _run(noise, tmp_path / "a.zarr", "--layers", "dsm,density", *flags) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("noise.laz: no surface: none of the 2,000 point(s) read is kept: 2,000 not of the classes "
                        "kept (every class but noise)"), err
    assert _run(withheld, tmp_path / "b.zarr", *flags) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("withheld.laz: no surface: none of the 2,000 point(s) read is kept: 2,000 withheld "
                        "(--keep-withheld keeps them)"), err
    assert _run(withheld, tmp_path / "c.zarr", "--keep-withheld", *flags) == 0


def test_no_surface_names_every_fate_of_the_points_read():
    from pipeline.runs.runner import RunReport, _no_surface

    # read = kept + every fate: with none kept, the reasons count every point read
    report = RunReport(points_read=10, filtered_class=3, filtered_withheld=2, not_ground=5)
    assert _no_surface(report, "2") == ("none of the 10 point(s) read is kept: 3 not of the classes kept (2), "
                                        "2 withheld (keep_withheld=True keeps them), 5 classified not ground")
