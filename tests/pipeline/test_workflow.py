"""Incremental workflows: only the tiles touched by changed files are computed again."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.errors import UsageError
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey
from pipeline.runs.workflow import Workflow, run_workflow, workflow_status
from pipeline.store.zarr_store import read_attrs
from pipeline.tiling.grid import TileGrid

from .store_checks import assert_same_store

ORIGIN = (651000.0, 6861000.0)
JOB = """
[workflow]
name = "nightly test"
inputs = ["archive/*.laz"]
output = "out/archive.zarr"

[run]
resolution = 2.0
tile_size = 40.0
buffer = 6.0
layers = ["slope"]
"""


def _patch(archive: Path, name: str, corner: tuple[float, float], seed: int, size: float = 50.0) -> Path:
    """A dense survey patch inside the base survey, as archive/NAME.laz."""
    spec = SurveySpec(
        origin=(ORIGIN[0] + corner[0], ORIGIN[1] + corner[1]), width=size, height=size,
        points=6000, files=1, overlap=0.0, seed=seed,
    )
    tmp = archive.parent / f"tmp_{name}"
    (path,) = write_survey(tmp, spec)
    target = archive / f"{name}.laz"
    shutil.move(path, target)
    shutil.rmtree(tmp)
    return target


@pytest.fixture
def job(tmp_path):
    archive = tmp_path / "archive"
    base = SurveySpec(origin=ORIGIN, width=240.0, height=160.0, points=24_000, files=2, seed=1)
    write_survey(archive, base)
    _patch(archive, "patch_a", (20.0, 20.0), seed=2)
    _patch(archive, "patch_b", (150.0, 90.0), seed=3)
    path = tmp_path / "nightly.toml"
    path.write_text(JOB)
    return path


def _chunk_times(path: Path) -> dict[str, int]:
    folder = Path(path) / "elevation"
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file() and p.name != "zarr.json"}


def _spy_tile_writes(monkeypatch) -> list[tuple[int, int]]:
    """The tiles whose DEM the runs of this process write from now on (a run without a scheduler uses threads)."""
    from pipeline.store import zarr_store

    written: list[tuple[int, int]] = []
    real = zarr_store.write_tile

    def spy(path, grid, row, col, layers, **kwargs):
        written.append((row, col))
        return real(path, grid, row, col, layers, **kwargs)

    monkeypatch.setattr(zarr_store, "write_tile", spy)
    return written


def _chunks_holding(path: Path, tiles) -> set[str]:
    """The elevation chunk files (as :func:`_chunk_times` names them) that hold
    cells of these tiles: the store's chunk rows count from the north edge,
    tile rows from the south, so a tile's cells may lie in two chunk rows."""
    grid = TileGrid.from_dict(read_attrs(path)["grid"])
    t = grid.tile_cells
    out = set()
    for row, col in tiles:
        r0, r1, _, _ = grid.cell_slice(row, col)
        out.update(f"c/{i}/{col}" for i in range((grid.ny - r1) // t, (grid.ny - r0 - 1) // t + 1))
    return out


def _full_run(workflow: Workflow, out: Path) -> Path:
    values = workflow.config.to_dict() | {"output": str(out), "overwrite": True}
    run(RunConfig.from_dict(values), progress=False)
    return out


def test_only_tiles_touched_by_changed_files_are_recomputed(job, tmp_path, monkeypatch):
    workflow = Workflow.load(job)
    assert workflow.config.output == str(tmp_path / "out" / "archive.zarr")
    assert workflow_status(workflow)["state"] == "never run"
    run_workflow(workflow, progress=False)
    status = workflow_status(workflow)
    assert status["state"] == "complete" and status["files_known"] == 4 and status["tiles_pending"] == 0
    before = _chunk_times(workflow.config.output)

    archive = tmp_path / "archive"
    time.sleep(0.01)
    _patch(archive, "patch_a", (20.0, 20.0), seed=20)  # changed content, same place
    (archive / "patch_b.laz").unlink()  # removed
    _patch(archive, "patch_c", (160.0, 20.0), seed=4)  # new
    status = workflow_status(workflow)
    assert status["new_files"] == [str(archive / "patch_c.laz")]
    assert status["changed_files"] == [str(archive / "patch_a.laz")]
    assert status["removed_files"] == [str(archive / "patch_b.laz")]
    total = status["tiles_total"]
    assert 0 < status["tiles_pending"] < total

    written = _spy_tile_writes(monkeypatch)
    report = run_workflow(workflow, progress=False)
    assert any("inputs changed" in note for note in report.notes), report.notes
    # the status counted the tiles with the run's own decision
    assert any(f"{status['tiles_pending']} of {total} tile(s) computed again" in n for n in report.notes), report.notes
    after = _chunk_times(workflow.config.output)
    untouched = {k for k in before if after.get(k) == before[k]}
    # near tiles' DEM was written again (a tile's faces now read the flips of its whole held
    # region, so on this small survey the faces reaching a recomputed tile's cells span it all)
    assert len(set(written)) > 0
    assert untouched == set(before) - _chunks_holding(Path(workflow.config.output), written)  # nor their chunks
    assert report.points_read == 24_000 + 2 * 6000
    # the same store as a full run over the archive as it is now
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))
    assert workflow_status(workflow)["tiles_pending"] == 0

    # a file touched but not changed (same bytes) costs nothing
    settled = _chunk_times(workflow.config.output)
    stamp = time.time() + 5
    os.utime(archive / "patch_c.laz", (stamp, stamp))
    status = workflow_status(workflow)  # status decides as the run does
    assert status["changed_files"] == [] and status["tiles_pending"] == 0
    report = run_workflow(workflow, progress=False)
    assert any("0 of" in note for note in report.notes), report.notes
    assert _chunk_times(workflow.config.output) == settled
    assert_same_store(Path(workflow.config.output), tmp_path / "full.zarr")


