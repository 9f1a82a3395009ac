"""``density``: returns per unit area in each cell."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .declare import ALL_BUT_NOISE, PER_AREA_UNITS, Product, Returns, Selection, TileContext

__all__ = ["DENSITY", "EVERY_RETURN"]

EVERY_RETURN = Selection(ALL_BUT_NOISE, Returns.ALL)
"""Every return of every class but noise."""


def _density(ctx: TileContext) -> NDArray[np.float32]:
    counts = ctx.cell_counts(ctx.points(EVERY_RETURN))
    return (counts / ctx.grid.resolution**2).astype(np.float32)


DENSITY = Product(
    name="density",
    dtype=np.dtype(np.float32),
    nodata=None,
    units=PER_AREA_UNITS,
    long_name="returns per unit area",
    description="the returns of every class but noise whose point lies in the cell, per square unit of the CRS",
    compute=_density,
    points=lambda settings: EVERY_RETURN,
    resampling="AVERAGE",
)
