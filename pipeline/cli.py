"""The ``terrain`` command line: thin wrappers over the Python API."""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from .config import positive_integer
from .errors import OutputWriteError, PipelineError, SeamError, StorageUnreachableError, UsageError
from .logs import LOGGER, configure

__all__ = ["main"]

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def _library_errors() -> tuple[type[Exception], ...]:
    """The error roots of meshcore and of the experiments, those imported
    (else none of their errors can have been raised): the command line starts
    without them."""
    roots = (("meshcore.errors", "MeshError"), ("experiments.errors", "ExperimentError"))
    return tuple(getattr(sys.modules[m], name) for m, name in roots if m in sys.modules)


def _positive_int(text: str) -> int:
    """A positive integer, also written as a whole float: 4e9 as the help shows it."""
    value = positive_integer(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _common_flags(**defaults) -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=defaults["verbose"],
                        help="more detail, and tracebacks of errors")
    common.add_argument("-q", "--quiet", action="store_true", default=defaults["quiet"], help="print errors only")
    common.add_argument("--log-json", action="store_true", default=defaults["log_json"],
                        help="log JSON lines on stderr (for schedulers)")
    return common


def _parser() -> argparse.ArgumentParser:
    common = _common_flags(verbose=0, quiet=False, log_json=False)
    # a sub-command's own defaults would undo the flags given before it
    nested = _common_flags(verbose=argparse.SUPPRESS, quiet=argparse.SUPPRESS, log_json=argparse.SUPPRESS)
    parser = argparse.ArgumentParser(
        prog="terrain",
        description="Combined triangle/quad terrain meshes and DEMs from point clouds.",
        epilog="Exit codes: 0 success; 1 some tiles or tasks failed; 2 usage or input error; 130 interrupted. "
        "Every command takes -v/--verbose, -q/--quiet and --log-json.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    real_add = sub.add_parser

    def add_parser(name, **kw):
        return real_add(name, parents=[common], **kw)

    sub.add_parser = add_parser  # type: ignore[method-assign]

    _add_experiment(sub)
    _add_run(sub)
    _add_demo(sub)
    _add_workflow(sub, nested)
    _add_preview(sub)
    _add_export(sub)
    _add_info(sub)
    _add_classify(sub)
    return parser


def _add_experiment(sub) -> None:
    """``terrain experiment``: the paper's error experiment."""
    exp = sub.add_parser(
        "experiment",
        help="run the error experiment of the combined-mesh paper (Tables 1-3, Figure 2)",
        description=(
            "Points uniform in the unit disc; convex, saddle and random test functions; "
            "rows S1 (triangulation), S2 (S1 + S2 quads), S3 (triangulation), S4 (S3 + S4 quads); "
            "L2 norms of f - g and grad f - grad g by Gauss quadrature over every face. "
            "Prints the tables and writes PNG figures to --out."
        ),
    )
    exp.add_argument("--points", type=_positive_int, default=500, help="points per trial (default 500)")
    exp.add_argument("--trials", type=_positive_int, default=20, help="point sets per function (default 20)")
    exp.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    exp.add_argument("--out", type=Path, default=Path("experiment-out"), help="folder for the PNG figures")
    exp.add_argument(
        "--merge", choices=("greedy", "optimal"), default="greedy", help="elimination strategy (default greedy)"
    )


def _add_run(sub) -> None:
    """``terrain run``: its flags mirror :class:`pipeline.config.RunConfig`."""
    run = sub.add_parser(
        "run",
        help="LAS/LAZ files -> one seamless DEM and combined mesh in a Zarr store",
        description=(
            "Stream LAS/LAZ inputs (files, folders, globs) through overlapping tiles on Dask and "
            "write the DEM (dims y, x; north-up; CF grid mapping) and the combined triangle/quad mesh "
            "(UGRID group 'mesh') to one Zarr store. Parameters may also come from a TOML job file."
        ),
    )
    add_config_flags(run)
    run.add_argument("--config", type=Path, help="a TOML job file; flags given here override it")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_config_flags(parser: argparse.ArgumentParser, names: Sequence[str] | None = None,
                     helps: dict[str, str] | None = None) -> None:
    """The flags of :class:`pipeline.config.RunConfig`'s parameters (``names``:
    only these), derived from its fields (:func:`pipeline.config.parameters`):
    ``--NAME`` (underscores as dashes), the field's help (or ``helps[NAME]``),
    an enum's values as choices.  None of them has a default here: a flag not
    given leaves the job file's value, or the field's default."""
    import enum

    from .config import parameters

    for p in parameters():
        if names is not None and p.name not in names:
            continue
        spec: dict = {"help": (helps or {}).get(p.name, p.flag.help)}
        if p.flag.metavar is not None:
            spec["metavar"] = p.flag.metavar
        if p.flag.positional:
            parser.add_argument(p.name, nargs="*", **spec)
            continue
        if p.kind is bool:
            spec.update(action="store_true", default=None)
        elif isinstance(p.kind, type) and issubclass(p.kind, enum.Enum):
            spec["choices"] = tuple(m.value for m in p.kind) + (("none",) if p.optional and p.default is not None else ())
        elif p.kind is float:
            spec["type"] = float
        elif p.kind is int:
            spec["type"] = _positive_int if p.flag.choices is None else int
            if p.flag.choices is not None:
                spec["choices"] = p.flag.choices
        opts = ([p.flag.short] if p.flag.short else []) + ["--" + p.name.replace("_", "-")]
        parser.add_argument(*opts, dest=p.name, **spec)


def _add_demo(sub) -> None:
    """``terrain demo``: the synthetic survey, run and drawn."""
    demo = sub.add_parser(
        "demo",
        help="write a realistic synthetic survey and run the whole job on it, with pictures",
        description="Writes a synthetic LiDAR survey (four overlapping LAZ strips in Lambert-93: hills, a "
        "valley with a lake that returns nothing, buildings and trees as non-ground classes) into "
        "DIR/survey, runs 'terrain run' on it into DIR/dem.zarr, prints the report, and draws "
        "DIR/dem.png (hillshade, and the canopy height beside it) and DIR/mesh.png (the combined mesh at the "
        "lake shore).",
    )
    demo.add_argument("--out", type=Path, default=Path("terrain-demo"), help="folder for the survey and the store")
    demo.add_argument("--points", type=_positive_int, default=400_000, help="points in the survey (default 400000)")


def _add_workflow(sub, nested: argparse.ArgumentParser) -> None:
    """``terrain workflow run|status``; ``nested`` carries the common flags to the actions."""
    wf = sub.add_parser(
        "workflow",
        help="incremental jobs from a TOML file (nightly archives)",
        description="A workflow file names inputs, an output store and any 'terrain run' parameters. "
        "'run' brings the store up to date, recomputing only the tiles touched by new, changed or "
        "removed files; 'status' says what the last run did and what the next one would do.",
    )
    wf_sub = wf.add_subparsers(dest="action", required=True, metavar="ACTION")
    wf_run = wf_sub.add_parser("run", parents=[nested], help="bring the workflow's store up to date")
    wf_run.add_argument("job", type=Path, help="the workflow file (TOML)")
    wf_run.add_argument("--no-progress", action="store_true", help="no progress bar")
    wf_status = wf_sub.add_parser("status", parents=[nested], help="last run, files known, tiles pending")
    wf_status.add_argument("job", type=Path, help="the workflow file (TOML)")
    wf_status.add_argument("--json", action="store_true", help="print JSON")


def _add_preview(sub) -> None:
    """``terrain preview``: a store drawn to a PNG."""
    preview = sub.add_parser(
        "preview",
        help="draw a store's DEM (hillshade, colour ramp, legend, scale) and optionally its mesh",
        description="Writes a PNG of the DEM; with --window, a second panel draws the combined mesh's "
        "triangles and quadrangles over the hillshade inside that box.",
    )
    preview.add_argument("store", help="a store written by terrain run")
    preview.add_argument("-o", "--output", required=True, help="the PNG to write")
    preview.add_argument("--window", help="xmin,ymin,xmax,ymax (store CRS) to zoom into and draw the mesh")


def _add_export(sub) -> None:
    """``terrain export``: a store's layers as COGs, and its STAC item."""
    export = sub.add_parser(
        "export",
        help="write a store's layers as Cloud-Optimized GeoTIFFs (any GIS opens them), and its STAC item",
        description="Writes each raster layer as a COG with the store's CRS, nodata and overviews: the first "
        "layer to OUTPUT, each further one beside it as STEM_LAYER.tif. A layer above --max-file-cells is "
        "written as one COG per block of chunk rows plus a VRT (STEM.vrt) that mosaics them. Then rewrites "
        "the store's STAC item (STORE's name with .stac.json) with the files as assets. Needs rasterio "
        "(the geotiff extra).",
    )
    export.add_argument("store", help="a store written by terrain run")
    export.add_argument("-o", "--output", required=True, help="the GeoTIFF to write (e.g. dem.tif)")
    export.add_argument("--layers", help="layers to write, e.g. elevation,slope (default: all the store holds)")
    export.add_argument("--max-file-cells", type=_positive_int, help="split layers above this many cells (default 2**30)")


def _add_info(sub) -> None:
    """``terrain info``: what LAS/LAZ headers say."""
    info = sub.add_parser("info", help="describe LAS/LAZ files (version, format, counts, classes, bounds, CRS)")
    info.add_argument("inputs", nargs="+", metavar="FILE", help="LAS/LAZ files, folders or glob patterns")
    info.add_argument("--json", action="store_true", help="print JSON")


def _add_classify(sub) -> None:
    """``terrain classify``: the ground stage's classes written back into LAZ copies of the inputs."""
    cls = sub.add_parser("classify", help="classify the ground of LAS/LAZ files and write them as LAZ "
                         "(class 2 ground, class 1 for former ground; nothing else changed)")
    cls.add_argument("inputs", nargs="+", metavar="INPUT", help="LAS/LAZ files, folders or glob patterns")
    cls.add_argument("-o", "--output", required=True, help="folder to write NAME.laz into, one per input")
    add_config_flags(cls, ("tile_size", "buffer", "in_crs", "override_crs", "workers", "scheduler", "overwrite"),
                     {"overwrite": "replace files already in the output folder"})
    cls.add_argument("--no-progress", action="store_true", help="no progress bars")


def _run_config(args: argparse.Namespace):
    from .config import RunConfig, parameters

    data: dict = {}
    if args.config is not None:
        job = RunConfig.from_toml(args.config)
        data = job.to_dict() | {"storage_options": job.storage_options}  # to_dict leaves credentials out
    flags = {p.name: getattr(args, p.name) for p in parameters()}
    for flag, other in (("in_crs", "override_crs"), ("override_crs", "in_crs")):
        if flags[flag] is not None:  # the command line's choice of the two replaces the job file's
            data.pop(other, None)
    data.update({k: v for k, v in flags.items() if v is not None and v != []})
    for needed in ("inputs", "output", "resolution"):
        if needed not in data:
            flag = {"inputs": "INPUT", "output": "-o/--output", "resolution": "--resolution"}[needed]
            raise UsageError(f"terrain run needs {flag} (on the command line or in --config)")
    return RunConfig.from_dict(data)


def _float_list(text: str, flag: str, count: int) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count:
        raise UsageError(f"{flag} takes {count} numbers separated by commas, got {text!r}")
    return values


def _demo(args: argparse.Namespace) -> int:
    from .config import RunConfig
    from .tools.preview import render_preview
    from .runs.compiling import compile_aside
    from .runs.runner import run
    from .inputs.sources import read_info
    from .tools.synthetic import demo_spec, write_survey

    out, points = args.out, args.points
    spec = demo_spec(points)
    survey = out / "survey"
    config = RunConfig(
        inputs=(str(survey),), output=str(out / "dem.zarr"), resolution=1.0, tile_size=256.0,
        # bridge the ground under buildings (<= 30 m), not the lake (140 m across)
        layers=("slope", "face_kind", "point_count", "dsm", "chm", "intensity", "density", "ground_density"),
        max_edge=50.0, overwrite=True,
    )
    # a machine's first run compiles its mesh kernels: another process starts
    # now, while this one writes the survey on one core, and the run takes it over
    compiling = compile_aside(config.mesh_options())
    try:
        paths = write_survey(survey, spec)
        written = sum(read_info(p).point_count for p in paths)  # none fall in the lake
        LOGGER.info(
            f"wrote {len(paths)} overlapping LAZ strips ({written:,} points, {spec.crs}: hills, a valley with a "
            f"lake, {spec.buildings} buildings, {spec.trees} trees) to {survey}"
        )
        report = run(config, progress=_progress(args), log=LOGGER.info)
    finally:
        compiling.stop()  # the run waited for it, unless it stopped first
    code = _report(args, report)
    x0, y0 = spec.origin
    lx, ly, r = spec.lake  # type: ignore[misc]
    overview = render_preview(config.output, out / "dem.png")
    shore = (x0 + lx - r - 25.0, y0 + ly - 20.0, x0 + lx - r + 15.0, y0 + ly + 20.0)
    zoom = render_preview(config.output, out / "mesh.png", window=shore)
    LOGGER.info(f"store: {config.output}  (xarray.open_zarr; the mesh is the group 'mesh')")
    LOGGER.info(f"pictures: {overview}, {zoom} (the mesh at the lake shore)")
    return code


def _progress(args: argparse.Namespace) -> bool | None:
    """Progress bars: on a terminal, unless asked for none, quiet or JSON logs."""
    if args.quiet or args.log_json or getattr(args, "no_progress", False):
        return False
    return None


def _parameter_patterns() -> tuple[re.Pattern[str], re.Pattern[str], re.Pattern[str]]:
    """How a library message names :class:`pipeline.config.RunConfig`'s
    parameters, from its fields: ``switch=True``, ``name=value``, and a name
    alone (one with an underscore anywhere; a one-word one as ``NAME must``,
    else it is a word of the prose: "the tile's buffer")."""
    from .config import parameters

    flagged = [p for p in parameters() if not p.flag.positional]
    switches = [p.name for p in flagged if p.kind is bool]
    values = [p.name for p in flagged if p.kind is not bool] + ["window"]  # (preview's --window)
    joined = "|".join(sorted(switches, key=len, reverse=True))
    valued = "|".join(sorted(values, key=len, reverse=True))
    underscored = "|".join(sorted((n for n in switches + values if "_" in n), key=len, reverse=True))
    single = "|".join(sorted((n for n in values if "_" not in n), key=len, reverse=True))
    return (re.compile(rf"\b({joined})=True\b"),
            re.compile(rf"\b({valued})=(?:'([^']*)'|([^\s;,)]+(?:, [^\s;,)]+)*\)?|\S+))"),
            re.compile(rf"\b(?:({underscored})\b|({single})(?= must\b))"))


_SWITCHES, _VALUES, _NAMES = _parameter_patterns()


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def as_flags(text: str) -> str:
    """A library message (which speaks of parameters) as the command line
    says it: ``overwrite=True`` is ``--overwrite``, ``in_crs='EPSG:2154'``
    is ``--in-crs EPSG:2154``, ``max_cells`` is ``--max-cells``.

    >>> as_flags("pass overwrite=True to replace it; give in_crs='EPSG:2154'")
    'pass --overwrite to replace it; give --in-crs EPSG:2154'
    """
    text = _SWITCHES.sub(lambda m: _flag(m.group(1)), text)
    text = _VALUES.sub(lambda m: f"{_flag(m.group(1))} {m.group(2) if m.group(2) is not None else m.group(3)}", text)
    return _NAMES.sub(lambda m: _flag(m.group(1) or m.group(2)), text)


def _said(args: argparse.Namespace, text: str) -> str:
    """``text`` in the words of the command: flags for a command line, parameters (the job file's keys) for a workflow."""
    return text if getattr(args, "command", None) == "workflow" else as_flags(text)


def _report(args: argparse.Namespace, report) -> int:
    """Show a run's report (a table, or one JSON log line); its exit code."""
    if args.log_json:
        LOGGER.info("run finished", extra={"data": {"report": report.to_dict()}})
    elif not args.quiet:
        print(report.table())
        for note in report.notes:
            print(f"note: {_said(args, note)}")
    return EXIT_OK if report.tiles_uncertified == 0 else EXIT_FAILED


_COORDINATE_FLAGS = ("--bbox", "--extent")


def _with_attached_values(argv: Sequence[str]) -> list[str]:
    """``--bbox -74.2,40.5,-73.7,40.9`` as ``--bbox=-74.2,40.5,-73.7,40.9``: argparse
    reads a value that starts with a minus sign (and is not one number) as a
    flag, so a box west or south of the origin was refused."""
    out: list[str] = []
    k = 0
    while k < len(argv):
        arg = argv[k]
        if arg in _COORDINATE_FLAGS and k + 1 < len(argv) and re.match(r"-[\d.]", argv[k + 1]):
            out.append(f"{arg}={argv[k + 1]}")
            k += 2
            continue
        out.append(arg)
        k += 1
    return out


def main(argv: Sequence[str] | None = None, *, process_ends: bool = False) -> int:
    """Entry point of ``terrain``; returns the exit code (0 ok, 1 failed, 2 usage or input error, 130 interrupted).

    ``process_ends``: the process ends with the command (the ``terrain``
    script), so the objects of the modules it loads are never garbage: the
    cycle collector leaves them alone (``gc.freeze``).  Each full collection
    walked every one of numba's, zarr's, laspy's and pyproj's: 50 ms of a
    one-file run, 0.2 s of a 20M-point one.  The objects made after that
    live as long: the kernels' typing and compiled code, the store's arrays,
    the tasks' records (about 150,000 in a one-file run): at its default
    threshold (every 700 new objects) the collector ran about 300 times over
    them, 50 ms of a 1.7 s run; it now waits for :data:`GC_THRESHOLD`.
    Called in a longer process (a notebook, a test), nothing changes."""
    parser = _parser()
    args = parser.parse_args(_with_attached_values(sys.argv[1:] if argv is None else argv))
    configure(-1 if args.quiet else args.verbose, args.log_json)
    try:
        return _command(args, process_ends)
    except (OutputWriteError, SeamError, StorageUnreachableError) as exc:  # the job failed part way: resumable
        LOGGER.error(f"terrain: error: {_said(args, str(exc))}", exc_info=args.verbose > 0)
        return EXIT_FAILED
    except (PipelineError, *_library_errors()) as exc:
        LOGGER.error(f"terrain: error: {_said(args, str(exc))}", exc_info=args.verbose > 0)
        return EXIT_USAGE
    except KeyboardInterrupt:
        LOGGER.error("terrain: stopped; run the same command again to resume")
        return EXIT_INTERRUPTED
    except Exception as exc:  # a failed task or a bug: one line, the traceback with -v
        hint = "" if args.verbose else " (-v shows the traceback)"
        LOGGER.error(f"terrain: error: {type(exc).__name__}: {exc}{hint}", exc_info=args.verbose > 0)
        return EXIT_FAILED


def console() -> None:
    """The ``terrain`` command: :func:`main`, then the process ends at once.

    Everything a command writes is written and closed before :func:`main`
    returns; what is left is the interpreter's own teardown (its threads,
    modules and compiled kernels freed one by one), 0.15-0.25 s of a 2 s job.
    """
    code = main(process_ends=True)
    try:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed or broken pipe: nothing more to say
        pass
    os._exit(code)


GC_THRESHOLD = 200_000
"""New container objects between two runs of the cycle collector in a
``terrain`` process (Python's default: 700).  Garbage in cycles is rare in a
run (its arrays are freed when their last reference goes) and waits at most
that many objects."""


def _process_ends() -> None:
    """The command's modules are loaded and the process ends with it: see :func:`main`."""
    gc.freeze()
    gc.set_threshold(GC_THRESHOLD)


def _command(args: argparse.Namespace, process_ends: bool = False) -> int:
    # once a command's modules are loaded: see main()
    loaded = _process_ends if process_ends else (lambda: None)
    if args.command == "experiment":
        from experiments.combined_mesh import experiment_command

        return experiment_command(points=args.points, trials=args.trials, seed=args.seed, out=args.out, merge=args.merge)
    if args.command == "run":
        from .runs.runner import run

        loaded()
        return _report(args, run(_run_config(args), progress=_progress(args), log=LOGGER.info))
    if args.command == "workflow":
        from .runs.workflow import Workflow, run_workflow, status_text, workflow_status

        loaded()
        workflow = Workflow.load(args.job)
        if args.action == "status":
            status = workflow_status(workflow)
            print(json.dumps(status, indent=2) if args.json else status_text(status))
            return EXIT_OK
        return _report(args, run_workflow(workflow, progress=_progress(args), log=LOGGER.info))
    if args.command == "demo":
        return _demo(args)
    if args.command == "preview":
        from .tools.preview import render_preview

        window = None if args.window is None else tuple(_float_list(args.window, "--window", 4))
        LOGGER.info(f"wrote {render_preview(args.store, args.output, window=window)}")
        return EXIT_OK
    if args.command == "export":
        from .store.catalog import write_stac_item
        from .store.export import MAX_FILE_CELLS, export_geotiff

        layers = None if args.layers is None else [name.strip() for name in args.layers.split(",") if name.strip()]
        written = export_geotiff(args.store, args.output, layers, max_file_cells=args.max_file_cells or MAX_FILE_CELLS)
        for item in written:
            more = f" over {len(item.parts)} COGs" if item.is_mosaic else ""
            LOGGER.info(f"wrote {item.path} ({item.layer}{more})")
        item_path = write_stac_item(args.store, {e.layer: [e.path, *(e.parts if e.is_mosaic else ())] for e in written})
        LOGGER.info(f"wrote {item_path} (STAC item)")
        return EXIT_OK
    if args.command == "classify":
        from .runs.classify import classify

        loaded()
        done = classify(args.inputs, args.output, tile_size=args.tile_size, buffer=args.buffer, workers=args.workers,
                        scheduler=args.scheduler, in_crs=args.in_crs, override_crs=args.override_crs,
                        overwrite=bool(args.overwrite),
                        progress=_progress(args))
        for note in done.notes:
            LOGGER.info(_said(args, note))
        LOGGER.info(done.table())
        return EXIT_OK
    if args.command == "info":
        from .tools.info import info_json, info_report
        from .inputs.sources import discover_inputs

        paths = discover_inputs(args.inputs)
        print(json.dumps(info_json(paths), indent=2, default=str) if args.json else info_report(paths))
        return EXIT_OK
    raise UsageError(f"unknown command {args.command!r}")  # pragma: no cover


if __name__ == "__main__":  # pragma: no cover
    console()
