"""A STAC Item beside each store: where it is, in which CRS, and its files.

``dem.zarr`` gets ``dem.stac.json``: a STAC 1.1 Item (GeoJSON Feature) with
the grid's footprint in longitude/latitude, the projection extension's
``proj:code`` (or ``proj:wkt2``), ``proj:bbox``, ``proj:shape`` and
``proj:transform``, the run's provenance under ``terrain:provenance``, and
one asset per file: the Zarr store, and the GeoTIFFs that
:func:`~pipeline.store.export.export_geotiff` wrote.  Hrefs are relative to the
item, so the folder can be moved or uploaded as it is.
"""

from __future__ import annotations

import json
import math
import os
import posixpath
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from ..errors import OutputWriteError, one_line
from .zarr_store import read_attrs
from ..tiling.grid import TileGrid
from ..urls import Location, filesystem, location

__all__ = ["STAC_VERSION", "PROJECTION_EXTENSION", "stac_item", "stac_item_path", "write_stac_item"]

STAC_VERSION = "1.1.0"
PROJECTION_EXTENSION = "https://stac-extensions.github.io/projection/v2.0.0/schema.json"
ZARR_MEDIA_TYPE = "application/vnd+zarr"
COG_MEDIA_TYPE = "image/tiff; application=geotiff; profile=cloud-optimized"
VRT_MEDIA_TYPE = "application/x-vrt"

_FOOTPRINT_STEPS = 16
"""Points per side of the footprint: a projected rectangle's edges curve in longitude/latitude."""


def stac_item_path(store: str | os.PathLike[str]) -> Location:
    """``dem.zarr`` -> ``dem.stac.json`` beside it (a URL beside a store on object storage)."""
    where = location(store)
    if isinstance(where, str):
        parent, _, name = where.rstrip("/").rpartition("/")
        return f"{parent}/{_item_name(name)}"
    return where.with_name(_item_name(where.name))


def _item_name(store_name: str) -> str:
    stem = store_name[: -len(".zarr")] if store_name.lower().endswith(".zarr") else store_name
    return f"{stem}.stac.json"


def stac_item(store: str | os.PathLike[str], files: Mapping[str, Sequence[str | os.PathLike[str]]] | None = None) -> dict[str, Any]:
    """The STAC Item of a store, as a dict.

    ``files`` maps a layer name to its exported files (one COG, or a VRT
    first and then its COGs); each becomes an asset.
    """
    where = os.fspath(store)
    attrs = read_attrs(where) or {}
    grid = TileGrid.from_dict(attrs["grid"])
    provenance = attrs.get("provenance", {})
    history = attrs.get("run_history") or [{}]
    crs = pyproj.CRS.from_wkt(provenance["crs_wkt"]) if provenance.get("crs_wkt") else None
    x0, y0 = grid.x0, grid.y0
    x1, y1 = x0 + grid.nx * grid.resolution, grid.y_top
    home = _parent(stac_item_path(where))
    properties: dict[str, Any] = {
        "datetime": history[-1].get("finished"),
        "proj:code": _epsg_code(crs),
        "proj:bbox": [x0, y0, x1, y1],
        "proj:shape": [grid.ny, grid.nx],
        "proj:transform": [grid.resolution, 0.0, x0, 0.0, -grid.resolution, y1],
        "terrain:provenance": provenance,
    }
    if crs is not None and properties["proj:code"] is None:
        properties["proj:wkt2"] = crs.to_wkt()
    bands = _layer_bands(where)
    assets: dict[str, Any] = {
        "zarr": {
            "href": _relative(where, home),
            "type": ZARR_MEDIA_TYPE,
            "title": "DEM layers and the combined triangle/quad mesh (UGRID group 'mesh')",
            "roles": ["data"],
            "terrain:layers": bands,
        }
    }
    for layer, paths in (files or {}).items():
        for k, path in enumerate(paths):
            mosaic = str(path).lower().endswith(".vrt")
            key = layer if k == 0 else f"{layer}-{k - 1:03d}"
            assets[key] = {
                "href": _relative(path, home),
                "type": VRT_MEDIA_TYPE if mosaic else COG_MEDIA_TYPE,
                "title": f"{layer}: {'mosaic of its row blocks' if mosaic else 'Cloud-Optimized GeoTIFF'}",
                "description": bands.get(layer, {}).get("description", layer),
                "roles": ["data"] if k == 0 else ["data", "tile"],
                "raster:bands": [_raster_band(bands.get(layer, {}))],
            }
    footprint = _footprint(crs, (x0, y0, x1, y1))
    item: dict[str, Any] = {
        "type": "Feature",
        "stac_version": STAC_VERSION,
        "stac_extensions": [PROJECTION_EXTENSION, *([RASTER_EXTENSION] if files else [])],
        "id": _name(stac_item_path(where)).removesuffix(".stac.json"),
        "geometry": footprint,
    }
    if footprint is not None:
        ring = np.asarray(footprint["coordinates"][0])
        item["bbox"] = [float(ring[:, 0].min()), float(ring[:, 1].min()), float(ring[:, 0].max()), float(ring[:, 1].max())]
    item |= {"properties": properties, "links": [], "assets": assets}
    return item


