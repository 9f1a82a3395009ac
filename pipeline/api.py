"""The Python API over a finished store: its tiles, their meshes and DEM windows.

``pipeline.open("dem.zarr")`` gives a :class:`TiledStore`; ``tiles()`` lists
the tiles, ``tile_mesh(tile)`` returns a tile's faces as a
:class:`meshcore.Mesh` with its node elevations, ``tile_dem(tile)`` and
``dem_window(x0, y0, x1, y1)`` return DEM windows as xarray datasets (every
layer the store holds: elevation, and the products asked for, ``dsm``,
``chm``, ``intensity``, ...), ``layers()`` names them, and ``map_tiles(fn)``
runs ``fn(tile, mesh, z)`` over every tile with dask (``map_tiles(fn,
layers=("chm",))``: ``fn(tile, mesh, z, dem)`` with the tile's cells of
those layers).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

import meshcore

from .store import zarr_store as store
from .errors import UsageError
from .tiling.grid import TileGrid

if TYPE_CHECKING:
    import xarray as xr

__all__ = ["TiledStore", "Tile", "open_store"]


@dataclass(frozen=True)
class Tile:
    """One tile of a store: its grid position and the box of its DEM cells."""

    row: int
    col: int
    box: tuple[float, float, float, float]


class TiledStore:
    """A finished store, opened read-only."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = os.fspath(path)
        ds = store.open_dem(self.path)
        attrs = dict(ds.attrs)
        ds.close()
        if not attrs.get("complete", False):
            raise UsageError(f"{self.path}: the store is not complete (its run did not finish)")
        self.attrs = attrs
        self.grid = TileGrid.from_dict(attrs["provenance"]["grid"])

    def tiles(self) -> list[Tile]:
        return [Tile(r, c, self.grid.box(r, c)) for r, c in self.grid.tiles()]

    def dem(self) -> xr.Dataset:
        """The whole DEM, lazily (dask arrays chunked by tile)."""
        return store.open_dem(self.path)

    def layers(self) -> list[str]:
        """The raster layers the store holds, elevation first (see :mod:`pipeline.products`)."""
        return [layer.value for layer in store.layer_names(self.path)]

    def dem_window(self, x0: float, y0: float, x1: float, y1: float, layers: Sequence[str] | None = None) -> xr.Dataset:
        """The cells whose centres lie in the box, of every layer (or of ``layers``), loaded."""
        ds = store.read_dem_window(self.path, x0, y0, x1, y1)
        return ds if layers is None else ds[self._held(layers)]

    def _held(self, layers: Sequence[str]) -> list[str]:
        held = self.layers()
        missing = [name for name in layers if name not in held]
        if missing:
            raise UsageError(f"{self.path}: holds no layer {', '.join(map(repr, missing))} (it holds {', '.join(held)})")
        return list(layers)

    def tile_dem(self, tile: Tile) -> xr.Dataset:
        """The tile's own block of cells, loaded (picked by index: cell
        centres need not be exact in binary, 0.1 m cells for one)."""
        r0, r1, c0, c1 = self.grid.cell_slice(tile.row, tile.col)
        ny = self.grid.ny
        with store.open_dem(self.path) as ds:
            return ds.isel(y=slice(ny - r1, ny - r0), x=slice(c0, c1)).load()  # y is descending

    def tile_mesh(self, tile: Tile) -> tuple[meshcore.Mesh, np.ndarray]:
        """The tile's faces as a :class:`meshcore.Mesh` (nodes numbered locally) and node z."""
        xy, z, faces = store.read_tile_mesh(self.path, (tile.row, tile.col))
        return meshcore.Mesh(np.asarray(xy), np.asarray(faces), np.arange(len(xy))), np.asarray(z)

    def mesh(self) -> tuple[meshcore.Mesh, np.ndarray]:
        """The whole stitched mesh (loads it all)."""
        xy, z, faces = store.read_mesh(self.path)
        return meshcore.Mesh(np.asarray(xy), np.asarray(faces), np.arange(len(xy))), np.asarray(z)

    def map_tiles(self, fn: Callable[..., Any], scheduler: str | None = None,
                  layers: Sequence[str] | None = None) -> list:
        """``fn(tile, mesh, z)`` for every tile, run with dask; results in tile
        order.  With ``layers``, ``fn(tile, mesh, z, dem)``: ``dem`` is the
        tile's cells of those layers (:meth:`tile_dem`)."""
        import dask

        chosen = None if layers is None else self._held(layers)

        def one(tile: Tile) -> Any:
            mesh, z = self.tile_mesh(tile)
            if chosen is None:
                return fn(tile, mesh, z)
            return fn(tile, mesh, z, self.tile_dem(tile)[chosen])

        tasks = [dask.delayed(one)(t) for t in self.tiles()]
        if scheduler:
            from distributed import Client

            with Client(scheduler):
                return list(dask.compute(*tasks))
        return list(dask.compute(*tasks, scheduler="threads"))


def open_store(path: str | os.PathLike[str]) -> TiledStore:
    """Open a store written by :func:`pipeline.run`."""
    return TiledStore(path)
