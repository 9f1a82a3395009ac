"""``point_count``: the DTM's points in each cell, counted by the tile that meshed them."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .declare import Product, TileContext

__all__ = ["POINT_COUNT"]


def _point_count(ctx: TileContext) -> NDArray[np.int32]:
    # counted from the tile's own points when it was meshed (see pipeline.meshing.tiles.mesh_tile)
    counts = ctx.load_piece("point_count") if ctx.load_piece is not None else np.zeros((0, 0), dtype=np.int32)
    return counts if counts.size else np.zeros(ctx.shape, dtype=np.int32)


POINT_COUNT = Product(
    name="point_count",
    dtype=np.dtype(np.int32),
    nodata=None,
    units="1",
    long_name="number of input points in the cell",
    description="the number of the DTM's points (after the class and return filters) in each cell",
    compute=_point_count,
    export_dtype="int32",
    resampling="NEAREST",
)
