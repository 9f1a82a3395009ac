"""The command line's contract: exit codes, one-line errors, quiet and JSON logs."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

import pipeline.runs.runner as runner
from pipeline.cli import main
from pipeline.tools.synthetic import SurveySpec, write_survey


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SurveySpec(points=20_000, files=2, width=200.0, height=120.0, seed=4))
    return folder


def _run(survey, out, *flags):
    return main(["run", str(survey), "-o", str(out), "--resolution", "4", "--tile-size", "64", *flags])


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "missing.laz"), "-o", str(tmp_path / "o.zarr"), "--resolution", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.laz" in err[0] and err[0].startswith("terrain: error:")
    assert main(["run", str(tmp_path / "missing.laz"), "-o", str(tmp_path / "o.zarr"), "--resolution", "1", "-v"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_quiet_prints_nothing_on_success(survey, tmp_path, capsys):
    assert _run(survey, tmp_path / "q.zarr", "-q") == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


def test_json_logs_are_one_object_per_line_ending_with_the_report(survey, tmp_path, capsys):
    assert _run(survey, tmp_path / "j.zarr", "--log-json") == 0
    captured = capsys.readouterr()
    assert captured.out == ""
    records = [json.loads(line) for line in captured.err.strip().splitlines()]
    assert all({"time", "level", "message"} <= set(r) for r in records)
    assert records[-1]["message"] == "run finished"
    assert records[-1]["report"]["points_read"] == 20_000


def test_a_failed_task_is_exit_1_with_one_line(survey, tmp_path, capsys, monkeypatch):
    def broken(job):
        raise RuntimeError("tile exploded")

    monkeypatch.setattr(runner, "mesh_tile", broken)
    assert _run(survey, tmp_path / "f.zarr", "--no-progress") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "terrain: error: RuntimeError: tile exploded (-v shows the traceback)"
    assert not any("Traceback" in line for line in err)


# Runs ``terrain`` with every DEM tile write slowed down and announced by a
# marker file, so the test interrupts the DEM stage for sure, however fast the
# machine finishes the rest of the job.
_SLOW_DEM = """
import pathlib, signal, sys, time
# Ctrl-C as a terminal's foreground job gets it: a runner started in the
# background (a shell's `&`) passes SIGINT on ignored, and Python keeps it so
signal.signal(signal.SIGINT, signal.default_int_handler)
from pipeline import cli
from pipeline.store import zarr_store as store
marker, real = pathlib.Path(sys.argv.pop(1)), store.write_tile
def slow(*args, **kwargs):
    marker.touch()
    time.sleep(1.0)
    return real(*args, **kwargs)
