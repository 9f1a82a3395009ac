"""The parameters of a run: one frozen, validated object equal to the CLI flags.

A :class:`RunConfig` is what ``terrain run`` builds from its flags, what
``pipeline.run`` takes, and what a TOML job file holds, so a job is a file you
can store and rerun.  Every field is checked when the object is built; an
invalid value raises :class:`~pipeline.errors.UsageError` naming the field and
the valid values.
"""

from __future__ import annotations

import math
import numbers
import os
import tomllib
from dataclasses import MISSING, asdict, dataclass, field, fields
from enum import Enum, StrEnum
from pathlib import Path
from collections.abc import Mapping
from typing import Any, TypeVar

from meshcore.options import MergeMethod, QuadMeasure, Surface, TriangleMeasure, parse_option

from .errors import UsageError

from .products.attributes import Returns
from .products.registry import names as _product_names

__all__ = ["RunConfig", "MeshOptions", "Flag", "Parameter", "parameters", "ZARR_FORMATS", "DuplicatePolicy", "Layer", "LAYERS", "DEFAULT_CLASSES", "Returns"]


E = TypeVar("E", bound=Enum)


class _LayerNames(StrEnum):
    """The raster layers a store can hold: one per product of
    :mod:`pipeline.products.registry`, in its order."""

    @classmethod
    def parse(cls, value: object) -> Layer:
        """The layer named ``value``; a :class:`UsageError` lists the valid names.

        >>> Layer.parse("slope")
        <Layer.SLOPE: 'slope'>
        """
        return parse_option(
            cls, value, "layer", error=UsageError, fold_case=False, message="unknown layer {value!r}; valid layers: {names}"
        )


Layer = _LayerNames("Layer", [(name.upper(), name) for name in _product_names()], module=__name__)
"""The raster layers a store can hold (``Layer.DSM``, ...), from the products' registry."""

LAYERS = tuple(member.value for member in Layer)
"""The DEM layers a run can write, by name; ``elevation`` is always written."""

DEFAULT_CLASSES = (2,)
"""ASPRS class 2: ground.  A survey whose points of it make no surface (none,
or too few) is meshed from every class but noise instead
(:data:`pipeline.runs.resume.ALL_BUT_NOISE`), with a note."""


class DuplicatePolicy(StrEnum):
    """The elevation kept for points that share x and y."""

    LOWEST = "lowest"
    HIGHEST = "highest"
    MEAN = "mean"
    FIRST = "first"


def _choice(enum: type[E], value: object, name: str) -> E:
    """The member of option ``name`` (exact text), by meshcore's parser of options."""
    return parse_option(enum, value, name, error=UsageError, fold_case=False)


def _flag(name: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise UsageError(f"{name} must be true or false, got {value!r}")
    return value


def positive_integer(value: object) -> int | None:
    """``value`` as a positive integer: an int, a whole float (``4e9``) or
    their text; None when it is none of these (or a bool)."""
    if isinstance(value, str):
        try:
            value = int(value)
        except ValueError:
            try:
                value = float(value)
            except ValueError:
                return None
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, float)):
        return None
    if isinstance(value, float) and not (math.isfinite(value) and value.is_integer()):
        return None
    return int(value) if value >= 1 else None


def _whole(name: str, value: object, allow_none: bool = False) -> int | None:
    if value is None and allow_none:
        return None
    number = None if isinstance(value, str) else positive_integer(value)  # text only on the command line
    if number is None:
        raise UsageError(f"{name} must be a positive integer, got {value!r}")
    return number


BOTH_CRS_OPTIONS = (
    "give in_crs or override_crs, not both: override_crs sets the CRS of every input, "
    "in_crs that of inputs without a usable CRS record"
)

#: fields whose default is not None but that accept None, and how a job file says None
_NONE_WORDS = {"classes": "all", "quad_measure": "none"}

#: fields that do not change a run's result (a store made with other values is resumed)
_NEUTRAL = {
    "workers", "scheduler", "overwrite", "scratch_dir", "max_cells", "inputs", "output", "extra", "storage_options",
}


