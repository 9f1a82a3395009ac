"""``pipeline.runs.runner``: LAS/LAZ archives -> tiles on Dask -> one seamless DEM and mesh in Zarr.

Stages (each timed in the run report):

1. *scan*: headers of every input, CRS plan, grid and tiles;
2. *route*: one streaming pass per input file (a Dask task each): filter,
   reproject, and append every point to the spill files of the tiles whose
   core plus buffer holds it;
3. *mesh*: one task per tile: its piece of the combined mesh (certified
   against its neighbours, see :mod:`pipeline.meshing.tiles`);
4. *dem and mesh*: one task per tile: the DEM of its cells from the
   stitched faces over it, written straight into the store (no locks: tiles
   that share a chunk run one after the other, see :func:`_dem_order`);
   beside them, one task per tile renumbers its piece's faces to global node
   ids, and one task per block of whole chunks writes the nodes or the faces
   (once the tiles it spans are numbered) into the store's UGRID group (the
   tasks: :mod:`pipeline.store.assemble`).

Every finished unit is recorded (:mod:`pipeline.tiling.checkpoint`), so a stopped run
resumes, and :func:`execute` can update a store after its inputs changed.
"""

from __future__ import annotations

import contextlib
import copy
import errno
import itertools
import math
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np
from meshcore import GroundParameters

from ..config import DEFAULT_CLASSES, RunConfig
from ..products import ProductSettings, Selection
from ..products.points import attribute_columns, product_code
from .cluster import LocalThreads, Progress, close, connect, map_tasks
from ..tiling.checkpoint import Ledger, WorkDir, output_lock, source_key, work_dir_for
from ..errors import CrsError, InputFileError, OutputWriteError, PipelineError, SeamError
from ..store.assemble import MeshBlock, global_node_ids, mesh_offsets, write_mesh_block
from ..meshing.surface import run_variogram, signed_area
from ..store.catalog import write_stac_item
from ..tiling.scratch import Scratch
from ..tiling.windows import WindowSource, hull_copies, survey_hull
from .. import urls
from ..meshing.tiles import (
    HeldBefore, TileJob, TileSummary, dem_tile, load_kernels, load_surface_kernels, mesh_tile, reached_tiles,
)
from .compiling import KernelCompile, compile_aside
from . import resume
from .changes import forget_tiles, tiles_whose_hull_moved
from .plan import RunPlan, plan_run, union_bounds
from ..tiling.grid import TileGrid, tile_key
from ..inputs.crs import unit_metres
from ..meshing.ground import GROUND_COLUMNS, GroundJob, GroundSummary, classify_block, ground_blocks, ground_provenance
from ..meshing.ground import tile_done as ground_tile_done
from ..tiling.routing import GROUND_SPILL, PRODUCT_SPILL, RouteResult, TileSpiller, drop_source_spill, grow_hull, hull_candidates, spill_by_source

__all__ = ["run", "execute", "RunReport", "route_source"]

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
    filtered_returns: int = 0
    """Points of the DTM's classes left out by the return filter (``returns``), and read for no product."""
    products_only: int = 0
    """Points read for the products only (``layers``): not of the DTM's classes or returns."""
    not_ground: int = 0
    """Points the ground stage classified as not ground (``classify_ground``), low outliers included."""
    low_outliers: int = 0
    """Of those, points below the ground (multipath), which the ground stage never takes for ground."""
    duplicates: int = 0
    vertices: int = 0
    faces: int = 0
    quads: int = 0
    tiles: int = 0
    tiles_uncertified: int = 0
    tile_expansions: int = 0
    flip_rounds: int = 0
    """The last round in which any tile's flips touched its core (the survey's flips end there)."""
    tiles_meshed_again: int = 0
    """Tiles meshed again because a tile around them flipped later than their certificate assumed."""
    certificate_reach: list[float] = field(default_factory=list)
    """How far beyond its buffer each tile meshed in this run had to hold every point for its
    flips' and eliminations' certificate: (median, largest), in CRS units."""
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
            *([("  filtered by return", f"{self.filtered_returns:,}")] if self.filtered_returns else []),
            *([("  for the products only", f"{self.products_only:,}")] if self.products_only else []),
            *([("  classified not ground", f"{self.not_ground:,}"),
               ("    of them low outliers", f"{self.low_outliers:,}")] if self.not_ground else []),
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
    products: ProductSettings | None = None
    """The run's products: the DTM's classes and returns, and the points and attributes the products read."""
    classify: bool = False
    """The DTM's points go to the ground stage's spill files, with their returns (:mod:`pipeline.meshing.ground`)."""
    ground_columns: tuple[str, ...] = GROUND_COLUMNS
    """Their columns after x, y, z (``terrain classify`` adds each point's position in its file)."""


def route_source(job: _RouteJob) -> RouteResult:
    """Stream one file into the tiles' spill files; returns its counts.

    With ``job.skip_bad`` a file found broken while reading is dropped whole
    (its spilled points removed) and the result says why (``skipped``).
    """
    try:
        return _route(job)
    except InputFileError as exc:
        if not job.skip_bad:
            raise
        drop_source_spill(job.scratch, job.index)
        return RouteResult(job.path, skipped=str(exc))


