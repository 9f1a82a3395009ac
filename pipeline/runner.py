"""``pipeline.runner``: LAS/LAZ archives -> tiles on Dask -> one seamless DEM and mesh in Zarr.

Stages (each timed in the run report):

1. *scan*: headers of every input, CRS plan, grid and tiles;
2. *route*: one streaming pass per input file (a Dask task each): filter,
   reproject, and append every point to the spill files of the tiles whose
   core plus buffer holds it;
3. *mesh*: one task per tile: its piece of the combined mesh (certified
   against its neighbours, see :mod:`pipeline.tiles`);
4. *dem*: one task per tile: the DEM chunk from the stitched faces over it,
   written straight into its own Zarr chunk (no locks);
5. *write mesh*: one task per tile renumbers its piece's faces to global node
   ids, then one task per block of whole chunks writes the nodes and faces
   into the store's UGRID group (the tasks: :mod:`pipeline.assemble`).

Every finished unit is recorded (:mod:`pipeline.checkpoint`), so a stopped run
resumes, and :func:`execute` can update a store after its inputs changed.
"""

from __future__ import annotations

import contextlib
import errno
import math
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .config import RunConfig
from .cluster import Progress, close, connect, map_tasks
from .checkpoint import WorkDir, output_lock, work_dir_for
from .errors import CrsError, InputFileError, OutputWriteError, PipelineError, SeamError, UsageError
from .assemble import MeshBlock, global_node_ids, mesh_offsets, write_mesh_block
from .surface import run_variogram
from .catalog import write_stac_item
from .scratch import Scratch
from .windows import WindowSource, hull_copies, survey_hull
from . import urls
from .tiles import TileJob, TileSummary, dem_tile, mesh_tile, piece_intact, reached_tiles
from .changes import (
    forget_changed_inputs, forget_tiles, reroute_near_growth, tiles_depending_on, tiles_moved_by_growth,
    tiles_whose_hull_moved,
)
from .tiling import (
    TileGrid, TileSpiller, check_cells, drop_source_spill, grow_hull, hull_candidates, spill_by_source, spill_intact,
    tile_key,
)

if TYPE_CHECKING:
    from .crs import CrsPlan

__all__ = ["run", "execute", "RunReport", "route_source"]

POINTS_PER_TILE = 500_000
"""Target number of points per tile when ``tile_size`` is not given.

The mesh passes sweep a tile's half-edge arrays many times, and a smaller
tile keeps more of them in cache; the buffer around a tile stays a few
percent of its points.  On a 20M-point archive, 0.5M-point tiles mesh about
9% faster than 1.5M-point ones, with a lower peak memory
(``bench/bench_pipeline.py throughput``)."""

SMOOTH_POINTS_PER_TILE = 125_000
"""The same for ``surface="smooth"``: kriging its nodes costs several times
meshing, so smaller tiles let every core krige (a survey of 500k points is
four tiles, not one)."""

ROUTE_CHUNK = 1_000_000
"""Points read and routed at a time.

Each of a chunk's arrays (x, y, z, the routed copy) then stays under glibc's
32 MiB limit for reusing freed memory, so the next chunk takes the same pages
instead of faulting in new ones: routing the 20M-point bench archive takes
8% less time than with 2M-point chunks (400k against 160k page faults)."""


@dataclass
class RunReport:
    """What a run did: counts of points by fate, tiles, mesh, time per stage."""

    points_read: int = 0
    points_kept: int = 0
    filtered_class: int = 0
    filtered_withheld: int = 0
    outside_bbox: int = 0
    duplicates: int = 0
    vertices: int = 0
    faces: int = 0
    quads: int = 0
    tiles: int = 0
    tiles_uncertified: int = 0
    tile_expansions: int = 0
    files: list[dict[str, Any]] = field(default_factory=list)
    skipped_files: list[dict[str, Any]] = field(default_factory=list)
    """Inputs left out with ``skip_bad_files``: path, reason, points their header claims."""
    notes: list[str] = field(default_factory=list)
    stages: dict[str, float] = field(default_factory=dict)

    @property
    def quad_share(self) -> float:
        return self.quads / self.faces if self.faces else 0.0

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["quad_share"] = self.quad_share
        return out

    def table(self) -> str:
        rows = [
            ("points read", f"{self.points_read:,}"),
            ("  filtered by class", f"{self.filtered_class:,}"),
            ("  withheld", f"{self.filtered_withheld:,}"),
            ("  outside bbox", f"{self.outside_bbox:,}"),
            ("  duplicates merged", f"{self.duplicates:,}"),
            ("points kept (vertices)", f"{self.vertices:,}"),
            ("tiles", f"{self.tiles:,}"),
            ("faces", f"{self.faces:,}"),
            ("share of quadrangles", f"{100 * self.quad_share:.1f} %"),
        ]
        if self.tiles_uncertified:
            rows.append(("tiles not certified", f"{self.tiles_uncertified}"))
        for skipped in self.skipped_files:
            rows.append(("skipped file", f"{skipped['reason']}"))
        for stage, seconds in self.stages.items():
            rows.append((f"time: {stage}", f"{seconds:.2f} s"))
        width = max(len(r[0]) for r in rows)
        return "\n".join(f"{name.ljust(width)}  {value}" for name, value in rows)