def write_stac_item(
    store: str | os.PathLike[str],
    files: Mapping[str, Sequence[str | os.PathLike[str]]] | None = None,
    *,
    keep_exports: bool = True,
) -> Path:
    """Write (or rewrite) the store's STAC Item beside it; returns its path.

    With ``keep_exports``, the GeoTIFF assets of an earlier export of other
    layers are kept while their files exist; a run passes False, since it
    changed the store those files were made from.
    """
    target = stac_item_path(store)
    item = stac_item(store, files)
    renewed = {_layer_of(key) for key in item["assets"]}
    for key, asset in _previous_assets(target).items() if keep_exports else ():
        if _layer_of(key) not in renewed and _exists(_join(_parent(target), asset.get("href", ""))):
            item["assets"][key] = asset
    text = json.dumps(item, indent=2, allow_nan=False) + "\n"
    try:
        if isinstance(target, str):
            fs, path = filesystem(target)
            fs.pipe_file(path, text.encode())  # an object is written whole
        else:
            partial = target.with_name(f".{target.name}.partial")
            try:
                partial.write_text(text)
                os.replace(partial, target)
            finally:
                partial.unlink(missing_ok=True)
    except OSError as exc:
        raise OutputWriteError(f"{target}: cannot write the STAC item ({exc.strerror or one_line(exc)})") from None
    return target


def _previous_assets(target: Location) -> dict[str, Any]:
    try:
        if isinstance(target, str):
            fs, path = filesystem(target)
            text = fs.cat_file(path).decode()
        else:
            text = target.read_text()
        return dict(json.loads(text).get("assets", {}))
    except (OSError, ValueError, AttributeError):
        return {}


def _parent(where: Location) -> Location:
    return where.rsplit("/", 1)[0] if isinstance(where, str) else where.parent


def _name(where: Location) -> str:
    return where.rsplit("/", 1)[-1] if isinstance(where, str) else where.name


def _join(home: Location, href: str) -> Location:
    if isinstance(home, str):
        scheme, rest = home.split("://", 1)
        return f"{scheme}://{posixpath.normpath(f'{rest}/{href}')}"
    return home / href


def _exists(where: Location) -> bool:
    if isinstance(where, str):
        fs, path = filesystem(where)
        return bool(fs.exists(path))
    return where.exists()


def _layer_of(asset_key: str) -> str:
    """``slope-002`` (a row block of slope) -> ``slope``."""
    head, _, tail = asset_key.rpartition("-")
    return head if head and tail.isdigit() else asset_key


RASTER_EXTENSION = "https://stac-extensions.github.io/raster/v1.1.0/schema.json"


def _layer_bands(store: str) -> dict[str, dict[str, Any]]:
    """Each raster layer the store holds, as its product declares it and the
    store records it: description, data type of its GeoTIFF, nodata, unit."""
    from ..products import product
    from .zarr_store import layer_attrs, layer_names

    out: dict[str, dict[str, Any]] = {}
    for layer in layer_names(store):
        spec = product(layer.value)
        units = layer_attrs(store, layer).get("units")
        nodata = spec.nodata
        out[layer.value] = {
            "description": spec.description,
            "data_type": spec.export_dtype,
            **({} if nodata is None else {"nodata": "nan" if isinstance(nodata, float) and math.isnan(nodata) else nodata}),
            **({} if units is None else {"unit": units}),
        }
    return out


def _raster_band(band: Mapping[str, Any]) -> dict[str, Any]:
    """The STAC raster extension's band of a layer's GeoTIFF."""
    return {k: v for k, v in band.items() if k in ("data_type", "nodata", "unit")}


def _epsg_code(crs: pyproj.CRS | None) -> str | None:
    if crs is None:
        return None
    authority = crs.to_authority(min_confidence=90)
    return None if authority is None else f"{authority[0]}:{authority[1]}"


def _footprint(crs: pyproj.CRS | None, box: tuple[float, float, float, float]) -> dict[str, Any] | None:
    """The box's outline in longitude/latitude (a GeoJSON Polygon), or None without a CRS."""
    if crs is None:
        return None
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    to_lonlat = pyproj.Transformer.from_crs(horizontal, "EPSG:4326", always_xy=True)
    x0, y0, x1, y1 = box
    t = np.linspace(0.0, 1.0, _FOOTPRINT_STEPS, endpoint=False)
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full_like(t, x1), x1 - (x1 - x0) * t, np.full_like(t, x0)])
    ys = np.concatenate([np.full_like(t, y0), y0 + (y1 - y0) * t, np.full_like(t, y1), y1 - (y1 - y0) * t])
    lon, lat = to_lonlat.transform(xs, ys)
    if not (np.isfinite(lon).all() and np.isfinite(lat).all()):
        return None
    ring = [[round(float(a), 9), round(float(b), 9)] for a, b in zip(lon, lat)]
    return {"type": "Polygon", "coordinates": [[*ring, ring[0]]]}


def _relative(path: str | os.PathLike[str], home: Location) -> str:
    """``path`` relative to the item's folder; an absolute URL where the two
    are not on one filesystem (a local GeoTIFF of a store on object storage)."""
    where = location(path)
    if isinstance(home, str) != isinstance(where, str):
        return str(where) if isinstance(where, str) else where.as_uri()
    if isinstance(home, str):
        assert isinstance(where, str)
        scheme = home.split("://", 1)[0]
        if not where.startswith(f"{scheme}://"):
            return where
        return "./" + posixpath.relpath(where.split("://", 1)[1], home.split("://", 1)[1])
    return "./" + Path(os.path.relpath(where, home)).as_posix()
