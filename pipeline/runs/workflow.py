"""Declarative, incremental jobs for archives that grow: ``terrain workflow``.

A workflow is a TOML file::

    [workflow]
    inputs = ["/data/archive/**/*.laz"]   # files, folders, globs (relative to this
                                          # file; $VARIABLES are expanded)
    output = "/data/dem/archive.zarr"
    scheduler = "tcp://scheduler:8786"    # optional: an existing Dask cluster

    [run]                                 # any ``terrain run`` parameter
    resolution = 1.0
    tile_size = 500.0
    buffer = 10.0

Each run remembers the input files it processed (path, size, modification
time, SHA-256 of the content) and keeps its work folder.  The next run
recomputes only the tiles whose points changed: the tiles that held points in
the bounds of a new, changed or removed file, or near a changed part of the
convex hull, plus the DEM of their neighbours; every DEM chunk that holds no
cell of those is left untouched.  The result equals a full run over the
current archive.

A survey that grows keeps its tiles when the grid only grows to the north or
east: the store's layers are resized (their chunk files renamed where whole
chunk rows come in at the north, never written again; written again from
their cells where the new rows are not whole chunks), and the new tiles, the
old grid's northern row or eastern column, and the tiles the new files or the
moved hull touch are computed.  Growth to the south or west moves the grid's
origin, and with it every tile, and ``terrain workflow status`` says why.
A job file that leaves ``tile_size`` and ``buffer`` unset keeps the values
its store's first run derived from the point density (recorded in the
provenance as ``derived``, :func:`~pipeline.runs.plan.kept_sizes`): derived
again from a grown archive they would change, and with them every tile.  A
workflow may declare its planned ``extent``: files inside it never move the
grid.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..config import RunConfig
from .. import urls
from ..errors import InputFileError, PipelineError, UsageError
from ..urls import is_url

__all__ = ["Workflow", "run_workflow", "workflow_status"]


@dataclass(frozen=True)
class Workflow:
    """A job file: where it lives, its name and the run it describes."""

    path: Path
    name: str
    config: RunConfig

    @classmethod
    def load(cls, path: str | Path) -> Workflow:
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except OSError as exc:
            raise UsageError(f"{path}: cannot read the workflow file ({exc.strerror})") from None
        except tomllib.TOMLDecodeError as exc:
            raise UsageError(f"{path}: not valid TOML ({exc})") from None
        head = data.get("workflow")
        if not isinstance(head, dict):
            raise UsageError(f"{path}: needs a [workflow] table with inputs and output")
        unknown = sorted(set(head) - {"inputs", "output", "scheduler", "name"})
        if unknown:
            raise UsageError(f"{path}: unknown key(s) in [workflow]: {unknown}")
        for key in ("inputs", "output"):
            if key not in head:
                raise UsageError(f"{path}: [workflow] needs {key!r}")
        inputs = head["inputs"]
        if isinstance(inputs, str):
            inputs = [inputs]
        base = path.parent
        params: dict[str, Any] = dict(data.get("run", {}))
        if "overwrite" in params:
            raise UsageError(f"{path}: 'overwrite' has no place in a workflow: each run updates its store")
        for key in ("inputs", "output", "scheduler"):
            if key in params:
                raise UsageError(f"{path}: {key!r} belongs in [workflow], not [run]")
        try:
            params["inputs"] = tuple(str(_resolve(base, p)) for p in inputs)
            params["output"] = str(_resolve(base, head["output"]))
            if head.get("scheduler"):
                params["scheduler"] = head["scheduler"]
            if "scratch_dir" in params:
                params["scratch_dir"] = str(_resolve(base, params["scratch_dir"]))
            config = RunConfig.from_dict(params)
        except UsageError as exc:
            raise UsageError(f"{path}: {exc}") from None
        return cls(path=path, name=str(head.get("name", path.stem)), config=config)


def _resolve(base: Path, value: str) -> Path | str:
    """A path of the file: ``~`` and ``$VARIABLES`` expanded, relative to
    ``base``; a URL with its variables expanded."""
    expanded = os.path.expandvars(value)
    if "$" in expanded:
        raise UsageError(f"{value!r}: an environment variable in it is not set")
    if is_url(expanded):
        return expanded
    p = Path(expanded).expanduser()
    return p if p.is_absolute() else base / p


def run_workflow(workflow: Workflow, *, progress: bool | None = None, log: Callable[[str], None] | None = None):
    """Bring the workflow's store up to date with its inputs; returns the run report."""
    from .runner import execute

    return execute(workflow.config, progress=progress, log=log, incremental=True)


