"""A finished store's raster layers as Cloud-Optimized GeoTIFFs, for any GIS.

GDAL before 3.9 (QGIS LTS, Debian 12) opens no Zarr v3; every GIS opens a
GeoTIFF.  :func:`export_geotiff` writes each layer as a COG (tiled, DEFLATE
with a predictor, overviews, the store's CRS and nodata), through GDAL's COG
driver (``rasterio``, the ``geotiff`` extra).

A layer of more than ``max_file_cells`` cells is written as one COG per block
of the store's chunk rows (counted from the north edge), beside a VRT that
mosaics them (``STEM.vrt``), which GDAL, QGIS and rasterio open as one raster.

Files are written under a temporary name and renamed into place once whole:
a stopped export leaves no file that looks finished.

Naming: the first layer exported goes to ``output``; each further layer goes
beside it as ``STEM_LAYER.tif`` (``dem.tif``, ``dem_slope.tif``, ...).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from ..config import Layer
from ..products import product
from ..errors import StoreError, UsageError
from ..urls import is_url
from .zarr_store import layer_names, nodata_value, read_attrs, read_layer
from ..tiling.grid import TileGrid

__all__ = ["ExportedLayer", "export_geotiff", "MAX_FILE_CELLS"]

MAX_FILE_CELLS = 2**30
"""Cells above which a layer is split into row blocks plus a VRT (4 GiB of float32)."""

_BLOCK = 512
"""COG tile edge in pixels."""

_GDAL_TYPES = {"float32": "Float32", "uint8": "Byte", "int32": "Int32"}


@dataclass(frozen=True)
class ExportedLayer:
    """One layer as written: ``path`` is the COG, or the VRT over ``parts``."""

    layer: str
    path: Path
    parts: tuple[Path, ...]

    @property
    def is_mosaic(self) -> bool:
        return self.path.suffix.lower() == ".vrt"


def export_geotiff(
    store: str | os.PathLike[str],
    output: str | os.PathLike[str],
    layers: Sequence[str] | None = None,
    *,
    max_file_cells: int = MAX_FILE_CELLS,
) -> list[ExportedLayer]:
    """Write the layers of a complete store as Cloud-Optimized GeoTIFFs.

    Parameters
    ----------
    store
        A store written by a finished run.
    output
        The GeoTIFF of the first layer (``.tif``); further layers go beside it.
    layers
        Layer names (default: every raster layer the store holds, elevation first).
    max_file_cells
        Layers with more cells are written as blocks of whole chunk rows plus a VRT.

    Raises
    ------
    StoreError
        If ``store`` is not a complete store, or lacks a layer asked for.
    UsageError
        If a layer name is unknown, ``max_file_cells`` is not a positive
        integer, or rasterio is not installed.
    """
    rasterio = _rasterio()
    where = os.fspath(store)
    if is_url(os.fspath(output)):
        raise UsageError(f"{os.fspath(output)}: GeoTIFFs are written to a local folder; upload them from there")
    attrs = read_attrs(where)
    if attrs is None:
        raise StoreError(f"{where}: is not a Zarr store")
    if not attrs.get("complete", False):
        raise StoreError(f"{where}: the store is not complete (its run did not finish); nothing exported")
    if isinstance(max_file_cells, bool) or not isinstance(max_file_cells, (int, np.integer)) or max_file_cells < 1:
        raise UsageError(f"max_file_cells must be a positive integer, got {max_file_cells!r}")
    held = layer_names(where)
    chosen = held if layers is None else [Layer.parse(name) for name in layers]
    missing = [layer.value for layer in chosen if layer not in held]
    if missing:
        raise StoreError(f"{where}: holds no layer {', '.join(map(repr, missing))} (it holds {', '.join(held)})")
    if not chosen:
        raise UsageError("layers is empty: name at least one layer")
    grid = TileGrid.from_dict(attrs["grid"])
    crs_wkt = attrs.get("provenance", {}).get("crs_wkt")
    crs = rasterio.crs.CRS.from_wkt(crs_wkt) if crs_wkt else None
    out = Path(output)
    out.parent.mkdir(parents=True, exist_ok=True)
    blocks = _row_blocks(grid, max_file_cells)
    written = []
    for i, layer in enumerate(dict.fromkeys(chosen)):
        target = out if i == 0 else out.with_name(f"{out.stem}_{layer.value}{out.suffix or '.tif'}")
        written.append(_export_layer(rasterio, where, grid, crs, layer, target, blocks))
    return written


def _rasterio():
    try:
        import rasterio
        import rasterio.crs
        import rasterio.shutil
        import rasterio.transform
    except ImportError:
        raise UsageError(
            "writing GeoTIFFs needs rasterio: pip install 'terrain-pipeline[geotiff]'"
        ) from None
    return rasterio


def _row_blocks(grid: TileGrid, max_file_cells: int) -> list[tuple[int, int]]:
    """North-up (first row, row count) of each file: whole chunk rows of the
    store (``tile_cells`` rows from the north edge; the southern one may be
    lower), at most ``max_file_cells`` cells each (at least one chunk row)."""
    if grid.nx * grid.ny <= max_file_cells:
        return [(0, grid.ny)]
    chunk_rows = max(1, max_file_cells // (grid.nx * grid.tile_cells))
    step = chunk_rows * grid.tile_cells
    return [(top, min(step, grid.ny - top)) for top in range(0, grid.ny, step)]


def _export_layer(rasterio, store: str, grid: TileGrid, crs, layer: Layer, target: Path,
                  blocks: list[tuple[int, int]]) -> ExportedLayer:
    if len(blocks) == 1:
        _write_cog(rasterio, store, grid, crs, layer, target, *blocks[0])
        return ExportedLayer(layer.value, target, (target,))
    parts = []
    for k, (top, rows) in enumerate(blocks):
        part = target.with_name(f"{target.stem}-{k:03d}{target.suffix or '.tif'}")
        _write_cog(rasterio, store, grid, crs, layer, part, top, rows)
        parts.append(part)
    vrt = target.with_suffix(".vrt")
    _replace_atomically(vrt, _vrt_xml(grid, crs, layer, parts, blocks).encode())
    return ExportedLayer(layer.value, vrt, tuple(parts))


def _write_cog(rasterio, store: str, grid: TileGrid, crs, layer: Layer, target: Path, top: int, rows: int) -> None:
    """Rows ``top:top+rows`` (north-up) of ``layer`` as one COG at ``target``."""
    spec = product(layer.value)  # its GeoTIFF sample type and how its overviews summarise cells
    dtype = spec.export_dtype
    nodata = nodata_value(layer)
    x0, res, _, y_top, _, _ = grid.geotransform
    transform = rasterio.transform.Affine(res, 0.0, x0, 0.0, -res, y_top - top * res)
    profile = dict(
        driver="GTiff", width=grid.nx, height=rows, count=1, dtype=dtype, crs=crs, transform=transform,
        nodata=nodata, tiled=True, blockxsize=_BLOCK, blockysize=_BLOCK, compress="deflate", zlevel=1,
        bigtiff="if_safer",
    )
    # GDAL's COG driver copies from a finished raster: a tiled scratch GeoTIFF, streamed from the store
    with tempfile.TemporaryDirectory(prefix=".export-", dir=target.parent) as scratch:
        staged = Path(scratch) / "layer.tif"
        with rasterio.open(staged, "w", **profile) as dst:
            dst.set_band_description(1, layer.value)
            step = grid.tile_cells * max(1, (1 << 24) // (grid.tile_cells * max(1, grid.nx)))
            for r in range(0, rows, step):
                n = min(step, rows - r)
                values = read_layer(store, layer, slice(top + r, top + r + n))
                dst.write(values.astype(dtype, copy=False), 1, window=((r, r + n), (0, grid.nx)))
        partial = Path(scratch) / target.name
        rasterio.shutil.copy(
            staged, partial, driver="COG", COMPRESS="DEFLATE", PREDICTOR="YES", BLOCKSIZE=str(_BLOCK),
            OVERVIEWS="AUTO", RESAMPLING=spec.resampling, BIGTIFF="IF_SAFER",
        )
        os.replace(partial, target)


def _vrt_xml(grid: TileGrid, crs, layer: Layer, parts: list[Path], blocks: list[tuple[int, int]]) -> str:
    """A VRT mosaic of the row blocks: one band, each block a source at its rows."""
    gdal_type = _GDAL_TYPES[product(layer.value).export_dtype]
    nodata = nodata_value(layer)
    lines = [f'<VRTDataset rasterXSize="{grid.nx}" rasterYSize="{grid.ny}">']
    if crs is not None:
        lines.append(f'  <SRS dataAxisToSRSAxisMapping="1,2">{escape(crs.to_wkt())}</SRS>')
    lines.append(f"  <GeoTransform>{', '.join(repr(float(v)) for v in grid.geotransform)}</GeoTransform>")
    lines.append(f'  <VRTRasterBand dataType="{gdal_type}" band="1">')
    lines.append(f"    <Description>{layer.value}</Description>")
    if nodata is not None:
        lines.append(f"    <NoDataValue>{'nan' if isinstance(nodata, float) and math.isnan(nodata) else nodata}</NoDataValue>")
    for part, (top, rows) in zip(parts, blocks):
        lines += [
            "    <SimpleSource>",
            f'      <SourceFilename relativeToVRT="1">{escape(part.name)}</SourceFilename>',
            "      <SourceBand>1</SourceBand>",
            f'      <SourceProperties RasterXSize="{grid.nx}" RasterYSize="{rows}" DataType="{gdal_type}" '
            f'BlockXSize="{_BLOCK}" BlockYSize="{_BLOCK}"/>',
            f'      <SrcRect xOff="0" yOff="0" xSize="{grid.nx}" ySize="{rows}"/>',
            f'      <DstRect xOff="0" yOff="{top}" xSize="{grid.nx}" ySize="{rows}"/>',
            "    </SimpleSource>",
        ]
    lines += ["  </VRTRasterBand>", "</VRTDataset>", ""]
    return "\n".join(lines)


def _replace_atomically(target: Path, data: bytes) -> None:
    partial = target.with_name(f".{target.name}.partial")
    partial.write_bytes(data)
    os.replace(partial, target)