def test_cli_workflow_run_and_status(job, capsys, tmp_path):
    assert main(["workflow", "status", str(job)]) == 0
    assert "never run" in capsys.readouterr().out
    early = tmp_path / "early.toml"  # a job whose archive is not there yet: a status, not an error
    early.write_text(JOB.replace("archive/*.laz", "later/*.laz"))
    assert main(["workflow", "status", str(early)]) == 0
    assert "later/*.laz: no .las/.laz file matches this pattern" in capsys.readouterr().out
    assert main(["workflow", "run", str(job), "--no-progress"]) == 0
    assert "points read" in capsys.readouterr().out
    assert main(["workflow", "status", str(job), "--json"]) == 0
    assert '"tiles_pending": 0' in capsys.readouterr().out


def test_bad_workflow_files_are_one_line_errors(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[workflow]\ninputs = ['x/*.laz']\n")
    with pytest.raises(UsageError, match="needs 'output'"):
        Workflow.load(bad)
    bad.write_text("[workflow]\ninputs = ['x']\noutput = 'o.zarr'\n[run]\nresolution = 1\noutput = 'p'\n")
    with pytest.raises(UsageError, match="belongs in \\[workflow\\]"):
        Workflow.load(bad)
    bad.write_text("[workflow]\ninputs = ['x']\noutput = 'o.zarr'\n[run]\nresolution = 1\noverwrite = true\n")
    with pytest.raises(UsageError, match="'overwrite' has no place in a workflow"):
        Workflow.load(bad)
    assert main(["workflow", "run", str(tmp_path / "missing.toml")]) == 2
    assert "cannot read the workflow file" in capsys.readouterr().err


def test_shipped_examples_load(monkeypatch):
    monkeypatch.setenv("TERRAIN_DATA", "/data")
    monkeypatch.setenv("TERRAIN_BUCKET", "terrain")  # docker-compose.yml's s3 profile sets it
    folder = Path(__file__).parents[2] / "workflows"
    jobs = sorted(folder.glob("*.toml"))
    assert len(jobs) >= 2
    for path in jobs:
        workflow = Workflow.load(path)
        assert workflow.config.tile_size and workflow.config.buffer  # written down (unset, the first run's are kept)


def test_unset_variables_in_paths_are_named(tmp_path, monkeypatch):
    monkeypatch.delenv("NO_SUCH_VARIABLE", raising=False)
    job = tmp_path / "job.toml"
    job.write_text("[workflow]\ninputs = ['$NO_SUCH_VARIABLE/x']\noutput = 'o.zarr'\n[run]\nresolution = 1\n")
    with pytest.raises(UsageError, match="NO_SUCH_VARIABLE.*not set"):
        Workflow.load(job)


def test_status_sees_a_new_file_that_moves_the_grid(job, tmp_path):
    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    _patch(tmp_path / "archive", "beyond", (-60.0, 40.0), seed=5)  # west of the old extent
    status = workflow_status(workflow)
    assert status["new_files"] == [str(tmp_path / "archive" / "beyond.laz")]
    assert str(status["tiles_pending"]).startswith("all")
    report = run_workflow(workflow, progress=False)
    assert any("grew south or west of the grid's origin" in note for note in report.notes), report.notes
    assert workflow_status(workflow)["tiles_pending"] == 0


def test_status_skips_a_bad_new_file_as_the_run_does(job, tmp_path):
    job.write_text(job.read_text().replace("[run]\n", "[run]\nskip_bad_files = true\n"))
    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    good = tmp_path / "archive" / "patch_a.laz"
    (tmp_path / "archive" / "broken.laz").write_bytes(good.read_bytes()[:400])  # a truncated delivery
    status = workflow_status(workflow)
    assert status["new_files"] == [str(tmp_path / "archive" / "broken.laz")]
    assert status["tiles_pending"] == 0  # it adds no points: no tile changes
    report = run_workflow(workflow, progress=False)
    assert [f["path"] for f in report.skipped_files] == [str(tmp_path / "archive" / "broken.laz")]


def test_names_left_by_a_stopped_renaming_are_not_read(job, tmp_path):
    import numpy as np

    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    work = next((tmp_path / "out").glob(".archive.zarr.work"))
    tile = work / "tiles" / "00000_00000"  # under patch_a, which changes below: meshed again
    # as a run killed between the two renaming steps leaves them (points far above the ground)
    stray = np.array([[ORIGIN[0] + 30.5 + k, ORIGIN[1] + 30.5, 999.0] for k in range(5)])
    np.save(tile / "tmp000003_000000.npy", stray)
    (work / "records" / "route" / "tmp000003.json").write_text("{}")
    time.sleep(0.01)
    _patch(tmp_path / "archive", "patch_a", (20.0, 20.0), seed=21)
    run_workflow(workflow, progress=False)
    assert not list(work.glob("tiles/*/tmp*")) and not list(work.glob("records/route/tmp*"))
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


def test_a_plain_run_on_a_workflow_store_keeps_its_work(job, tmp_path):
    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    work = tmp_path / "out" / ".archive.zarr.work"
    assert work.is_dir()
    # `terrain run` with the workflow's own parameters: already complete, and
    # the workflow's intermediate files stay for its next run
    report = run(workflow.config, progress=False)
    assert any("already complete" in note for note in report.notes), report.notes
    assert work.is_dir()
    time.sleep(0.01)
    _patch(tmp_path / "archive", "patch_a", (20.0, 20.0), seed=22)
    report = run_workflow(workflow, progress=False)
    assert not any("work folder was missing" in note for note in report.notes), report.notes
    (note,) = [n for n in report.notes if "inputs changed" in n]
    done, total = (int(w) for w in note.split(": ")[1].split(" tile")[0].split(" of "))
    assert 0 < done < total
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


def test_a_new_file_in_another_height_unit_recomputes_every_slope(tmp_path):
    """The archive's heights are declared in US survey feet over metres, so
    slopes scale them by 0.3048.  A new file of heights in metres makes the
    units mixed (scale 1, with a warning): the slopes of tiles the file does
    not touch change too, so every tile is computed again."""
    archive = tmp_path / "archive"
    write_survey(archive, SurveySpec(origin=ORIGIN, width=240.0, height=160.0, points=24_000, files=2, seed=1,
                                     crs="EPSG:2154+6360"))
    path = tmp_path / "heights.toml"
    path.write_text(JOB + 'out_crs = "EPSG:2154"\n')
    workflow = Workflow.load(path)
    run_workflow(workflow, progress=False)
    before = _chunk_times(workflow.config.output)
    _patch(archive, "patch_m", (20.0, 20.0), seed=2)  # plain EPSG:2154: heights presumed in metres

    assert workflow_status(workflow)["tiles_pending"] == "all (the grid, extent, buffer or height unit changes)"
    report = run_workflow(workflow, progress=False)
    assert any("height unit changed: every tile" in note for note in report.notes), report.notes
    assert any("heights are in different units" in note for note in report.notes), report.notes
    after = _chunk_times(workflow.config.output)
    assert all(after[k] != t for k, t in before.items())
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


# a new flight block beside the survey, inside the planned area: (corner, side)
BLOCKS = {"north": (60.0, 160.0), "east": (240.0, 40.0), "south": (60.0, -80.0), "west": (-80.0, 40.0)}


@pytest.mark.parametrize("side", list(BLOCKS))
def test_a_new_block_inside_a_declared_extent_recomputes_only_the_tiles_it_touches(tmp_path, side, monkeypatch):
    archive = tmp_path / "archive"
    write_survey(archive, SurveySpec(origin=ORIGIN, width=240.0, height=160.0, points=12_000, files=2, seed=1))
    extent = [ORIGIN[0] - 100.0, ORIGIN[1] - 100.0, ORIGIN[0] + 340.0, ORIGIN[1] + 260.0]
    job = tmp_path / "nightly.toml"
    job.write_text(JOB.replace("tile_size = 40.0", "tile_size = 80.0").replace("layers = ", f"extent = {extent}\nlayers = "))
    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    before = _chunk_times(workflow.config.output)

    _patch(archive, side, BLOCKS[side], seed=7, size=80.0)
    status = workflow_status(workflow)
    assert status["new_files"] == [str(archive / f"{side}.laz")]
    assert 0 < status["tiles_pending"] < status["tiles_total"] / 2, status
    written = _spy_tile_writes(monkeypatch)
    run_workflow(workflow, progress=False)
    after = _chunk_times(workflow.config.output)
    assert set(after) == set(before)  # the grid did not move
    untouched = {k for k in before if after[k] == before[k]}
    assert untouched == set(before) - _chunks_holding(Path(workflow.config.output), written)  # far chunks kept
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


# a block beyond a 400 x 240 m survey of 5 x 3 tiles of 80 m, without a declared extent
GROWTH = {"north": (60.0, 240.0), "east": (400.0, 40.0), "south": (60.0, -80.0), "west": (-80.0, 40.0)}


def _grown_chunk_times(before: dict[str, int], rows: int) -> dict[str, int]:
    """Chunk file names of a north-up layer after the grid gained ``rows`` tile rows at the north."""
    out = {}
    for key, stamp in before.items():
        c, i, j = key.split("/")
        out[f"{c}/{int(i) + rows}/{j}"] = stamp
    return out


def _first_run(tmp_path: Path, width: float, height: float, points: int) -> tuple[Path, Workflow]:
    """A survey of ``width`` x ``height`` m without a declared extent, in 80 m
    tiles, and its workflow's first run."""
    archive = tmp_path / "archive"
    write_survey(archive, SurveySpec(origin=ORIGIN, width=width, height=height, points=points, files=2, seed=1))
    job = tmp_path / "nightly.toml"
    job.write_text(JOB.replace("tile_size = 40.0", "tile_size = 80.0"))
    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    return archive, workflow


@pytest.mark.parametrize("side", ["north", "east"])
def test_without_an_extent_growth_north_or_east_resizes_the_store_and_keeps_far_tiles(tmp_path, side):
    archive, workflow = _first_run(tmp_path, 400.0, 240.0, 20_000)
    out = Path(workflow.config.output)
    before = _chunk_times(out)
    assert {k.split("/")[1] for k in before} == {"0", "1", "2"}  # 3 tile rows

    _patch(archive, side, GROWTH[side], seed=7, size=80.0)
    status = workflow_status(workflow)
    assert status["new_files"] == [str(archive / f"{side}.laz")]
    assert isinstance(status["tiles_pending"], int), status
    report = run_workflow(workflow, progress=False)
    assert any("the grid grew from 3 x 5 to" in note for note in report.notes), report.notes
    # the status foresaw the run: the new tiles, the old edge's, those the block touches
    assert any(f"{status['tiles_pending']} of {report.tiles} tile(s) computed again" in n for n in report.notes), (
        status, report.notes)
    assert status["tiles_pending"] < report.tiles
    after = _chunk_times(out)
    moved = _grown_chunk_times(before, 1) if side == "north" else before
    assert set(moved) <= set(after)  # every chunk file is still there (renamed at the north)
    untouched = [k for k in moved if after[k] == moved[k]]
    # the southern tiles, far from the block, were neither computed nor written again
    assert len(untouched) >= 1, (len(untouched), len(moved))
    assert_same_store(out, _full_run(workflow, tmp_path / "full.zarr"))
    assert workflow_status(workflow)["tiles_pending"] == 0


@pytest.mark.parametrize("side", ["north", "east"])
def test_growth_by_part_of_a_tile_gives_the_store_of_a_full_run(tmp_path, side):
    """A survey of 390 x 230 m in 80 m tiles: its northern tile row and
    eastern column are partial, and so are the store's southern and eastern
    chunks.  A block of 50 m grows it by 25 cells, no whole tile: the chunk
    boundaries, counted from the north edge, move (the store's chunks are
    written again from the cells they hold, no tile is computed for it), and
    the partial tiles are computed again."""
    archive, workflow = _first_run(tmp_path, 390.0, 230.0, 20_000)
    out = Path(workflow.config.output)
    before = TileGrid.from_dict(read_attrs(out)["grid"])
    assert before.rows_share_chunks and before.nx % before.tile_cells
    corner = {"north": (60.0, 230.0), "east": (390.0, 40.0)}[side]
    _patch(archive, side, corner, seed=7, size=50.0)
    status = workflow_status(workflow)
    report = run_workflow(workflow, progress=False)
    after = TileGrid.from_dict(read_attrs(out)["grid"])
    grown = after.ny - before.ny if side == "north" else after.nx - before.nx
    assert 0 < grown < after.tile_cells and after.extends(before)
    assert isinstance(status["tiles_pending"], int), status
    assert any(f"{status['tiles_pending']} of {after.n_tiles} tile(s) computed again" in n for n in report.notes)
    far = after.n_cols if side == "north" else after.n_rows  # the southern row, or the western column
    assert status["tiles_pending"] <= after.n_tiles - far
    assert_same_store(out, _full_run(workflow, tmp_path / "full.zarr"))


def test_a_job_file_without_sizes_keeps_those_its_first_run_derived_and_grows_as_cheaply(tmp_path, monkeypatch):
    """A job file that leaves tile_size and buffer to their defaults: its
    first run derives them from the point density and records them; a dense
    block to the north would change them (and with them every tile), so the
    next runs keep them.  It then computes again only the tiles a job file
    fixing those sizes computes again, and gives the same store as a full
    run with them."""
    from pipeline.runs import plan as planning

    # tiles of a few thousand points, so that a small survey has several
    monkeypatch.setattr(planning, "POINTS_PER_TILE", 3000)
    monkeypatch.setattr(planning, "MIN_POINTS_PER_TILE", 1000)
    archive = tmp_path / "archive"
    write_survey(archive, SurveySpec(origin=ORIGIN, width=400.0, height=400.0, points=20_000, files=2, seed=1))
    unsized = JOB.replace("tile_size = 40.0\n", "").replace("buffer = 6.0\n", "")
    default = tmp_path / "default.toml"
    default.write_text(unsized.replace("out/archive.zarr", "out/default.zarr"))
    workflow = Workflow.load(default)
    assert workflow.config.tile_size is None and workflow.config.buffer is None
    run_workflow(workflow, progress=False)
    out = Path(workflow.config.output)
    derived = read_attrs(out)["provenance"]["derived"]
    assert set(derived) == {"tile_size", "buffer"}
    assert read_attrs(out)["provenance"]["grid"]["tile_cells"] * 2.0 == derived["tile_size"]
    fixed = tmp_path / "fixed.toml"  # the same job with those sizes written down
    fixed.write_text(unsized.replace("out/archive.zarr", "out/fixed.zarr").replace(
        "[run]\n", f"[run]\ntile_size = {derived['tile_size']!r}\nbuffer = {derived['buffer']!r}\n"))
    fixed_workflow = Workflow.load(fixed)
    run_workflow(fixed_workflow, progress=False)
    assert "derived" not in read_attrs(fixed_workflow.config.output)["provenance"]

    _patch(archive, "north", (60.0, 400.0), seed=7, size=100.0)
    # derived again from the archive as it is now, the sizes would differ: every tile would move
    fresh = planning.plan_run(workflow.config)
    assert (fresh.grid.tile_cells * 2.0, fresh.buffer) != (derived["tile_size"], derived["buffer"])
    status, fixed_status = workflow_status(workflow), workflow_status(fixed_workflow)
    assert isinstance(status["tiles_pending"], int), status
    assert status["tiles_pending"] == fixed_status["tiles_pending"]
    before = TileGrid.from_dict(read_attrs(out)["grid"])
    written = _spy_tile_writes(monkeypatch)
    report = run_workflow(workflow, progress=False)
    after = TileGrid.from_dict(read_attrs(out)["grid"])
    assert after.extends(before) and after.n_rows > before.n_rows and after.nx == before.nx
    assert any(f"{status['tiles_pending']} of {after.n_tiles} tile(s) computed again" in n for n in report.notes)
    assert any("kept from the store" in n for n in report.notes), report.notes
    # the new tiles and the old northern row: the southern rows, far from the block, are neither computed
    # nor written again
    assert status["tiles_pending"] == after.n_tiles - before.n_tiles + before.n_cols < after.n_tiles
    assert not any(row < before.n_rows - 2 for row, _ in written) and before.n_rows > 2
    assert read_attrs(out)["provenance"]["derived"] == derived  # recorded again, as derived
    run_workflow(fixed_workflow, progress=False)
    assert_same_store(out, Path(fixed_workflow.config.output))
    assert_same_store(out, _full_run(fixed_workflow, tmp_path / "full.zarr"))


@pytest.mark.parametrize("side", ["south", "west"])
def test_without_an_extent_growth_south_or_west_says_why_every_tile_is_pending(tmp_path, side):
    archive, workflow = _first_run(tmp_path, 240.0, 160.0, 12_000)
    _patch(archive, side, GROWTH[side], seed=7, size=80.0)
    why = "the survey grew south or west of the grid's origin, which {} every tile"
    assert workflow_status(workflow)["tiles_pending"] == f"all ({why.format('moves')})"
    report = run_workflow(workflow, progress=False)
    assert f"{why.format('moved')}: every tile was computed again" in report.notes, report.notes
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


def test_a_store_left_half_grown_is_made_again(tmp_path):
    """A run stopped while it renamed chunks leaves a store whose chunks are
    half moved: the next run makes it again instead of trusting it."""
    from pipeline.store import zarr_store as store

    archive, workflow = _first_run(tmp_path, 240.0, 160.0, 12_000)
    _patch(archive, "north", (60.0, 160.0), seed=7, size=80.0)
    real = store._shift_chunk_rows

    def stop_after_one(path, array, grid, shift):
        real(path, array, grid, shift)
        raise KeyboardInterrupt

    store._shift_chunk_rows = stop_after_one
    try:
        with pytest.raises(KeyboardInterrupt):
            run_workflow(workflow, progress=False)
    finally:
        store._shift_chunk_rows = real
    assert store.read_attrs(workflow.config.output)[store.GROWING_ATTR]
    report = run_workflow(workflow, progress=False)
    assert "an earlier run stopped while it grew the grid: every tile was computed again" in report.notes
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))


