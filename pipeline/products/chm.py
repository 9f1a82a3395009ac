"""``chm``: the canopy height model, the DSM minus the DTM (height above ground)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .declare import HEIGHT_UNITS, Preview, Product, TileContext

__all__ = ["CHM"]


def _chm(ctx: TileContext) -> NDArray[np.float32]:
    # in float32, the cells of both layers as stored: chm == dsm - elevation, cell by cell, for a reader
    return (ctx.layers["dsm"] - ctx.layers["elevation"]).astype(np.float32)


CHM = Product(
    name="chm",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units=HEIGHT_UNITS,
    long_name="height above ground of the surface",
    description="canopy height model: dsm minus elevation (0 where the DSM has no return and takes the DTM)",
    compute=_chm,
    needs=("dsm", "elevation"),
    preview=Preview("viridis", "height above ground", (0.0, 99.5)),
)