def _route(job: _RouteJob) -> RouteResult:
    from ..inputs.crs import Reprojector
    from ..inputs.sources import PointFilter, file_digest, iter_points

    t0 = time.perf_counter()
    drop_source_spill(job.scratch, job.index)  # left by a stopped run: routed again from the start
    spill = TileSpiller(job.scratch, job.grid, job.buffer, job.index, folder=GROUND_SPILL if job.classify else "")
    settings = job.products or ProductSettings.for_run(("elevation",), job.classes, "all")
    # one read for the DTM and the products: their points, and the attributes that tell them apart
    split = _RouteSplit(job, settings)
    reproject = Reprojector(job.source_wkt, job.target_wkt, job.z_factor)
    reading, attributes = settings.reading()
    if job.classify:  # the ground stage seeds its surface with last returns
        attributes = tuple(dict.fromkeys((*attributes, *job.ground_columns)))
    point_filter = PointFilter(reading.classes, job.keep_withheld, reading.returns)
    counts = dict.fromkeys(("read", "filtered_class", "filtered_withheld", "outside_bbox", "kept", "beyond_grid",
                            "filtered_returns", "products_only"), 0)
    bounds: list[float] | None = None
    gx0, gy0, gx1, gy1 = job.grid.extent
    hull = np.empty((0, 3))
    # a COPC file in the target CRS reads only the octree nodes that meet the bbox
    window = job.bbox if reproject.is_identity else None
    for chunk in iter_points(job.path, point_filter, ROUTE_CHUNK, window=window, attributes=attributes):
        counts["read"] += chunk.read
        counts["outside_bbox"] += chunk.outside_window
        counts["filtered_class"] += chunk.filtered_class
        counts["filtered_withheld"] += chunk.filtered_withheld
        counts["filtered_returns"] += chunk.filtered_returns
        try:
            x, y, z = reproject.transform(chunk.x, chunk.y, chunk.z)
        except CrsError as exc:  # points of this file: a bad input, named (and skippable)
            raise InputFileError(f"{job.path}: {exc}") from None
        extra = chunk.attributes
        if job.bbox is not None:
            inside = (x >= job.bbox[0]) & (x <= job.bbox[2]) & (y >= job.bbox[1]) & (y <= job.bbox[3])
            counts["outside_bbox"] += int(x.size - np.count_nonzero(inside))
            x, y, z = x[inside], y[inside], z[inside]
            extra = {k: v[inside] for k, v in extra.items()}
        x, y, z, extra = split.add(x, y, z, extra, counts)
        counts["kept"] += int(x.size)
        # a stale header: kept points (in the mesh) where the DEM has no cells
        counts["beyond_grid"] += int(x.size - np.count_nonzero((x >= gx0) & (x <= gx1) & (y >= gy0) & (y <= gy1)))
        if x.size:
            b = bounds = bounds or [math.inf, math.inf, -math.inf, -math.inf]
            b[0], b[1] = min(b[0], float(x.min())), min(b[1], float(y.min()))
            b[2], b[3] = max(b[2], float(x.max())), max(b[3], float(y.max()))
        if job.classify:
            spill.add(x, y, z, attribute_columns(extra, job.ground_columns, x.shape[0]))
        else:
            spill.add(x, y, z)
        hull = grow_hull(hull, x, y, z)
    spill.flush()
    split.flush()
    return RouteResult(
        job.path, **counts,
        bounds=None if bounds is None else tuple(bounds),
        parts=tuple(tuple(p) for p in spill.parts),  # a resume checks they are still there
        product_parts=tuple(tuple(p) for p in split.parts),
        tile_points=tuple(tuple(t) for t in spill.points),  # the tiles' work, to start the largest first
        sha256=file_digest(job.path),
        seconds=time.perf_counter() - t0,
        hull=hull,
    )


class _RouteSplit:
    """Parts one read into the DTM's points and the products' (spilled to
    each tile's product folder with their attributes), counting the points
    read for neither (those the reader kept for a union of the two)."""

    def __init__(self, job: _RouteJob, settings: ProductSettings) -> None:
        self.settings = settings
        self.reading = settings.reading()[0]
        self.spill = None
        if settings.reads is not None:
            self.spill = TileSpiller(job.scratch, job.grid, settings.spill_buffer(job.buffer), job.index,
                                     folder=PRODUCT_SPILL)

    def add(self, x, y, z, attributes, counts: dict[str, int]):
        """The DTM's points of ``x, y, z`` and their attributes; the products' ones spilled."""
        s = self.settings
        if s.reads is None or s.dtm == self.reading:
            dtm = None
        else:
            dtm = s.dtm.mask(x.size, attributes)
        if s.reads is not None:
            mine = s.reads.mask(x.size, attributes) if s.reads != self.reading else np.ones(x.size, dtype=bool)
            if mine.all():  # every point read is the products' (the usual case): no copy
                self.spill.add(x, y, z, product_code(attributes, s.columns, x.shape[0]))
            else:
                self.spill.add(x[mine], y[mine], z[mine],
                               product_code({k: v[mine] for k, v in attributes.items()}, s.columns, int(mine.sum())))
            if dtm is not None:
                counts["products_only"] += int(np.count_nonzero(mine & ~dtm))
                neither = ~mine & ~dtm
                if neither.any():  # the reader kept them for a union: the DTM's class, or not
                    in_class = Selection(s.dtm.classes).mask(x.size, attributes)
                    counts["filtered_returns"] += int(np.count_nonzero(neither & in_class))
                    counts["filtered_class"] += int(np.count_nonzero(neither & ~in_class))
        if dtm is None:
            return x, y, z, attributes
        return x[dtm], y[dtm], z[dtm], {k: v[dtm] for k, v in attributes.items()}

    @property
    def parts(self) -> list[list[int]]:
        return [] if self.spill is None else self.spill.parts

    def flush(self) -> None:
        if self.spill is not None:
            self.spill.flush()


def _skipped_note(skipped: list) -> str:
    return f"{len(skipped)} bad file(s) skipped (skip_bad_files=True); their points are not in the output"


