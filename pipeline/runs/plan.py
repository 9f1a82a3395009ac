"""A run's plan: what it fixes before it reads a point.

:func:`plan_run` reads the inputs' headers, decides the CRS plan, the grid,
the data extent and the buffer (an incremental run keeps the tile size and
buffer that its store's first run derived, :func:`kept_sizes`), and writes
the provenance that a store keeps:
the same code for ``terrain run`` and for ``terrain workflow status``, which
asks what the next run would do.  :func:`frame_moved`, :func:`frame_grew`
and :func:`frame_change` compare the frame of two provenances (the entries
that fix the tiles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import urls
from ..config import RunConfig
from ..errors import GridTooLargeError, InputFileError, PipelineError, UsageError
from ..tiling.grid import TileGrid, check_cells

if TYPE_CHECKING:
    from ..products import ProductSettings
    from ..inputs.crs import CrsPlan
    from ..inputs.header import SourceInfo

__all__ = [
    "RunPlan", "plan_run", "read_headers", "job_frame", "job_frame_record", "frame_moved", "frame_grew",
    "frame_change", "kept_sizes", "union_bounds", "POINTS_PER_TILE", "SMOOTH_POINTS_PER_TILE", "DERIVED",
]

POINTS_PER_TILE = 500_000
"""Target number of points per tile when ``tile_size`` is not given.

The mesh passes sweep a tile's half-edge arrays many times, and a smaller
tile keeps more of them in cache; the buffer around a tile stays a few
percent of its points.  On a 20M-point archive, 0.5M-point tiles mesh about
9% faster than 1.5M-point ones, with a lower peak memory
(``bench/bench_pipeline.py throughput``)."""

MIN_AUTO_TILES = 6
"""A survey too small to fill that many tiles of :data:`POINTS_PER_TILE` is
still cut in about this many (of at least :data:`MIN_POINTS_PER_TILE`), so
that the cores share its tiles evenly: a 700k-point file is 3 x 3 tiles, not
2 x 2 of which two cores mesh three large ones and a nearly empty one (its
mesh stage 0.50 s instead of 0.60 s, ``bench/bench_peer.py whitebox``)."""

MIN_POINTS_PER_TILE = 100_000

MAX_AUTO_TILE_CELLS = 4096
"""The largest tile edge the automatic size takes, in cells.  A tile is one
chunk of every layer, held and written whole (64 MiB of float32 at this
size), even where the grid is narrower than the tile: sparse points over a
long strip, or a header whose bounds reach far beyond its points, would
otherwise give chunks of gigabytes."""

LARGEST_TILE_CELLS = 23_170
"""The largest tile edge at all: a chunk of float32 cells must stay under the
2 GiB (2**31 bytes) a compression codec takes."""

SMALL_TILE_POINTS = 2_000
"""A ``tile_size`` whose tiles hold fewer points than this on average gets a
note: a tile's own cost (its work files, its store chunk, the mesh pieces
its DEM reads) is 20-30 ms on two cores however few points it holds: the
289k points of ign_semis in 6,724 tiles of 12.3 m took 205 s."""

SMOOTH_POINTS_PER_TILE = 125_000
"""The same for ``surface="smooth"``: kriging its nodes costs several times
meshing, so smaller tiles let every core krige (a survey of 500k points is
four tiles, not one)."""


@dataclass(frozen=True)
class RunPlan:
    """What a run fixes before it reads a point: its inputs, their CRS plan,
    the grid, the data extent, the buffer, and the provenance a store keeps."""

    config: RunConfig
    paths: tuple[Path | str, ...]
    infos: tuple[SourceInfo, ...]
    skipped_files: tuple[dict[str, Any], ...]
    """Inputs left out with ``skip_bad_files`` (path, reason, points)."""
    crs: CrsPlan
    grid: TileGrid
    bounds: tuple[float, float, float, float]
    """The data extent: the headers' bounds (cut to the bbox, grown to a declared extent)."""
    buffer: float
    file_bounds: tuple[tuple[float, float, float, float] | None, ...]
    """Each input's header bounds in the target CRS."""
    provenance: dict[str, Any]
    kept: dict[str, Any] = field(default_factory=dict)
    """The sizes (``tile_size``, ``buffer``, ...) and the ``out_crs`` the config left unset that an
    incremental run took from its store, as the store's first run derived them."""
    dsm_max_edge: float = math.inf
    """The DSM's maximum edge (``config.dsm_max_edge``, or derived from the
    point density); infinite when the run computes no DSM."""

    def products(self, classes: tuple[int, ...] | None, classified: bool = False) -> ProductSettings:
        """The run's products, for the DTM's ``classes`` (the config's, or a fallback's; with
        ``classified``, those the ground stage classifies)."""
        from ..products import ProductSettings

        c = self.config
        return ProductSettings.for_run(c.layers, classes, c.returns, self.dsm_max_edge, c.keep_withheld, classified,
                                       c.resolution)

    @property
    def notes(self) -> list[str]:
        """What the plan's readers should know: the headers' notes, the CRS
        plan's, sizes kept from the store, a tile size rounded to whole cells,
        and tiles given too small."""
        notes = [f"{p}: {note}" for p, info in zip(self.paths, self.infos) for note in info.notes] + list(self.crs.notes)
        if self.kept:
            sizes = " and ".join(f"{name}={value:g}" if isinstance(value, float) else f"{name}={value}"
                                 for name, value in self.kept.items())
            why = "the point density" + (" and the inputs' CRS" if "out_crs" in self.kept else "")
            notes.append(f"{sizes} kept from the store, which derived them from {why} in its first run")
        c = self.config
        cells = None if c.tile_size is None else given_tile_cells(c)
        if cells is not None and not math.isclose(cells * c.resolution, c.tile_size, rel_tol=1e-9):
            notes.append(
                f"tile_size={c.tile_size:g} is not a whole multiple of resolution={c.resolution:g}: the tiles are "
                f"{cells:,} cells ({cells * c.resolution:g}) a side (the results do not depend on the tiles)"
            )
        tiles = self.grid.n_tiles
        points = sum(info.point_count for info in self.infos)
        if self.config.tile_size is not None and tiles > 1 and points < SMALL_TILE_POINTS * tiles:
            notes.append(
                f"tile_size={self.config.tile_size:g} cuts the survey into {tiles:,} tiles of about "
                f"{points / tiles:,.0f} points each (every class counted): a tile costs tens of milliseconds however "
                "few points it holds, so larger tiles run faster (without a tile_size, tiles are sized from the "
                "points' density)"
            )
        return notes