@dataclass(frozen=True)
class _RouteJob:
    index: int
    path: str
    scratch: Scratch
    grid: TileGrid
    buffer: float
    source_wkt: str
    target_wkt: str
    z_factor: float
    classes: tuple[int, ...] | None
    keep_withheld: bool
    bbox: tuple[float, float, float, float] | None
    skip_bad: bool = False


def route_source(job: _RouteJob) -> dict[str, Any]:
    """Stream one file into the tiles' spill files; returns its counts.

    With ``job.skip_bad`` a file found broken while reading is dropped whole
    (its spilled points removed) and the counts say why (``"skipped"``).
    """
    try:
        return _route(job)
    except InputFileError as exc:
        if not job.skip_bad:
            raise
        drop_source_spill(job.scratch, job.index)
        return {"path": job.path, "skipped": str(exc), "read": 0, "filtered_class": 0, "filtered_withheld": 0,
                "outside_bbox": 0, "kept": 0, "hull": np.empty((0, 3))}


def _route(job: _RouteJob) -> dict[str, Any]:
    from .crs import Reprojector
    from .sources import PointFilter, file_digest, iter_points

    t0 = time.perf_counter()
    drop_source_spill(job.scratch, job.index)  # left by a stopped run: routed again from the start
    spill = TileSpiller(job.scratch, job.grid, job.buffer, job.index)
    reproject = Reprojector(job.source_wkt, job.target_wkt, job.z_factor)
    point_filter = PointFilter(
        classes=None if job.classes is None else frozenset(job.classes), keep_withheld=job.keep_withheld
    )
    counts: dict[str, Any] = {
        "path": job.path, "read": 0, "filtered_class": 0, "filtered_withheld": 0, "outside_bbox": 0, "kept": 0,
        "beyond_grid": 0,
    }
    gx0, gy0, gx1, gy1 = job.grid.extent
    hull = np.empty((0, 3))
    # a COPC file in the target CRS reads only the octree nodes that meet the bbox
    window = job.bbox if reproject.is_identity else None
    for chunk in iter_points(job.path, point_filter, ROUTE_CHUNK, window=window):
        counts["read"] += chunk.read
        counts["outside_bbox"] += chunk.outside_window
        counts["filtered_class"] += chunk.filtered_class
        counts["filtered_withheld"] += chunk.filtered_withheld
        try:
            x, y, z = reproject.transform(chunk.x, chunk.y, chunk.z)
        except CrsError as exc:  # points of this file: a bad input, named (and skippable)
            raise InputFileError(f"{job.path}: {exc}") from None
        if job.bbox is not None:
            inside = (x >= job.bbox[0]) & (x <= job.bbox[2]) & (y >= job.bbox[1]) & (y <= job.bbox[3])
            counts["outside_bbox"] += int(x.size - np.count_nonzero(inside))
            x, y, z = x[inside], y[inside], z[inside]
        counts["kept"] += int(x.size)
        # a stale header: kept points (in the mesh) where the DEM has no cells
        counts["beyond_grid"] += int(x.size - np.count_nonzero((x >= gx0) & (x <= gx1) & (y >= gy0) & (y <= gy1)))
        if x.size:
            b = counts.setdefault("bounds", [math.inf, math.inf, -math.inf, -math.inf])
            b[0], b[1] = min(b[0], float(x.min())), min(b[1], float(y.min()))
            b[2], b[3] = max(b[2], float(x.max())), max(b[3], float(y.max()))
        spill.add(x, y, z)
        hull = grow_hull(hull, x, y, z)
    spill.flush()
    counts["parts"] = spill.parts  # a resume checks they are still there
    counts["tile_points"] = spill.points  # the tiles' work, to start the largest first
    counts["sha256"] = file_digest(job.path)
    counts["hull"] = hull
    counts["seconds"] = time.perf_counter() - t0
    return counts


def read_headers(config: RunConfig) -> tuple[list[Path], list, list[dict[str, Any]]]:
    """The inputs' paths and header information (bounds measured from the
    points where the header's are unusable), and with ``skip_bad_files`` the
    files left out and why."""
    from .sources import discover_inputs, read_info, with_measured_bounds

    paths, infos, skipped = [], [], []
    for p in discover_inputs(config.inputs):
        try:
            info = read_info(p)
            if info.point_count and not info.bounds_usable:  # the grid needs them
                info = with_measured_bounds(info)
        except InputFileError as exc:
            if not config.skip_bad_files:
                raise
            skipped.append({"path": str(p), "reason": str(exc), "points": None})
            continue
        infos.append(info)
        paths.append(p)
    if not paths:
        raise InputFileError("every input was skipped: " + "; ".join(f["reason"] for f in skipped))
    return paths, infos, skipped


