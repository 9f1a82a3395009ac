"""``elevation``: the DTM, the run's surface (linear or smooth) at each cell centre."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


from .declare import HEIGHT_UNITS, Product, TileContext

__all__ = ["ELEVATION"]


def _elevation(ctx: TileContext) -> NDArray[np.float32]:
    import meshcore

    shape = ctx.shape
    if ctx.mesh is None or ctx.mesh.faces.shape[0] == 0:
        return np.full(shape, np.nan, dtype=np.float32)
    g = ctx.grid
    elev = meshcore.rasterize(ctx.mesh, ctx.z, g.x0, g.y0, g.resolution, shape[1], shape[0],
                              max_edge=ctx.max_edge, first_cell=ctx.first_cell, **ctx.surface)
    return elev.astype(np.float32)


ELEVATION = Product(
    name="elevation",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units=HEIGHT_UNITS,
    long_name="elevation",
    description="the bare-earth surface (DTM) of the run's classes and returns, at each cell centre",
    compute=_elevation,
    export_dtype="float32",
    resampling="AVERAGE",
)