def plan_run(config: RunConfig, keep_sizes: bool = False) -> RunPlan:
    """The plan of a run of ``config`` over its inputs as they are now.

    ``keep_sizes``: an incremental run, which takes the tile size and buffer
    that ``config`` leaves unset from its store's provenance (:func:`kept_sizes`),
    so that a survey that grows keeps its tiles.  The provenance records the
    sizes derived (or kept) under :data:`DERIVED`.
    """
    from ..inputs.crs import resolve_crs

    paths, infos, skipped = read_headers(config)
    kept = kept_sizes(config) if keep_sizes else {}
    out_crs, chosen = _out_crs(config, infos, kept)
    crs = resolve_crs(infos, config.in_crs, out_crs, override_crs=config.override_crs)
    if chosen:
        crs = replace(crs, notes=(chosen, *crs.notes))
    sized = replace(config, **kept)
    infos, (grid, bounds, buffer, file_bounds) = _frame_measuring_wide_headers(sized, paths, infos, crs)
    tile_cells, _ = _auto_sizes(sized, bounds, sum(i.point_count for i in infos))
    dsm_edge = _dsm_max_edge(sized, bounds, sum(i.point_count for i in infos))
    derived = {"tile_size": tile_cells * config.resolution, "buffer": buffer,
               **({} if math.isinf(dsm_edge) else {"dsm_max_edge": dsm_edge}),
               **({} if out_crs is None else {"out_crs": out_crs})}
    derived = {name: value for name, value in derived.items() if getattr(config, name) is None}
    provenance = {
        "software": "terrain-pipeline",
        "version": _version(),
        "parameters": config.to_dict(),
        **({DERIVED: derived} if derived else {}),
        "inputs": [
            {
                "path": str(i.path), "size": i.size_bytes, "points": i.point_count, **urls.version(i.path),
                "bounds": b,
            }
            for i, b in zip(infos, file_bounds)
        ],
        "crs_wkt": crs.target_wkt,
        **job_frame_record(grid, bounds, buffer, crs),
    }
    plan = RunPlan(config, tuple(paths), tuple(infos), tuple(skipped), crs, grid, bounds, buffer, tuple(file_bounds),
                   provenance, kept, dsm_edge)
    return plan