store.write_tile = slow
sys.exit(cli.main())
"""


def test_ctrl_c_is_exit_130_quiet_and_resumable(tmp_path):
    folder = tmp_path / "survey"
    write_survey(folder, SurveySpec(points=200_000, files=2, width=500.0, height=400.0, seed=9))
    out = tmp_path / "c.zarr"
    flags = ["run", str(folder), "-o", str(out), "--resolution", "1", "--tile-size", "50", "--no-progress"]
    meshed = tmp_path / ".c.zarr.work" / "records" / "mesh"
    marker = tmp_path / "dem-started"
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_DEM, str(marker), *flags], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    deadline = time.monotonic() + 300
    while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert marker.exists(), proc.communicate(timeout=60)[1]
    assert len(list(meshed.glob("*.json"))) == 99  # every one of the 9 x 11 tiles was meshed first
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err  # interrupted in the DEM stage
    lines = err.strip().splitlines()
    assert lines[-1] == "terrain: stopped; run the same command again to resume"
    assert not any("distributed" in line or "Traceback" in line for line in lines), err
    again = subprocess.run([sys.executable, "-m", "pipeline.cli", *flags], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert "resumed" in again.stdout


def test_a_full_disk_is_one_line_exit_1_and_resumable(survey, tmp_path, capsys, monkeypatch):
    import errno

    from pipeline.store import zarr_store as store

    real = store.write_tile
    calls = []

    def full(*args, **kw):
        calls.append(1)
        if len(calls) == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kw)

    monkeypatch.setattr(store, "write_tile", full)
    out = tmp_path / "full.zarr"
    assert _run(survey, out, "--no-progress") == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"terrain: error: {out}: cannot write tile") and "No space left on device" in err[-1]
    assert store.read_attrs(out)["complete"] is False
    monkeypatch.setattr(store, "write_tile", real)
    assert _run(survey, out, "--no-progress") == 0
    assert "resumed" in capsys.readouterr().out


def test_a_dem_above_max_cells_names_the_widest_input(tmp_path, capsys):
    folder = tmp_path / "pair"
    small, wide = write_survey(folder, SurveySpec(points=4_000, files=2, width=100.0, height=50.0, seed=2))
    import laspy  # stretch one file's points (and header) tenfold east: a wrong header or CRS looks like this

    las = laspy.read(wide)
    las.x = las.x.min() + (las.x - las.x.min()) * 10
    las.write(wide)
    code = main(["run", str(folder), "-o", str(tmp_path / "o.zarr"), "--resolution", "1", "--max-cells", "10000",
                 "--no-progress"])
    assert code == 2
    (line,) = [line for line in capsys.readouterr().err.splitlines() if line.startswith("terrain: error")]
    assert "above --max-cells 10,000" in line and f"the widest input is {wide}: x " in line


def _honest_and_lying_runs(tmp_path, spec, west: float):
    """A survey run as written and with its last file's header minimum x
    moved ``west`` metres: that file, and the two stores by name."""
    import shutil
    import struct

    honest = tmp_path / "honest"
    files = write_survey(honest, spec)
    lying = tmp_path / "lying"
    shutil.copytree(honest, lying)
    wrong = lying / files[-1].name
    data = bytearray(wrong.read_bytes())
    data[187:195] = struct.pack("<d", struct.unpack("<d", data[187:195])[0] - west)  # the header's min x
    wrong.write_bytes(data)
    stores = {}
    for name, folder in (("honest", honest), ("lying", lying)):
        stores[name] = tmp_path / f"{name}.zarr"
        assert main(["run", str(folder), "-o", str(stores[name]), "--resolution", "1", "--no-progress"]) == 0
    return wrong, stores


def test_a_header_claiming_far_more_than_its_points_is_measured_and_the_run_succeeds(tmp_path, capsys):
    """A header whose x minimum was mistyped 9,000 km west: the DEM it implies is
    over --max-cells, but the file's points are valid; the grid follows them."""
    import xarray as xr

    wrong, stores = _honest_and_lying_runs(tmp_path, SurveySpec(points=6_000, files=2, width=120.0, height=80.0, seed=4),
                                           9.0e6)
    out = capsys.readouterr().out
    assert f"note: {wrong}: header bounds x " in out and "reach far beyond its points" in out
    assert out.count("reach far beyond its points") == 1  # the honest files are left as they are
    with xr.open_zarr(stores["honest"]) as a, xr.open_zarr(stores["lying"]) as b:
        assert a.sizes == b.sizes
        assert a["elevation"].equals(b["elevation"])


