"""Pictures of a store: a hillshaded DEM with a colour ramp, legend and scale
bar, a panel beside it for each layer whose product declares a preview (the
canopy height model), and optionally the combined mesh over a zoom window
(triangles and quadrangles in two colours)."""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..inputs.crs import cf_metres, unit_metres
from ..errors import UsageError

__all__ = ["render_preview", "MAX_MESH_FACES"]

MAX_MESH_FACES = 60_000
"""More faces than this in the zoom window would draw as a grey smear: refused."""


def _ramp():
    """Green lowlands to brown and white heights: matplotlib's "terrain" without
    its blue, which would read as water on dry land."""
    from matplotlib import colormaps
    from matplotlib.colors import ListedColormap

    return ListedColormap(colormaps["terrain"](np.linspace(0.22, 1.0, 256)), name="terrain_land")


def _nice_length(span: float) -> float:
    """A round scale-bar length near a fifth of ``span`` (1, 2 or 5 times a power of ten)."""
    target = span / 5.0
    power = 10 ** math.floor(math.log10(target))
    return max(m * power for m in (1, 2, 5) if m * power <= target)


def _hillshade(elevation: np.ndarray, resolution: float, ramp=None, height_scale: float = 1.0):
    """A hillshade of the elevation (lit from the north-west at 45 degrees,
    the cosine of the angle between the light and each cell's normal)
    multiplied over its colour on a ramp (default: land colours); NaN cells
    white.  ``height_scale`` puts a height in the unit of ``resolution``, so
    the relief is shaded at its true steepness (times the usual exaggeration).
    Returns the RGB(A), the norm and the ramp."""
    from matplotlib.colors import LightSource, Normalize

    ramp = _ramp() if ramp is None else ramp

    valid = np.isfinite(elevation)
    lo, hi = float(np.nanmin(elevation)), float(np.nanmax(elevation))
    if hi <= lo:
        hi = lo + 1.0
    filled = np.where(valid, elevation, np.nanmean(elevation))
    light = LightSource(azdeg=315, altdeg=45)
    norm = Normalize(lo, hi)
    shade = light.hillshade(filled, vert_exag=3.0 * height_scale, dx=resolution, dy=resolution)
    rgb = ramp(norm(filled))
    rgb[..., :3] *= (0.25 + 0.75 * shade)[..., None]  # the relief's light and shadow over the heights' colours
    rgb[~valid] = (1.0, 1.0, 1.0, 1.0)
    return rgb, norm, ramp


def _crs_name(ds) -> str:
    from pyproj import CRS

    wkt = ds["spatial_ref"].attrs.get("crs_wkt")
    return CRS.from_wkt(wkt).name if wkt else "no CRS"


_UNIT_SYMBOLS = {"metre": "m", "foot": "ft", "US survey foot": "US ft"}


def _units(ds) -> tuple[str, str, float]:
    """Symbols of the horizontal and the height unit, and what turns a height
    into horizontal units.  Heights without a CF ``units`` are taken to be in
    the horizontal unit, as the run presumed them."""
    from pyproj import CRS

    wkt = ds["spatial_ref"].attrs.get("crs_wkt")
    crs = CRS.from_wkt(wkt) if wkt else None
    if crs is not None and crs.is_compound:
        crs = crs.sub_crs_list[0]
    axes = crs.axis_info if crs is not None else []
    if not axes:
        return "m", "m", 1.0
    name, xy_metres = axes[0].unit_name, axes[0].unit_conversion_factor
    xy = _UNIT_SYMBOLS.get(name, name)
    z_metres = cf_metres(str(ds["elevation"].attrs.get("units", "")))
    if z_metres is None:
        return xy, xy, 1.0
    known = (symbol for name, symbol in _UNIT_SYMBOLS.items() if math.isclose(unit_metres(name) or 0.0, z_metres))
    return xy, next(known, f"{z_metres!r} m"), z_metres / xy_metres


def _previewed_layers(ds) -> list:
    """The products the store holds that declare a preview, in registry order (elevation has its own panel)."""
    from ..products import PRODUCTS

    return [p for p in PRODUCTS if p.preview is not None and p.name != "elevation" and p.name in ds]