DERIVED = "derived"
"""The provenance's entry of what a run derived because its parameters left
it unset: ``{"tile_size": ..., "buffer": ..., "dsm_max_edge": ...}`` (CRS
units) and, for inputs in degrees, ``"out_crs"`` (their UTM zone), each
present only when its parameter is unset."""


def kept_sizes(config: RunConfig) -> dict[str, Any]:
    """The sizes ``config`` leaves unset (``tile_size``, ``buffer``,
    ``dsm_max_edge``), and the UTM zone of inputs in degrees (``out_crs``),
    that the store at ``config.output`` recorded as derived: an incremental
    run keeps them.  Derived again, they would follow the inputs as they are
    now, and a new file would change them and with them every tile.  Empty
    without a store, with ``overwrite``, or for a store that recorded none."""
    from ..store import zarr_store as store

    if config.overwrite:
        return {}
    attrs = store.read_attrs(config.output) or {}
    derived = attrs.get("provenance", {}).get(DERIVED, {})
    unset = [name for name in ("tile_size", "buffer", "dsm_max_edge") if getattr(config, name) is None]
    kept: dict[str, Any] = {name: float(derived[name]) for name in unset if name in derived}
    if config.out_crs is None and "out_crs" in derived:
        kept["out_crs"] = str(derived["out_crs"])
    return kept


def _out_crs(config: RunConfig, infos: list, kept: dict[str, Any]) -> tuple[str | None, str | None]:
    """The CRS to reproject to: ``config.out_crs``, or the one an incremental
    run keeps, or, for inputs in degrees (or geocentric), the WGS 84 UTM
    zone at their centre, with the note that says so (meshes and cells need
    linear coordinates).  None: the inputs' own CRS."""
    from ..inputs.crs import working_crs

    if config.out_crs is not None or "out_crs" in kept:
        return config.out_crs or kept["out_crs"], None
    utm = working_crs(infos, config.in_crs, override_crs=config.override_crs)
    if utm is None:
        return None, None
    return utm[0], (f"the inputs' CRS is not projected (degrees or geocentric): the DEM and the mesh are in "
                    f"{utm[1]} ({utm[0]}), the UTM zone at their centre; give out_crs for another")


def read_headers(config: RunConfig) -> tuple[list[Path], list, list[dict[str, Any]]]:
    """The inputs' paths and header information (bounds measured from the
    points where the header's are unusable), and with ``skip_bad_files`` the
    files left out and why."""
    from ..inputs.sources import discover_inputs, read_info, with_measured_bounds

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


THIN_HEADER = 16.0
"""A file whose header bounds would hold its points this many times more
thinly than the survey's files hold theirs (the median) has its bounds
measured from its points, when they widen the survey's extent."""


def _frame_measuring_wide_headers(config: RunConfig, paths, infos, plan):
    """:func:`job_frame`, and the infos it was computed from.

    Header bounds that claim far more than a file's points (edited files whose
    header was not updated, a mistyped offset) widen the DEM with empty cells,
    up to one too large to plan.  So the bounds of a file whose header would
    hold its points :data:`THIN_HEADER` times more thinly than the survey's
    files do are measured from its points, where they widen the extent; and
    while the DEM is too large, the widest files' bounds are measured, one
    at a time, widest first, until it fits.  Each file whose points fill less
    than half of its header's bounds along an axis then takes its points'
    bounds, with a note.  An extent that is truly too large still raises,
    once the widest file not yet measured proves to hold its header's bounds
    (an archive planned at too fine a resolution is not read whole before it
    is told).
    """
    infos = list(infos)
    measured: set[int] = set()
    for k in [] if config.bbox is not None else _thin_headers(infos, plan):  # a bbox bounds the grid already
        measured.add(k)
        infos[k] = _bounds_of_points(infos[k])[0]
    while True:
        try:
            return infos, job_frame(config, paths, infos, plan)
        except GridTooLargeError:
            spans = _spans([_file_bounds(i, src, plan.target_wkt) for i, src in zip(infos, plan.source_wkts)])
            left = [k for k in np.argsort(spans)[::-1] if k not in measured and spans[k] > 0.0]
            if not left:
                raise
            k = int(left[0])
            measured.add(k)
            infos[k], filled = _bounds_of_points(infos[k])
            if filled:
                raise  # its points fill its header's bounds: the extent is real


