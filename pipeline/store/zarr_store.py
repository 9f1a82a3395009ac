"""The output store: one Zarr group holding the DEM and the combined mesh.

Layout
------
::

    <store>/                      root group; attrs: provenance, ``Conventions``,
                                  ``grid`` (TileGrid.to_store_attr()), ``run_history``
        x          (x,)           cell-centre x, ascending        float64
        y          (y,)           cell-centre y, DESCENDING       float64
        spatial_ref ()            CF grid mapping: crs_wkt, spatial_ref (GDAL),
                                  GeoTransform, CRS.to_cf() parameters
        elevation  (y, x)         float32, NaN = no data
        slope      (y, x)         float32 degrees, NaN = no data   (optional)
        face_kind  (y, x)         int8: 0 none, 1 triangle, 2 quadrangle (optional)
        point_count (y, x)        int32                            (optional)
        mesh/                     UGRID-1.0 group
            mesh2d      ()        topology (cf_role mesh_topology)
            node_x, node_y (nNodes)           float64
            node_z      (nNodes)              float64, on the nodes
            face_nodes  (nFaces, nMaxFaceNodes=4) int32 (int64 past 2**31 nodes), -1 pads triangles
            spatial_ref ()        the same grid mapping as the root
            tile_row, tile_col (nTiles)       int64
            tile_node_offset, tile_face_offset (nTileOffsets = nTiles + 1) int64
        status/
            tile_done  (tile_row, tile_col)  int8: 1 once the tile's layers are
                                  written (rows from the south; one chunk each)

The root attribute ``complete`` is true only once every tile and the mesh are
written; until then a rerun of the same job resumes.

The raster layers are north-up (row 0 is the northern-most row) and hold the
grid's cells, no more, chunked in ``tile_cells x tile_cells`` blocks from the
north-west corner: the chunks of the southern row and the eastern column may
be partial.  A tile's column of cells is a column of chunks; its rows,
counted from the south, are chunk rows only when ``ny`` is a multiple of
``tile_cells``.  Otherwise a tile writes parts of two chunk rows, and so do
its neighbours to the north and south: tiles of one row parity never share a
chunk, so they are written in parallel without locks, and a tile of an odd
row after its neighbours to the north and south
(:attr:`~pipeline.tiling.grid.TileGrid.rows_share_chunks`).

Both Zarr formats are written: 3 (the default, dimensions in
``dimension_names``) and 2 for older readers such as GDAL 3.6 (dimensions in
``_ARRAY_DIMENSIONS``).  Arrays also carry GDAL's ``_CRS`` attribute, which is
how GDAL before 3.9 reads a Zarr CRS.  Metadata is consolidated by
:func:`create_store`, :meth:`MeshWriter.close` and :func:`finalize_store`.

Examples
--------
>>> import tempfile, numpy as np, xarray as xr
>>> grid = TileGrid(x0=0.0, y0=0.0, resolution=1.0, nx=3, ny=2, tile_cells=2)
>>> with tempfile.TemporaryDirectory() as tmp:
...     store = f"{tmp}/out.zarr"
...     create_store(store, grid, "EPSG:2154", attrs={"run": 1})
...     write_tile(store, grid, 0, 0, {"elevation": np.array([[1.0, 2.0], [3.0, 4.0]])})
...     open_dem(store)["elevation"].values.tolist()
[[3.0, 4.0, nan], [1.0, 2.0, nan]]
"""

from __future__ import annotations

import asyncio
import base64
import functools
import json
import math
import numbers
import os
import re
import shutil
import struct
import threading
import uuid
import warnings
from collections.abc import Coroutine, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numcodecs
import numpy as np
import pyproj
import zarr
import zarr.api.asynchronous
import zarr.errors
from zarr.codecs import BloscCodec
from zarr.core.sync import sync as zarr_sync
from numpy.typing import ArrayLike, NDArray

from ..config import Layer
from ..products import HEIGHT_UNITS, PER_AREA_UNITS, Product, product
from ..errors import CrsError, StoreError, UsageError
from ..tiling.grid import TileGrid
from ..urls import describe_os_error, filesystem, is_url, options_for

if TYPE_CHECKING:
    import xarray as xr

__all__ = [
    "StoreError",
    "grow_store",
    "Layer",
    "create_store",
    "write_tile",
    "mark_tile_done",
    "tiles_done",
    "reset_tiles_done",
    "read_attrs",
    "MeshWriter",
    "finalize_store",
    "open_dem",
    "read_dem_window",
    "read_mesh",
    "read_tile_mesh",
    "read_layer",
    "layer_names",
    "layer_attrs",
    "nodata_value",
]

StorePath = str | os.PathLike[str]

CONVENTIONS = "CF-1.8 UGRID-1.0"
GRID_MAPPING = "spatial_ref"
MESH_GROUP = "mesh"
TOPOLOGY = "mesh2d"
HISTORY_ATTR = "run_history"

STATUS_GROUP = "status"
TILE_DONE = f"{STATUS_GROUP}/tile_done"
"""Array ``(tile_row, tile_col)`` of int8 in group ``status``: 1 once a tile's layers are written."""

MESH_CHUNK = 1 << 18
"""Nodes (and faces) per chunk of the mesh arrays: 2 MiB of float64."""


def _spec(layer: Layer) -> Product:
    """The declaration of ``layer`` (:mod:`pipeline.products`): its dtype, fill value and attributes."""
    return product(layer.value)


def _layer_attrs(spec: Product, z_units: str | None, xy_unit: str | None) -> dict[str, Any]:
    """A layer's CF attributes: its long name, units (heights in the store's
    height unit, densities per square horizontal unit) and flags."""
    out: dict[str, Any] = {"long_name": spec.long_name}
    if spec.units == HEIGHT_UNITS:
        if z_units is not None:
            out["units"] = z_units
    elif spec.units == PER_AREA_UNITS:
        if xy_unit is not None:
            out["units"] = f"({xy_unit})-2" if " " in xy_unit else f"{xy_unit}-2"
    elif spec.units is not None:
        out["units"] = spec.units
    return out | dict(spec.attrs)


