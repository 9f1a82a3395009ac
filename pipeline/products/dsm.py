"""``dsm``: the surface of the highest returns, a TIN of first returns with a maximum edge.

Method: lidR's ``dsmtin`` (a Delaunay triangulation of the first returns of
every class but noise, 7 and 18, withheld points left out, drawn linearly at
each cell centre), with two rules that make it the same at any tiling:

- a triangle is drawn only when its longest edge *and its circumradius* are
  at most ``dsm_max_edge``.  Such a triangle's circumcircle lies within
  ``2 * dsm_max_edge`` of any cell centre it holds, so a tile that holds every
  first return within that margin (the route buffer is at least it) has
  exactly the survey's triangles over its cells: the Delaunay triangulation
  is unique (meshcore breaks co-circular ties by the coordinates alone).
  The circumradius rule leaves out only slivers, which a long edge leaves
  out anyway in dsmtin;
- points sharing x and y keep the highest z, each triangle starts at its
  smallest corner, and the triangles are drawn in an order of their
  coordinates, so a cell centre on a shared edge reads the same triangle in
  every tile.

Why a TIN rather than the highest return per cell (lidR ``p2r``): it leaves
no pits between returns at cells finer than the point spacing, and it has
no holes where a cell holds no first return; why not ``pitfree``: its
stacked TINs of height thresholds cost one triangulation per threshold, and
need the normalised heights first.  The DSM keeps what dsmtin keeps: the
top of the canopy and of the roofs, with the pits that deep gaps between
crowns make.

Voids (no triangle: water that returns nothing, gaps wider than
``dsm_max_edge``, outside the survey) take the DTM's elevation, so the CHM
is 0 there; where the DTM has none either, the cell is NaN.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


from .declare import ALL_BUT_NOISE, HEIGHT_UNITS, Product, Returns, Selection, TileContext

__all__ = ["DSM", "FIRST_RETURNS", "dsm_faces"]

FIRST_RETURNS = Selection(ALL_BUT_NOISE, Returns.FIRST)
"""The DSM's points: first returns of every class but noise."""


def dsm_faces(vertices: NDArray[np.float64], triangles: NDArray[np.int64], max_edge: float) -> NDArray[np.int64]:
    """The ``triangles`` (k, 3, counter-clockwise) the DSM draws, each from its
    smallest corner (by x, then y), as faces (m, 4) padded with -1: those
    whose longest edge and circumradius are at most ``max_edge``
    (:func:`meshcore.tiles.bounded_triangles`).  Every number there comes from
    the corners' coordinates in one order, so a triangle gets the same answer
    in every tile, and the rasterizer takes a centre on a shared edge from
    the face first by its corners, whatever the order of the faces."""
    import meshcore.tiles

    return meshcore.tiles.bounded_triangles(vertices, triangles, max_edge)


def _dsm(ctx: TileContext) -> NDArray[np.float32]:
    import meshcore

    shape = ctx.shape
    elevation = ctx.layers["elevation"]
    points = ctx.points(FIRST_RETURNS)
    out = np.full(shape, np.nan)
    max_edge = float(ctx.settings.dsm_max_edge)
    if len(points) >= 3:
        mesh = meshcore.build_mesh(points.xy, "delaunay", None)
        z = np.full(mesh.vertices.shape[0], -np.inf)
        np.maximum.at(z, mesh.input_to_vertex, points.z)  # points sharing x and y: the highest
        faces = dsm_faces(mesh.vertices, mesh.faces[:, :3].astype(np.int64), max_edge)
        if faces.shape[0]:
            x0, y0 = ctx.origin
            drawn = meshcore.Mesh(mesh.vertices, faces, np.arange(mesh.vertices.shape[0]))
            out = meshcore.rasterize(drawn, z, x0, y0, ctx.grid.resolution, shape[1], shape[0])
    void = np.isnan(out)
    out[void] = elevation[void]
    return out.astype(np.float32)


def _points(settings) -> Selection:
    return FIRST_RETURNS


DSM = Product(
    name="dsm",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units=HEIGHT_UNITS,
    long_name="surface of the highest returns",
    description="digital surface model: a TIN of the first returns of every class but noise (lidR dsmtin) whose "
    "triangles have edges and circumradius of at most dsm_max_edge; voids take the DTM's elevation",
    compute=_dsm,
    points=_points,
    needs=("elevation",),
)