def run(config: RunConfig, *, progress: bool | None = None, log: Callable[[str], None] | None = None) -> RunReport:
    """Run a job end to end and return its report (also stored in the store's attributes).

    ``progress`` draws progress bars on stderr (default: when it is a terminal);
    ``log`` receives one-line messages about the run.

    A job that was stopped (killed, interrupted, failed) resumes when run
    again with the same parameters and inputs: finished files, tiles and mesh
    blocks are skipped (see :mod:`pipeline.tiling.checkpoint`).  A store made with
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
    whose points (or hull) changed are computed again (see :mod:`pipeline.runs.workflow`).

    Raises
    ------
    OutputWriteError
        When the store or the work folder cannot be written (read-only, full,
        ...): one line naming the file; the run resumes once the cause is fixed.
    """
    urls.use_storage_options(config.storage_options)
    try:
        with output_lock(config.output):
            try:
                return _execute(config, progress=progress, log=log, incremental=incremental)
            finally:
                _finish_removals()
    except PipelineError:  # input errors are OSErrors too; their messages are already clear
        raise
    except Exception as exc:
        cause = urls.unreachable(exc) if urls.is_url(config.output) else None
        if cause is not None:  # the store's server: writing it failed part way
            raise urls.unreachable_error(str(config.output), cause) from None
        if not isinstance(exc, OSError):
            raise
        if exc.filename is None:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):  # a full disk (a short write says so: Scratch)
                raise OutputWriteError(
                    f"{config.output}: cannot write the store or its work files ({exc.strerror or exc}); "
                    "run the same command again once there is room: finished work is kept"
                ) from exc
            raise
        raise OutputWriteError(
            f"{config.output}: cannot write {exc.filename} ({exc.strerror or exc}); "
            "run the same command again once this is fixed: finished work is kept"
        ) from exc


def _finish_removals() -> None:
    """Wait for the deletion of the store this run replaced (it runs beside the run)."""
    from ..store import zarr_store as store

    store.finish_removals()