def _tile_window(grid: TileGrid, tile_row: int, tile_col: int) -> tuple[slice, slice]:
    """North-up (rows, cols) of a tile's cells in the store: one chunk column,
    one chunk row or parts of two (see the module's notes)."""
    if not (0 <= tile_row < grid.n_rows and 0 <= tile_col < grid.n_cols):
        raise UsageError(
            f"tile ({tile_row}, {tile_col}) is outside the grid's "
            f"{grid.n_rows} x {grid.n_cols} tiles"
        )
    r0, r1, c0, c1 = grid.cell_slice(tile_row, tile_col)
    return slice(grid.ny - r1, grid.ny - r0), slice(c0, c1)


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------


def create_store(
    path: StorePath,
    grid: TileGrid,
    crs_wkt: str | None,
    *,
    layers: Sequence[str] = ("elevation",),
    attrs: Mapping[str, Any],
    zarr_format: int = 3,
    overwrite: bool = False,
    height_units: str | None = None,
) -> None:
    """Create the store: the root group, its coordinates, grid mapping and empty layers.

    Parameters
    ----------
    path : str or os.PathLike
        A local directory.  If it exists it must be an empty directory or a
        Zarr store (replaced only with ``overwrite=True``).
    grid : TileGrid
        The DEM grid; ``grid.tile_cells`` is the chunk edge.
    crs_wkt : str or None
        The CRS (any form pyproj reads; stored as WKT2).  None for data
        without a CRS: the grid mapping then holds only the GeoTransform.
    layers : sequence of str
        Names from :class:`Layer`.
    attrs : mapping
        JSON-serialisable provenance, stored as the root's attributes.
    zarr_format : {3, 2}
    overwrite : bool
        Replace an existing Zarr store at ``path``.
    height_units : str, optional
        CF ``units`` of the elevation (e.g. ``"0.3048 metre"``); default: the
        vertical unit of ``crs_wkt`` when it has one.

    Raises
    ------
    StoreError
        ``path`` exists and is not a Zarr store, or is one and ``overwrite`` is false.
    UsageError, CrsError
        Invalid layer names, format, attributes or CRS.
    """
    wanted = tuple(dict.fromkeys(Layer.parse(name) for name in layers))
    if zarr_format not in (2, 3):
        raise UsageError(f"zarr_format must be 2 or 3, got {zarr_format!r}")
    root_attrs = _json_attrs(attrs, "attrs") | {"Conventions": CONVENTIONS, "grid": grid.to_store_attr()}
    crs = _parse_crs(crs_wkt)
    grid_mapping = _grid_mapping_attrs(crs, grid)
    x_attrs, y_attrs, z_units = _axis_attrs(crs)
    z_units = height_units or z_units

    _make_room(path, overwrite)
    root = zarr.create_group(store=_zarr_store(path), zarr_format=zarr_format, attributes=root_attrs)
    root.create_group(STATUS_GROUP)
    gdal_crs = {} if crs is None else {"_CRS": {"wkt": grid_mapping["crs_wkt"]}}
    xy_unit = x_attrs.get("units")
    _create_arrays(root, [
        _NewArray("x", data=grid.x, dims=("x",), attrs=x_attrs),
        _NewArray("y", data=grid.y, dims=("y",), attrs=y_attrs),
        _NewArray(GRID_MAPPING, data=np.int32(0), dims=(), attrs=grid_mapping),
        *(_NewArray(
            layer,
            shape=(grid.ny, grid.nx),
            chunks=(grid.tile_cells, grid.tile_cells),
            dtype=spec.dtype,
            fill=spec.fill,
            masked=spec.masked,
            dims=("y", "x"),
            attrs=_layer_attrs(spec, z_units, xy_unit)
            | {"grid_mapping": GRID_MAPPING, "coordinates": GRID_MAPPING} | gdal_crs,
        ) for layer, spec in ((layer, _spec(layer)) for layer in wanted)),
        _NewArray(
            TILE_DONE,  # in the status group
            shape=(-(-grid.ny // grid.tile_cells), -(-grid.nx // grid.tile_cells)),
            chunks=(1, 1),  # one object per tile: tiles record themselves without locks
            dtype=np.int8,
            fill=0,
            dims=("tile_row", "tile_col"),
            attrs={"long_name": "1 where the tile's DEM is written (tile rows from the south)", "flag_values": [0, 1]},
        ),
    ])
    _consolidate(path)


GROWING_ATTR = "growing"
"""Root attribute set while :func:`grow_store` moves chunks: a store that
still has it was left half grown by a stopped run (and is made again)."""


def grow_store(path: StorePath, before: TileGrid, after: TileGrid) -> None:
    """Extend the store's grid to the north and east, keeping every tile written.

    ``after`` has the origin, cells and tiles of ``before`` and at least its
    rows and columns.  Each layer is resized (Zarr ``resize``): a chunk keeps
    its file and bytes, and the cells that the old northern and eastern
    chunks held beyond the grid read as no data.  New rows at the north move
    every cell of the north-up layers south by as many rows.  When they are
    whole chunk rows, the chunk files are renamed (on object storage, copied
    within the bucket), never decoded or written again; otherwise the chunk
    boundaries, counted from the north edge, fall elsewhere in the cells, and
    every chunk is written again from the cells it now holds (decoded and
    encoded; no tile is computed again).  The coordinates, the GeoTransform,
    the tiles' status (rows from the south: none move) and the ``grid``
    attribute follow; the new cells read as no data until their tiles are
    written.

    Raises
    ------
    UsageError
        ``after`` does not extend ``before`` to the north and east only.
    """
    same = (before.x0, before.y0, before.resolution, before.tile_cells) == (
        after.x0, after.y0, after.resolution, after.tile_cells
    )
    if not (same and after.nx >= before.nx and after.ny >= before.ny):
        raise UsageError(f"grow_store: grid {after.to_store_attr()} does not extend {before.to_store_attr()} to the north and east")
    root = _open_group(path, mode="r+")
    root.attrs.update({GROWING_ATTR: {"from": before.to_store_attr(), "to": after.to_store_attr()}, "complete": False})
    shift = after.ny - before.ny
    whole = shift % before.tile_cells == 0
    for layer in Layer:
        if layer.value not in root:
            continue
        array = root[layer.value]
        if shift and whole:
            _shift_chunk_rows(path, array, before, shift // before.tile_cells)
        array.resize((after.ny, after.nx))
        if not whole:
            _shift_rows(path, layer, before, after)
    _create_arrays(root, [_NewArray(name, data=values, dims=(name,), attrs=_user_attrs(root[name]), overwrite=True)
                          for name, values in (("x", after.x), ("y", after.y))])
    mapping = root[GRID_MAPPING]
    mapping.attrs.update({"GeoTransform": " ".join(repr(v) for v in after.geotransform)})
    _open_array(path, TILE_DONE).resize((after.n_rows, after.n_cols))  # rows from the south: none move
    root.attrs.update({"grid": after.to_store_attr()})
    root.attrs.pop(GROWING_ATTR)
    _consolidate(path)


def _shift_rows(path: StorePath, layer: Layer, before: TileGrid, after: TileGrid) -> None:
    """Move the cells of a north-up layer, already resized to ``after``,
    ``after.ny - before.ny`` rows south, one chunk at a time, the southern
    chunk rows first: a chunk row is written once the chunk rows south of it,
    which take some of its cells, have read them.  The new northern rows are
    no data."""
    array = _open_array(path, layer)  # every chunk stored, as the tiles store theirs
    shift, t = after.ny - before.ny, after.tile_cells
    fill = _spec(layer).fill
    for k in reversed(range(-(-after.ny // t))):
        top, bottom = k * t, min((k + 1) * t, after.ny)
        first = max(top - shift, 0)  # the first row, before the move, that this chunk row takes
        for left in range(0, after.nx, t):
            cols = slice(left, min(left + t, after.nx))
            block = np.full((bottom - top, cols.stop - cols.start), fill, dtype=array.dtype)
            if bottom - shift > first:
                block[first + shift - top:] = array[first : bottom - shift, cols]
            array[top:bottom, cols] = block


def _shift_chunk_rows(path: StorePath, array: zarr.Array, grid: TileGrid, shift: int) -> None:
    """Rename the chunk files of a north-up layer ``shift`` chunk rows south,
    the southern-most first (no new name meets one still in use)."""
    where = os.fspath(path)
    if is_url(where):
        fs, base = filesystem(where)
        base = base.rstrip("/")
        exists, move = fs.exists, fs.mv
    else:
        fs, base = None, where
        exists, move = os.path.exists, os.replace
    prefix = f"{base}/{array.path}"
    encode = array.metadata.encode_chunk_key
    for i in reversed(range(grid.n_rows)):
        for j in range(grid.n_cols):
            old, new = f"{prefix}/{encode((i, j))}", f"{prefix}/{encode((i + shift, j))}"
            if not exists(old):  # never written: reads as no data in both places
                continue
            if fs is None:
                os.makedirs(os.path.dirname(new), exist_ok=True)
            move(old, new)


def mark_tile_done(path: StorePath, tile_row: int, tile_col: int, *, run: str = "") -> None:
    """Record that a tile's layers are written (call only after writing them);
    ``run``: as in :func:`write_tile`."""
    _open_array(path, TILE_DONE, run)[tile_row, tile_col] = 1


def tiles_done(path: StorePath) -> NDArray[np.bool_]:
    """``(n_rows, n_cols)``: which tiles' layers are written (rows from the south)."""
    return _open_array(path, TILE_DONE)[...] == 1


def reset_tiles_done(path: StorePath, tiles: Sequence[tuple[int, int]] | None = None) -> None:
    """Mark tiles (default: all) as not written (their layers will be written again)."""
    array = _open_array(path, TILE_DONE)
    if tiles is None:
        array[...] = 0
        return
    index = tuple(np.array(list(tiles), dtype=np.int64).reshape(-1, 2).T)
    done = array[...]
    if done[index].any():  # one write, and none when nothing changes
        done[index] = 0
        array[...] = done


def read_attrs(path: StorePath) -> dict[str, Any] | None:
    """The root attributes of an existing store, or None when ``path`` holds none."""
    where = os.fspath(path)
    if not _is_zarr_store(where):
        return None
    return dict(_open_group(path).attrs.asdict())


def write_tile(
    path: StorePath, grid: TileGrid, tile_row: int, tile_col: int, layers: Mapping[str, ArrayLike], *, run: str = "",
    mark_done: bool = False,
) -> None:
    """Write one tile's layers, given south-up, into their north-up cells.

    Parameters
    ----------
    path : str or os.PathLike
        A store made by :func:`create_store` with this ``grid``.
    grid : TileGrid
    tile_row, tile_col : int
        The tile, counted from the south-west tile ``(0, 0)``.
    layers : mapping of layer name to array
        Each of shape ``(rows, cols)`` of the tile's cells, ``(tile_cells,
        tile_cells)`` except at the north and east edges; row 0 is the
        southern-most.

    run : str, optional
        Names a run during which the store's arrays keep their shape: the
        arrays opened for it are kept open in this process for the other
        tiles of the same run (a few milliseconds each).
    mark_done : bool, optional
        Then record the tile as written (:func:`mark_tile_done`), once every
        layer is: in the same trip through Zarr's event loop, which each
        call waits for behind the threads running Python (2-15 ms a tile
        beside a run's other tiles).

    Each call opens only the arrays it writes (one small metadata read each)
    and writes cells no other tile holds, in chunks no tile of the same row
    parity touches: tiles of one parity are safe from many threads or
    processes at once, without locks.  Where ``grid.rows_share_chunks``, a
    tile fills its part of a chunk that its northern or southern neighbour
    fills too (Zarr reads the chunk and writes it back whole): the two must
    not be written at the same time.
    """
    rows, cols = _tile_window(grid, tile_row, tile_col)
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    checked = []
    for name, values in layers.items():
        layer = Layer.parse(name)
        values = np.asarray(values)
        if values.shape != shape:
            raise UsageError(
                f"layer {layer.value!r} of tile ({tile_row}, {tile_col}): shape {values.shape}, expected {shape}"
            )
        dtype = _spec(layer).dtype
        if not np.can_cast(values.dtype, dtype, casting="same_kind"):
            raise UsageError(f"layer {layer.value!r}: cannot store {values.dtype} values as {dtype}")
        checked.append((layer, values[::-1].astype(dtype, copy=False)))
    arrays = [(_open_array(path, layer, run).async_array, north_up) for layer, north_up in checked]
    done = _open_array(path, TILE_DONE, run).async_array if mark_done else None  # every array opened first

    async def layers_then_done() -> None:
        await asyncio.gather(*(array.setitem((rows, cols), north_up) for array, north_up in arrays))
        if done is not None:
            await done.setitem((tile_row, tile_col), np.int8(1))

    zarr_sync(layers_then_done())


def face_index_dtype(n_nodes: int) -> np.dtype:
    """The smallest signed integer type that numbers ``n_nodes`` nodes (and -1)."""
    return np.dtype(np.int32) if n_nodes < 2**31 else np.dtype(np.int64)


class MeshWriter:
    """Streams the combined mesh into the store's UGRID group ``mesh``.

    Sizes are known up front; nodes and faces are written in slices, in any
    order, then :meth:`set_tiles` records which tile owns which slice and
    :meth:`close` checks that everything was written and consolidates the
    metadata.  One writer per store; slices written from several threads
    must not share a chunk (``2**18`` nodes or faces).

    Parameters
    ----------
    path : str or os.PathLike
        A store made by :func:`create_store`.  An existing mesh group is replaced.
    n_nodes, n_faces : int
    zarr_format : {2, 3}, optional
        Checked against the store's format; by default the store's.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> grid = TileGrid(x0=0.0, y0=0.0, resolution=1.0, nx=2, ny=2, tile_cells=2)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     create_store(tmp + "/s.zarr", grid, "EPSG:2154", attrs={})
    ...     with MeshWriter(tmp + "/s.zarr", n_nodes=3, n_faces=1) as mesh:
    ...         mesh.write_nodes(0, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [5.0, 6.0, 7.0])
    ...         mesh.write_faces(0, [[0, 1, 2, -1]])
    ...         mesh.set_tiles([0], [0], [0, 3], [0, 1])
    ...     read_mesh(tmp + "/s.zarr")[2].tolist()
    [[0, 1, 2, -1]]
    """

    def __init__(self, path: StorePath, n_nodes: int, n_faces: int, zarr_format: int | None = None) -> None:
        for name, value in (("n_nodes", n_nodes), ("n_faces", n_faces)):
            if not isinstance(value, numbers.Integral) or value < 0:
                raise UsageError(f"MeshWriter.{name} must be an integer >= 0, got {value!r}")
        self.path = path
        self.n_nodes = int(n_nodes)
        self.n_faces = int(n_faces)
        root = _open_group(path, mode="r+")
        if zarr_format is not None and zarr_format != root.metadata.zarr_format:
            raise UsageError(
                f"{os.fspath(path)}: store is Zarr format {root.metadata.zarr_format}, not {zarr_format}"
            )
        self._written: dict[str, list[tuple[int, int]]] = {"nodes": [], "faces": []}
        self._tiles_set = False

        x_attrs = _user_attrs(root["x"])
        y_attrs = _user_attrs(root["y"])
        elevation_attrs = _user_attrs(root[Layer.ELEVATION]) if Layer.ELEVATION in root else {}
        group = root.create_group(MESH_GROUP, overwrite=True, attributes={"Conventions": CONVENTIONS})
        topology = {
            "cf_role": "mesh_topology",
            "long_name": "combined triangle/quadrangle terrain mesh",
            "topology_dimension": 2,
            "node_coordinates": "node_x node_y",
            "face_node_connectivity": "face_nodes",
            "node_dimension": "nNodes",
            "face_dimension": "nFaces",
            "max_face_nodes_dimension": "nMaxFaceNodes",
        }
        node = {"shape": (self.n_nodes,), "chunks": (_chunk(self.n_nodes),), "dims": ("nNodes",)}
        xy = [(name, {k: v for k, v in attrs.items() if k in ("standard_name", "units")}
               | {"long_name": f"{name[-1]} of the mesh nodes"})
              for name, attrs in (("node_x", x_attrs), ("node_y", y_attrs))]
        z_attrs = {k: v for k, v in elevation_attrs.items() if k in ("long_name", "units")}
        _create_arrays(group, [
            _NewArray(TOPOLOGY, data=np.int32(0), dims=(), attrs=topology),
            _NewArray(GRID_MAPPING, data=np.int32(0), dims=(), attrs=_user_attrs(root[GRID_MAPPING])),
            *(_NewArray(name, dtype=np.float64, attrs=attrs, **node) for name, attrs in xy),
            _NewArray("node_z", dtype=np.float64, bit_shuffle=True, **node,
                      attrs=z_attrs | {"mesh": TOPOLOGY, "location": "node", "grid_mapping": GRID_MAPPING}),
            _NewArray(
                "face_nodes",
                shape=(self.n_faces, 4),
                chunks=(_chunk(self.n_faces), 4),
                dtype=face_index_dtype(self.n_nodes),
                fill=-1,
                masked=True,
                dims=("nFaces", "nMaxFaceNodes"),
                bit_shuffle=True,
                attrs={
                    "cf_role": "face_node_connectivity",
                    "long_name": "nodes of each face; -1 pads triangles",
                    "start_index": 0,
                },
            ),
        ])
        self._group = group

    @classmethod
    def attach(cls, path: StorePath) -> MeshWriter:
        """A writer for slices of a mesh group another writer created (e.g. on a
        worker).  Its record of what it wrote stays local: the creating writer
        learns of the slices through :meth:`record`."""
        self = cls.__new__(cls)
        self.path = path
        self._group = _open_group(path, MESH_GROUP, mode="r+")
        self.n_nodes = int(self._group["node_x"].shape[0])
        self.n_faces = int(self._group["face_nodes"].shape[0])
        self._written = {"nodes": [], "faces": []}
        self._tiles_set = False
        return self

    def record(self, what: str, start: int, stop: int) -> None:
        """Count rows ``[start, stop)`` of "nodes" or "faces" as written by an attached writer."""
        if what not in self._written:
            raise UsageError(f"record: what must be 'nodes' or 'faces', got {what!r}")
        self._claim(what, start, stop - start, self.n_nodes if what == "nodes" else self.n_faces)

    def write_nodes(self, start: int, x: ArrayLike, y: ArrayLike, z: ArrayLike) -> None:
        """Write nodes ``start, start + 1, ...`` (1-D x, y, z of equal length)."""
        x, y, z = (np.asarray(a, dtype=np.float64) for a in (x, y, z))
        if x.ndim != 1 or x.shape != y.shape or x.shape != z.shape:
            raise UsageError(f"write_nodes: x, y, z must be 1-D of one length, got {x.shape} {y.shape} {z.shape}")
        stop = self._claim("nodes", start, x.size, self.n_nodes)
        for name, values in (("node_x", x), ("node_y", y), ("node_z", z)):
            self._group[name][start:stop] = values

    def write_faces(self, start: int, faces: ArrayLike) -> None:
        """Write faces ``start, start + 1, ...``: ``(m, 4)`` global node ids, -1 fourth for triangles."""
        faces = np.asarray(faces)
        if faces.ndim != 2 or faces.shape[1] != 4 or not np.issubdtype(faces.dtype, np.integer):
            raise UsageError(f"write_faces: faces must be (m, 4) integers, got {faces.dtype} {faces.shape}")
        lowest = faces.min(axis=0) if faces.size else None  # one pass for both checks of the low end
        if faces.size and (lowest[:3].min() < 0 or lowest[3] < -1 or faces.max() >= self.n_nodes):
            raise UsageError(f"write_faces: node ids must be in [0, {self.n_nodes}), -1 only in the 4th column")
        stop = self._claim("faces", start, faces.shape[0], self.n_faces)
        self._group["face_nodes"][start:stop] = faces

    def set_tiles(
        self,
        tile_row: ArrayLike,
        tile_col: ArrayLike,
        node_offsets: ArrayLike,
        face_offsets: ArrayLike,
    ) -> None:
        """Record the tiles: tile ``t`` owns nodes ``node_offsets[t]:node_offsets[t + 1]``
        and faces ``face_offsets[t]:face_offsets[t + 1]`` (offsets: one per tile + 1)."""
        row = np.asarray(tile_row, dtype=np.int64)
        col = np.asarray(tile_col, dtype=np.int64)
        if row.ndim != 1 or col.shape != row.shape:
            raise UsageError(f"set_tiles: tile_row, tile_col must be 1-D of one length, got {row.shape} {col.shape}")
        _create_arrays(self._group, [
            _NewArray(name, data=values, dims=(dim,), attrs={"long_name": long_name}, overwrite=True)
            for name, values, dim, long_name in (
                ("tile_row", row, "nTiles", "tile row, counted from the south"),
                ("tile_col", col, "nTiles", "tile column, counted from the west"),
                ("tile_node_offset", _offsets("node", node_offsets, row.size, self.n_nodes), "nTileOffsets",
                 "tile t owns nodes [off[t], off[t+1])"),
                ("tile_face_offset", _offsets("face", face_offsets, row.size, self.n_faces), "nTileOffsets",
                 "tile t owns faces [off[t], off[t+1])"),
            )
        ])
        self._tiles_set = True

    def close(self) -> None:
        """Check that every node, face and the tiles were written; consolidate the metadata."""
        where = os.fspath(self.path)
        for what, total in (("nodes", self.n_nodes), ("faces", self.n_faces)):
            gap = _first_gap(self._written[what], total)
            if gap is not None:
                raise StoreError(f"{where}: mesh {what} [{gap[0]}, {gap[1]}) were never written")
        if not self._tiles_set:
            raise StoreError(f"{where}: mesh tiles were never recorded (call set_tiles)")
        _consolidate(self.path)

    def __enter__(self) -> MeshWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()

    def _claim(self, what: str, start: int, count: int, total: int) -> int:
        if not isinstance(start, numbers.Integral) or start < 0 or start + count > total:
            raise UsageError(f"write_{what}: [{start}, {start + count}) is outside [0, {total})")
        self._written[what].append((int(start), int(start) + count))
        return int(start) + count


def finalize_store(
    path: StorePath, attrs_update: Mapping[str, Any] | None = None, *, history: Mapping[str, Any] | None = None
) -> None:
    """Update the root's attributes and consolidate the metadata.

    ``attrs_update`` replaces or adds root attributes (e.g. the run report);
    ``history`` (e.g. the run's parameters and time) is appended to the
    ``run_history`` list attribute.  Both must be JSON-serialisable.
    Writes that a stopped run left unfinished are removed (call it only while
    no other process writes to the store).
    """
    update = _json_attrs(attrs_update or {}, "attrs_update")
    root = _open_group(path, mode="r+")
    _remove_partial_writes(path)
    if history is not None:
        entry = _json_attrs(history, "history")
        update[HISTORY_ATTR] = [*root.attrs.get(HISTORY_ATTR, []), entry]
    if update:
        root.attrs.update(update)
    _consolidate(path)


# --------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------


def open_dem(path: StorePath, **kwargs: Any) -> xr.Dataset:
    """The DEM as a lazy (dask) dataset: ``xarray.open_zarr`` with the store's defaults.

    ``spatial_ref`` is a coordinate (the data variables list it in
    ``coordinates``), so rioxarray finds the CRS and GeoTransform.
    """
    import xarray as xr

    return xr.open_zarr(_zarr_store(path, read_only=True), **kwargs)


def read_dem_window(path: StorePath, x0: float, y0: float, x1: float, y1: float) -> xr.Dataset:
    """The layers' cells whose centres lie in the box ``[x0, x1] x [y0, y1]``, loaded."""
    if not (x0 <= x1 and y0 <= y1):
        raise UsageError(f"read_dem_window: empty box ({x0}, {y0}, {x1}, {y1})")
    with open_dem(path) as ds:
        return ds.sel(x=slice(x0, x1), y=slice(y1, y0)).load()  # y is descending


def layer_names(path: StorePath) -> list[Layer]:
    """The raster layers the store holds, in :class:`Layer` order."""
    root = _open_group(path)
    held = set(root.array_keys())
    return [layer for layer in Layer if layer.value in held]


def layer_attrs(path: StorePath, layer: Layer | str) -> dict[str, Any]:
    """The attributes of one layer's array (``long_name``, ``units``, ...)."""
    layer = Layer.parse(layer)
    try:
        array = zarr.open_array(store=_zarr_store(path, read_only=True), path=layer.value, mode="r")
    except FileNotFoundError:
        raise StoreError(f"{os.fspath(path)}: holds no layer {layer.value!r}") from None
    return _user_attrs(array)


def read_layer(path: StorePath, layer: Layer | str, rows: slice = slice(None), cols: slice = slice(None)) -> NDArray:
    """A window of one layer's cells, loaded, north-up (row 0 is the northern-most)."""
    layer = Layer.parse(layer)
    try:
        array = zarr.open_array(store=_zarr_store(path, read_only=True), path=layer.value, mode="r")
    except FileNotFoundError:
        raise StoreError(f"{os.fspath(path)}: holds no layer {layer.value!r}") from None
    return array[rows, cols]


def nodata_value(layer: Layer | str) -> float | int | None:
    """The value that marks a cell without data in ``layer``, as its product
    declares it: NaN for heights, slopes and means, 0 (no face) for
    face_kind, none for counts and densities (0 is a count)."""
    return _spec(Layer.parse(layer)).nodata


def read_mesh(path: StorePath) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """The whole mesh: node ``(n, 2)`` xy, node z ``(n,)``, faces ``(m, 4)`` with -1 padding."""
    mesh = _open_group(path, MESH_GROUP)
    xy = np.column_stack([mesh["node_x"][:], mesh["node_y"][:]])
    return xy, mesh["node_z"][:], mesh["face_nodes"][:]


def read_tile_mesh(
    path: StorePath, tile: int | tuple[int, int]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """One tile's faces with the nodes they need, numbered locally.

    Parameters
    ----------
    tile : int or (row, col)
        The tile's index in the mesh's tile arrays, or its (row, col).

    Returns
    -------
    node_xy, node_z, faces
        The nodes the tile owns plus those of neighbouring tiles its faces
        use, in global order; faces index into them (-1 padding kept).
    """
    mesh = _open_group(path, MESH_GROUP)
    t = _tile_index(mesh, tile, path)
    node_off = mesh["tile_node_offset"][t : t + 2]
    face_off = mesh["tile_face_offset"][t : t + 2]
    faces = mesh["face_nodes"][face_off[0] : face_off[1]]
    used = faces >= 0
    ids = np.union1d(np.arange(node_off[0], node_off[1]), faces[used])
    local = np.full_like(faces, -1)
    local[used] = np.searchsorted(ids, faces[used])
    selection = (ids,)
    xy = np.column_stack(
        [mesh["node_x"].get_orthogonal_selection(selection), mesh["node_y"].get_orthogonal_selection(selection)]
    )
    return xy, mesh["node_z"].get_orthogonal_selection(selection), local


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------


_PARTIAL_WRITE = re.compile(r"\.[0-9a-f]{32}\.partial$")
"""A file zarr's local store writes a chunk or metadata document to before
renaming it into place: ``<name>.<uuid4 hex>.partial``."""


def _remove_partial_writes(path: StorePath) -> None:
    """Delete the temporary files of writes a killed process never finished.

    zarr renames a finished write into place, so the store's data is whole,
    but a process killed mid-write leaves its temporary file behind; a resumed
    run would otherwise end with a store that holds stray files.
    """
    if is_url(os.fspath(path)):
        return  # an object store writes each object whole: no temporary files
    for root, _, files in os.walk(os.fspath(path)):
        for name in files:
            if _PARTIAL_WRITE.search(name):
                try:
                    os.remove(os.path.join(root, name))
                except FileNotFoundError:
                    pass


#: the files at the top of a Zarr store (its arrays and groups are folders)
_ZARR_METADATA = frozenset({"zarr.json", ".zgroup", ".zattrs", ".zarray", ".zmetadata"})


def _is_zarr_store(path: StorePath) -> bool:
    if is_url(os.fspath(path)):
        fs, where = _filesystem(os.fspath(path))
        return any(fs.exists(f"{where}/{name}") for name in ("zarr.json", ".zgroup", ".zarray"))
    return os.path.isdir(path) and any(
        os.path.exists(os.path.join(path, name)) for name in ("zarr.json", ".zgroup", ".zarray")
    )


def _make_room(path: StorePath, overwrite: bool) -> None:
    """Clear the way for a new store at ``path``, never deleting anything but a Zarr store."""
    where = os.fspath(path)
    if is_url(where):
        _make_room_remote(where, overwrite)
        return
    if not os.path.lexists(where):
        return
    if _is_zarr_store(where):
        if not overwrite:
            raise StoreError(f"{where}: a Zarr store already exists; pass overwrite=True to replace it")
        if os.path.islink(where):
            raise StoreError(f"{where}: is a symbolic link; to replace the store, give the path it points to")
        strays = sorted(
            e.name for e in os.scandir(where)
            if (e.name not in _ZARR_METADATA if not e.is_dir() else not _is_zarr_store(e.path))  # arrays and groups
        )
        if strays:
            raise StoreError(
                f"{where}: holds files that are not Zarr's ({', '.join(strays[:3])}); refusing to replace it"
            )
        _remove_in_background(where)
    elif not (os.path.isdir(where) and not os.listdir(where)):
        raise StoreError(f"{where}: exists and is not a Zarr store; refusing to replace it")


_REPLACED = ".replaced-"
"""Infix of the name a replaced store takes while it is deleted (``.NAME.replaced-ID``)."""

_removals: list[threading.Thread] = []
_removals_lock = threading.Lock()


def _remove_in_background(where: str) -> None:
    """Delete a replaced local store on a thread of its own: it is renamed
    aside at once (the new store takes its place), and its files, which can
    take a quarter of a second to free on a file system that trims what it
    frees, go while the run computes.  :func:`finish_removals` waits for
    them; a copy left by a stopped process goes with the next replacement."""
    parent, name = os.path.split(os.path.abspath(where))
    for left in os.scandir(parent):
        if left.name.startswith(f".{name}{_REPLACED}") and left.is_dir(follow_symlinks=False):
            shutil.rmtree(left.path, ignore_errors=True)
    aside = os.path.join(parent, f".{name}{_REPLACED}{uuid.uuid4().hex[:12]}")
    os.rename(where, aside)
    thread = threading.Thread(target=shutil.rmtree, args=(aside, True), name="terrain-remove", daemon=True)
    thread.start()
    with _removals_lock:
        _removals.append(thread)


def finish_removals() -> None:
    """Wait until the stores replaced by this process are deleted."""
    with _removals_lock:
        threads, _removals[:] = list(_removals), []
    for thread in threads:
        thread.join()


def _make_room_remote(url: str, overwrite: bool) -> None:
    fs, where = _filesystem(url)
    try:
        bucket = where.split("/", 1)[0]
        if url.lower().startswith("s3://") and not fs.exists(bucket):
            raise FileNotFoundError("The specified bucket does not exist")
        held = fs.find(where, maxdepth=1, withdirs=True)
    except OSError as exc:
        raise StoreError(f"{url}: {describe_os_error(exc, url)}") from None
    if not held:
        return
    if not _is_zarr_store(url):
        raise StoreError(f"{url}: objects exist under this prefix and it is not a Zarr store; refusing to replace it")
    if not overwrite:
        raise StoreError(f"{url}: a Zarr store already exists; pass overwrite=True to replace it")
    fs.rm(where, recursive=True)


def _filesystem(url: str) -> tuple[Any, str]:
    fs, where = filesystem(url)
    return fs, where.rstrip("/")


def _zarr_store(path: StorePath, read_only: bool = False) -> Any:
    """What zarr opens: the local path, or an fsspec store over the URL."""
    where = os.fspath(path)
    if not is_url(where):
        return where
    from zarr.storage import FsspecStore

    try:
        return FsspecStore.from_url(where, storage_options=options_for(where) or None, read_only=read_only)
    except (TypeError, ValueError, ImportError) as exc:
        raise StoreError(f"{where}: cannot open the store ({type(exc).__name__}: {exc})") from None


def _open_group(path: StorePath, name: str = "", mode: str = "r") -> zarr.Group:
    where = os.fspath(path)
    try:
        return zarr.open_group(_zarr_store(where, read_only=mode == "r"), path=name or None, mode=mode)
    except (FileNotFoundError, zarr.errors.NodeTypeValidationError):
        what = f"has no group {name!r}" if name and _is_zarr_store(where) else "is not a Zarr store"
        raise StoreError(f"{where}: {what}") from None


def _open_array(path: StorePath, name: str, run: str = "") -> zarr.Array:
    """An array to write tiles to.  Every chunk written is stored, even one
    that equals the fill value: a v2 array without one (a null ``fill_value``)
    leaves missing chunks undefined to its readers.  With ``run``, the array
    opened for that run (see :func:`write_tile`)."""
    if run:
        return _open_array_of_run(os.fspath(path), name, run)
    try:
        array = zarr.open_array(store=_zarr_store(path), path=name, mode="r+")
        return array.with_config({"write_empty_chunks": True})
    except FileNotFoundError:
        where = os.fspath(path)
        raise StoreError(f"{where}: no array '{name}' (was the store created with this layer?)") from None


@functools.lru_cache(maxsize=64)
def _open_array_of_run(path: str, name: str, run: str) -> zarr.Array:
    return _open_array(path, name)


@dataclass(frozen=True)
class _NewArray:
    """An array for :func:`_create_arrays` to create, readable by xarray and GDAL in either Zarr format.

    Chunks are compressed with Blosc (zstd level 1), byte shuffle by default.
    ``bit_shuffle`` suits node ids and survey heights (few significant bits
    that change from value to value): on face corners it encodes 1.6x faster
    into files 23% smaller than byte shuffle.

    ``fill`` is what unwritten chunks read as (NaN for floats by default);
    ``masked`` says it also marks missing data (CF ``_FillValue``).  The two
    formats say that differently: xarray takes a v2 array's ``fill_value`` as
    ``_FillValue``, so an unmasked v2 array stores a null fill value (reading
    back as 0); in v3 xarray ignores ``fill_value`` and reads the
    ``_FillValue`` attribute, floats base64-encoded (so both formats give
    ``encoding["_FillValue"]``, the nodata value rioxarray exports).
    """

    name: str
    dims: tuple[str, ...]
    attrs: Mapping[str, Any]
    data: ArrayLike | None = None
    shape: tuple[int, ...] | None = None
    chunks: tuple[int, ...] | None = None
    dtype: Any = None
    fill: float | int | None = None
    masked: bool = False
    overwrite: bool = False
    bit_shuffle: bool = False


def _in_one_trip(coroutines: Sequence[Coroutine[Any, Any, Any]]) -> list[Any]:
    """The results of Zarr's ``coroutines``, run together: one trip through
    Zarr's event loop rather than one each.  Each trip waits for the GIL
    behind any thread that runs Python (a run loads its kernels, or meshes
    another tile, meanwhile): a store's eleven arrays took 0.3 s one by one
    beside the kernels' loading, and 0.05 s alone; a products tile's six
    layers took 0.5 s of the tiles' writing time one by one, 0.33 s together."""

    async def together() -> list[Any]:
        return list(await asyncio.gather(*coroutines))

    return zarr_sync(together())  # type: ignore[no-any-return]


def _create_arrays(group: zarr.Group, arrays: Sequence[_NewArray]) -> list[zarr.Array]:
    """The ``arrays`` in ``group``, created together (:func:`_in_one_trip`)."""
    zarr_format = group.metadata.zarr_format

    async def create(new: _NewArray) -> Any:
        kwargs, data = _array_arguments(new, zarr_format)
        array = await zarr.api.asynchronous.create_array(group.store_path, name=new.name, zarr_format=zarr_format,
                                                         **kwargs)
        if data is not None:
            await array.setitem(Ellipsis, data)
        return array

    return [zarr.Array(array) for array in _in_one_trip([create(new) for new in arrays])]


def _array_arguments(new: _NewArray, zarr_format: int) -> tuple[dict[str, Any], np.ndarray | None]:
    """``zarr.create_array``'s arguments for ``new`` in ``zarr_format``, and the data to write."""
    attrs, data, shape, dtype, fill, masked = dict(new.attrs), new.data, new.shape, new.dtype, new.fill, new.masked
    if data is not None:
        data = np.asarray(data)
        shape, dtype = data.shape, data.dtype
    dtype = np.dtype(dtype)
    if fill is None and dtype.kind == "f":
        fill, masked = math.nan, True
    chunks = shape if new.chunks is None else new.chunks
    kwargs: dict[str, Any] = {}
    if zarr_format == 2:
        attrs["_ARRAY_DIMENSIONS"] = list(new.dims)
        fill_value = fill if masked else None
        shuffle = numcodecs.Blosc.BITSHUFFLE if new.bit_shuffle else numcodecs.Blosc.SHUFFLE
        kwargs["compressors"] = numcodecs.Blosc(cname="zstd", clevel=1, shuffle=shuffle)
    else:
        kwargs["dimension_names"] = new.dims
        shuffle = "bitshuffle" if new.bit_shuffle else "shuffle"
        kwargs["compressors"] = BloscCodec(cname="zstd", clevel=1, shuffle=shuffle)
        fill_value = 0 if fill is None else fill
        if masked and dtype.kind in "iu":
            attrs["_FillValue"] = int(fill)
        elif masked:  # as xarray writes a float's: base64 of the little-endian double
            attrs["_FillValue"] = base64.standard_b64encode(struct.pack("<d", fill)).decode("ascii")
    kwargs.update(shape=shape, chunks=chunks, dtype=dtype, fill_value=fill_value, attributes=attrs,
                  overwrite=new.overwrite)
    return kwargs, data


def _user_attrs(array: zarr.Array) -> dict[str, Any]:
    """An array's attributes without the format's own keys, to copy onto another array."""
    return {k: v for k, v in array.attrs.asdict().items() if k not in ("_ARRAY_DIMENSIONS", "_FillValue")}


def _consolidate(path: StorePath) -> None:
    with warnings.catch_warnings():
        # zarr-python warns that v3 consolidated metadata is not in the v3 spec
        # yet; xarray and zarr-python read it, and other readers ignore it.
        warnings.filterwarnings("ignore", message="Consolidated metadata", category=UserWarning)
        zarr.consolidate_metadata(_zarr_store(path))


def _json_attrs(attrs: Mapping[str, Any], what: str) -> dict[str, Any]:
    """A JSON round trip of ``attrs``: tuples become lists, anything else non-JSON is an error."""
    try:
        return json.loads(json.dumps(dict(attrs), allow_nan=False))
    except (TypeError, ValueError) as err:
        raise UsageError(f"{what} must be JSON-serialisable: {err}") from None


def _parse_crs(crs_wkt: str | None) -> pyproj.CRS | None:
    if crs_wkt is None:
        return None
    try:
        return pyproj.CRS.from_user_input(crs_wkt)
    except pyproj.exceptions.CRSError as err:
        raise CrsError(f"cannot parse the CRS {str(crs_wkt)[:60]!r}: {err}") from None


def _grid_mapping_attrs(crs: pyproj.CRS | None, grid: TileGrid) -> dict[str, Any]:
    """The CF grid mapping variable's attributes, with what GDAL and rioxarray read."""
    attrs: dict[str, Any] = {}
    if crs is not None:
        wkt = crs.to_wkt()
        attrs |= _json_attrs(crs.to_cf(), "CRS.to_cf()")
        attrs |= {"crs_wkt": wkt, "spatial_ref": wkt}
    attrs["GeoTransform"] = " ".join(repr(v) for v in grid.geotransform)
    return attrs


def _axis_attrs(crs: pyproj.CRS | None) -> tuple[dict[str, Any], dict[str, Any], str | None]:
    """CF attributes of the x and y coordinates, and the vertical unit if the CRS has one."""
    x = {"standard_name": "projection_x_coordinate", "long_name": "x of the cell centres", "axis": "X"}
    y = {"standard_name": "projection_y_coordinate", "long_name": "y of the cell centres", "axis": "Y"}
    z_units = None
    if crs is not None:
        for axis in crs.cs_to_cf():
            keys = {k: axis[k] for k in ("standard_name", "units") if k in axis}
            match axis.get("axis"):
                case "X":
                    x |= keys
                case "Y":
                    y |= keys
                case "Z":
                    z_units = axis.get("units")
    return x, y, z_units


def _offsets(what: str, values: ArrayLike, n_tiles: int, total: int) -> NDArray[np.int64]:
    values = np.asarray(values, dtype=np.int64)
    if values.shape != (n_tiles + 1,) or values[0] != 0 or values[-1] != total or (np.diff(values) < 0).any():
        raise UsageError(
            f"set_tiles: {what}_offsets must be {n_tiles + 1} non-decreasing offsets from 0 to {total}"
        )
    return values


def _chunk(n: int) -> int:
    return max(1, min(n, MESH_CHUNK))


def _first_gap(intervals: list[tuple[int, int]], total: int) -> tuple[int, int] | None:
    """The first part of ``[0, total)`` no interval covers, or None."""
    reached = 0
    for start, stop in sorted(intervals):
        if start > reached:
            return reached, start
        reached = max(reached, stop)
    return (reached, total) if reached < total else None


def _tile_index(mesh: zarr.Group, tile: int | tuple[int, int], path: StorePath) -> int:
    where = os.fspath(path)
    if "tile_row" not in mesh:
        raise StoreError(f"{where}: the mesh has no tiles")
    if isinstance(tile, tuple):
        hits = np.flatnonzero((mesh["tile_row"][:] == tile[0]) & (mesh["tile_col"][:] == tile[1]))
        if hits.size == 0:
            raise UsageError(f"{where}: the mesh has no tile {tile}")
        return int(hits[0])
    n_tiles = mesh["tile_row"].shape[0]
    if not 0 <= tile < n_tiles:
        raise UsageError(f"{where}: tile index {tile} is outside [0, {n_tiles})")
    return int(tile)
