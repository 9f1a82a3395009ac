"""``ground_density``: the DTM's points per unit area in each cell (where it is only interpolation: 0)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .declare import PER_AREA_UNITS, Product, Selection, TileContext

__all__ = ["GROUND_DENSITY"]


def _points(settings) -> Selection | None:
    # the classes (ground by default) and returns the DTM is made of; the ground stage's points are read apart
    return None if settings.classified else settings.dtm


def _ground_density(ctx: TileContext) -> NDArray[np.float32]:
    if ctx.settings.classified:  # the ground stage's points, not a class of the files
        assert ctx.load_dtm_points is not None
        counts = ctx.cell_counts(ctx.load_dtm_points())
    else:
        counts = ctx.cell_counts(ctx.points(ctx.settings.dtm))
    return (counts / ctx.grid.resolution**2).astype(np.float32)


GROUND_DENSITY = Product(
    name="ground_density",
    dtype=np.dtype(np.float32),
    nodata=None,
    units=PER_AREA_UNITS,
    long_name="ground points per unit area",
    description="the points the DTM is made of (its classes, ground by default, and returns) in the cell, per "
    "square unit of the CRS: 0 where the DTM only interpolates",
    compute=_ground_density,
    points=_points,
    resampling="AVERAGE",
)