def _layer_panel(fig, ax, values: np.ndarray, spec, extent, z_unit: str, xy_unit: str) -> None:
    """One product's cells on its preview's colour map, with a colour bar."""
    import matplotlib.pyplot as plt

    preview = spec.preview
    valid = values[np.isfinite(values)]
    lo, hi = (np.percentile(valid, preview.percentiles) if valid.size else (0.0, 1.0))
    if hi <= lo:
        hi = lo + 1.0
    image = ax.imshow(np.ma.masked_invalid(values), extent=extent, origin="upper", interpolation="nearest",
                      cmap=plt.get_cmap(preview.cmap).with_extremes(bad="white"), vmin=lo, vmax=hi)
    units = z_unit if spec.units == "<height>" else (spec.units or "")
    fig.colorbar(image, ax=ax, shrink=0.8, label=f"{preview.label} ({units})" if units else preview.label)
    ax.set_title(f"{spec.name}: {spec.long_name}", fontsize=10)
    ax.set_xlabel(f"x ({xy_unit})")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=8)


def _window_faces(store_path: str, window: tuple[float, float, float, float]):
    """The mesh's faces meeting the window, as corner coordinates, and their kinds."""
    from .. import api

    tiles = api.open_store(store_path)
    polys, quads = [], []
    reach = tiles.grid.tile_size  # a tile's faces may cross into its neighbours
    for tile in tiles.tiles():
        x0, y0, x1, y1 = tile.box
        if x1 + reach < window[0] or x0 - reach > window[2] or y1 + reach < window[1] or y0 - reach > window[3]:
            continue
        mesh, _ = tiles.tile_mesh(tile)
        f = mesh.faces
        if f.shape[0] == 0:
            continue
        xy = mesh.vertices[np.maximum(f, 0)]  # (m, 4, 2)
        is_quad = f[:, 3] >= 0
        xy[~is_quad, 3] = xy[~is_quad, 2]
        lo, hi = xy.min(axis=1), xy.max(axis=1)
        hit = (hi[:, 0] >= window[0]) & (lo[:, 0] <= window[2]) & (hi[:, 1] >= window[1]) & (lo[:, 1] <= window[3])
        polys.append(xy[hit])
        quads.append(is_quad[hit])
    if not polys:
        return np.empty((0, 4, 2)), np.empty(0, dtype=bool)
    return np.concatenate(polys), np.concatenate(quads)


def render_preview(
    store_path: str | Path,
    out: str | Path,
    *,
    window: tuple[float, float, float, float] | None = None,
    max_pixels: int = 1600,
) -> Path:
    """Draw the store's DEM (and with ``window`` the mesh over it) into a PNG.

    A DEM without a value (a valid run can make one: its notes say why, as
    cells coarser than every face under ``max_edge``) is drawn as its grid's
    extent with that said, and the mesh in ``window`` over it.

    Parameters
    ----------
    store_path : a store written by ``terrain run``
    out : the PNG to write
    window : (xmin, ymin, xmax, ymax) in the store's CRS, optional
        A second panel zooms into this box and draws the combined mesh's
        triangles and quadrangles over the hillshade.
    max_pixels : the longest side of the overview, in DEM cells (coarser
        stores are subsampled, never resampled)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..store.zarr_store import StoreError, open_dem, read_attrs

    if read_attrs(store_path) is None:
        raise StoreError(f"{store_path}: not a Zarr store")
    ds = open_dem(store_path)
    if "elevation" not in ds:
        raise UsageError(f"{store_path}: the store has no elevation layer")
    view = _overview(ds, max_pixels)
    xy_unit, z_unit, height_scale = _units(ds)

    drawn = [] if view.empty else _previewed_layers(ds)
    panels = 1 + len(drawn) + (window is not None)
    fig, axes = plt.subplots(1, panels, figsize=(7.5 * panels, 6.5), squeeze=False, constrained_layout=True)
    ax = axes[0, 0]
    if view.empty:
        _empty_panel(ax, ds, store_path, view, xy_unit)
    else:
        rgb, norm, ramp = _hillshade(view.elev, view.cell, height_scale=height_scale)
        _overview_panel(fig, ax, ds, store_path, view, rgb, norm, ramp, xy_unit, z_unit)
    rows, cols, step = view.rows, view.cols, view.step
    for k, spec in enumerate(drawn):
        values = ds[spec.name].values[::step, ::step].astype(np.float64)[rows[0]: rows[-1] + 1, cols[0]: cols[-1] + 1]
        _layer_panel(fig, axes[0, 1 + k], values, spec, view.extent, z_unit, xy_unit)

    if window is not None:
        x0, y0, x1, y1 = window
        if not (x0 < x1 and y0 < y1):
            raise UsageError(f"window={window!r} must be (xmin, ymin, xmax, ymax) with min < max")
        ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="red", linewidth=1.5))
        extent = view.extent
        polys, quads = _window_faces(str(store_path), window)
        if polys.shape[0] == 0:
            plt.close(fig)
            raise UsageError(f"window={window!r} meets no face of the mesh (its extent: x {extent[0]:g} .. "
                             f"{extent[1]:g}, y {extent[2]:g} .. {extent[3]:g})")
        if polys.shape[0] > MAX_MESH_FACES:
            plt.close(fig)
            raise UsageError(
                f"the window holds {polys.shape[0]:,} faces, too many to draw legibly "
                f"(at most {MAX_MESH_FACES:,}); choose a smaller window"
            )
        _mesh_panel(axes[0, panels - 1], ds, window, polys, quads, view, height_scale, xy_unit)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


@dataclass(frozen=True)
class _Overview:
    """The DEM subsampled by ``step`` and cropped to its cells with data
    (``rows``, ``cols`` of the subsampled grid), drawn over ``extent``
    (left, right, bottom, top) with cells of ``cell``; ``res``, ``xs`` and
    ``ys`` are the store's own cells."""

    elev: np.ndarray
    extent: tuple[float, float, float, float]
    cell: float
    step: int
    rows: np.ndarray
    cols: np.ndarray
    res: float
    xs: np.ndarray
    ys: np.ndarray

    @property
    def empty(self) -> bool:
        """Whether no cell has an elevation (``elev`` is then empty, ``extent`` the whole grid's)."""
        return self.elev.size == 0


