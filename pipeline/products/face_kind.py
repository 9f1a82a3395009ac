"""``face_kind``: which kind of mesh face holds each cell centre."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


from .declare import Product, TileContext

__all__ = ["FACE_KIND"]


def _face_kind(ctx: TileContext) -> NDArray[np.int8]:
    """1 where a triangle covers the cell centre, 2 for a quadrangle, 0 for none."""
    import meshcore

    mesh, shape = ctx.mesh, ctx.shape
    if mesh is None or mesh.faces.shape[0] == 0:
        return np.zeros(shape, dtype=np.int8)
    f = mesh.faces
    corners = np.where(f >= 0, np.arange(f.size).reshape(f.shape), -1)
    vertices = mesh.vertices[np.maximum(f, 0)].reshape(-1, 2)
    value = np.repeat(ctx.kinds.astype(np.float64), 4)
    split = meshcore.Mesh(vertices, corners, np.arange(vertices.shape[0]))
    g = ctx.grid
    out = meshcore.rasterize(split, value, g.x0, g.y0, g.resolution, shape[1], shape[0], max_edge=ctx.max_edge,
                             first_cell=ctx.first_cell)
    return np.nan_to_num(np.rint(out), nan=0.0).astype(np.int8)


FACE_KIND = Product(
    name="face_kind",
    dtype=np.dtype(np.int8),
    nodata=0,
    units=None,
    long_name="kind of the mesh face under the cell centre",
    description="the kind of the combined mesh's face under each cell centre: 0 none, 1 triangle, 2 quadrangle",
    compute=_face_kind,
    export_dtype="uint8",
    resampling="MODE",
    attrs={"flag_values": [0, 1, 2], "flag_meanings": "none triangle quadrangle"},
)