def workflow_status(workflow: Workflow) -> dict[str, Any]:
    """Last run, files known, and what the next run would do."""
    from ..store import zarr_store as store
    from .changes import same_input
    from .resume import work_reusable
    from ..tiling.checkpoint import Ledger, WorkDir, source_key, work_dir_for
    from ..inputs.sources import discover_inputs

    cfg = workflow.config
    status: dict[str, Any] = {"workflow": workflow.name, "job_file": str(workflow.path), "output": cfg.output}
    attrs = store.read_attrs(cfg.output)
    if attrs is None:
        status.update(state="never run", files_known=0, points_known=0, last_run=None)
    else:
        history = attrs.get(store.HISTORY_ATTR, [])
        known = attrs.get("provenance", {}).get("inputs", [])
        status.update(
            state="complete" if attrs.get("complete") else "unfinished (the next run resumes)",
            last_run=history[-1].get("finished") if history else None,
            files_known=len(known),
            points_known=sum(int(i.get("points", 0)) for i in known),
        )
    try:
        current = [str(p) for p in discover_inputs(cfg.inputs)]
    except (UsageError, InputFileError) as exc:  # shown as a row: inputs may not be there yet
        status.update(inputs_error=str(exc))
        current = []
    known = (attrs or {}).get("provenance", {}).get("inputs", [])
    before = {i["path"]: i for i in known}
    index = {i["path"]: k for k, i in enumerate(known)}
    work = WorkDir(work_dir_for(cfg.output, cfg.scratch_dir, cluster=cfg.scheduler_address is not None))
    new = [p for p in current if p not in before]
    gone = [p for p in before if p not in set(current)]
    changed = []
    for p in current:
        if p in before:
            item = {"path": p, "size": urls.size(p), **urls.version(p)}
            routed = work.recorded(Ledger.ROUTE, source_key(index[p])) if work.exists() else None
            if not same_input(before[p], item, routed):  # as the run decides: a touched file is the same
                changed.append(p)
    status.update(new_files=new, changed_files=changed, removed_files=gone)
    if attrs is None:
        status["tiles_pending"] = "all"
        return status
    done = store.tiles_done(cfg.output)
    status["tiles_total"] = int(done.size)
    if not (new or changed or gone):
        if attrs.get("complete"):
            status["tiles_pending"] = 0
        else:  # the run resumes, unless it must start over (work folder lost, or made by another version)
            status["tiles_pending"] = int(done.size - done.sum()) if work_reusable(work) else "all"
        return status
    status["tiles_pending"] = _pending_after_changes(cfg, work, done)
    return status


def _pending_after_changes(config: RunConfig, work, done) -> int | str:
    """Tiles the next run would compute again, decided by the run's own code:
    its plan (headers, CRS plan, grid, :func:`~pipeline.runs.plan.plan_run`), its
    decision on the store (:func:`~pipeline.runs.resume.decide`) and the tiles an
    update meshes again (:func:`~pipeline.runs.resume.plan_update`)."""
    from .plan import frame_change, plan_run
    from .resume import class_fallback, decide, plan_update, work_reusable

    try:
        plan = plan_run(config, keep_sizes=True)
        decision = decide(plan, incremental=True)
    except PipelineError as exc:
        return f"unknown: the next run would stop: {exc}"
    if decision.moved_from is not None:
        return f"all ({frame_change(decision.moved_from, plan.provenance, done=False)})"
    if decision.previous is None or not work_reusable(work):
        return "all"
    if decision.same_inputs:  # a file left out or only touched: the run resumes or has nothing to do
        return 0 if decision.complete else int(done.size - done.sum())
    if class_fallback(work) is not None:  # a survey without ground: new inputs may hold some
        return "all"
    return len(plan_update(plan, decision, work).tiles)


def status_text(status: dict[str, Any]) -> str:
    """The status as aligned lines for a terminal."""
    rows = [
        ("workflow", status["workflow"]),
        ("store", f"{status['output']} ({status['state']})"),
        ("last run", status.get("last_run") or "never"),
        ("files known", f"{status['files_known']:,} ({status['points_known']:,} points)"),
        ("new files", str(len(status["new_files"]))),
        ("changed files", str(len(status["changed_files"]))),
        ("removed files", str(len(status["removed_files"]))),
        ("tiles pending", f"{status['tiles_pending']}" + (f" of {status['tiles_total']}" if "tiles_total" in status else "")),
    ]
    if "inputs_error" in status:
        rows.append(("inputs", status["inputs_error"]))
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name.ljust(width)}  {value}" for name, value in rows)