def test_an_upgrade_between_runs_computes_every_tile_again(job, tmp_path, monkeypatch):
    # tiles meshed by another version beside this version's would not make one
    # conforming mesh: the work folder is stamped with the sources that wrote it
    from pipeline.runs import resume

    workflow = Workflow.load(job)
    run_workflow(workflow, progress=False)
    time.sleep(0.01)
    _patch(tmp_path / "archive", "patch_a", (20.0, 20.0), seed=23)
    assert workflow_status(workflow)["tiles_pending"] not in (0, "all")  # the same version: a few tiles
    monkeypatch.setattr(resume, "sources_digest", lambda: "another version")
    assert workflow_status(workflow)["tiles_pending"] == "all"
    report = run_workflow(workflow, progress=False)
    assert any("another version of the software: every tile" in note for note in report.notes), report.notes
    assert not any("inputs changed" in note for note in report.notes)
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))
    # and the next run, by the same version, keeps the work
    _patch(tmp_path / "archive", "patch_a", (20.0, 20.0), seed=24)
    report = run_workflow(workflow, progress=False)
    assert any("inputs changed" in note for note in report.notes), report.notes


def _reclassify(path: Path, classes: list[int] | None) -> None:
    """Set every point of ``path`` to class ``classes[0]`` (``None``: back to the classes saved beside it)."""
    import laspy
    import numpy as np

    las = laspy.read(path)
    saved = path.with_suffix(".classes.npy")
    if classes is None:
        las.classification = np.load(saved)
        saved.unlink()
    else:
        np.save(saved, np.asarray(las.classification))
        las.classification = np.full(len(las.points), classes[0], dtype=np.uint8)
    las.write(path)


def test_a_survey_without_ground_that_gains_some_is_computed_again_with_ground_only(job, tmp_path):
    archive = tmp_path / "archive"
    files = sorted(archive.glob("*.laz"))
    for path in files:
        _reclassify(path, [1])
    workflow = Workflow.load(job)
    report = run_workflow(workflow, progress=False)
    assert any("input point(s) of the default classes (2, ground)" in n for n in report.notes), report.notes
    assert report.filtered_class == 0
    assert report.points_kept + report.not_ground == report.points_read - report.filtered_withheld
    assert report.not_ground > 0  # the ground was classified: the trees are not ground

    time.sleep(0.01)
    _reclassify(files[0], None)  # one file classified: the survey now has ground
    status = workflow_status(workflow)
    assert status["changed_files"] == [str(files[0])] and status["tiles_pending"] == "all"
    report = run_workflow(workflow, progress=False)
    assert any("every tile was computed again" in n for n in report.notes), report.notes
    assert not any("input point(s) of the default classes (2, ground)" in n for n in report.notes), report.notes
    assert 0 < report.points_kept < report.points_read
    assert_same_store(Path(workflow.config.output), _full_run(workflow, tmp_path / "full.zarr"))
