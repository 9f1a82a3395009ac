"""``dsm``: the surface of the highest returns, a TIN of the highest first return of each cell with a maximum edge.

Method: lidR's ``dsmtin`` with its default ``highest = TRUE``: the highest
first return of every cell (of every class but noise, 7 and 18, withheld
points left out) is kept, those are triangulated (Delaunay) and the TIN is
drawn linearly at each cell centre.  Keeping one return per cell takes the
lower returns of a cell out of the TIN, the pits between the top of a crown
and the returns that went deeper through it, and the triangulation has
fewer points (on a survey of 5 returns a square metre at 0.5 m cells, half
of them).  The cells are the grid's, or, where those are coarser than a
quarter of ``dsm_max_edge``, cells of that side on the same origin
(:attr:`~pipeline.products.ProductSettings.dsm_cell`): one return per coarse
cell would leave returns farther apart than the maximum edge, and no
triangle between them.  Three rules make it the same at any tiling:

- a cell's highest return is the highest of its points, ties by x then y
  (:func:`meshcore.tiles.highest_per_cell`), on cells aligned on the grid's
  origin: the same point in every tile that holds the whole cell;
- a triangle is drawn only when its longest edge *and its circumradius* are
  at most ``dsm_max_edge``.  Such a triangle's circumcircle lies within
  ``2 * dsm_max_edge`` of any cell centre it holds, and the cells of the
  returns inside it within one cell's diagonal more, so a tile that holds
  every first return within that margin (the route buffer is at least
  :attr:`~pipeline.products.ProductSettings.margin`) has exactly the
  survey's triangles over its cells: the Delaunay triangulation is unique
  (meshcore breaks co-circular ties by the coordinates alone).  The
  circumradius rule leaves out only slivers, which a long edge leaves out
  anyway in dsmtin;
- each triangle starts at its smallest corner, and the triangles are drawn
  in an order of their coordinates, so a cell centre on a shared edge reads
  the same triangle in every tile.

Why a TIN rather than the highest return per cell alone (lidR ``p2r``): it
leaves no holes where a cell holds no first return (cells finer than the
point spacing); why not ``pitfree``: its stacked TINs of height thresholds
cost one triangulation per threshold, and need the normalised heights
first.  The DSM keeps what dsmtin keeps: the top of the canopy and of the
roofs, with the pits that deep gaps between crowns make.

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
    import meshcore.tiles

    shape = ctx.shape
    elevation = ctx.layers["elevation"]
    points = ctx.points(FIRST_RETURNS)
    out = np.full(shape, np.nan)
    max_edge = float(ctx.settings.dsm_max_edge)
    g = ctx.grid
    highest = meshcore.tiles.highest_per_cell(points.x, points.y, points.z, g.x0, g.y0, ctx.settings.dsm_cell)
    if highest.size >= 3:
        mesh = meshcore.build_mesh(np.column_stack([points.x[highest], points.y[highest]]), "delaunay", None)
        z = np.empty(mesh.vertices.shape[0])
        z[mesh.input_to_vertex] = points.z[highest]  # one point a cell: no two share x and y
        faces = dsm_faces(mesh.vertices, mesh.faces[:, :3].astype(np.int64), max_edge)
        if faces.shape[0]:
            drawn = meshcore.Mesh(mesh.vertices, faces, np.arange(mesh.vertices.shape[0]))
            out = meshcore.rasterize(drawn, z, g.x0, g.y0, g.resolution, shape[1], shape[0], first_cell=ctx.first_cell)
    void = np.isnan(out)
    out[void] = elevation[void]
    return out.astype(np.float32)


def _warm_up() -> None:
    import meshcore.tiles

    x, y = np.array([0.5, 1.5, 0.5, 1.5, 0.7]), np.array([0.5, 0.5, 1.5, 1.5, 0.6])
    meshcore.tiles.highest_per_cell(x, y, x + y, 0.0, 0.0, 1.0)  # a cell each
    meshcore.tiles.highest_per_cell(x * 1e3, y * 1e3, x + y, 0.0, 0.0, 1.0)  # sparse: by sorting
    dsm_faces(np.column_stack([x, y]), np.array([[0, 1, 3], [0, 3, 2]]), 2.0)


def _points(settings) -> Selection:
    return FIRST_RETURNS


DSM = Product(
    name="dsm",
    dtype=np.dtype(np.float32),
    nodata=math.nan,
    units=HEIGHT_UNITS,
    long_name="surface of the highest returns",
    description="digital surface model: a TIN of the highest first return of each cell, of every class but noise "
    "(lidR dsmtin), whose triangles have edges and circumradius of at most dsm_max_edge; voids take the DTM's "
    "elevation",
    compute=_dsm,
    points=_points,
    needs=("elevation",),
    warm_up=_warm_up,
)
