"""``intensity``: the mean intensity of the first returns in each cell."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from .declare import Attribute, Product, TileContext
from .dsm import FIRST_RETURNS

__all__ = ["INTENSITY"]


def _intensity(ctx: TileContext) -> NDArray[np.float32]:
    points = ctx.points(FIRST_RETURNS)
    counts = ctx.cell_counts(points)
    # integer sums: the same mean whatever order the tile read its points in
    sums = ctx.cell_counts(points, points.attributes[Attribute.INTENSITY])
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return mean.astype(np.float32)


INTENSITY = Product(
    name="intensity",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units="1",
    long_name="mean intensity of the first returns",
    description="the mean intensity of the first returns of every class but noise whose point lies in the cell "
    "(NaN: none); a file that records no intensity gives 0",
    compute=_intensity,
    points=lambda settings: FIRST_RETURNS,
    attributes=(Attribute.INTENSITY,),
)