def _execute(
    config: RunConfig,
    *,
    progress: bool | None,
    log: Callable[[str], None] | None,
    incremental: bool,
) -> RunReport:
    from ..store import zarr_store as store

    # absolute: tasks on a cluster's workers run in other folders
    config = replace(config, output=str(urls.location(config.output)))
    show = sys.stderr.isatty() if progress is None else progress
    say = log or (lambda message: None)
    report = RunReport()
    t_start = t0 = time.perf_counter()

    plan = plan_run(config, keep_sizes=incremental)
    report.skipped_files = list(plan.skipped_files)
    report.notes.extend(plan.notes)
    report.tiles = plan.grid.n_tiles
    grid = plan.grid
    say(f"{len(plan.paths)} file(s), grid {grid.nx} x {grid.ny} cells, {grid.n_rows} x {grid.n_cols} tiles")
    work = WorkDir(work_dir_for(config.output, config.scratch_dir, cluster=config.scheduler_address is not None))
    decision = resume.decide(plan, incremental)
    report.notes.extend(decision.notes)
    if decision.complete:
        return _already_complete(config, decision, work, report, say)
    # the cluster first: an unreachable scheduler leaves no store and no work folder behind
    client, cluster = connect(config)
    # the digest that stamps the work folder, read before a thread loads the kernels: its ~90 source
    # files take 10 ms alone, and ten times that read one by one behind a thread running Python
    resume.sources_digest()
    compiling = KernelCompile(None)
    if isinstance(client, LocalThreads):
        # the tiles' kernels are loaded (from the compiled cache) by a thread
        # that the store's creation and the inputs leave idle: 0.1-0.2 s of a
        # one-file job that its first tiles waited for.  Not compiled yet (the
        # first run on this machine): the mesh kernels are compiled in another
        # process meanwhile, the DEM's in that thread
        job = _kernel_job(plan, work.scratch)
        compiling = compile_aside(job.options)
        client.submit(_load_surface_kernels if compiling.processes else load_kernels, job)
    try:
        resume.prepare(plan, decision, work, incremental, report.notes, say)
        report.stages["scan"] = time.perf_counter() - t0
    except BaseException:
        compiling.stop()
        with contextlib.suppress(Exception):  # the first error is the one to report
            close(client, cluster)
        raise

    provenance = dict(plan.provenance)
    try:
        before = copy.deepcopy(report)
        meshed = _route_and_mesh(plan, work, client, compiling, show, report, provenance)
        if isinstance(meshed, NoDefaultSurface):
            # the default classes made no surface (a survey never classified, or a ground point or
            # two): the ground classified from every point but noise, rather than no surface
            resume.keep_all_but_noise(work, config.output, meshed.points, meshed.left_by_returns)
            report = before
            meshed = _route_and_mesh(plan, work, client, compiling, show, report, provenance)
            assert isinstance(meshed, Meshed)  # the fallback's classes are not the default ones
        t0 = time.perf_counter()
        valued = _dem_stage(plan, work, client, meshed, mesh_offsets(grid, list(meshed.summaries.values())), show)
        if valued == 0:
            report.notes.append(_empty_dem_note(config))
        report.stages["dem and mesh"] = time.perf_counter() - t0
    finally:
        compiling.stop()
        close(client, cluster)

    report.stages["total"] = time.perf_counter() - t_start
    store.finalize_store(
        config.output,
        {"provenance": provenance, "report": report.to_dict(), "complete": True, "incremental": decision.keep_work},
        history={"finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "report": report.to_dict()},
    )
    write_stac_item(config.output, keep_exports=False)
    if not decision.keep_work:
        work.remove()
    return report


def _already_complete(config: RunConfig, decision: resume.Resume, work: WorkDir, report: RunReport,
                      say: Callable[[str], None]) -> RunReport:
    """The report of a store already finished from these inputs."""
    say(f"{config.output}: already complete; nothing to do")
    assert decision.previous is not None
    done = RunReport(**{k: v for k, v in decision.previous.get("report", {}).items() if k != "quad_share"})
    done.notes.append("the store was already complete: nothing was recomputed")
    done.skipped_files = report.skipped_files  # this run's bad files, not the last run's
    if not decision.keep_work:
        work.remove()  # left by a run stopped just after it marked the store complete
    if report.skipped_files:
        done.notes.append(_skipped_note(report.skipped_files))
    return done


@dataclass(frozen=True)
class NoDefaultSurface:
    """The mesh stage's result when the inputs' points of the default classes
    make no surface and they hold points of others: the run starts over on
    the ground it classifies (:func:`pipeline.runs.resume.keep_all_but_noise`)."""

    points: int
    """The points of the default classes that were kept."""
    left_by_returns: int = 0
    """The points of the default classes that ``returns`` left out."""


def _route_and_mesh(plan: RunPlan, work: WorkDir, client, compiling: KernelCompile, show: bool, report: RunReport,
                    provenance: dict[str, Any]) -> Meshed | NoDefaultSurface:
    """The route, variogram and mesh stages (see :func:`_execute`)."""
    config = plan.config
    t0 = time.perf_counter()
    routed = _route_stage(plan, work, client, show, report)
    report.stages["route"] = time.perf_counter() - t0
    if routed.classify:
        t0 = time.perf_counter()
        parameters = ground_parameters(plan, routed)
        routed = replace(routed, hull=_ground_stage(plan, work, client, routed, show, report, parameters))
        report.stages["ground"] = time.perf_counter() - t0
        provenance["ground_classification"] = ground_provenance(parameters.to_dict())
    if routed.fallback is not None:
        found, left = routed.fallback.default_points, routed.fallback.default_left_by_returns
        default = ", ".join(str(c) for c in DEFAULT_CLASSES)
        why = (f"{'no' if found == 0 else f'only {found:,}'} input point(s) of the default classes ({default}, ground)"
               f"{'' if config.bbox is None else ' inside the bbox'}"
               f"{f' kept, {left:,} more left out by returns={config.returns.value}' if left else ''}")
        provenance["classes_kept"] = {"classes": routed.fallback.classes, "why": why}
        noise = " and ".join(str(c) for c in resume.NOISE_CLASSES)
        report.notes.append(
            f"{why}{'' if found == 0 else ', too few or all on one line'}: the ground was classified from every point "
            f"but noise (classes {noise}) and the surface made from it (as with classify_ground)"
        )
    variogram = None
    if config.surface == "smooth":
        t0 = time.perf_counter()
        variogram, provenance["smooth_surface"] = run_variogram(
            work, plan.grid, config.duplicates, report.points_kept, routed.hull
        )
        report.stages["variogram"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    compiling.wait()
    meshed = _mesh_stage(plan, work, client, routed, variogram, show, report)
    report.stages["mesh"] = time.perf_counter() - t0
    return meshed


@dataclass(frozen=True)
class Routed:
    """What the route stage leaves for the tiles: each input's result (its
    route record), the inputs the tiles read by window, the global hull."""

    results: list[RouteResult]
    windows: tuple[WindowSource, ...]
    hull: np.ndarray
    fallback: resume.ClassFallback | None
    """Every class but noise classified, because the default ones made no surface (None: the run's classes)."""
    classify: bool = False
    """The ground stage classifies the ground (``classify_ground``, or the fallback)."""


def _route_stage(plan: RunPlan, work: WorkDir, client, show: bool, report: RunReport,
                 ground_columns: tuple[str, ...] = GROUND_COLUMNS) -> Routed:
    """Route every input not yet routed into the tiles' spill files (a COPC
    file in the output CRS only gives its hull), count the points by fate,
    and compute the global hull; the tiles near a part of it that moved are
    computed again."""
    config, grid, crs, scratch = plan.config, plan.grid, plan.crs, work.scratch
    paths, infos = plan.paths, plan.infos
    fallback = resume.class_fallback(work)
    classify = config.classify_ground or fallback is not None
    classes = resume.ALL_BUT_NOISE if classify else config.classes
    records = (work.recorded(Ledger.ROUTE, source_key(i), "hull") for i in range(len(paths)))
    results = [None if rec is None else RouteResult.from_record(rec) for rec in records]
    # a file an earlier run of this work folder routed keeps its spill files
    windows = () if classify else tuple(w for w in _window_sources(config, classes, paths, infos, crs)
                                        if results[w.index] is None or results[w.index].window)
    windowed = {w.index for w in windows}
    jobs = [
        _RouteJob(
            i, str(p), scratch, grid, plan.buffer, crs.source_wkts[i], crs.target_wkt, crs.z_factor(i),
            classes, config.keep_withheld, config.bbox, config.skip_bad_files, _products(plan, classify), classify,
            ground_columns,
        )
        for i, p in enumerate(paths)
        if results[i] is None and i not in windowed
    ]

    def routed(index: int, result: RouteResult) -> None:
        work.record(Ledger.ROUTE, source_key(index), result.to_record(), hull=result.hull)
        results[index] = result

    map_tasks(client, route_source, jobs, Progress("read", len(jobs), show), lambda r: r.read,
              lambda job, result: routed(job.index, result))
    surveys = [w for w in windows if results[w.index] is None]
    map_tasks(client, survey_hull, surveys, Progress("hull", len(surveys), show), lambda _: 0,
              lambda w, result: routed(w.index, result))
    done: list[RouteResult] = []
    for i, c in enumerate(results):
        assert c is not None
        done.append(c)
        if c.window:  # counted by the tiles that read it
            continue
        if c.skipped is not None:
            report.skipped_files.append({"path": c.path, "reason": c.skipped, "points": infos[i].point_count})
            continue
        report.points_read += c.read
        report.filtered_class += c.filtered_class
        report.filtered_withheld += c.filtered_withheld
        report.outside_bbox += c.outside_bbox
        report.filtered_returns += c.filtered_returns
        report.products_only += c.products_only
        report.points_kept += c.kept
        if c.kept == 0:
            report.notes.append(f"{c.path}: no points of the chosen classes")
        if c.beyond_grid:
            report.notes.append(
                f"{c.path}: {c.beyond_grid:,} point(s) lie beyond the bounds its header announces "
                "(a stale header?): the mesh holds them, the DEM stops at the header's extent"
            )
    if report.skipped_files:
        report.notes.append(_skipped_note(report.skipped_files))
    hull = np.empty((0, 3))
    if not classify:  # else the hull of the ground stage's points
        hull = _settled_hull(plan, work, np.concatenate([c.hull for c in done]), windows, report)
    return Routed(done, windows, hull, fallback, classify)


def _products(plan: RunPlan, classify: bool) -> ProductSettings:
    """The run's products, the same for the route stage (which spills their points' columns) and the DEM
    stage (which reads them): with the ground classified, of the points it classifies."""
    if classify:
        return plan.products(resume.ALL_BUT_NOISE, classified=True)
    return plan.products(plan.config.classes)


def _settled_hull(plan: RunPlan, work: WorkDir, candidates: np.ndarray, windows: tuple[WindowSource, ...],
                  report: RunReport) -> np.ndarray:
    """The global hull of the kept points (from their parts' hulls, ``candidates``), saved; the tiles near a
    part of it that moved since the work folder's last run are computed again."""
    config, grid = plan.config, plan.grid
    hull = _hull_points(candidates, grid, work.scratch, config.duplicates, windows)
    moved = tiles_whose_hull_moved(work, grid, plan.buffer, hull)
    if moved:
        forget_tiles(work, config.output, grid, moved)
        report.notes.append(f"the convex hull changed near {len(moved)} tile(s): computed again")
    work.save("hull.npy", hull)
    return hull


def ground_parameters(plan: RunPlan, routed: Routed) -> GroundParameters:
    """The ground filter's parameters for this survey: the defaults, for its
    point spacing (:meth:`meshcore.GroundParameters.for_spacing`), measured
    as the square root of the area of the convex hull of the points routed
    over their number, so the same whatever the tiling: each point counted
    once (the tiles' counts hold the copies sent to their buffers too)."""
    unit = unit_metres(plan.crs.horizontal_unit) or 1.0
    hull = routed_hull(routed)
    count = sum(c.kept for c in routed.results)
    if hull.shape[0] < 3 or count <= 0:
        return GroundParameters()
    area = abs(signed_area(hull - hull.min(axis=0)))
    return GroundParameters().for_spacing(math.sqrt(area / count) * unit)


def routed_hull(routed: Routed) -> np.ndarray:
    """The convex hull ``(h, 2)`` of the points routed (every class but noise when
    classifying), from each input's hull candidates: the same whatever the tiling."""
    parts = [np.asarray(c.hull).reshape(-1, 3) for c in routed.results if c.hull is not None]
    return hull_candidates(np.concatenate(parts))[:, :2] if parts else np.empty((0, 2))


def _ground_stage(plan: RunPlan, work: WorkDir, client, routed: Routed, show: bool, report: RunReport,
                  parameters: GroundParameters, columns: tuple[str, ...] = GROUND_COLUMNS) -> np.ndarray:
    """Classify the ground of every block of tiles not done (:mod:`pipeline.meshing.ground`), count the
    points it left out, and return the global hull of the ground points."""
    grid, scratch = plan.grid, work.scratch
    unit = unit_metres(plan.crs.horizontal_unit) or 1.0
    points: dict[tuple[int, int], int] = {}
    for c in routed.results:
        for r, col, n in c.tile_points:
            points[(r, col)] = points.get((r, col), 0) + n

    def done(r: int, c: int) -> bool:
        return ground_tile_done(scratch, r, c) and work.recorded(Ledger.GROUND, tile_key(r, c)) is not None

    hull = routed_hull(routed)
    jobs = [GroundJob(rows, cols, scratch, grid, plan.buffer, unit, parameters.to_dict(), columns=columns, hull=hull)
            for rows, cols in ground_blocks(grid, points, parameters.margin(unit))]
    jobs = [job for job in jobs if not all(done(r, c) for r, c in job.tiles())]
    if isinstance(client, LocalThreads) and jobs:  # this process's threads: those fewer blocks leave idle
        jobs = [replace(job, threads=max(1, client.threads // len(jobs))) for job in jobs]

    def classified(job: GroundJob, summaries: list[GroundSummary]) -> None:
        for s in summaries:
            work.record(Ledger.GROUND, tile_key(s.row, s.col), s.to_record(), hull=s.hull)

    map_tasks(client, classify_block, jobs, Progress("ground", len(jobs), show),
              lambda summaries: sum(s.ground + s.not_ground for s in summaries), classified)
    hulls = []
    for r, c in grid.tiles():
        rec = work.recorded(Ledger.GROUND, tile_key(r, c), "hull")
        if rec is None:
            continue
        report.not_ground += int(rec["not_ground"])
        report.low_outliers += int(rec["low_outliers"])
        hulls.append(np.asarray(rec["hull"]).reshape(-1, 3))
    report.points_kept -= report.not_ground
    return _settled_hull(plan, work, np.concatenate(hulls) if hulls else np.empty((0, 3)), (), report)


def _load_surface_kernels(job: TileJob) -> None:
    load_surface_kernels(job.options.max_edge, job.options.surface, job.options.layers)


def _kernel_job(plan: RunPlan, scratch: Scratch) -> TileJob:
    """A tile job with the run's measures, for :func:`load_kernels`."""
    config = plan.config
    return TileJob(0, 0, scratch, plan.grid, plan.buffer, plan.bounds, config.mesh_options())


@dataclass(frozen=True)
class Meshed:
    """What the mesh stage leaves: every tile's job and summary, and the
    tiles meshed by this run."""

    tile_jobs: list[TileJob]
    summaries: dict[tuple[int, int], TileSummary]
    meshed_now: list[TileJob]


def _mesh_stage(plan: RunPlan, work: WorkDir, client, routed: Routed, variogram, show: bool,
                report: RunReport) -> Meshed | NoDefaultSurface:
    """Mesh every tile without a record, the largest first, and total the tiles' counts
    (:class:`NoDefaultSurface` when the default classes made no surface)."""
    config, grid, results = plan.config, plan.grid, routed.results
    # where the points are: the headers' extent, grown where a stale header
    # understates it (the tiles' search for missing points must reach them)
    extent = union_bounds([plan.bounds, *(c.bounds for c in results if c.bounds is not None)])
    run_id = uuid.uuid4().hex
    tile_jobs = [
        TileJob(
            r, c, work.scratch, grid, plan.buffer, extent, config.mesh_options(), hull=routed.hull,
            height_scale=plan.crs.height_scale, run_id=run_id, variogram=variogram, windows=routed.windows,
        )
        for r, c in grid.tiles()
    ]
    summaries: dict[tuple[int, int], TileSummary] = {}
    for job in tile_jobs:
        rec = work.recorded(Ledger.MESH, _tile_key(job))
        if rec is not None:
            rec["held"] = tuple(tuple(box) for box in rec.get("held", ()))
            rec["reach"] = None if rec.get("reach") is None else tuple(rec["reach"])
            rec["window_counts"] = tuple(tuple(row) for row in rec.get("window_counts", ()))
            summaries[(job.row, job.col)] = TileSummary(**rec)
    pending = [job for job in tile_jobs if (job.row, job.col) not in summaries]
    # the largest tiles first, so that no core is left with one at the end
    work_of: dict[tuple[int, int], int] = {}
    for c in results:
        for r, col, n in c.tile_points:
            work_of[(r, col)] = work_of.get((r, col), 0) + n
    pending.sort(key=lambda job: -work_of.get((job.row, job.col), 0))

    def meshed(job: TileJob, summary: TileSummary) -> None:
        work.record(Ledger.MESH, _tile_key(job), asdict(summary))
        summaries[(job.row, job.col)] = summary

    map_tasks(client, mesh_tile, pending, Progress("mesh", len(pending), show), lambda s: s.points_owned, meshed)
    while True:
        # a tile's certificate assumed its neighbours make no flip after its assumed rounds: where one
        # did, mesh it again assuming as many (its faces change only if the assumption was wrong)
        again = _rounds_unchecked(grid, tile_jobs, summaries)
        if not again:
            break
        done = {(job.row, job.col) for job in pending}
        pending = pending + [job for job in again if (job.row, job.col) not in done]
        map_tasks(client, mesh_tile, again, Progress("mesh", len(again), show), lambda s: s.points_owned, meshed)
        report.tiles_meshed_again += len(again)
    reach = [summaries[(job.row, job.col)].grown for job in pending]
    if reach:
        report.certificate_reach = [float(np.median(reach)), float(max(reach))]
    _count_windows(report, results, plan.infos, routed.windows, summaries.values())
    report.files = [c.to_report() for c in results if c.skipped is None]
    for s in summaries.values():
        report.duplicates += s.duplicates
        report.vertices += s.vertices_owned
        report.faces += s.faces
        report.quads += s.quads
        report.tile_expansions += s.expansions
        report.flip_rounds = max(report.flip_rounds, s.last_flip_round)
        report.tiles_uncertified += 0 if s.certified else 1
    if report.faces == 0:
        paths = plan.paths
        names = ", ".join(str(p) for p in paths[:3]) + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")
        # points of other classes than the DTM's: left out, or read for the products only
        if report.filtered_class + report.products_only > 0 and config.classes == DEFAULT_CLASSES \
                and routed.fallback is None:
            return NoDefaultSurface(report.points_kept, report.filtered_returns)
        kept = "every class but noise" if routed.fallback is not None else ", ".join(str(c) for c in config.classes or ())
        raise PipelineError(f"{names}: no surface: {_no_surface(report, kept)}")
    uncertified = sorted(key for key, s in summaries.items() if not s.certified)
    if uncertified:  # recorded by an older version that gave up: mesh them again
        raise SeamError(
            f"{config.output}: {len(uncertified)} tile(s), first {uncertified[0]}, were meshed by a version "
            "that could not certify their seams; run again with overwrite to mesh every tile again"
        )
    return Meshed(tile_jobs, summaries, pending)


def _no_surface(report: RunReport, kept: str) -> str:
    """Why the kept points made no surface: too few, or none kept, and what left the points read out."""
    if report.points_kept > 0:
        return f"the {report.vertices:,} distinct kept point(s) are fewer than three or all on one line"
    fates = [
        (report.filtered_class, f"not of the classes kept ({kept})"),
        (report.products_only, f"read for the layers only (not of the classes kept, {kept}, or of the returns kept)"),
        (report.filtered_withheld, "withheld (keep_withheld=True keeps them)"),
        (report.outside_bbox, "outside the bbox"),
        (report.filtered_returns, "left out by returns"),
        (report.not_ground, "classified not ground"),
    ]
    return f"none of the {report.points_read:,} point(s) read is kept: " + ", ".join(
        f"{count:,} {why}" for count, why in fates if count)


def _rounds_unchecked(grid, tile_jobs: list[TileJob], summaries: dict) -> list[TileJob]:
    """The tiles to mesh again, each with the rounds it must assume: those
    around which a tile flipped later than their certificate assumed.

    A tile's flips spread doubt over the triangles it holds only until the
    round its certificate assumed; the tiles whose windows meet the boxes it
    held say how long the survey flipped there: each gives the last flip
    round of every block of its window
    (:meth:`~pipeline.meshing.tiles.TileSummary.last_flip_round_in`), so a
    late flip in the middle of a tile makes only the tiles whose held boxes
    reach it mesh again, not the eight around it.
    """
    # only the tiles that flipped later than a tile assumed can make it mesh
    # again: a survey of thousands of tiles holding boxes across hundreds of
    # others asks a few of them, not every tile its boxes span
    latest = sorted(((s.latest_flip_round, key) for key, s in summaries.items()), reverse=True)
    out = []
    for job in tile_jobs:
        s = summaries[(job.row, job.col)]
        late = [key for round_, key in itertools.takewhile(lambda rk: rk[0] > s.assumed_rounds, latest)]
        if not late:
            continue
        held = list(s.held) or [grid.window(job.row, job.col)]
        need = max((summaries[key].last_flip_round_in(held) for key in grid.tiles_meeting(held, among=late)), default=0)
        if s.assumed_rounds < need:
            out.append(replace(job, assume_rounds=need, held_before=HeldBefore(s.held, s.grown)))
    return out


def _empty_dem_note(config: RunConfig) -> str:
    """Why a DEM of a surface has no value."""
    if config.max_edge is not None:
        return (f"the DEM is empty: no cell centre lies under a face no longer than max_edge={config.max_edge:g}; "
                "finer cells, or a larger max_edge, give some")
    return "the DEM is empty: no cell centre lies under a face (the surface is smaller than the cells); finer cells give some"


def _dem_stage(plan: RunPlan, work: WorkDir, client, meshed: Meshed, offsets: tuple[np.ndarray, np.ndarray],
               show: bool) -> int | None:
    """Write the DEM of every tile not yet written, and of every tile that a
    face meshed by this run reaches, and the mesh; returns the cells with an
    elevation, when this run wrote every tile (else None: the others were
    not counted).

    The same tasks number the pieces' nodes and write the nodes and faces
    into the store's mesh group in blocks of whole chunks (``offsets``: the
    tiles' first node and face), a block of faces once the tiles it spans are
    numbered (:func:`_dem_order`): the cores go from one to the other without
    waiting at the end of the DEM for its last tile."""
    from ..store import zarr_store as store

    config, grid = plan.config, plan.grid
    node_offsets, face_offsets = offsets
    tile_jobs = _dem_jobs(plan, work, meshed)
    written = store.tiles_done(config.output)
    pending = [job for job in tile_jobs if not written[job.row, job.col]]

    def dem_and_write(job: TileJob) -> int:
        """The tile's DEM written; how many of its cells have an elevation."""
        layers = dem_tile(job)
        try:
            store.write_tile(config.output, grid, job.row, job.col, layers, run=job.run_id, mark_done=True)
        except OSError as exc:
            raise OutputWriteError(
                f"{config.output}: cannot write tile ({job.row}, {job.col}): {exc.strerror or exc}; "
                "the store is incomplete: run the same command again to resume once this is fixed"
            ) from None
        return int(np.count_nonzero(np.isfinite(layers["elevation"])))

    unnumbered = [job for job in tile_jobs if work.recorded(Ledger.WRITE, f"ids_{_tile_key(job)}") is None]
    number = partial(global_node_ids, node_offsets=node_offsets)
    writer, blocks = _mesh_blocks(config, grid, work, node_offsets, face_offsets)
    work_of = {"dem": dem_and_write, "number": lambda job: number(job) or 0, "write": write_mesh_block}
    valued = 0

    def done(task: tuple[str, Any], result: Any) -> None:
        nonlocal valued
        what, item = task
        if what == "number":
            work.record(Ledger.WRITE, f"ids_{_tile_key(item)}", {})
        elif what == "write":
            writer.record(*result)
            work.record(Ledger.WRITE, f"{item.what}_{item.start}", {"stop": item.stop})
        else:
            valued += result

    tasks: list[tuple[str, Any]] = ([("dem", job) for job in pending] + [("number", job) for job in unnumbered]
                                    + [("write", block) for block in blocks])
    map_tasks(client, lambda task: work_of[task[0]](task[1]), tasks, Progress("dem", len(tasks), show),
              lambda _: 0, done, after=_dem_order(grid, tasks))
    order = list(grid.tiles())
    writer.set_tiles(np.array([r for r, _ in order]), np.array([c for _, c in order]), node_offsets, face_offsets)
    writer.close()
    return valued if len(pending) == len(tile_jobs) else None


def _dem_jobs(plan: RunPlan, work: WorkDir, meshed: Meshed) -> list[TileJob]:
    """Every tile's job for the DEM stage, with the tiles whose faces reach it
    and the products; the tiles under faces meshed by this run are marked to
    be written again, however far the faces reach."""
    from ..store import zarr_store as store

    grid = plan.grid
    reached = {key: reached_tiles(grid, s.reach, *key) for key, s in meshed.summaries.items()}
    reaching: dict[tuple[int, int], set[tuple[int, int]]] = {t: set() for t in grid.tiles()}
    for key, tiles in reached.items():
        for t in tiles:
            reaching[t].add(key)
    store.reset_tiles_done(plan.config.output,
                           sorted({t for job in meshed.meshed_now for t in reached[(job.row, job.col)]}))
    classify = plan.config.classify_ground or resume.class_fallback(work) is not None
    products = _products(plan, classify)
    return [replace(job, reaching=tuple(sorted(reaching[(job.row, job.col)])), products=products)
            for job in meshed.tile_jobs]


def _dem_order(grid: TileGrid, tasks: list[tuple[str, Any]]) -> dict[int, list[int]]:
    """Which of the DEM stage's tasks (by index) each must wait for.

    - A block of faces waits for the numbering of the tiles it spans (it
      writes their global node ids).
    - Where the store's chunk rows each hold parts of two tile rows
      (:attr:`~pipeline.tiling.grid.TileGrid.rows_share_chunks`), a tile of
      an odd row waits for the tiles of the even rows north and south of it
      in its column, the only ones that write parts of its chunks (a tile's
      column of cells is a column of chunks): no two tiles writing parts of
      one chunk run at the same time, and the others need not wait."""
    dem = {(item.row, item.col): i for i, (what, item) in enumerate(tasks) if what == "dem"}
    numbered = {(item.row, item.col): i for i, (what, item) in enumerate(tasks) if what == "number"}
    out: dict[int, list[int]] = {}
    for i, (what, item) in enumerate(tasks):
        if what == "write" and item.what == "faces":
            before = [numbered[item.tiles[k]] for k, _, _ in item.spans() if item.tiles[k] in numbered]
        elif what == "dem" and grid.rows_share_chunks and item.row % 2:
            before = [dem[(item.row + d, item.col)] for d in (-1, 1) if (item.row + d, item.col) in dem]
        else:
            continue
        if before:
            out[i] = before
    return out


def _tile_key(job: TileJob) -> str:
    return tile_key(job.row, job.col)


def plan_reads_points(config: RunConfig) -> bool:
    """Whether a product of the run reads points (they are routed, with their attributes)."""
    return ProductSettings.for_run(config.layers, config.classes, config.returns).reads_points


def _window_sources(config: RunConfig, classes: tuple[int, ...] | None, paths, infos, plan) -> tuple[WindowSource, ...]:
    """The inputs tiles read by window: COPC files already in the target CRS.

    The others are routed, and so is every file of a run that skips broken
    files (a routing pass finds a broken one before any tile uses it) or
    samples a variogram (which needs the number of points kept beforehand),
    or filters returns or computes products from points (read with their attributes).
    """
    from ..inputs.crs import Reprojector

    if config.skip_bad_files or config.surface != "linear" or config.returns != "all" or plan_reads_points(config):
        return ()
    return tuple(
        WindowSource(i, str(p), classes, config.keep_withheld, config.bbox)
        for i, (p, info) in enumerate(zip(paths, infos))
        if info.is_copc and Reprojector(plan.source_wkts[i], plan.target_wkt, plan.z_factor(i)).is_identity
    )


def _count_windows(report: RunReport, results: list[RouteResult], infos, windows, summaries) -> None:
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
        results[w.index] = results[w.index].counted(header, filtered_class, filtered_withheld, outside_bbox + unread, kept)
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
    from ..meshing.tiles import vertex_z

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
        # the rows at a hull point's x first (a few of the tile's), then their x and y together
        near = np.flatnonzero(np.isin(pts[:, 0], hull[mine, 0]))
        pts = pts[near]
        pkey = pts[:, 0] + 1j * pts[:, 1]
        sel = np.isin(pkey, key[mine])
        # every copy of a hull point, reduced by the duplicate policy like any vertex
        by_key = np.argsort(key[mine])
        group = np.searchsorted(key[mine][by_key], pkey[sel])
        hull[mine[by_key], 2] = vertex_z(group, mine.size, pts[sel, 2], policy)
    return hull


def _mesh_blocks(config: RunConfig, grid: TileGrid, work: WorkDir, node_offsets,
                 face_offsets) -> tuple[Any, list[MeshBlock]]:
    """The store's mesh writer, and the blocks of whole chunks of its nodes
    and faces left to write (those written before a stop are kept)."""
    from ..store import zarr_store as store

    order = tuple(grid.tiles())
    sizes = {"nodes": int(node_offsets[-1]), "faces": int(face_offsets[-1])}
    if work.recorded(Ledger.WRITE, "created") == sizes:
        writer = store.MeshWriter.attach(config.output)
    else:
        writer = store.MeshWriter(config.output, sizes["nodes"], sizes["faces"], config.zarr_format)
        work.record(Ledger.WRITE, "created", sizes)
    step = 4 * store.MESH_CHUNK
    blocks = []
    for what, offsets in (("nodes", node_offsets), ("faces", face_offsets)):
        for start in range(0, int(offsets[-1]), step):
            stop = min(start + step, int(offsets[-1]))
            if work.recorded(Ledger.WRITE, f"{what}_{start}") is not None:
                writer.record(what, start, stop)
                continue
            blocks.append(MeshBlock(config.output, work.scratch, order, tuple(int(v) for v in offsets), what, start, stop))
    return writer, blocks
