"""``slope``: the steepness of the DTM's surface at each cell centre, in degrees."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


from .declare import Product, TileContext

__all__ = ["SLOPE"]


def _slope(ctx: TileContext) -> NDArray[np.float32]:
    import meshcore

    shape = ctx.shape
    slope = np.full(shape, np.nan, dtype=np.float32)
    ok = np.isfinite(ctx.layers["elevation"])
    if ok.any():
        g = ctx.grid
        c0, r0 = ctx.first_cell
        jj, ii = np.nonzero(ok)
        # the grid's centres, to the bit (TileContext.first_cell)
        gx, gy = meshcore.gradient(ctx.mesh, ctx.z, g.x0 + (c0 + ii + 0.5) * g.resolution,
                                   g.y0 + (r0 + jj + 0.5) * g.resolution, **ctx.surface)
        slope[jj, ii] = np.degrees(np.arctan(ctx.height_scale * np.hypot(gx, gy)))
    return slope


def _warm_up() -> None:
    import meshcore

    vertices = np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0], [0.0, 4.0], [4.0, 4.0], [8.0, 5.0], [2.0, 8.0]])
    faces = np.array([[0, 1, 4, 3], [1, 2, 5, -1], [3, 4, 6, -1]])
    mesh = meshcore.Mesh(vertices, faces, np.arange(vertices.shape[0]))
    z = vertices[:, 0] * 0.1 + np.sin(vertices[:, 1])
    meshcore.gradient(mesh, z, np.array([1.0, 5.0]), np.array([1.0, 2.0]))


SLOPE = Product(
    name="slope",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units="degree",
    long_name="slope of the surface",
    description="the DTM's slope at each cell centre, in degrees",
    compute=_slope,
    needs=("elevation",),
    export_dtype="float32",
    resampling="AVERAGE",
    warm_up=_warm_up,
)
