"""Resuming stopped jobs: a failed or killed run, run again, gives the same store."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import pipeline.runs.runner as run_module
from pipeline.store import zarr_store as store
from pipeline.config import RunConfig
from pipeline.errors import UsageError
from pipeline.tools.synthetic import SurveySpec, write_survey

from .store_checks import assert_same_store

SPEC = SurveySpec(points=48_000, files=3, width=240.0, height=160.0, seed=11)


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SPEC)
    return folder


def _config(survey, out, **kw) -> RunConfig:
    values = dict(inputs=(str(survey),), output=str(out), resolution=2.0, tile_size=48.0, workers=2)
    values.update(kw)
    return RunConfig(**values)


def _stop_in_the_dem_stage(monkeypatch, config: RunConfig, at: int) -> None:
    """Run ``config`` until its ``at``-th DEM tile fails (a failed task), then undo the failure."""
    real = run_module.dem_tile
    calls = []

    def failing(job):
        calls.append(1)
        if len(calls) == at:
            raise RuntimeError("disk on fire")
        return real(job)

    monkeypatch.setattr(run_module, "dem_tile", failing)
    with pytest.raises(RuntimeError, match="disk on fire"):
        run_module.run(config, progress=False)
    monkeypatch.setattr(run_module, "dem_tile", real)


@pytest.fixture(scope="module")
def reference(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("reference") / "dem.zarr"
    run_module.run(_config(survey, out), progress=False)
    return out


def test_a_failed_run_resumes_where_it_stopped(survey, reference, tmp_path, monkeypatch):
    out = tmp_path / "dem.zarr"
    real_dem, real_mesh = run_module.dem_tile, run_module.mesh_tile
    calls = {"dem": 0, "mesh": 0}

    def failing_dem(job):
        calls["dem"] += 1
        if calls["dem"] == 6:
            raise RuntimeError("disk on fire")
        return real_dem(job)

    monkeypatch.setattr(run_module, "dem_tile", failing_dem)
    with pytest.raises(RuntimeError, match="disk on fire"):
        run_module.run(_config(survey, out), progress=False)
    assert store.read_attrs(out)["complete"] is False
    done = store.tiles_done(out)
    assert 0 < done.sum() < done.size

    def counting_mesh(job):
        calls["mesh"] += 1
        return real_mesh(job)

    monkeypatch.setattr(run_module, "dem_tile", real_dem)
    monkeypatch.setattr(run_module, "mesh_tile", counting_mesh)
    report = run_module.run(_config(survey, out), progress=False)
    assert calls["mesh"] == 0  # every tile was meshed before the failure
    assert any("resumed" in note for note in report.notes)
    assert report.points_read == SPEC.points
    assert_same_store(out, reference)
    assert not (tmp_path / ".dem.zarr.work").exists()


def test_one_store_spelt_two_ways_has_one_work_folder(tmp_path):
    from pipeline.tiling.checkpoint import work_dir_for

    for scratch in (None, str(tmp_path / "scratch")):
        spelt = work_dir_for(str(tmp_path / "jobs" / ".." / "out" / "a.zarr"), scratch)
        assert spelt == work_dir_for(str(tmp_path / "out" / "a.zarr"), scratch)


def test_where_the_work_folder_of_a_store_on_object_storage_goes(tmp_path, monkeypatch):
    from pipeline.tiling.checkpoint import work_dir_for

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # TMPDIR read again
    store = "s3://dems/2026/dem.zarr"
    # this machine's threads: on this machine; a cluster's workers: beside the store, which they all reach
    here = work_dir_for(store, None)
    assert here.startswith(str(tmp_path / "terrain-work" / ".dem.zarr-")) and here.endswith(".work")
    assert work_dir_for(store, None, cluster=True) == "s3://dems/2026/.dem.zarr.work"
    # a scratch folder given is used either way, on disk or on object storage
    for cluster in (False, True):
        inside = work_dir_for(store, "s3://scratch/jobs/", cluster=cluster)
        assert inside.startswith("s3://scratch/jobs/.dem.zarr-") and inside.endswith(".work")
        assert work_dir_for(store, str(tmp_path / "s"), cluster=cluster).startswith(str(tmp_path / "s" / ".dem.zarr-"))


def test_stores_of_one_name_share_a_scratch_folder_without_harm(survey, reference, tmp_path, monkeypatch):
    scratch = tmp_path / "scratch"
    a, b = tmp_path / "a" / "dem.zarr", tmp_path / "b" / "dem.zarr"
    _stop_in_the_dem_stage(monkeypatch, _config(survey, a, scratch_dir=str(scratch)), at=4)
    run_module.run(_config(survey, b, scratch_dir=str(scratch)), progress=False)  # must not reset a's work
    report = run_module.run(_config(survey, a, scratch_dir=str(scratch)), progress=False)
    assert any("resumed" in note for note in report.notes)
    assert_same_store(a, reference)
    assert_same_store(b, reference)


def test_a_complete_store_is_left_alone(survey, reference):
    before = {p: p.stat().st_mtime_ns for p in Path(reference).rglob("*") if p.is_file()}
    report = run_module.run(_config(survey, reference), progress=False)
    assert any("already complete" in note for note in report.notes)
    assert report.points_read == SPEC.points
    assert {p: p.stat().st_mtime_ns for p in Path(reference).rglob("*") if p.is_file()} == before


def test_paths_typed_from_another_folder_are_the_same_job(survey, reference, tmp_path, monkeypatch):
    # relative paths are made absolute: a rerun from elsewhere (or a worker
    # on a cluster, in its own folder) sees the same files and store
    monkeypatch.chdir(survey.parent)
    out = tmp_path / "rel.zarr"
    run_module.run(_config(Path(survey.name), os.path.relpath(out)), progress=False)
    monkeypatch.chdir(tmp_path)
    report = run_module.run(_config(Path(os.path.relpath(survey)), out.name), progress=False)
    assert any("already complete" in note for note in report.notes)
    inputs = store.read_attrs(out)["provenance"]["inputs"]
    assert inputs and all(Path(i["path"]).is_absolute() for i in inputs)
    assert_same_store(out, reference)


def test_other_parameters_are_an_error_naming_them(survey, reference):
    with pytest.raises(UsageError, match=r"other parameters \(triangle_measure: 's3' -> 's1'"):
        run_module.run(_config(survey, reference, triangle_measure="s1"), progress=False)


def test_changed_inputs_are_an_error(survey, tmp_path):
    folder = tmp_path / "survey"
    folder.mkdir()
    for p in Path(survey).glob("*.laz"):
        (folder / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "dem.zarr"
    run_module.run(_config(folder, out, tile_size=96.0), progress=False)
    first = sorted(folder.glob("*.laz"))[0]
    os.utime(first, (time.time() + 10, time.time() + 10))
    with pytest.raises(UsageError, match=f"inputs changed.*{first.name}"):
        run_module.run(_config(folder, out, tile_size=96.0), progress=False)
    run_module.run(_config(folder, out, tile_size=96.0, overwrite=True), progress=False)
    assert store.read_attrs(out)["complete"] is True


def _units_done(out: Path) -> int:
    """Units of work a stopped run leaves recorded: the work folder's records
    (files routed, tiles meshed and renumbered, mesh blocks written) and the
    tiles the store marks written."""
    records = out.with_name(f".{out.name}.work") / "records"
    return len(list(records.glob("*/*.json"))) + len(list((out / "status" / "tile_done" / "c").glob("*/*")))


def test_runs_killed_at_random_moments_resume_to_the_same_store(survey, reference, tmp_path):
    out = tmp_path / "dem.zarr"
    command = [
        sys.executable, "-m", "pipeline.cli", "run", str(survey), "-o", str(out),
        "--resolution", "2", "--tile-size", "48", "--workers", "2", "--no-progress",
    ]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    rng = np.random.default_rng(7)
    # kill moments are drawn in units of work, not seconds, so that every
    # stage can be hit however fast the machine is: a file routed, a tile
    # meshed, a tile written, a tile renumbered (blocks and the store come on top)
    tiles = int(np.asarray(store.tiles_done(reference)).size)
    units = SPEC.files + 3 * tiles
    targets = np.sort(rng.choice(np.arange(1, units - 2), size=5, replace=False))
    kills = []
    for target in targets.tolist():
        proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 300  # a run that stops making progress is killed too, and fails below
        while proc.poll() is None and _units_done(out) < target and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.02))  # anywhere in the next unit, a write included
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            kills.append(_units_done(out))
        proc.wait()
    # a run stopped before its last units of work cannot have finished
    assert len(kills) == len(targets) and all(k >= t for k, t in zip(kills, targets)), (targets, kills)
    final = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert final.returncode == 0, final.stderr
    assert_same_store(out, reference)


def test_a_second_run_on_a_store_in_use_stops_at_once(survey, tmp_path):
    from pipeline.tiling.checkpoint import output_lock

    out = tmp_path / "busy.zarr"
    with output_lock(str(out)):  # as another process's run holds it
        with pytest.raises(UsageError, match=r"busy.zarr: another run is writing this store"):
            run_module.run(_config(survey, out), progress=False)
        assert not out.exists()
    run_module.run(_config(survey, out), progress=False)  # released: the run goes on
    assert not (tmp_path / ".busy.zarr.lock").exists()


def test_a_work_folder_left_after_the_store_was_complete_is_removed(survey, reference, tmp_path):
    out = tmp_path / "done.zarr"
    run_module.run(_config(survey, out), progress=False)
    left = tmp_path / ".done.zarr.work" / "records"
    left.mkdir(parents=True)  # as a run killed just after marking the store complete leaves it
    report = run_module.run(_config(survey, out), progress=False)
    assert any("already complete" in note for note in report.notes)
    assert not (tmp_path / ".done.zarr.work").exists()


def test_a_full_disk_under_the_work_files_is_one_line_and_resumes(survey, reference, tmp_path, monkeypatch):
    import errno

    from pipeline.tiling import routing as tiling
    from pipeline.errors import OutputWriteError

    out = tmp_path / "full.zarr"
    real = tiling.TileSpiller.flush

    def full(self):  # np.save into a file object: the OSError names no file
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tiling.TileSpiller, "flush", full)
    with pytest.raises(OutputWriteError, match=r"full.zarr: cannot write the store or its work files \(No space left"):
        run_module.run(_config(survey, out), progress=False)
    assert store.read_attrs(out)["complete"] is False
    monkeypatch.setattr(tiling.TileSpiller, "flush", real)
    report = run_module.run(_config(survey, out), progress=False)
    assert report.points_read == SPEC.points
    assert_same_store(out, reference)


def test_a_short_write_of_a_work_file_on_a_full_disk_is_a_full_disk(survey, reference, tmp_path, monkeypatch):
    """numpy reports a write that stopped short with no errno ("56 requested
    and 0 written"): the file system's free space says the disk is full, and
    the run says so, as for any full disk."""
    import os
    from types import SimpleNamespace

    import numpy as np

    from pipeline.tiling import scratch
    from pipeline.errors import OutputWriteError

    out = tmp_path / "short.zarr"
    real_save, real_statvfs = np.save, os.statvfs

    def short(handle, value, *args, **kwargs):
        raise OSError(f"{value.nbytes} requested and 0 written")

    monkeypatch.setattr(scratch.np, "save", short)
    monkeypatch.setattr(scratch.os, "statvfs", lambda path: SimpleNamespace(f_bavail=0, f_frsize=4096))
    with pytest.raises(OutputWriteError, match=r"cannot write the store or its work files \(No space left on device \(0 bytes free"):
        run_module.run(_config(survey, out), progress=False)
    assert store.read_attrs(out)["complete"] is False
    monkeypatch.setattr(scratch.np, "save", real_save)
    monkeypatch.setattr(scratch.os, "statvfs", real_statvfs)
    run_module.run(_config(survey, out), progress=False)
    assert_same_store(out, reference)


def test_units_whose_work_files_were_lost_are_done_again(survey, reference, tmp_path, monkeypatch):
    import shutil

    out = tmp_path / "lost.zarr"
    _stop_in_the_dem_stage(monkeypatch, _config(survey, out), at=3)
    # a cleaner removes a tile's piece and one routed file's spill in another tile
    work = tmp_path / ".lost.zarr.work" / "tiles"
    shutil.rmtree(work / "00001_00002" / "piece")
    next((work / "00000_00001").glob("000001_*.npy")).unlink()
    report = run_module.run(_config(survey, out), progress=False)
    assert any("2 finished unit(s) had lost files in the work folder" in note for note in report.notes), report.notes
    assert_same_store(out, reference)
