"""Whether a run starts afresh, resumes, or updates a store: one place for
both of a run's ledgers.

A run's finished work is recorded in two places: the work folder's records
(:class:`~pipeline.tiling.checkpoint.WorkDir`: routed files, meshed tiles, written
mesh blocks) and the store's ``status/tile_done`` (DEM tiles written).
:func:`decide` compares the plan of this run with the store's provenance;
:func:`prepare` then makes the store and the work folder agree with the
decision: a new store, a store grown north or east, the records of the units
that changed forgotten, or nothing (a resume).
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from .changes import changed_inputs, forget_changed_inputs, forget_tiles, reroute_near_growth, tiles_depending_on
from ..tiling.checkpoint import Ledger, WorkDir, source_key
from ..config import RunConfig
from ..errors import PipelineError, UsageError
from .plan import RunPlan, frame_change, frame_grew, frame_moved
from ..meshing.piece import SURFACE_ARRAYS, Piece
from ..tiling.grid import TileGrid, tile_key
from ..tiling.routing import spill_intact

__all__ = [
    "Resume", "Update", "decide", "plan_update", "prepare", "work_reusable", "NOISE_CLASSES", "ALL_BUT_NOISE", "ClassFallback",
    "class_fallback", "keep_all_but_noise",
]


@dataclass(frozen=True)
class Resume:
    """What a run does with the store it finds."""

    previous: dict[str, Any] | None
    """The store's attributes when the run goes on from them; None: afresh."""
    grown_from: TileGrid | None = None
    """The grid an incremental run grows to the north or east."""
    same_inputs: bool = False
    keep_work: bool = False
    """A workflow's store keeps its work folder between runs."""
    notes: tuple[str, ...] = field(default=())
    moved_from: dict[str, Any] | None = None
    """The store's provenance when this run moves its frame (not a growth
    north or east): every tile is computed again, for :func:`~pipeline.runs.plan.frame_change`'s reason."""

    @property
    def complete(self) -> bool:
        """The store is finished, from these very inputs: nothing to do."""
        return self.previous is not None and bool(self.previous.get("complete")) and self.same_inputs


def decide(plan: RunPlan, incremental: bool) -> Resume:
    """Compare the plan with the store at ``plan.config.output``.

    Raises UsageError for a store of another job (other parameters, other
    inputs unless ``incremental``, another grid) unless ``overwrite``.
    """
    from ..store import zarr_store as store

    config, provenance = plan.config, plan.provenance
    previous = existing_job(config, provenance, allow_new_inputs=incremental)
    fresh_frame = previous is not None and frame_moved(previous.get("provenance", {}), provenance)
    grown_from = moved_from = None
    notes: list[str] = []
    if incremental and fresh_frame and previous.get(store.GROWING_ATTR):
        notes.append("an earlier run stopped while it grew the grid: every tile was computed again")
        previous = None
    elif incremental and fresh_frame and frame_grew(previous["provenance"], provenance):
        grown_from = TileGrid.from_dict(previous["provenance"]["grid"])
    elif incremental and fresh_frame:
        moved_from = previous["provenance"]
        notes.append(f"{frame_change(moved_from, provenance)}: every tile was computed again")
        previous = None
    elif fresh_frame:
        raise UsageError(f"{config.output}: the existing store has another grid; pass overwrite=True to replace it")
    same_inputs = previous is not None and input_keys(previous["provenance"]["inputs"]) == input_keys(provenance["inputs"])
    # a workflow's store keeps its work folder: its next run reuses the tiles
    # no changed input touches, whichever command finished the store meanwhile
    keep_work = incremental or bool(previous is not None and previous.get("incremental"))
    return Resume(previous, grown_from, same_inputs, keep_work, tuple(notes), moved_from)


@dataclass(frozen=True)
class Update:
    """What a run over changed inputs computes again in a store it keeps."""

    keep: dict[int, int]
    """The inputs of the last run that stay: old index -> new index."""
    regions: tuple[tuple, ...]
    """The boxes whose points changed."""
    tiles: frozenset[tuple[int, int]]
    """The tiles meshed again: those whose piece held points in a region,
    those without a record, and the old edge of a grid grown north or east."""


def plan_update(plan: RunPlan, resume: Resume, work: WorkDir) -> Update:
    """The :class:`Update` of a store that ``resume`` keeps (``previous`` set,
    inputs not the same), from its work folder, which it leaves as it is:
    the run applies it (:func:`prepare`), ``terrain workflow status`` counts it."""
    keep, regions = changed_inputs(work, resume.previous["provenance"]["inputs"], plan.provenance["inputs"])
    tiles = tiles_depending_on(work, plan.grid, regions)
    if resume.grown_from is not None:
        tiles |= plan.grid.edge_tiles_moved_by(resume.grown_from)
    return Update(keep, tuple(regions), frozenset(tiles))