def job_frame(config: RunConfig, paths, infos, plan) -> tuple[TileGrid, tuple, float, list]:
    """The grid, the extent and the buffer of a job over these inputs (and the
    files' bounds in the target CRS): what a run fixes before reading points."""
    file_bounds = [_file_bounds(i, src, plan.target_wkt) for i, src in zip(infos, plan.source_wkts)]
    bounds = _union_bounds(file_bounds)
    if config.bbox is not None:
        b = config.bbox
        bounds = (max(bounds[0], b[0]), max(bounds[1], b[1]), min(bounds[2], b[2]), min(bounds[3], b[3]))
    if not all(math.isfinite(v) for v in bounds) or bounds[0] > bounds[2] or bounds[1] > bounds[3]:
        raise PipelineError("no points to grid: the inputs are empty or the bbox misses them")
    if config.extent is not None:  # the planned area: files inside it never move the grid
        bounds = _union_bounds([bounds, config.extent])
    if not (math.isfinite(bounds[2] - bounds[0]) and math.isfinite(bounds[3] - bounds[1])):
        raise UsageError(f"the inputs span more than the largest float: x {bounds[0]:.6g} .. {bounds[2]:.6g}, "
                         f"y {bounds[1]:.6g} .. {bounds[3]:.6g}")
    tile_cells, buffer = _auto_sizes(config, bounds, sum(i.point_count for i in infos))
    grid = TileGrid.covering(bounds, config.resolution, tile_cells)
    try:
        check_cells(grid, config.max_cells)
    except UsageError as exc:  # say which file spans the most: a wrong CRS or header shows up here
        spans = [(b[2] - b[0]) * (b[3] - b[1]) if b else -1.0 for b in file_bounds]
        widest = int(np.argmax(spans))
        b = file_bounds[widest]
        raise UsageError(
            f"{exc}; the widest input is {paths[widest]}: x {b[0]:.2f} .. {b[2]:.2f}, y {b[1]:.2f} .. {b[3]:.2f}"
        ) from None
    return grid, bounds, buffer, file_bounds


def _skipped_note(skipped: list) -> str:
    return f"{len(skipped)} bad file(s) skipped (--skip-bad-files); their points are not in the output"


def job_frame_record(grid: TileGrid, bounds, buffer: float, plan: CrsPlan) -> dict[str, Any]:
    """The provenance entries that fix a job's tiles, and the unit of its
    heights (a slope compares heights with distances)."""
    return {
        "grid": grid.to_dict(), "extent": list(bounds), "buffer": buffer,
        "heights": {"unit": plan.height_unit, "scale": plan.height_scale},
    }


def frame_moved(before: dict[str, Any], now: dict[str, Any]) -> bool:
    """Whether two provenances differ in the entries that fix the tiles or in
    the heights' unit (every tile is then computed again: a new file in
    another height unit changes the slopes of tiles it does not touch)."""
    if any(before.get(k) != now.get(k) for k in ("grid", "extent", "buffer")):
        return True
    # stores written before the heights were recorded have none: taken as unchanged
    return "heights" in before and before["heights"] != now.get("heights")


def frame_grew(before: dict[str, Any], now: dict[str, Any]) -> bool:
    """Whether the frame ``now`` keeps the tiles of ``before`` and only grows
    its grid to the north or east (or leaves it as it was while the data
    extent moved inside it): the same origin, cells, tiles, buffer and heights.
    The tiles written then stay (:func:`pipeline.store.grow_store`)."""
    if "grid" not in before or before.get("buffer") != now.get("buffer"):
        return False
    if "heights" in before and before["heights"] != now.get("heights"):
        return False
    return TileGrid.from_dict(now["grid"]).extends(TileGrid.from_dict(before["grid"]))


def frame_change(before: dict[str, Any], now: dict[str, Any], done: bool = True) -> str:
    """Why every tile is (``done``) or will be computed again when a frame
    moved and did not grow."""
    if "grid" in before and before.get("buffer") == now.get("buffer"):
        was, grid = TileGrid.from_dict(before["grid"]), TileGrid.from_dict(now["grid"])
        if (was.resolution, was.tile_cells) == (grid.resolution, grid.tile_cells) and (grid.x0, grid.y0) != (was.x0, was.y0):
            return f"the survey grew south or west of the grid's origin, which {'moved' if done else 'moves'} every tile"
    return f"the grid, extent, buffer or height unit {'changed' if done else 'changes'}"


def _grid_spec(grid: TileGrid):
    from . import store

    return store.GridSpec(grid.x0, grid.y0, grid.resolution, grid.nx, grid.ny, grid.tile_cells)


def _file_bounds(info, source_wkt: str, target_wkt: str) -> tuple[float, float, float, float] | None:
    """A file's header bounds in the target CRS (None for an empty file)."""
    from pyproj import CRS, Transformer

    if info.point_count == 0:
        return None
    b = info.bounds
    x0, y0, x1, y1 = b[0], b[1], b[3], b[4]
    if source_wkt != target_wkt:
        t = Transformer.from_crs(CRS.from_wkt(source_wkt), CRS.from_wkt(target_wkt), always_xy=True)
        x0, y0, x1, y1 = t.transform_bounds(x0, y0, x1, y1, densify_pts=21)
    return float(x0), float(y0), float(x1), float(y1)


def _union_bounds(boxes) -> tuple[float, float, float, float]:
    """Union of boxes (None ones skipped); infinite when there are none."""
    xmin = ymin = math.inf
    xmax = ymax = -math.inf
    for b in boxes:
        if b is None:
            continue
        xmin, ymin = min(xmin, b[0]), min(ymin, b[1])
        xmax, ymax = max(xmax, b[2]), max(ymax, b[3])
    return xmin, ymin, xmax, ymax