def _overview(ds, max_pixels: int) -> _Overview:
    """The DEM's overview: at most ``max_pixels`` cells a side, cropped to its data."""
    res = float(abs(ds["x"].values[1] - ds["x"].values[0])) if ds.sizes["x"] > 1 else 1.0
    step = max(1, math.ceil(max(ds.sizes["x"], ds.sizes["y"]) / max_pixels))
    elev = ds["elevation"].values[::step, ::step].astype(np.float64)
    xs, ys = ds["x"].values, ds["y"].values
    extent = (xs[0] - res / 2, xs[-1] + res / 2, ys[-1] - res / 2, ys[0] + res / 2)
    if not np.isfinite(elev).any():
        none = np.zeros(0, dtype=np.int64)
        return _Overview(np.empty((0, 0)), extent, res * step, step, none, none, res, xs, ys)
    # crop the overview to the cells with data (the grid is the data's box, which a survey need not fill)
    rows = np.flatnonzero(np.isfinite(elev).any(axis=1))
    cols = np.flatnonzero(np.isfinite(elev).any(axis=0))
    elev = elev[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    cell = res * step
    left, top = extent[0] + cols[0] * cell, extent[3] - rows[0] * cell
    extent = (left, left + elev.shape[1] * cell, top - elev.shape[0] * cell, top)
    return _Overview(elev, extent, cell, step, rows, cols, res, xs, ys)


def _map_axes(ax, xy_unit: str) -> None:
    """A map panel's axes: x and y in the CRS's unit, plain numbers (no offset)."""
    ax.set_xlabel(f"x ({xy_unit})")
    ax.set_ylabel(f"y ({xy_unit})")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=8)


def _empty_panel(ax, ds, store_path, view: _Overview, xy_unit: str) -> None:
    """The grid's extent, saying that no cell has an elevation, with the run's note on why."""
    report = ds.attrs.get("report")
    notes = report.get("notes", []) if isinstance(report, dict) else []
    why = next((str(n) for n in notes if "DEM is empty" in str(n)), "")
    ax.set_xlim(view.extent[0], view.extent[1])
    ax.set_ylim(view.extent[2], view.extent[3])
    ax.set_aspect("equal")
    text = "no cell of this DEM has an elevation"
    if why:
        text += "\n\n" + textwrap.fill(why, 60)
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=10,
            bbox={"facecolor": "white", "edgecolor": "none"})
    ax.set_title(f"{Path(store_path).name}: empty DEM, {view.res:g} {xy_unit} cells ({_crs_name(ds)})", fontsize=10)
    _map_axes(ax, xy_unit)