def _positive(name: str, value: object, allow_none: bool = False, allow_zero: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    if (
        isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
        or value < 0 or (value == 0 and not allow_zero)
    ):
        raise UsageError(f"{name} must be a {'non-negative' if allow_zero else 'positive'} number, got {value!r}")
    return float(value)


def _box(name: str, value: object) -> tuple[float, float, float, float] | None:
    """A finite (xmin, ymin, xmax, ymax) with min < max (or its text,
    ``xmin,ymin,xmax,ymax``), or None."""
    if value is None:
        return None
    if isinstance(value, str):
        value = value.split(",")
    try:
        box = tuple(float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise UsageError(f"{name} must be (xmin, ymin, xmax, ymax), got {value!r}") from None
    if len(box) != 4 or not all(math.isfinite(v) for v in box) or not (box[0] < box[2] and box[1] < box[3]):
        raise UsageError(f"{name} must be (xmin, ymin, xmax, ymax) with min < max, got {value!r}")
    return box  # type: ignore[return-value]


ZARR_FORMATS = (2, 3)
"""The Zarr formats a store can be written in."""


@dataclass(frozen=True)
class Flag:
    """How the command line takes a :class:`RunConfig` parameter: ``--NAME``
    (underscores as dashes), its help, and how its value is written there.

    The kind of value follows the field's type: a bool is a switch, an enum
    offers its values (and ``"none"`` where the parameter may be None), a
    number is a number, and a tuple is given as text that
    :class:`RunConfig` reads itself (``2,9``; ``xmin,ymin,xmax,ymax``).
    """

    help: str
    metavar: str | None = None
    short: str | None = None
    """A one-letter form (``-o``)."""
    positional: bool = False
    """Given without a flag, as many as wanted (the inputs)."""
    choices: tuple[object, ...] | None = None
    """For a number: the values it may take (the Zarr format)."""


@dataclass(frozen=True)
class Parameter:
    """A :class:`RunConfig` parameter that the command line takes: its field's
    name and :class:`Flag`, the kind of its value (the field's type, None
    left out) and whether it may be None."""

    name: str
    flag: Flag
    kind: Any
    optional: bool
    default: Any


def parameters() -> tuple[Parameter, ...]:
    """The parameters of :class:`RunConfig` that the command line takes, in
    the fields' order, their kinds read from the fields' types."""
    import types
    import typing

    hints = typing.get_type_hints(RunConfig)
    out = []
    for f in fields(RunConfig):
        if "flag" not in f.metadata:
            continue
        kind, args = hints[f.name], typing.get_args(hints[f.name])
        optional = isinstance(kind, types.UnionType) and type(None) in args
        if optional:
            kind = next(a for a in args if a is not type(None))
        out.append(Parameter(f.name, f.metadata["flag"], kind, optional, f.default))
    return tuple(out)


def _param(default: object = MISSING, help: str = "", **flag: object) -> Any:
    """A :class:`RunConfig` field that the command line takes (see :class:`Flag`)."""
    meta = {"flag": Flag(help, **flag)}  # type: ignore[arg-type]
    return field(metadata=meta) if default is MISSING else field(default=default, metadata=meta)


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs: the one home of a run's parameters.

    ``terrain run``'s flags and a job file's keys are these fields (each
    field's :class:`Flag` holds its help); options are enums end to end.

    Examples
    --------
    >>> cfg = RunConfig(inputs=("tiles/*.laz",), output="dem.zarr", resolution=1.0)
    >>> cfg.classes, cfg.duplicates.value, cfg.quad_measure.value
    ((2,), 'lowest', 's4')
    >>> RunConfig.from_dict(cfg.to_dict()) == cfg
    True
    """

    inputs: tuple[str, ...] = _param(help="LAS/LAZ files, folders or glob patterns", metavar="INPUT", positional=True)
    output: str = _param(help="the Zarr store to write (e.g. dem.zarr)", short="-o")
    resolution: float = _param(help="DEM cell size in CRS units")
    tile_size: float | None = _param(
        None, "tile edge in CRS units, rounded to whole cells (default: ~0.5M points a tile; the result is "
        "the same at any tile size)")
    buffer: float | None = _param(None, "overlap around each tile in CRS units (default: 12 point spacings)")
    classes: tuple[int, ...] | None = _param(
        DEFAULT_CLASSES, "ASPRS classes to keep, e.g. 2 or 2,9, or 'all' (default 2: ground; a survey whose ground "
        "makes no surface: its ground is classified, with a note)")
    classify_ground: bool = _param(
        False, "classify the ground from every point but noise, ignoring the files' classes")
    """Classify the ground from every point but noise (classes 7 and 18),
    ignoring the files' own classes (:mod:`pipeline.meshing.ground`).  A
    survey whose points of the default classes make no surface is classified
    so whatever this says."""
    keep_withheld: bool = _param(False, "keep points flagged withheld")
    bbox: tuple[float, float, float, float] | None = _param(None, "xmin,ymin,xmax,ymax in the output CRS")
    extent: tuple[float, float, float, float] | None = _param(
        None, "xmin,ymin,xmax,ymax in the output CRS: the survey's planned area, which the grid covers (files "
        "inside it never move the grid)")
    """The survey's planned area (output CRS): the grid covers it, so files
    inside it never move the grid (an archive that grows file by file)."""
    in_crs: str | None = _param(None, "CRS of inputs with a missing or broken CRS (e.g. EPSG:2154)")
    """The CRS of inputs whose record is missing or broken (PDAL's ``default_srs``)."""
    override_crs: str | None = _param(
        None, "CRS of every input, whatever its CRS record says (e.g. EPSG:32612): for records the coordinates "
        "contradict; not with --in-crs")
    """The CRS of every input, whatever its record says (PDAL's ``override_srs``):
    for files whose record the coordinates contradict."""
    out_crs: str | None = _param(None, "reproject to this CRS (required for inputs in several CRSs; for inputs "
                                       "in degrees, default: the WGS 84 UTM zone at their centre)")
    duplicates: DuplicatePolicy = _param(
        DuplicatePolicy.LOWEST, "z of points sharing x,y (default lowest; first: the first read, files in sorted "
        "path order)")
    triangle_measure: TriangleMeasure = _param(TriangleMeasure.S3, "flip measure (default s3)")
    quad_measure: QuadMeasure | None = _param(QuadMeasure.S4, "elimination measure (default s4; none: triangles only)")
    merge: MergeMethod = _param(MergeMethod.GREEDY, "elimination strategy (default greedy)")
    max_edge: float | None = _param(None, "leave cells of faces with a longer edge as nodata")
    surface: Surface = _param(
        Surface.LINEAR, "linear: the mesh's flat triangles and bilinear quads (default); smooth: cubic patches "
        "through every point, kriged between them, voids filled from their rims (more accurate; 1.25-1.86x the "
        "time of a linear run on the real samples)")
    """The surface the DEM samples: "linear" (the mesh's own faces) or
    "smooth" (cubic patches through every point, kriged between them)."""
    layers: tuple[Layer, ...] = _param(
        ("elevation",), "extra DEM layers, comma-separated: " + ",".join(_product_names()[1:]) + " (see docs/products.md)")
    returns: Returns = _param(
        Returns.ALL, "returns the DTM is made of (default all; the DSM always uses first returns)")
    """The returns the DTM is made of: "all", "first", "last" or "single"
    (the DSM is made of first returns whatever this says)."""
    dsm_max_edge: float | None = _param(
        None, "longest edge and circumradius of the DSM's triangles (default: 5 point spacings)")
    """The longest edge (and circumradius) of the DSM's triangles; None: five
    mean point spacings of the survey (every return counted)."""
    workers: int | None = _param(
        None, "threads of this process that run the tasks (default: one per core; not with --scheduler)")
    scheduler: str | None = _param(None, "address of a dask.distributed scheduler (or DASK_SCHEDULER_ADDRESS)")
    zarr_format: int = _param(3, "Zarr format (default 3, read by GDAL 3.11+; 2 for older GDAL)", choices=ZARR_FORMATS)
    scratch_dir: str | None = _param(
        None, "folder for the work files (default: .NAME.work beside the store; shared by all workers on a cluster)")
    overwrite: bool = _param(False, "replace an existing store")
    max_cells: int = _param(4_000_000_000, "refuse a DEM above this many cells (default 4e9)")
    skip_bad_files: bool = _param(
        False, "skip unreadable or broken inputs (listed in the report with the reason) instead of stopping")
    storage_options: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    """fsspec options for URL inputs and stores (``endpoint_url``, ``key``,
    ``secret``, ``anon``, ...).  Kept out of :meth:`to_dict`, so out of the
    provenance: it may hold credentials."""
    extra: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        inputs = (self.inputs,) if isinstance(self.inputs, (str, Path)) else self.inputs
        inputs = tuple(str(p) for p in inputs)
        if not inputs:
            raise UsageError("inputs: give at least one file, directory or glob")
        object.__setattr__(self, "inputs", inputs)
        if not str(self.output):
            raise UsageError("output: give the path of the Zarr store to write")
        object.__setattr__(self, "output", str(self.output))
        object.__setattr__(self, "resolution", _positive("resolution", self.resolution))
        # not a whole number of cells: the plan rounds it, and says so (tiles never change the results)
        tile = _positive("tile_size", self.tile_size, allow_none=True)
        object.__setattr__(self, "tile_size", tile)
        object.__setattr__(self, "buffer", _positive("buffer", self.buffer, allow_none=True, allow_zero=True))
        object.__setattr__(self, "max_edge", _positive("max_edge", self.max_edge, allow_none=True))
        object.__setattr__(self, "dsm_max_edge", _positive("dsm_max_edge", self.dsm_max_edge, allow_none=True))
        object.__setattr__(self, "returns", _choice(Returns, self.returns, "returns"))
        classes = self.classes
        if isinstance(classes, str):  # "all", or "2,9" as on the command line
            words = [w.strip() for w in classes.split(",")]
            classes = None if [w.lower() for w in words] == ["all"] else words
        if classes is not None:
            try:
                classes = tuple(sorted({int(c) for c in classes}))
            except (TypeError, ValueError):
                raise UsageError(f"classes must be integers 0-255 or \"all\", got {self.classes!r}") from None
            if not classes or any(c < 0 or c > 255 for c in classes):
                raise UsageError(f"classes must be integers 0-255 or \"all\", got {self.classes!r}")
        object.__setattr__(self, "classes", classes)
        for name in ("bbox", "extent"):
            object.__setattr__(self, name, _box(name, getattr(self, name)))
        object.__setattr__(self, "duplicates", _choice(DuplicatePolicy, self.duplicates, "duplicates"))
        object.__setattr__(
            self, "triangle_measure", _choice(TriangleMeasure, self.triangle_measure, "triangle_measure")
        )
        if self.quad_measure is not None and str(self.quad_measure).lower() != "none":
            object.__setattr__(self, "quad_measure", _choice(QuadMeasure, self.quad_measure, "quad_measure"))
        else:
            object.__setattr__(self, "quad_measure", None)
        object.__setattr__(self, "merge", _choice(MergeMethod, self.merge, "merge"))
        object.__setattr__(self, "surface", _choice(Surface, self.surface, "surface"))
        layers = tuple(w.strip() for w in self.layers.split(",") if w.strip()) if isinstance(self.layers, str) else tuple(self.layers)
        unknown = [name for name in layers if name not in LAYERS]
        if unknown:
            raise UsageError(f"unknown layer(s) {unknown}; expected some of {', '.join(LAYERS)}")
        # in one order whatever the order asked: the store is the same
        object.__setattr__(self, "layers", tuple(Layer(name) for name in LAYERS if name == "elevation" or name in layers))
        object.__setattr__(self, "workers", _whole("workers", self.workers, allow_none=True))
        if self.zarr_format not in ZARR_FORMATS or isinstance(self.zarr_format, (bool, float)):
            raise UsageError(f"zarr_format must be 2 or 3, got {self.zarr_format!r}")
        object.__setattr__(self, "max_cells", _whole("max_cells", self.max_cells))
        for name in ("classify_ground", "keep_withheld", "overwrite", "skip_bad_files"):
            object.__setattr__(self, name, _flag(name, getattr(self, name)))
        options = self.storage_options
        if not isinstance(options, Mapping) or not all(isinstance(k, str) for k in options):
            raise UsageError(f"storage_options must be a table of option names, got {type(options).__name__}")
        object.__setattr__(self, "storage_options", dict(options))
        for name in ("in_crs", "override_crs", "out_crs", "scheduler", "scratch_dir"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, (str, Path)):
                raise UsageError(f"{name} must be a string, got {value!r}")
            object.__setattr__(self, name, None if value is None else str(value))
        if self.in_crs is not None and self.override_crs is not None:
            raise UsageError(BOTH_CRS_OPTIONS)

    def mesh_options(self) -> MeshOptions:
        """The part of the parameters a tile's mesh and grid read."""
        return MeshOptions.of(self)

    @property
    def scheduler_address(self) -> str | None:
        """The Dask scheduler the run's tasks go to (``scheduler``, else
        ``DASK_SCHEDULER_ADDRESS``), or None for this process's threads."""
        return self.scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None

    def to_dict(self) -> dict[str, Any]:
        """Plain values (lists for tuples), JSON- and TOML-friendly: ``None``
        fields are omitted, except those whose default is not None, which are
        written as their word ("all" classes, "none" quad measure)."""
        out: dict[str, Any] = {}
        for key, value in asdict(self).items():
            if key in ("extra", "storage_options"):  # storage_options may hold credentials
                continue
            if value is None:
                if key in _NONE_WORDS:
                    out[key] = _NONE_WORDS[key]
                continue
            out[key] = list(value) if isinstance(value, tuple) else (value.value if isinstance(value, Enum) else value)
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """Build from plain values; unknown keys are an error naming them."""
        known = {f.name for f in fields(cls)} - {"extra"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise UsageError(f"unknown parameter(s) {unknown}; known: {', '.join(sorted(known))}")
        values = dict(data)
        for key in ("inputs", "classes", "bbox", "extent", "layers"):
            if isinstance(values.get(key), list):
                values[key] = tuple(values[key])
        return cls(**values)

    @classmethod
    def from_toml(cls, path: str | Path) -> RunConfig:
        """Read a job file: the parameters at the top level or under ``[run]``."""
        try:
            with open(path, "rb") as f:
                data = tomllib.load(f)
        except OSError as exc:
            raise UsageError(f"{path}: cannot read the job file ({exc.strerror})") from None
        except tomllib.TOMLDecodeError as exc:
            raise UsageError(f"{path}: not valid TOML ({exc})") from None
        return cls.from_dict(data.get("run", data))

    def differences(self, other: RunConfig) -> list[str]:
        """Names of the parameters that change the result and differ from ``other``."""
        mine, theirs = asdict(self), asdict(other)
        return sorted(k for k in mine if k not in _NEUTRAL and mine[k] != theirs[k])


@dataclass(frozen=True)
class MeshOptions:
    """The part of a :class:`RunConfig` that a tile's mesh and grid read,
    taken from it by name (:meth:`RunConfig.mesh_options`): a task gets this,
    not copies of the fields one by one."""

    triangle_measure: TriangleMeasure = TriangleMeasure.S3
    quad_measure: QuadMeasure | None = QuadMeasure.S4
    merge: MergeMethod = MergeMethod.GREEDY
    duplicates: DuplicatePolicy = DuplicatePolicy.LOWEST
    surface: Surface = Surface.LINEAR
    max_edge: float | None = None
    layers: tuple[Layer, ...] = (Layer("elevation"),)

    @classmethod
    def of(cls, config: RunConfig) -> MeshOptions:
        """The options ``config`` sets."""
        return cls(**{f.name: getattr(config, f.name) for f in fields(cls)})