def _thin_headers(infos, plan) -> list[int]:
    """The files whose header bounds widen the survey's extent and would hold
    their points :data:`THIN_HEADER` times more thinly than the median file."""
    bounds = [_file_bounds(i, src, plan.target_wkt) for i, src in zip(infos, plan.source_wkts)]
    spans = _spans(bounds)
    density = [i.point_count / a if a > 0.0 and i.point_count else math.nan for i, a in zip(infos, spans)]
    if sum(math.isfinite(d) for d in density) < 2:
        return []
    median = float(np.nanmedian(density))
    thin = []
    for k, d in enumerate(density):
        if not d < median / THIN_HEADER:
            continue
        others = union_bounds([b for j, b in enumerate(bounds) if j != k and b])
        b = bounds[k]
        if b[0] < others[0] or b[1] < others[1] or b[2] > others[2] or b[3] > others[3]:
            thin.append(k)
    return thin


def _bounds_of_points(info):
    """``(info, filled)``: ``info`` with its points' bounds (and a note) when
    they fill less than half of its header's bounds along an axis; ``filled``
    when they fill them (``info`` then as it was)."""
    from ..inputs.sources import measured_bounds

    points = measured_bounds(info)
    header = info.bounds
    if points is None:
        return info, False
    if points[3] - points[0] >= 0.5 * (header[3] - header[0]) and points[4] - points[1] >= 0.5 * (header[4] - header[1]):
        return info, True
    note = (f"header bounds x {header[0]:.8g} .. {header[3]:.8g}, y {header[1]:.8g} .. {header[4]:.8g} reach far "
            f"beyond its points (x {points[0]:.8g} .. {points[3]:.8g}, y {points[1]:.8g} .. {points[4]:.8g}): "
            "the grid follows its points")
    return replace(info, bounds=points, notes=(*info.notes, note)), False


def _spans(file_bounds) -> list[float]:
    """The area of each file's bounds (-1 for a file without points)."""
    return [(b[2] - b[0]) * (b[3] - b[1]) if b else -1.0 for b in file_bounds]


def job_frame(config: RunConfig, paths, infos, plan) -> tuple[TileGrid, tuple, float, list]:
    """The grid, the extent and the buffer of a job over these inputs (and the
    files' bounds in the target CRS): what a run fixes before reading points."""
    file_bounds = [_file_bounds(i, src, plan.target_wkt) for i, src in zip(infos, plan.source_wkts)]
    bounds = union_bounds(file_bounds)
    if config.bbox is not None:
        b = config.bbox
        bounds = (max(bounds[0], b[0]), max(bounds[1], b[1]), min(bounds[2], b[2]), min(bounds[3], b[3]))
    if not all(math.isfinite(v) for v in bounds) or bounds[0] > bounds[2] or bounds[1] > bounds[3]:
        raise PipelineError("no points to grid: the inputs are empty or the bbox misses them")
    if config.extent is not None:  # the planned area: files inside it never move the grid
        bounds = union_bounds([bounds, config.extent])
    if not (math.isfinite(bounds[2] - bounds[0]) and math.isfinite(bounds[3] - bounds[1])):
        raise GridTooLargeError(f"the inputs span more than the largest float: x {bounds[0]:.6g} .. {bounds[2]:.6g}, "
                         f"y {bounds[1]:.6g} .. {bounds[3]:.6g}")
    tile_cells, buffer = _auto_sizes(config, bounds, sum(i.point_count for i in infos))
    grid = TileGrid.covering(bounds, config.resolution, tile_cells)
    try:
        check_cells(grid, config.max_cells)
    except GridTooLargeError as exc:  # say which file spans the most: a wrong CRS or header shows up here
        widest = int(np.argmax(_spans(file_bounds)))
        b = file_bounds[widest]
        raise GridTooLargeError(
            f"{exc}; the widest input is {paths[widest]}: x {b[0]:.2f} .. {b[2]:.2f}, y {b[1]:.2f} .. {b[3]:.2f}"
        ) from None
    return grid, bounds, buffer, file_bounds


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
    The tiles written then stay (:func:`pipeline.store.zarr_store.grow_store`)."""
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


def _file_bounds(info, source_wkt: str, target_wkt: str) -> tuple[float, float, float, float] | None:
    """A file's header bounds in the target CRS (None for an empty file)."""
    from ..inputs.crs import transform_bounds

    if info.point_count == 0:
        return None
    b = info.bounds
    box = (float(b[0]), float(b[1]), float(b[3]), float(b[4]))
    return box if source_wkt == target_wkt else transform_bounds(source_wkt, target_wkt, box)