def test_common_flags_before_a_workflow_action_count(tmp_path, capsys):
    missing = str(tmp_path / "missing.toml")
    assert main(["workflow", "--log-json", "status", missing]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert json.loads(line)["message"].endswith("cannot read the workflow file (No such file or directory)")
    assert main(["workflow", "status", "--log-json", missing]) == 2  # after the action too
    assert json.loads(capsys.readouterr().err.strip().splitlines()[-1])["level"] == "error"


def test_max_cells_takes_the_notation_its_help_shows():
    from pipeline.cli import _parser

    args = _parser().parse_args(["run", "a.laz", "-o", "o.zarr", "--resolution", "1", "--max-cells", "4e9"])
    assert args.max_cells == 4_000_000_000
    with pytest.raises(SystemExit):
        _parser().parse_args(["run", "a.laz", "-o", "o.zarr", "--resolution", "1", "--max-cells", "2.5"])


def test_an_unreachable_scheduler_leaves_nothing_behind(survey, tmp_path, capsys):
    out = tmp_path / "e.zarr"
    assert _run(survey, out, "--no-progress", "--scheduler", "tcp://127.0.0.1:1") == 2
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:1" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / ".e.zarr.work").exists()


def _seam_fault(job):
    """A tile that cannot be certified: only a bug does this."""
    from pipeline.errors import SeamError
    from pipeline.meshing.tiles import mesh_tile

    if (job.row, job.col) == (0, 1):
        raise SeamError(f"tile ({job.row}, {job.col}): its piece cannot be certified")
    return mesh_tile(job)


def test_a_tile_that_cannot_be_certified_fails_the_run_naming_it(survey, tmp_path, capsys, monkeypatch):
    from pipeline.store import zarr_store as store

    monkeypatch.setattr(runner, "mesh_tile", _seam_fault)
    out = tmp_path / "seam.zarr"
    assert _run(survey, out, "--no-progress") == 1
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and "tile (0, 1)" in err[0] and "certified" in err[0], err
    assert store.read_attrs(out)["complete"] is False


def test_a_header_kilometres_off_within_max_cells_is_measured_too(tmp_path, capsys, monkeypatch):
    """A header whose x minimum is 3 km off: the DEM fits --max-cells, but it
    would be 25 times wider than the survey and empty there.  The file's
    header holds its points far more thinly than the others': measured, and
    the grid follows the points.  The honest files are not read twice."""
    import xarray as xr

    from pipeline.inputs import sources

    measured = []
    measure = sources.measured_bounds
    monkeypatch.setattr(sources, "measured_bounds", lambda info: measured.append(info.path) or measure(info))
    wrong, stores = _honest_and_lying_runs(tmp_path, SurveySpec(points=9_000, files=3, width=120.0, height=80.0, seed=6),
                                           3000.0)
    out = capsys.readouterr().out
    assert f"note: {wrong}: header bounds x " in out and out.count("reach far beyond its points") == 1
    assert [str(p) for p in measured] == [str(wrong)]
    with xr.open_zarr(stores["honest"]) as a, xr.open_zarr(stores["lying"]) as b:
        assert a.sizes == b.sizes
        assert a["elevation"].equals(b["elevation"])


def test_a_bbox_or_extent_west_or_south_of_the_origin_is_read_as_coordinates(tmp_path):
    from pipeline.cli import _parser, _run_config, _with_attached_values

    argv = ["run", "in.las", "-o", str(tmp_path / "o.zarr"), "--resolution", "1",
            "--bbox", "-7481089.5,-20,-7479506,5", "--extent", "-.5e3,-2e3,0,0"]
    config = _run_config(_parser().parse_args(_with_attached_values(argv)))
    assert config.bbox == (-7481089.5, -20.0, -7479506.0, 5.0)
    assert config.extent == (-500.0, -2000.0, 0.0, 0.0)
    # a flag after --bbox is still a flag
    assert _with_attached_values(["run", "--bbox", "--resolution", "1"]) == ["run", "--bbox", "--resolution", "1"]


def test_override_crs_is_a_flag_that_replaces_a_job_files_in_crs(tmp_path):
    from pipeline.cli import _parser, _run_config, as_flags

    job = tmp_path / "job.toml"
    job.write_text('[run]\ninputs = ["a.laz"]\noutput = "o.zarr"\nresolution = 1.0\nin_crs = "EPSG:2154"\n')
    config = _run_config(_parser().parse_args(["run", "--config", str(job), "--override-crs", "EPSG:32612"]))
    assert (config.in_crs, config.override_crs) == (None, "EPSG:32612")
    config = _run_config(_parser().parse_args(["run", "--config", str(job)]))
    assert (config.in_crs, config.override_crs) == ("EPSG:2154", None)
    assert as_flags("its record is replaced by override_crs='WGS 84 / UTM zone 12N (EPSG:32612)'; give override_crs "
                    "the CRS") == "its record is replaced by --override-crs WGS 84 / UTM zone 12N (EPSG:32612); " \
                                  "give --override-crs the CRS"


def test_a_record_its_coordinates_contradict_is_one_line_exit_2_and_the_override_runs(tmp_path, capsys):
    """A survey in UTM zone 12N metres whose record says degrees: refused
    before any transform (never a message about an empty bbox), and run with
    --override-crs, which the report and the provenance record."""
    import pyproj

    from pipeline.store import zarr_store as store

    from .test_sources import write_las

    path = write_las(tmp_path / "degrees.las", n=3000, crs="EPSG:4326", origin=(515_368.0, 4_918_340.0),
                     classes=(2,)).path
    for flags in ([], ["--out-crs", "EPSG:32612"], ["--in-crs", "EPSG:32612"]):
        assert _run(path, tmp_path / "o.zarr", "--no-progress", *flags) == 2
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert line.startswith(f"terrain: error: {path}: its CRS record WGS 84 (EPSG:4326) is in degrees, but its "
                               "header bounds (x 515,368")
        assert line.endswith("if the record is wrong, give --override-crs the CRS the coordinates are in")
    out = tmp_path / "o.zarr"
    assert _run(path, out, "--no-progress", "--override-crs", "EPSG:32612") == 0
    assert f"note: {path}: its CRS record WGS 84 (EPSG:4326) is replaced by --override-crs WGS 84 / UTM zone 12N " \
           "(EPSG:32612)" in capsys.readouterr().out
    attrs = store.read_attrs(out)
    assert attrs["provenance"]["parameters"]["override_crs"] == "EPSG:32612"
    assert pyproj.CRS.from_wkt(attrs["provenance"]["crs_wkt"]).to_epsg() == 32612
    assert any(str(path) in note and "replaced by override_crs=" in note for note in attrs["report"]["notes"])


def test_the_smooth_surfaces_cost_in_the_help_is_the_docs():
    """``terrain run --help`` and docs/surfaces.md's "Which surface" give the same cost of ``--surface smooth``."""
    import re
    from pathlib import Path

    from pipeline.cli import _parser

    run = next(a for a in _parser()._subparsers._group_actions[0].choices["run"]._actions if "--surface" in a.option_strings)
    page = Path(__file__).resolve().parents[2] / "docs" / "surfaces.md"
    section = page.read_text().split("## Which surface", 1)[1].split("\n## ", 1)[0]
    ratio = r"(\d+(?:\.\d+)?)[-–](\d+(?:\.\d+)?)x"
    in_help = re.search(ratio, run.help)
    in_docs = re.search(ratio + r" the linear run", " ".join(section.split()))
    assert in_help and in_docs
    assert (float(in_help[1]), float(in_help[2])) == (float(in_docs[1]), float(in_docs[2]))


def test_every_parameter_of_a_run_is_a_flag_with_its_values(tmp_path):
    """The flags are RunConfig's fields: every parameter with a Flag can be set
    on the command line, an option offers exactly its enum's values, and the
    value reaches the config as that enum's member."""
    import dataclasses
    import enum
    import types
    import typing

    from pipeline.cli import _parser, _run_config
    from pipeline.config import RunConfig

    parser = _parser()
    run = next(a for a in parser._subparsers._group_actions[0].choices.items() if a[0] == "run")[1]
    by_dest = {a.dest: a for a in run._actions}
    hints = typing.get_type_hints(RunConfig)
    flagged = [f for f in dataclasses.fields(RunConfig) if "flag" in f.metadata]
    assert {f.name for f in flagged} == {f.name for f in dataclasses.fields(RunConfig)} - {"storage_options", "extra"}
    for f in flagged:
        assert f.name in by_dest, f.name
        hint = hints[f.name]  # X | None: X
        kind = next(a for a in typing.get_args(hint) if a is not type(None)) if isinstance(hint, types.UnionType) else hint
        if isinstance(kind, type) and issubclass(kind, enum.Enum):
            values = [m.value for m in kind]
            assert [c for c in by_dest[f.name].choices if c != "none"] == values, f.name
            for value in values:
                argv = ["run", "in.las", "-o", str(tmp_path / "o.zarr"), "--resolution", "1",
                        f"--{f.name.replace('_', '-')}", value]
                got = getattr(_run_config(parser.parse_args(argv)), f.name)
                assert got is kind(value), (f.name, value, got)
    argv = ["run", "in.las", "-o", str(tmp_path / "o.zarr"), "--resolution", "0.5", "--tile-size", "64",
            "--classes", "2,9", "--layers", "dsm,slope", "--quad-measure", "none", "--keep-withheld",
            "--workers", "3", "--zarr-format", "2"]
    config = _run_config(parser.parse_args(argv))
    assert (config.resolution, config.tile_size, config.classes, config.quad_measure) == (0.5, 64.0, (2, 9), None)
    assert config.layers == ("elevation", "slope", "dsm") and config.keep_withheld is True
    assert (config.workers, config.zarr_format) == (3, 2)


def test_a_bad_value_of_a_derived_flag_names_the_flag(tmp_path, capsys):
    code = main(["run", str(tmp_path / "in.las"), "-o", str(tmp_path / "o.zarr"), "--resolution", "1",
                 "--bbox", "1,2,3"])
    err = capsys.readouterr().err
    assert code == 2 and "--bbox" in err and err.count("\n") == 1