@functools.cache
def sources_digest() -> str:
    """SHA-256 of the sources that make a work folder's units (meshcore's and the pipeline's)."""
    import meshcore

    packages = (Path(meshcore.__file__).parent, Path(__file__).resolve().parents[1])
    digest = hashlib.sha256()
    for package in packages:
        for path in sorted(package.rglob("*.py")):
            digest.update(path.relative_to(package.parent).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def work_reusable(work: WorkDir) -> bool:
    """Whether the work folder holds units made by these very sources.

    Another version meshes, krigs and numbers its tiles in its own way: its
    pieces beside this version's would not make one conforming mesh (nor
    give the smooth surface's shared edges the same nodes)."""
    record = work.recorded(Ledger.SOFTWARE, "sources")  # None in a folder without records
    return record is not None and record.get("digest") == sources_digest()


NOISE_CLASSES = (7, 18)
"""ASPRS low and high noise."""

ALL_BUT_NOISE = tuple(c for c in range(256) if c not in NOISE_CLASSES)
"""Every ASPRS class but :data:`NOISE_CLASSES`: what a survey whose default
classes (ground) make no surface is meshed from (:func:`keep_all_but_noise`)."""


@dataclass(frozen=True)
class ClassFallback:
    """A survey whose points of the default classes made no surface, meshed from :attr:`classes` instead."""

    classes: tuple[int, ...]
    default_points: int
    """The points the default classes kept (none, or too few or all on one line for a surface)."""
    default_left_by_returns: int = 0
    """The points of the default classes that the run's ``returns`` left out (0 in records of an older version)."""


def class_fallback(work: WorkDir) -> ClassFallback | None:
    """The fallback :func:`keep_all_but_noise` recorded in this job's work folder, if any.

    An update of such a survey's inputs starts over (:func:`prepare`): new
    inputs may hold ground."""
    recorded = work.recorded(Ledger.SURVEY, "classes")
    if recorded is None:
        return None
    return ClassFallback(tuple(recorded["classes"]), int(recorded["default_points"]),
                         int(recorded.get("default_left_by_returns", 0)))


def keep_all_but_noise(work: WorkDir, output: str, default_points: int, left_by_returns: int = 0) -> None:
    """Start the job over classifying the ground from every class but noise:
    its inputs' points of the default classes (ground), ``default_points`` of
    them kept and ``left_by_returns`` left out by the run's ``returns``, made
    no surface.

    A survey that was never classified (class 0 or 1 throughout), or holds a
    ground point or two, is valid input; its ground is classified by the
    ground stage (:mod:`pipeline.meshing.ground`) instead of giving no surface.  The work folder starts empty with the fallback recorded
    first, so that a run stopped while routing again resumes with it; the
    store forgets any tile it marked written.
    """
    _start_over(work, output)
    work.record(Ledger.SURVEY, "classes", {"classes": list(ALL_BUT_NOISE), "default_points": int(default_points),
                                           "default_left_by_returns": int(left_by_returns)})


def _start_over(work: WorkDir, output: str) -> None:
    """Every unit of the job to be done again: no DEM tile of the store marked
    written, and an empty work folder."""
    from ..store import zarr_store as store

    store.reset_tiles_done(output)
    _start_work(work)


def _start_work(work: WorkDir) -> None:
    """An empty work folder, stamped with the sources that will fill it."""
    work.reset()
    work.record(Ledger.SOFTWARE, "sources", {"digest": sources_digest()})


def prepare(plan: RunPlan, resume: Resume, work: WorkDir, incremental: bool, notes: list[str],
            say: Callable[[str], None]) -> None:
    """Make the store and the work folder agree with ``resume``: create the
    store, or grow it, or forget the units that changed inputs touch, or
    keep everything (a resume); then forget the units whose files are lost."""
    from ..store import zarr_store as store
    from ..inputs.crs import cf_units

    config, grid, provenance, previous = plan.config, plan.grid, plan.provenance, resume.previous
    if resume.grown_from is not None and resume.grown_from != grid:
        store.grow_store(config.output, resume.grown_from, grid)
    if previous is None:
        store.create_store(
            config.output,
            grid,
            plan.crs.target_wkt,
            layers=config.layers,
            attrs={"provenance": provenance, "complete": False, "incremental": resume.keep_work},
            zarr_format=config.zarr_format,
            overwrite=config.overwrite or incremental,
            height_units=cf_units(plan.crs.height_unit),
        )
        _start_work(work)
    elif not work_reusable(work):
        # the intermediate files are gone, or another version wrote them: every stage runs again
        why = "was written by another version of the software" if work.exists() else "was missing"
        _start_over(work, config.output)
        notes.append(f"the work folder {why}: every tile was computed again")
    elif not resume.same_inputs and (class_fallback(work) is not None or config.classify_ground):
        # the inputs held no ground point: whether the new ones do decides the classes again; and a new point
        # may change the class of points far beyond its tile (the ground stage reads far)
        _start_over(work, config.output)
        why = ("in a survey whose ground is classified" if config.classify_ground
               else "in a survey that held no point of the default classes")
        notes.append(f"inputs changed {why}: every tile was computed again")
        store.finalize_store(config.output, {"provenance": provenance, "complete": False})
    elif not resume.same_inputs:
        update = plan_update(plan, resume, work)
        forget_changed_inputs(work, len(previous["provenance"]["inputs"]), update.keep)
        grown_from = resume.grown_from
        if grown_from is not None:
            reroute_near_growth(work, grown_from, provenance["inputs"], plan.buffer)
            if grown_from != grid:
                notes.append(
                    f"the grid grew from {grown_from.n_rows} x {grown_from.n_cols} to {grid.n_rows} x {grid.n_cols} "
                    "tiles (north or east): the tiles written were kept"
                )
        forget_tiles(work, config.output, grid, set(update.tiles))
        notes.append(
            f"inputs changed ({len(update.regions)} region(s)): {len(update.tiles)} of {grid.n_tiles} tile(s) computed again"
        )
        store.finalize_store(config.output, {"provenance": provenance, "complete": False})
    else:
        say(f"{config.output}: resuming an unfinished run")
        notes.append("resumed an unfinished run: finished work was kept")
    if previous is not None and work.exists():
        lost = forget_lost_units(work, len(plan.paths), grid, SURFACE_ARRAYS if config.surface == "smooth" else ())
        if lost:
            notes.append(f"{lost} finished unit(s) had lost files in the work folder: done again")


def forget_lost_units(work: WorkDir, n_inputs: int, grid: TileGrid, piece_extra: tuple[str, ...] = ()) -> int:
    """Forget the records of finished units whose files are gone from the work
    folder (a cleaner, a user), so they are done again; returns how many.
    ``piece_extra``: arrays a meshed piece must also hold (the smooth surface's nodes)."""
    lost = 0
    for i in range(n_inputs):
        rec = work.recorded(Ledger.ROUTE, source_key(i))
        if rec is not None and not spill_intact(work.scratch, i, rec.get("parts", [])):
            work.forget_record(Ledger.ROUTE, source_key(i))  # routed again: its spill files are rewritten
            lost += 1
    for r, c in grid.tiles():
        key = tile_key(r, c)
        if work.recorded(Ledger.MESH, key) is not None and not Piece.intact(work.scratch, r, c, piece_extra):
            work.forget_record(Ledger.MESH, key)
            work.forget_record(Ledger.WRITE, f"ids_{key}")
            lost += 1
        elif work.recorded(Ledger.WRITE, f"ids_{key}") is not None and not Piece.intact(work.scratch, r, c, ("node_ids",)):
            work.forget_record(Ledger.WRITE, f"ids_{key}")
            lost += 1
    return lost


def input_keys(inputs: list[dict[str, Any]]) -> set[tuple]:
    return {(i.get("path"), i.get("size"), i.get("mtime"), i.get("etag")) for i in inputs}


def _plain(value: object) -> object:
    """A parameter's value as its job file writes it (an option's text, not its enum)."""
    if isinstance(value, tuple):
        return tuple(_plain(v) for v in value)
    return value.value if isinstance(value, Enum) else value


def existing_job(config: RunConfig, provenance: dict[str, Any], allow_new_inputs: bool = False) -> dict[str, Any] | None:
    """The attributes of an earlier run of the same job at ``config.output`` (to
    resume or skip), or None to start afresh.  An existing store of another job
    (or, unless ``allow_new_inputs``, of other inputs) is an error unless
    ``config.overwrite``."""
    from ..store import zarr_store as store

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
        raise UsageError(f"{where}: an existing store of unknown origin; pass overwrite=True to replace it") from None
    changed = config.differences(before)
    if changed:
        detail = ", ".join(f"{k}: {_plain(getattr(before, k))!r} -> {_plain(getattr(config, k))!r}" for k in changed)
        raise UsageError(f"{where}: the existing store was made with other parameters ({detail}); pass overwrite=True to replace it")
    was, now = input_keys(old.get("inputs", [])), input_keys(provenance["inputs"])
    if was != now and not allow_new_inputs:
        added = sorted(p for p, *_ in now - was)
        gone = sorted(p for p, *_ in was - now)
        raise UsageError(
            f"{where}: the inputs changed since the store was made (new or changed: {added or 'none'}; "
            f"gone or changed: {gone or 'none'}); pass overwrite=True, or use a workflow for incremental runs"
        )
    return attrs