def union_bounds(boxes) -> tuple[float, float, float, float]:
    """Union of boxes (None ones skipped); infinite when there are none."""
    xmin = ymin = math.inf
    xmax = ymax = -math.inf
    for b in boxes:
        if b is None:
            continue
        xmin, ymin = min(xmin, b[0]), min(ymin, b[1])
        xmax, ymax = max(xmax, b[2]), max(ymax, b[3])
    return xmin, ymin, xmax, ymax


def _spacing(config: RunConfig, bounds, n_points: int) -> float:
    """The survey's mean point spacing (every class), from the headers."""
    area = max((bounds[2] - bounds[0]) * (bounds[3] - bounds[1]), config.resolution**2)
    return 1.0 / math.sqrt(max(n_points, 1) / area)


def _dsm_max_edge(config: RunConfig, bounds, n_points: int) -> float:
    """The DSM's maximum edge: the config's, or :data:`~pipeline.products.DSM_EDGE_SPACINGS`
    point spacings; infinite when the run computes no DSM."""
    from ..products import DSM_EDGE_SPACINGS, layers_needed

    if "dsm" not in layers_needed(config.layers):
        return math.inf
    if config.dsm_max_edge is not None:
        return config.dsm_max_edge
    return DSM_EDGE_SPACINGS * _spacing(config, bounds, n_points)


def _auto_sizes(config: RunConfig, bounds, n_points: int) -> tuple[int, float]:
    """Tile edge in cells and buffer (CRS units) from the point density (the
    products' points are spilled with a margin of their own:
    :attr:`pipeline.products.ProductSettings.margin`)."""
    area = max((bounds[2] - bounds[0]) * (bounds[3] - bounds[1]), config.resolution**2)
    density = max(n_points, 1) / area
    spacing = 1.0 / math.sqrt(density)
    if config.tile_size is not None:
        tile_cells = given_tile_cells(config)
        if tile_cells > LARGEST_TILE_CELLS:
            raise UsageError(
                f"tile_size {config.tile_size:g} at resolution {config.resolution:g} gives tiles of {tile_cells:,} x "
                f"{tile_cells:,} cells, chunks over the 2 GiB a layer's chunk can hold; give a tile_size of at most "
                f"{LARGEST_TILE_CELLS * config.resolution:g}"
            )
    else:
        per_tile = POINTS_PER_TILE if config.surface == "linear" else SMOOTH_POINTS_PER_TILE
        per_tile = min(per_tile, max(n_points // MIN_AUTO_TILES, MIN_POINTS_PER_TILE))
        target = math.sqrt(per_tile / density) / config.resolution
        # as many tiles along each side as that size needs, all of one size:
        # 351 x 370 m of 700k points is 2 x 2 tiles of 192 m, not one of
        # 304 m that holds 60% of the points beside three small ones
        cells = [max(1.0, (bounds[2] - bounds[0]) / config.resolution), max(1.0, (bounds[3] - bounds[1]) / config.resolution)]
        even = max(math.ceil(side / max(1, math.ceil(side / target))) for side in cells)
        tile_cells = min(max(16, -(-even // 16) * 16), MAX_AUTO_TILE_CELLS)
    buffer = config.buffer if config.buffer is not None else max(12.0 * spacing, 2.0 * config.resolution)
    return tile_cells, float(buffer)


def given_tile_cells(config: RunConfig) -> int:
    """The cells a side of the tiles ``config.tile_size`` asks for: the nearest
    whole number, at least one (a size that is not a whole multiple of the
    resolution is rounded, with a note; tiles never change the results)."""
    assert config.tile_size is not None
    return max(1, math.floor(config.tile_size / config.resolution + 0.5))


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("terrain-pipeline")
    except PackageNotFoundError:  # pragma: no cover
        return "unknown"