def _auto_sizes(config: RunConfig, bounds, n_points: int) -> tuple[int, float]:
    """Tile edge in cells and buffer (CRS units) from the point density."""
    area = max((bounds[2] - bounds[0]) * (bounds[3] - bounds[1]), config.resolution**2)
    density = max(n_points, 1) / area
    spacing = 1.0 / math.sqrt(density)
    if config.tile_size is not None:
        tile_cells = int(round(config.tile_size / config.resolution))
    else:
        per_tile = POINTS_PER_TILE if config.surface == "linear" else SMOOTH_POINTS_PER_TILE
        target = math.sqrt(per_tile / density) / config.resolution
        # as many tiles along each side as that size needs, all of one size:
        # 351 x 370 m of 700k points is 2 x 2 tiles of 192 m, not one of
        # 304 m that holds 60% of the points beside three small ones
        cells = [max(1.0, (bounds[2] - bounds[0]) / config.resolution), max(1.0, (bounds[3] - bounds[1]) / config.resolution)]
        even = max(math.ceil(side / max(1, math.ceil(side / target))) for side in cells)
        tile_cells = max(16, -(-even // 16) * 16)
    buffer = config.buffer if config.buffer is not None else max(12.0 * spacing, 2.0 * config.resolution)
    return tile_cells, float(buffer)


def run(config: RunConfig, *, progress: bool | None = None, log: Callable[[str], None] | None = None) -> RunReport:
    """Run a job end to end and return its report (also stored in the store's attributes).

    ``progress`` draws progress bars on stderr (default: when it is a terminal);
    ``log`` receives one-line messages about the run.

    A job that was stopped (killed, interrupted, failed) resumes when run
    again with the same parameters and inputs: finished files, tiles and mesh
    blocks are skipped (see :mod:`pipeline.checkpoint`).  A store made with
    other parameters or inputs is an error unless ``config.overwrite``.
    """
    return execute(config, progress=progress, log=log)


def execute(
    config: RunConfig,
    *,
    progress: bool | None = None,
    log: Callable[[str], None] | None = None,
    incremental: bool = False,
) -> RunReport:
    """:func:`run`, or with ``incremental`` an update of the store after its
    inputs changed: the work folder is kept after the run, and only the tiles
    whose points (or hull) changed are computed again (see :mod:`pipeline.workflow`).

    Raises
    ------
    OutputWriteError
        When the store or the work folder cannot be written (read-only, full,
        ...): one line naming the file; the run resumes once the cause is fixed.
    """
    urls.use_storage_options(config.storage_options)
    try:
        with output_lock(config.output):
            return _execute(config, progress=progress, log=log, incremental=incremental)
    except PipelineError:  # input errors are OSErrors too; their messages are already clear
        raise
    except Exception as exc:
        cause = urls.unreachable(exc) if urls.is_url(config.output) else None
        if cause is not None:  # the store's server: writing it failed part way
            raise urls.unreachable_error(str(config.output), cause) from None
        if not isinstance(exc, OSError):
            raise
        if exc.filename is None:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT) or "requested and" in str(exc):  # a short write: full
                raise OutputWriteError(
                    f"{config.output}: cannot write the store or its work files ({exc.strerror or exc}); "
                    "run the same command again once there is room: finished work is kept"
                ) from exc
            raise
        raise OutputWriteError(
            f"{config.output}: cannot write {exc.filename} ({exc.strerror or exc}); "
            "run the same command again once this is fixed: finished work is kept"
        ) from exc


def _execute(
    config: RunConfig,
    *,
    progress: bool | None,
    log: Callable[[str], None] | None,
    incremental: bool,
) -> RunReport:
    from . import store
    from .crs import cf_units, resolve_crs

    # absolute: tasks on a cluster's workers run in other folders
    config = replace(config, output=str(urls.location(config.output)))
    show = sys.stderr.isatty() if progress is None else progress
    say = log or (lambda message: None)
    report = RunReport()
    t_start = time.perf_counter()

    t0 = time.perf_counter()
    paths, infos, report.skipped_files = read_headers(config)
    for p, info in zip(paths, infos):
        report.notes.extend(f"{p}: {note}" for note in info.notes)
    plan = resolve_crs(infos, config.in_crs, config.out_crs)
    report.notes.extend(plan.notes)
    grid, bounds, buffer, file_bounds = job_frame(config, paths, infos, plan)
    report.tiles = grid.n_tiles
    say(f"{len(paths)} file(s), grid {grid.nx} x {grid.ny} cells, {grid.n_rows} x {grid.n_cols} tiles")

    provenance = {
        "software": "terrain-pipeline",
        "version": _version(),
        "parameters": config.to_dict(),
        "inputs": [
            {
                "path": str(i.path), "size": i.size_bytes, "points": i.point_count, **urls.version(i.path),
                "bounds": b,
            }
            for i, b in zip(infos, file_bounds)
        ],
        "crs_wkt": plan.target_wkt,
        **job_frame_record(grid, bounds, buffer, plan),
    }
    spec = _grid_spec(grid)
    work = WorkDir(work_dir_for(config.output, config.scratch_dir, cluster=config.scheduler_address is not None))
    previous = _existing_job(config, provenance, allow_new_inputs=incremental)
    fresh_frame = previous is not None and frame_moved(previous.get("provenance", {}), provenance)
    grown_from = None  # the grid an incremental run grows north or east
    if incremental and fresh_frame and previous.get(store.GROWING_ATTR):
        report.notes.append("an earlier run stopped while it grew the grid: every tile was computed again")
        previous = None
    elif incremental and fresh_frame and frame_grew(previous["provenance"], provenance):
        grown_from = TileGrid.from_dict(previous["provenance"]["grid"])
    elif incremental and fresh_frame:
        report.notes.append(f"{frame_change(previous['provenance'], provenance)}: every tile was computed again")
        previous = None
    elif fresh_frame:
        raise UsageError(f"{config.output}: the existing store has another grid; pass --overwrite to replace it")
    same_inputs = previous is not None and _input_keys(previous["provenance"]["inputs"]) == _input_keys(provenance["inputs"])
    # a workflow's store keeps its work folder: its next run reuses the tiles
    # no changed input touches, whichever command finished the store meanwhile
    keep_work = incremental or bool(previous is not None and previous.get("incremental"))
    if previous is not None and previous.get("complete") and same_inputs:
        say(f"{config.output}: already complete; nothing to do")
        done = RunReport(**{k: v for k, v in previous.get("report", {}).items() if k != "quad_share"})
        done.notes.append("the store was already complete: nothing was recomputed")
        done.skipped_files = report.skipped_files  # this run's bad files, not the last run's
        if not keep_work:
            work.remove()  # left by a run stopped just after it marked the store complete
        if report.skipped_files:
            done.notes.append(_skipped_note(report.skipped_files))
        return done
    # the cluster first: an unreachable scheduler leaves no store and no work folder behind
    client, cluster = connect(config)
    try:
        if grown_from is not None and grown_from != grid:
            store.grow_store(config.output, _grid_spec(grown_from), spec)
        if previous is None:
            store.create_store(
                config.output,
                spec,
                plan.target_wkt,
                layers=config.layers,
                attrs={"provenance": provenance, "complete": False, "incremental": keep_work},
                zarr_format=config.zarr_format,
                overwrite=config.overwrite or incremental,
                height_units=cf_units(plan.height_unit),
            )
            work.reset()
        elif not work.exists():
            # the intermediate files are gone: every stage runs again
            store.reset_tiles_done(config.output)
            work.reset()
            report.notes.append("the work folder was missing: every tile was computed again")
        elif not same_inputs:
            changed = forget_changed_inputs(work, previous["provenance"]["inputs"], provenance["inputs"])
            tiles = tiles_depending_on(work, grid, changed)
            if grown_from is not None:
                tiles |= tiles_moved_by_growth(grown_from, grid)
                reroute_near_growth(work, grown_from, provenance["inputs"], buffer)
                if grown_from != grid:
                    report.notes.append(
                        f"the grid grew from {grown_from.n_rows} x {grown_from.n_cols} to {grid.n_rows} x {grid.n_cols} "
                        "tiles (north or east): the tiles written were kept"
                    )
            forget_tiles(work, config.output, grid, tiles)
            report.notes.append(
                f"inputs changed ({len(changed)} region(s)): {len(tiles)} of {grid.n_tiles} tile(s) computed again"
            )
            store.finalize_store(config.output, {"provenance": provenance, "complete": False})
        else:
            say(f"{config.output}: resuming an unfinished run")
            report.notes.append("resumed an unfinished run: finished work was kept")
        if previous is not None and work.exists():
            lost = _forget_lost_units(work, len(paths), grid, ("nodes",) if config.surface == "smooth" else ())
            if lost:
                report.notes.append(f"{lost} finished unit(s) had lost files in the work folder: done again")
        report.stages["scan"] = time.perf_counter() - t0
    except BaseException:
        with contextlib.suppress(Exception):  # the first error is the one to report
            close(client, cluster)
        raise

    scratch = work.scratch
    try:
        t0 = time.perf_counter()
        counts: list[dict[str, Any] | None] = [work.recorded("route", f"{i:06d}", "hull") for i in range(len(paths))]
        # a file an earlier run of this work folder routed keeps its spill files
        windows = tuple(w for w in _window_sources(config, paths, infos, plan)
                        if counts[w.index] is None or counts[w.index].get("window"))
        windowed = {w.index for w in windows}
        jobs = [
            _RouteJob(
                i, str(p), scratch, grid, buffer, plan.source_wkts[i], plan.target_wkt, plan.z_factor(i),
                config.classes, config.keep_withheld, config.bbox, config.skip_bad_files,
            )
            for i, p in enumerate(paths)
            if counts[i] is None and i not in windowed
        ]

        def routed(index: int, result: dict[str, Any]) -> None:
            work.record("route", f"{index:06d}", {k: v for k, v in result.items() if k != "hull"}, hull=result["hull"])
            counts[index] = result

        map_tasks(client, route_source, jobs, Progress("read", len(jobs), show), lambda c: c["read"],
                  lambda job, result: routed(job.index, result))
        surveys = [w for w in windows if counts[w.index] is None]
        map_tasks(client, survey_hull, surveys, Progress("hull", len(surveys), show), lambda _: 0,
                  lambda w, result: routed(w.index, result))
        for i, c in enumerate(counts):
            assert c is not None
            if c.get("window"):  # counted by the tiles that read it
                continue
            if "skipped" in c:
                report.skipped_files.append({"path": c["path"], "reason": c["skipped"], "points": infos[i].point_count})
                continue
            report.points_read += c["read"]
            report.filtered_class += c["filtered_class"]
            report.filtered_withheld += c["filtered_withheld"]
            report.outside_bbox += c["outside_bbox"]
            report.points_kept += c["kept"]
            if c["kept"] == 0:
                report.notes.append(f"{c['path']}: no points of the chosen classes")
            if c.get("beyond_grid", 0):
                report.notes.append(
                    f"{c['path']}: {c['beyond_grid']:,} point(s) lie beyond the bounds its header announces "
                    "(a stale header?): the mesh holds them, the DEM stops at the header's extent"
                )
        if report.skipped_files:
            report.notes.append(_skipped_note(report.skipped_files))
        hull = _hull_points(np.concatenate([c["hull"] for c in counts if c is not None]), grid, scratch, config.duplicates,
                            windows)
        moved = tiles_whose_hull_moved(work, grid, buffer, hull)
        if moved:
            forget_tiles(work, config.output, grid, moved)
            report.notes.append(f"the convex hull changed near {len(moved)} tile(s): computed again")
        work.save("hull.npy", hull)
        report.stages["route"] = time.perf_counter() - t0

        variogram = None
        if config.surface == "smooth":
            t0 = time.perf_counter()
            variogram, fitted = run_variogram(work, grid, config.duplicates, report.points_kept)
            provenance["smooth_surface"] = fitted
            report.stages["variogram"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        # where the points are: the headers' extent, grown where a stale header
        # understates it (the tiles' search for missing points must reach them)
        extent = _union_bounds([bounds, *(tuple(c["bounds"]) for c in counts if c is not None and "bounds" in c)])
        run_id = uuid.uuid4().hex
        tile_jobs = [
            TileJob(
                r, c, scratch, grid, buffer, extent, config.duplicates, config.triangle_measure,
                config.quad_measure, config.merge, config.max_edge, config.layers, hull=hull,
                height_scale=plan.height_scale, run_id=run_id, surface=config.surface, variogram=variogram,
                windows=windows,
            )
            for r, c in grid.tiles()
        ]
        summaries: dict[tuple[int, int], TileSummary] = {}
        for job in tile_jobs:
            rec = work.recorded("mesh", _tile_key(job))
            if rec is not None:
                rec["held"] = tuple(tuple(box) for box in rec.get("held", ()))
                rec["reach"] = None if rec.get("reach") is None else tuple(rec["reach"])
                rec["window_counts"] = tuple(tuple(row) for row in rec.get("window_counts", ()))
                summaries[(job.row, job.col)] = TileSummary(**rec)
        pending = [job for job in tile_jobs if (job.row, job.col) not in summaries]
        # the largest tiles first, so that no core is left with one at the end
        work_of: dict[tuple[int, int], int] = {}
        for c in counts:
            for r, col, n in (c or {}).get("tile_points", ()):
                work_of[(r, col)] = work_of.get((r, col), 0) + n
        pending.sort(key=lambda job: -work_of.get((job.row, job.col), 0))

        def meshed(job: TileJob, summary: TileSummary) -> None:
            work.record("mesh", _tile_key(job), asdict(summary))
            summaries[(job.row, job.col)] = summary

        map_tasks(client, mesh_tile, pending, Progress("mesh", len(pending), show), lambda s: s.points_owned, meshed)
        _count_windows(report, counts, infos, windows, summaries.values())
        report.files = [{k: v for k, v in c.items() if k not in ("hull", "parts", "tile_points", "window")}
                        for c in counts if c is not None and "skipped" not in c]
        for s in summaries.values():
            report.duplicates += s.duplicates
            report.vertices += s.vertices_owned
            report.faces += s.faces
            report.quads += s.quads
            report.tile_expansions += s.expansions
            report.tiles_uncertified += 0 if s.certified else 1
        if report.faces == 0:
            names = ", ".join(str(p) for p in paths[:3]) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")
            raise PipelineError(
                f"{names}: no surface: the {report.vertices:,} distinct kept point(s) are fewer than three "
                "or all on one line"
            )
        uncertified = sorted(key for key, s in summaries.items() if not s.certified)
        if uncertified:  # recorded by an older version that gave up: mesh them again
            raise SeamError(
                f"{config.output}: {len(uncertified)} tile(s), first {uncertified[0]}, were meshed by a version "
                "that could not certify their seams; run again with overwrite to mesh every tile again"
            )
        report.stages["mesh"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        node_offsets, face_offsets = mesh_offsets(grid, list(summaries.values()))
        reached = {key: reached_tiles(grid, s.reach, *key) for key, s in summaries.items()}
        reaching: dict[tuple[int, int], set[tuple[int, int]]] = {t: set() for t in grid.tiles()}
        for key, tiles in reached.items():
            for t in tiles:
                reaching[t].add(key)
        # the DEM under faces meshed again, however far they reach, is written again
        store.reset_tiles_done(config.output, sorted({t for job in pending for t in reached[(job.row, job.col)]}))
        tile_jobs = [replace(job, reaching=tuple(sorted(reaching[(job.row, job.col)]))) for job in tile_jobs]
        written = store.tiles_done(config.output)
        pending = [job for job in tile_jobs if not written[job.row, job.col]]

        def dem_and_write(job: TileJob) -> int:
            layers = dem_tile(job)
            try:
                store.write_tile(config.output, spec, job.row, job.col, layers)
                store.mark_tile_done(config.output, job.row, job.col)
            except OSError as exc:
                raise OutputWriteError(
                    f"{config.output}: cannot write tile ({job.row}, {job.col}): {exc.strerror or exc}; "
                    "the store is incomplete: run the same command again to resume once this is fixed"
                ) from None
            return 0

        map_tasks(client, dem_and_write, pending, Progress("dem", len(pending), show), lambda _: 0)
        report.stages["dem"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        _write_mesh(client, config, grid, work, tile_jobs, node_offsets, face_offsets, show)
        report.stages["write mesh"] = time.perf_counter() - t0
    finally:
        close(client, cluster)

    report.stages["total"] = time.perf_counter() - t_start
    store.finalize_store(
        config.output,
        {"provenance": provenance, "report": report.to_dict(), "complete": True, "incremental": keep_work},
        history={"finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "report": report.to_dict()},
    )
    write_stac_item(config.output, keep_exports=False)
    if not keep_work:
        work.remove()
    return report


def _forget_lost_units(work: WorkDir, n_inputs: int, grid: TileGrid, piece_extra: tuple[str, ...] = ()) -> int:
    """Forget the records of finished units whose files are gone from the work
    folder (a cleaner, a user), so they are done again; returns how many.
    ``piece_extra``: arrays a meshed piece must also hold (the smooth surface's nodes)."""
    lost = 0
    for i in range(n_inputs):
        rec = work.recorded("route", f"{i:06d}")
        if rec is not None and not spill_intact(work.scratch, i, rec.get("parts", [])):
            work.forget_record("route", f"{i:06d}")  # routed again: its spill files are rewritten
            lost += 1
    for r, c in grid.tiles():
        key = tile_key(r, c)
        if work.recorded("mesh", key) is not None and not piece_intact(work.scratch, r, c, piece_extra):
            work.forget_record("mesh", key)
            work.forget_record("write", f"ids_{key}")
            lost += 1
        elif work.recorded("write", f"ids_{key}") is not None and not piece_intact(work.scratch, r, c, ("node_ids",)):
            work.forget_record("write", f"ids_{key}")
            lost += 1
    return lost


def _tile_key(job: TileJob) -> str:
    return tile_key(job.row, job.col)


def _input_keys(inputs: list[dict[str, Any]]) -> set[tuple]:
    return {(i.get("path"), i.get("size"), i.get("mtime"), i.get("etag")) for i in inputs}


def _existing_job(config: RunConfig, provenance: dict[str, Any], allow_new_inputs: bool = False) -> dict[str, Any] | None:
    """The attributes of an earlier run of the same job at ``config.output`` (to
    resume or skip), or None to start afresh.  An existing store of another job
    (or, unless ``allow_new_inputs``, of other inputs) is an error unless
    ``config.overwrite``."""
    from . import store

    if config.overwrite:
        return None
    attrs = store.read_attrs(config.output)
    if attrs is None:
        return None
    where = config.output
    old = attrs.get("provenance", {})
    try:
        before = RunConfig.from_dict(old.get("parameters", {}))
    except (PipelineError, TypeError):
        raise UsageError(f"{where}: an existing store of unknown origin; pass --overwrite to replace it") from None
    changed = config.differences(before)
    if changed:
        detail = ", ".join(f"{k}: {getattr(before, k)!r} -> {getattr(config, k)!r}" for k in changed)
        raise UsageError(f"{where}: the existing store was made with other parameters ({detail}); pass --overwrite to replace it")
    was, now = _input_keys(old.get("inputs", [])), _input_keys(provenance["inputs"])
    if was != now and not allow_new_inputs:
        added = sorted(p for p, *_ in now - was)
        gone = sorted(p for p, *_ in was - now)
        raise UsageError(
            f"{where}: the inputs changed since the store was made (new or changed: {added or 'none'}; "
            f"gone or changed: {gone or 'none'}); pass --overwrite, or use 'terrain workflow' for incremental runs"
        )
    return attrs


def _window_sources(config: RunConfig, paths, infos, plan) -> tuple[WindowSource, ...]:
    """The inputs tiles read by window: COPC files already in the target CRS.

    The others are routed, and so is every file of a run that skips broken
    files (a routing pass finds a broken one before any tile uses it) or
    samples a variogram (which needs the number of points kept beforehand).
    """
    from .crs import Reprojector

    if config.skip_bad_files or config.surface != "linear":
        return ()
    return tuple(
        WindowSource(i, str(p), config.classes, config.keep_withheld, config.bbox)
        for i, (p, info) in enumerate(zip(paths, infos))
        if info.is_copc and Reprojector(plan.source_wkts[i], plan.target_wkt, plan.z_factor(i)).is_identity
    )


def _count_windows(report: RunReport, counts: list, infos, windows, summaries) -> None:
    """The counts of each window source, from the tiles that counted its nodes:
    the points of nodes no tile read (outside the bbox) are outside the bbox."""
    totals = {w.path: [0] * 5 for w in windows}
    for s in summaries:
        for path, *values in s.window_counts:
            if path in totals:
                totals[path] = [a + int(b) for a, b in zip(totals[path], values)]
    for w in windows:
        read, filtered_class, filtered_withheld, outside_bbox, kept = totals[w.path]
        header = int(infos[w.index].point_count)
        unread = header - read
        if unread < 0:
            raise PipelineError(f"{w.path}: the tiles counted {read:,} points, more than its header's {header:,}")
        c = counts[w.index]
        c.update(read=header, filtered_class=filtered_class, filtered_withheld=filtered_withheld,
                 outside_bbox=outside_bbox + unread, kept=kept)
        report.points_read += header
        report.filtered_class += filtered_class
        report.filtered_withheld += filtered_withheld
        report.outside_bbox += outside_bbox + unread
        report.points_kept += kept
        if kept == 0:
            report.notes.append(f"{w.path}: no points of the chosen classes")


def _hull_points(
    candidates: np.ndarray, grid: TileGrid, scratch: Scratch, policy: str, windows: tuple[WindowSource, ...] = ()
) -> np.ndarray:
    """The global convex hull's points, with the z their owner tile will give them.

    Every tile meshes with these, so its own convex hull is the global one and
    every region of its window is covered by its triangles.
    """
    from .tiles import vertex_z

    hull = hull_candidates(candidates)
    if hull.shape[0] == 0:
        return hull
    key = hull[:, 0] + 1j * hull[:, 1]
    _, first = np.unique(key, return_index=True)
    hull = hull[np.sort(first)]  # distinct points, still in counter-clockwise order
    key = hull[:, 0] + 1j * hull[:, 1]
    rows, cols = grid.owner(hull[:, 0], hull[:, 1])
    # every copy of a hull point in a window source, read from the few nodes that hold one
    copies = {w.index: hull_copies(w, hull[:, :2]) for w in windows}
    for r, c in set(zip(rows.tolist(), cols.tolist())):
        by_source = {**spill_by_source(scratch, r, c), **copies}  # source after source, as a tile holds them
        pts = np.concatenate([by_source[k] for k in sorted(by_source)]) if by_source else np.empty((0, 3))
        mine = np.flatnonzero((rows == r) & (cols == c))
        pkey = pts[:, 0] + 1j * pts[:, 1]
        sel = np.isin(pkey, key[mine])
        # every copy of a hull point, reduced by the duplicate policy like any vertex
        by_key = np.argsort(key[mine])
        group = np.searchsorted(key[mine][by_key], pkey[sel])
        hull[mine[by_key], 2] = vertex_z(group, mine.size, pts[sel, 2], policy)
    return hull


def _write_mesh(
    client, config: RunConfig, grid: TileGrid, work: WorkDir, tile_jobs: list[TileJob], node_offsets, face_offsets, show: bool
) -> None:
    """Renumber every piece's faces to global node ids, then write the nodes and
    faces into the store's mesh group in blocks of whole chunks on the workers
    (tiles renumbered and blocks written before a stop are kept)."""
    from . import store

    pending = [job for job in tile_jobs if work.recorded("write", f"ids_{_tile_key(job)}") is None]
    map_tasks(
        client, partial(global_node_ids, node_offsets=node_offsets), pending, Progress("number", len(pending), show),
        lambda _: 0, lambda job, _: work.record("write", f"ids_{_tile_key(job)}", {}),
    )
    order = tuple(grid.tiles())
    sizes = {"nodes": int(node_offsets[-1]), "faces": int(face_offsets[-1])}
    if work.recorded("write", "created") == sizes:
        writer = store.MeshWriter.attach(config.output)
    else:
        writer = store.MeshWriter(config.output, sizes["nodes"], sizes["faces"], config.zarr_format)
        work.record("write", "created", sizes)
    step = 4 * store.MESH_CHUNK
    blocks = []
    for what, offsets in (("nodes", node_offsets), ("faces", face_offsets)):
        for start in range(0, int(offsets[-1]), step):
            stop = min(start + step, int(offsets[-1]))
            if work.recorded("write", f"{what}_{start}") is not None:
                writer.record(what, start, stop)
                continue
            blocks.append(MeshBlock(config.output, work.scratch, order, tuple(int(v) for v in offsets), what, start, stop))

    def written(block: MeshBlock, result: tuple[str, int, int]) -> None:
        writer.record(*result)
        work.record("write", f"{block.what}_{block.start}", {"stop": block.stop})

    map_tasks(client, write_mesh_block, blocks, Progress("write", len(blocks), show), lambda _: 0, written)
    writer.set_tiles(
        np.array([r for r, _ in order]),
        np.array([c for _, c in order]),
        node_offsets,
        face_offsets,
    )
    writer.close()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("terrain-pipeline")
    except PackageNotFoundError:  # pragma: no cover
        return "unknown"