def _overview_panel(fig, ax, ds, store_path, view: _Overview, rgb, norm, ramp, xy_unit: str, z_unit: str) -> None:
    """The hillshaded DEM with its scale bar, north arrow and colour bar."""
    import matplotlib.pyplot as plt
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    extent, res = view.extent, view.res
    ax.imshow(rgb, extent=extent, origin="upper", interpolation="nearest")
    span = extent[1] - extent[0]
    length = _nice_length(span)
    ax.add_artist(AnchoredSizeBar(ax.transData, length, f"{length:g} {xy_unit}", "lower left", pad=0.5,
                                  color="black", frameon=True, size_vertical=span / 250))
    ax.annotate("N", xy=(0.95, 0.93), xytext=(0.95, 0.8), xycoords="axes fraction", ha="center",
                arrowprops={"arrowstyle": "-|>", "color": "black"}, fontsize=12, fontweight="bold")
    mappable = plt.cm.ScalarMappable(norm=norm, cmap=ramp)
    fig.colorbar(mappable, ax=ax, shrink=0.8, label=f"elevation ({z_unit})")
    ax.set_title(f"{Path(store_path).name}: DEM hillshade, {res:g} {xy_unit} cells ({_crs_name(ds)})", fontsize=10)
    _map_axes(ax, xy_unit)


def _mesh_panel(zoom, ds, window, polys, quads, view: _Overview, height_scale: float, xy_unit: str) -> None:
    """The combined mesh's faces in ``window`` over a grey relief, faces longer than ``max_edge`` dashed."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    x0, y0, x1, y1 = window
    xs, ys, res = view.xs, view.ys, view.res
    c0 = max(0, int((x0 - (xs[0] - res / 2)) // res))
    c1 = min(len(xs), int(math.ceil((x1 - (xs[0] - res / 2)) / res)))
    r0 = max(0, int(((ys[0] + res / 2) - y1) // res))
    r1 = min(len(ys), int(math.ceil(((ys[0] + res / 2) - y0) / res)))
    sub = ds["elevation"].values[r0:r1, c0:c1].astype(np.float64)
    if np.isfinite(sub).any():
        # grey relief under the mesh, so the two face colours read clearly
        zrgb, _, _ = _hillshade(sub, res, ramp=plt.get_cmap("Greys_r"), height_scale=height_scale)
        zoom.imshow(zrgb, extent=(xs[0] - res / 2 + c0 * res, xs[0] - res / 2 + c1 * res,
                                  ys[0] + res / 2 - r1 * res, ys[0] + res / 2 - r0 * res),
                    origin="upper", interpolation="nearest", alpha=0.5)
    max_edge = ds.attrs.get("provenance", {}).get("parameters", {}).get("max_edge")
    closed = np.concatenate([polys, polys[:, :1]], axis=1)
    longest = np.sqrt((np.diff(closed, axis=1) ** 2).sum(axis=2)).max(axis=1)
    bridged = longest > max_edge if max_edge else np.zeros(len(polys), dtype=bool)
    colours = {"triangles": "#2166ac", "quadrangles": "#f4a516"}
    handles = []
    for label, sel in (("triangles", ~quads & ~bridged), ("quadrangles", quads & ~bridged)):
        zoom.add_collection(PolyCollection(polys[sel], facecolors=colours[label], edgecolors="#202020",
                                           linewidths=0.3, alpha=0.6))
        handles.append(Patch(facecolor=colours[label], alpha=0.6, edgecolor="#202020",
                             label=f"{label} ({int(sel.sum()):,})"))
    if bridged.any():
        zoom.add_collection(PolyCollection(polys[bridged], facecolors="none", edgecolors="#808080",
                                           linewidths=0.4, linestyles="dashed"))
        handles.append(Patch(facecolor="white", edgecolor="#808080", linestyle="dashed",
                             label=f"edge > max_edge {max_edge:g} {xy_unit}: no DEM ({int(bridged.sum()):,})"))
    zoom.legend(handles=handles, loc="upper right", fontsize=8, framealpha=0.9)
    zoom.set_xlim(x0, x1)
    zoom.set_ylim(y0, y1)
    zoom.set_aspect("equal")
    zlen = _nice_length(x1 - x0)
    zoom.add_artist(AnchoredSizeBar(zoom.transData, zlen, f"{zlen:g} {xy_unit}", "lower left", pad=0.5,
                                    color="black", frameon=True, size_vertical=(x1 - x0) / 250))
    zoom.set_title("combined mesh in the red box", fontsize=10)
    zoom.ticklabel_format(useOffset=False, style="plain")
    zoom.tick_params(labelsize=8)
