"""The smooth surface's node values: local kriging in cells of about a point spacing.

The smooth surface (``surface="smooth"``) puts a cubic patch on every face
(:mod:`meshcore.patches`).  Its corners take the points' z; its other nodes
(two per edge, the inner ones of each face) take the value of universal
kriging with a linear drift:

- the nodes are grouped in square cells of 1.4 point spacings
  (:attr:`Variogram.spacing`), aligned on multiples of the cell's side; each
  cell's nodes are kriged from the ``neighbours`` vertices nearest the
  cell's centre: one system per cell, solved once in its dual form
  (Cholesky of the covariances, the drift by its Schur complement), then
  evaluated at each of its nodes.  About one system per two points: a system
  per edge and per face (five per point) gave the same errors at several
  times the cost;
- nearest is exact, with ties broken by coordinates, so a node's value
  depends only on the points inside its cell's disk (the centre and the
  distance to its last neighbour, :attr:`Neighbourhoods.disks`), never on the
  order of the points or on which points a tile happens to hold beyond it;
- an edge's nodes are placed from its end first in coordinate order, so the
  two faces of an edge, in one tile or in two, put them at the same
  positions, in the same cells, and get bit-identical values: the surface is
  continuous (C0 across every edge) and seamless across tiles;
- the kriged value is clamped to the range of the neighbours' values and of
  its edge's (an inner node: its face's) corners.  Kriging with a linear
  drift reproduces linear functions, and a linear function stays inside that
  range, so the surface reproduces linear functions exactly; the clamp
  stops overshoot where the neighbours lie to one side (the hull, voids).
  On ground the variogram calls smooth and nearly noise-free (a Matérn model,
  a nugget under 0.1% of the sill) only those nodes are clamped, so that a
  crest may rise above the points beside it (:func:`_clamps_inside`);
- a system whose neighbours are collinear (no plane fits) gives its nodes
  the linear surface's values;
- a node in a void (farther than :data:`VOID_NEAR` spacings from its
  cell's points) is blended, by its distance from them, into the void's
  fill: the linear surface, then the TIN of the points around the void,
  moved half the way to their natural-neighbour interpolant
  (:mod:`meshcore.natural`) where the two agree (:data:`VOID_AGREEMENT`).
  There the cell's points lie on one side of the rim, and kriging carries
  that side's tilt and noise across the void: beyond a few spacings it was
  worse than the TIN; the fill reads the whole rim, stays within its values
  and reproduces linear functions.  The blend depends on the node's
  position and its cell's points alone, so edges stay C0 and tiles seamless;
  a node's natural neighbours are read from disks that :attr:`Neighbourhoods.disks`
  reports with the cells' (:func:`_void_blend`);
- first, faces with an edge longer than a few spacings are cut
  (:func:`smooth_plan`, :mod:`meshcore.refine`): the edge is split into
  equal pieces by its length alone, the new points are kriged from their
  cells' systems as nodes are, and the patches lie on the triangles
  (:func:`smooth_surface`).

The covariance is a :class:`Variogram` of one of :data:`MODELS`;
:func:`fit_variogram` chooses the model, its nugget and range by
leave-one-out cross-validation of this same kriging on a sample, and
measures the spacing.

Its concepts have their own modules: the covariance and its fit
(:mod:`meshcore.variogram`), the kriging systems (:mod:`meshcore.kriging`),
the cells of nodes and the point spacing (:mod:`meshcore.cells`) and the
voids (:mod:`meshcore.voids`); this one lays the nodes out on the faces, finds
each cell's neighbourhood, and makes the plan and the surface.
"""

from __future__ import annotations
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._buckets import _disks_holding, _nearest, _nearest_around
from ._jit import empty, full, larger, njit, njit_helper, smaller, zeros
from .errors import InvalidInputError
from .mesh import Mesh, mesh_arrays, vertex_values
from .natural import join_places, take_places
from .patches import NODES_PER_FACE
from .refine import Refinement, _first_end, refine_long_faces
from .cells import CELL_PER_SPACING, _cells, _mesh_spacing
from .kriging import (DEFAULT_NEIGHBOURS, _LAG_SCALE, _check_neighbours, _dual_values, _kriging_scratch, _one_sided,
                      _solve_systems)
from .variogram import MODELS, Variogram, fit_variogram
from .voids import VoidFill, _NO_ENDS, _NO_FILL, _gaps, _void_blend, _void_distances, _void_fills

__all__ = ["Neighbourhoods", "AddedPoints", "SmoothPlan", "SmoothSurface", "smooth_nodes", "smooth_neighbourhoods", "smooth_plan", "smooth_surface"]


@njit
def _nodes_kriged_kernel(
    xy: np.ndarray, z: np.ndarray, centres: np.ndarray, neighbours: np.ndarray, first: np.ndarray,
    positions: np.ndarray, corners: np.ndarray, pattern: np.ndarray, pattern_weights: np.ndarray,
    nugget_ratio: float, inv_range: float, model: int, clamp_inside: bool, gap: np.ndarray, fill: np.ndarray,
    near: float, far: float, out: np.ndarray,
) -> None:
    """Krig the nodes of every system (a cell), clamp them, and blend those in voids into the fill.

    System ``s`` (centre ``centres[s]``, its neighbours) gives the nodes
    ``first[s] .. first[s + 1] - 1``.  A node is clamped to the
    range of its neighbours' values widened to its ``corners``' values (in a
    void: to the linear surface's value there, its corners' values by the
    weights of its ``pattern``): every node when ``clamp_inside``, else only
    those of systems whose neighbours lie to one side of the centre
    (:func:`_one_sided`), and those in voids; a
    singular system, or one that meets an unknown z, gives its nodes the
    linear surface's value (the corners' weights, row ``pattern[n]`` of
    ``pattern_weights``).  A node farther than ``near`` from its nearest
    neighbour (``gap[n]``) is clamped to the range of its natural neighbours
    (``fill[n, 1:]``) and blended into the void's fill ``fill[n, 0]`` (NaN:
    none, the linear surface's value then), which alone it is from ``far`` on
    (:func:`_void_blend`).
    """
    k = neighbours.shape[1]
    room = _kriging_scratch(k)
    most = 0
    for s in range(centres.shape[0]):
        most = larger(most, first[s + 1] - first[s])
    qx = empty(most)
    qy = empty(most)
    values = empty(most)
    block = empty((3, most * k))
    scale = _LAG_SCALE[model] * inv_range
    s0 = 0
    while s0 < centres.shape[0]:
        lanes, count = _solve_systems(xy, z, centres, neighbours, s0, nugget_ratio, scale, model, room)
        for b in range(lanes):
            s = s0 + b
            lo = math.inf
            hi = -math.inf
            finite = True
            for i in range(count):
                zi = z[neighbours[s, i]]
                if not math.isfinite(zi):
                    finite = False
                lo = smaller(lo, zi)
                hi = larger(hi, zi)
            radius = room.radius[b] if finite else math.nan
            kriged = math.isfinite(radius)
            clamp = kriged and (clamp_inside or _one_sided(room.xs[b], room.ys[b], count))
            if kriged:
                m = first[s + 1] - first[s]
                for t in range(m):
                    qx[t] = positions[first[s] + t, 0] - centres[s, 0]
                    qy[t] = positions[first[s] + t, 1] - centres[s, 1]
                _dual_values(room.xs[b], room.ys[b], count, room.coef[b], radius, scale, model, qx, qy, m, block, values)
            for n in range(first[s], first[s + 1]):
                linear = _linear_value(z, corners, pattern_weights, pattern[n], n)
                if kriged:
                    value = values[n - first[s]]
                    if gap[n] > near:
                        # in a void always clamped (no crest is known there to keep): to the
                        # neighbours' range and the linear surface's value (a linear function
                        # lies there), not to the far ends of a long edge across the void, then
                        # to the range of its natural neighbours, within which its fill lies
                        low = smaller(lo, linear)
                        high = larger(hi, linear)
                        out[n] = smaller(larger(value, low), high)
                        if math.isfinite(fill[n, 1]):
                            out[n] = smaller(larger(out[n], fill[n, 1]), fill[n, 2])
                    else:
                        # beside its points: the neighbours' range widened to its edge's (face's)
                        # corners, which a crest between them may rise to
                        low = lo
                        high = hi
                        for j in range(4):
                            v = corners[n, j]
                            if v >= 0 and math.isfinite(z[v]):
                                low = smaller(low, z[v])
                                high = larger(high, z[v])
                        out[n] = smaller(larger(value, low), high) if clamp else value
                else:
                    out[n] = linear
                if gap[n] > near:
                    out[n] = _void_blend(out[n], linear, fill[n, 0], gap[n], near, far)
        s0 += lanes


@njit_helper
def _linear_value(z: np.ndarray, corners: np.ndarray, pattern_weights: np.ndarray, row: int, n: int) -> float:
    """The linear surface at node ``n``: its corners' values by the weights of ``pattern_weights[row]``."""
    linear = 0.0
    for j in range(4):
        v = corners[n, j]
        if v >= 0 and math.isfinite(z[v]):
            linear += pattern_weights[row, j] * z[v]
    return linear


class Neighbourhoods(NamedTuple):
    """Where the smooth surface's nodes are and which points each is kriged from.

    The nodes are grouped in square cells of side ``cell``, aligned on
    multiples of it: one kriging system per cell that holds a node, over the
    ``neighbours`` vertices nearest the cell's centre.  Computed by
    :func:`smooth_neighbourhoods` and taken by :func:`smooth_nodes`.

    Attributes
    ----------
    centres : (m, 2) the cells' centres
    index : (m, k) their nearest vertices, nearest first (``-1`` pads)
    radius : (m,) the distance from each centre to its last neighbour
    first : (m + 1,) cell ``s`` holds the nodes ``first[s] .. first[s+1]-1``
    positions : (n, 2) the nodes
    take : (n_f, 12) int32, the node in each slot of a face's row (``-1``: unused, or a face left out)
    corners : (n, 4) int32, the vertices whose values bound each node's clamp (``-1`` pads)
    pattern : (n,) uint8, where the node lies in its face: the row of
        :data:`_PATTERN_WEIGHTS` that gives the linear surface's weights of its corners
    cell : float, the side of the cells
    gap : (n,) float64, the distance from each node to the nearest of its cell's neighbours
        (exact beyond :data:`VOID_NEAR` spacings; nearer, any distance up to it)
    fill : VoidFill, the nodes in voids (``gap`` over :data:`VOID_NEAR` spacings) and their natural neighbours
    """

    centres: NDArray[np.float64]
    index: NDArray[np.int64]
    radius: NDArray[np.float64]
    first: NDArray[np.int64]
    positions: NDArray[np.float64]
    take: NDArray[np.int64]
    corners: NDArray[np.int32]
    pattern: NDArray[np.uint8]
    cell: float
    gap: NDArray[np.float64]
    fill: "VoidFill"

    @property
    def weights(self) -> NDArray[np.float64]:
        """``(n, 4)``: the linear surface's weights of each node's corners."""
        return _PATTERN_WEIGHTS[self.pattern]

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(m, 3)`` rows ``(x, y, r)``: the closed disks the node values read points from
        (the cells' neighbourhoods, then the circles of the voids' natural neighbours)."""
        return np.concatenate([np.column_stack([self.centres, self.radius]), self.fill.coordinates.disks])


_THIRD = 1.0 / 3.0


_QUAD_INNER = ((_THIRD, _THIRD), (2 * _THIRD, _THIRD), (2 * _THIRD, 2 * _THIRD), (_THIRD, 2 * _THIRD))


_PATTERN_WEIGHTS = np.array(
    [[1.0 - _THIRD, _THIRD, 0.0, 0.0], [1.0 - 2.0 * _THIRD, 2.0 * _THIRD, 0.0, 0.0], [_THIRD, _THIRD, _THIRD, 0.0]]
    + [[(1.0 - u) * (1.0 - v), u * (1.0 - v), u * v, (1.0 - u) * v] for u, v in _QUAD_INNER]
)
"""The linear surface's weights of a node's corners, by the node's place: an
edge's node at a third and at two thirds, a triangle's centroid, a
quadrangle's four inner nodes."""


@njit
def _layout_kernel(vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray):
    """:func:`_layout`: every edge found once by bucketing its slots by their first end."""
    n_f = faces.shape[0]
    n_v = vertices.shape[0]
    start = zeros(n_v + 1, dtype=np.int64)
    n_tri = 0
    for f in range(n_f):
        nc = 4 if faces[f, 3] >= 0 else 3
        if nc == 3:
            n_tri += 1
        for k in range(nc):
            s = faces[f, k]
            e = faces[f, (k + 1) % nc]
            start[(s if _first_end(vertices, s, e) else e) + 1] += 1
    for v in range(n_v):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    other = empty(start[n_v], dtype=np.int64)
    slot = empty(start[n_v], dtype=np.int64)
    for f in range(n_f):
        nc = 4 if faces[f, 3] >= 0 else 3
        for k in range(nc):
            s = faces[f, k]
            e = faces[f, (k + 1) % nc]
            forward = _first_end(vertices, s, e)
            a = s if forward else e
            other[fill[a]] = e if forward else s
            slot[fill[a]] = f * 4 + k
            fill[a] += 1
    edge = full(start[n_v], -1, dtype=np.int64)
    n_e = 0
    for v in range(n_v):
        for i in range(start[v], start[v + 1]):
            if edge[i] < 0:
                edge[i] = n_e
                for j in range(i + 1, start[v + 1]):
                    if other[j] == other[i]:
                        edge[j] = n_e
                n_e += 1
    n_quad = n_f - n_tri
    n_nodes = 2 * n_e + n_tri + 4 * n_quad
    positions = empty((n_nodes, 2))
    corners = empty((n_nodes, 4), dtype=np.int32)
    pattern = empty(n_nodes, dtype=np.uint8)
    take = empty((n_f, 12), dtype=np.int32)  # every slot written: a node, or -1 past a triangle's
    third = 1.0 / 3.0
    placed = 0  # the edges numbered below this have their nodes (edges are numbered in slot order)
    for v in range(n_v):
        for i in range(start[v], start[v + 1]):
            f = slot[i] // 4
            k = slot[i] % 4
            b = other[i]
            node = 2 * edge[i]
            forward = faces[f, k] == v
            take[f, 2 * k] = node if forward else node + 1
            take[f, 2 * k + 1] = node + 1 if forward else node
            if edge[i] < placed:
                continue  # the edge's other face placed its nodes
            placed = edge[i] + 1
            for j in range(2):
                t = third if j == 0 else 2.0 * third
                positions[node + j, 0] = vertices[v, 0] + t * (vertices[b, 0] - vertices[v, 0])
                positions[node + j, 1] = vertices[v, 1] + t * (vertices[b, 1] - vertices[v, 1])
                corners[node + j, 0] = v
                corners[node + j, 1] = b
                corners[node + j, 2] = -1
                corners[node + j, 3] = -1
                pattern[node + j] = j
    tri = 2 * n_e
    quad = 2 * n_e + n_tri
    for f in range(n_f):
        if faces[f, 3] < 0:
            positions[tri, 0] = (vertices[faces[f, 0], 0] + vertices[faces[f, 1], 0] + vertices[faces[f, 2], 0]) * third
            positions[tri, 1] = (vertices[faces[f, 0], 1] + vertices[faces[f, 1], 1] + vertices[faces[f, 2], 1]) * third
            for j in range(3):
                corners[tri, j] = faces[f, j]
            corners[tri, 3] = -1
            pattern[tri] = 2
            take[f, 8] = tri
            for j in (6, 7, 9, 10, 11):
                take[f, j] = -1
            tri += 1
        else:
            for m in range(4):
                x = 0.0
                y = 0.0
                for j in range(4):
                    x += weights[3 + m, j] * vertices[faces[f, j], 0]
                    y += weights[3 + m, j] * vertices[faces[f, j], 1]
                    corners[quad, j] = faces[f, j]
                positions[quad, 0] = x
                positions[quad, 1] = y
                pattern[quad] = 3 + m
                take[f, 8 + m] = quad
                quad += 1
    return positions, take, corners, pattern


def _layout(vertices: NDArray[np.float64], faces: NDArray[np.int64]):
    """The nodes of :class:`Neighbourhoods`: ``positions, take, corners, pattern``.

    An edge is listed once, its nodes placed from its end first in
    coordinate order, so that every face (in any tile) computes them from the
    same numbers.
    """
    return _layout_kernel(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64),
                          _PATTERN_WEIGHTS)


@njit
def _gather_nodes(order: np.ndarray, positions: np.ndarray, corners: np.ndarray, pattern: np.ndarray, take: np.ndarray):
    """The nodes in ``order`` (their positions, corners and patterns), and ``take`` renumbered to it in place."""
    n = order.shape[0]
    renumber = empty(n, dtype=np.int32)
    out_positions = empty((n, 2))
    out_corners = empty((n, 4), dtype=np.int32)
    out_pattern = empty(n, dtype=np.uint8)
    for t in range(n):
        p = order[t]
        renumber[p] = t
        out_positions[t, 0] = positions[p, 0]
        out_positions[t, 1] = positions[p, 1]
        for j in range(4):
            out_corners[t, j] = corners[p, j]
        out_pattern[t] = pattern[p]
    for f in range(take.shape[0]):
        for j in range(take.shape[1]):
            if take[f, j] >= 0:
                take[f, j] = renumber[take[f, j]]
    return out_positions, out_corners, out_pattern


_SMOOTH_GROUND_NUGGET = 1e-3
"""A Matérn variogram whose nugget is below this share of its sill describes
smooth, nearly noise-free ground (:func:`_clamps_inside`)."""


def _clamps_inside(variogram: Variogram) -> bool:
    """Whether :func:`smooth_nodes` clamps every node, or only those kriged from one side.

    Kriging a smooth surface rises above all its neighbours at a crest, and
    the clamp would cut it off; on rough or noisy ground a value outside the
    neighbours' range is ringing or noise more often than relief.  So every
    node is clamped unless the variogram is a Matérn model (a differentiable
    surface) with a nugget under :data:`_SMOOTH_GROUND_NUGGET` of its sill;
    nodes kriged from one side (the hull, voids) are always clamped.
    Measured (``bench/bench_accuracy.py``, RMSE change against the TIN): on
    lidR's smooth test (its first 10 sets) clamping only the one-sided nodes
    gives -94.9% against -90.6%; on the real surveys, whose variograms then kept every node clamped,
    clamping only those would lose up to 0.6 points (ign_semis -7.0% ->
    -6.4%).  The fit does not always keep them so: the whole of ign_semis
    now fits a Matérn 5/2 with a nugget of 1e-6 of its sill.  On the draws
    measured, its leave-one-out error lay within 1-2% of a Matérn's with a
    1-3% nugget, and which wins changes with the sample (4,000 points
    instead of 2,000: the 3% nugget); the draw of 5 m voids that lost most
    to the TIN (+31%) had the nugget of 1e-6.
    """
    return variogram.model == "exponential" or not variogram.nugget < _SMOOTH_GROUND_NUGGET * variogram.sill


def _check_variogram(variogram: object) -> Variogram:
    if not isinstance(variogram, Variogram):
        raise InvalidInputError(f"variogram must be a Variogram, got {type(variogram).__name__}")
    return variogram



def _face_mask(faces: ArrayLike, n_f: int) -> NDArray[np.bool_]:
    mask = np.asarray(faces)
    if mask.dtype != np.bool_ or mask.shape != (n_f,):
        raise InvalidInputError(f"faces must be a boolean mask of the mesh's {n_f} faces, got {mask.dtype} {mask.shape}")
    return mask


def smooth_neighbourhoods(mesh: Mesh, neighbours: int = DEFAULT_NEIGHBOURS, spacing: float | None = None,
                          data_vertices: int | None = None, faces: ArrayLike | None = None) -> Neighbourhoods:
    """The smooth surface's kriging systems and nodes for ``mesh`` (see :class:`Neighbourhoods`).

    ``spacing`` is the survey's point spacing (:attr:`Variogram.spacing`);
    the cells are ``CELL_PER_SPACING`` of it.  Without it the mesh's
    vertices give it.  The node values of :func:`smooth_nodes` depend on the
    mesh's vertices inside the (closed) disks ``.disks`` only: a piece of a
    larger point set gets the values of the whole set once every point of the
    set inside each disk is among its vertices, and both use one spacing.
    ``data_vertices``: only the first this many vertices are kriged from (the
    others are points a refined mesh added, :mod:`meshcore.refine`).
    ``faces``: a mask of the faces that get nodes (default: all); the others'
    rows of ``take`` are -1, and no system serves them alone.  The nodes in
    voids get their natural neighbours too (``.fill``), whose circles are
    among the disks.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> mesh = meshcore.build_mesh(np.random.default_rng(1).random((50, 2)))
    >>> hoods = smooth_neighbourhoods(mesh, spacing=0.15)
    >>> bool(np.all(hoods.disks[:, 2] > 0)), hoods.cell == 0.15 * CELL_PER_SPACING
    (True, True)
    """
    return _neighbourhoods(mesh, neighbours, spacing, data_vertices, faces, True)


def _neighbourhoods(mesh: Mesh, neighbours: int, spacing: float | None, data_vertices: int | None,
                    faces: ArrayLike | None, fills: bool) -> Neighbourhoods:
    """:func:`smooth_neighbourhoods`, the voids' natural neighbours left out unless ``fills``."""
    k = _check_neighbours(neighbours)
    vertices, mesh_faces = mesh_arrays(mesh)
    if spacing is None:
        spacing = _mesh_spacing(vertices, k)
    elif isinstance(spacing, bool) or not isinstance(spacing, (int, float)) or not (math.isfinite(spacing) and spacing > 0.0):
        raise InvalidInputError(f"spacing must be a finite number > 0, got {spacing!r}")
    cell = float(spacing) * CELL_PER_SPACING
    if faces is None:
        positions, take, corners, pattern = _layout(vertices, mesh_faces)
    else:
        wanted = _face_mask(faces, mesh_faces.shape[0])
        # a node lies on its edge or face alone: the faces wanted give theirs as all the faces do
        positions, some, corners, pattern = _layout(vertices, mesh_faces[wanted])
        take = np.full((mesh_faces.shape[0], NODES_PER_FACE), -1, dtype=np.int32)
        take[wanted] = some
    order, first, centres = _cells(positions, cell)
    positions, corners, pattern = _gather_nodes(order, positions, corners, pattern, take)
    data = vertices if data_vertices is None else np.ascontiguousarray(vertices[:data_vertices])
    index, d2 = _nearest(data, centres, k)
    gap = _gaps(data, index, first, positions, cell)
    if fills:
        (fill,) = _void_fills(vertices, data.shape[0], _NO_ENDS, cell, (positions, gap, index, first, corners))
    else:
        fill = _NO_FILL
    return Neighbourhoods(np.ascontiguousarray(centres), index, _radii(d2), first, positions, take, corners, pattern, cell,
                          gap, fill)


def smooth_nodes(
    mesh: Mesh,
    z: ArrayLike,
    variogram: Variogram | None = None,
    neighbours: int = DEFAULT_NEIGHBOURS,
    neighbourhoods: Neighbourhoods | None = None,
) -> NDArray[np.float64]:
    """The node values of the smooth surface's patches, one row of twelve per face.

    The nodes are grouped in cells of :data:`CELL_PER_SPACING` point spacings; each cell's
    nodes are kriged (universal kriging, linear drift) from the
    ``neighbours`` vertices nearest the cell's centre.  A node is then
    clamped to the range of its neighbours' values and of its edge's (an
    inner node: its face's) corners: a linear function is within that range,
    so the clamp keeps it exact while stopping overshoot where the neighbours
    lie to one side (the hull, voids).  With a variogram of smooth, nearly
    noise-free ground only the nodes kriged from one side are clamped.

    Parameters
    ----------
    mesh : Mesh
        A conforming mesh; its vertices are the points kriged (every vertex,
        also those no face uses).
    z : (n_v,) array
        The value at every vertex.
    variogram : Variogram, optional
        The covariance model and the point spacing; fitted from the mesh's
        vertices by :func:`fit_variogram` when omitted.
    neighbours : int
        Points per kriging neighbourhood, 4 to 64.
    neighbourhoods : Neighbourhoods, optional
        From :func:`smooth_neighbourhoods` for this mesh and the variogram's
        spacing (computed when omitted).

    Returns
    -------
    (n_f, 12) float64
        Node values in the layout of :mod:`meshcore.patches`; unused columns NaN.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> xy = np.random.default_rng(2).random((60, 2))
    >>> mesh = meshcore.build_mesh(xy, "s3", "s4")
    >>> z = 2.0 * mesh.vertices[:, 0] - mesh.vertices[:, 1]
    >>> nodes = smooth_nodes(mesh, z, Variogram(0.0, 1.0, 0.5))
    >>> nodes.shape == (mesh.faces.shape[0], 12)
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    variogram = fit_variogram(vertices, zv, neighbours=k) if variogram is None else _check_variogram(variogram)
    out = np.empty((faces.shape[0], NODES_PER_FACE))  # every entry written: a node or NaN
    if faces.shape[0] == 0:
        return out
    hoods = smooth_neighbourhoods(mesh, k, variogram.spacing) if neighbourhoods is None else neighbourhoods
    if hoods.take.shape != out.shape:
        raise InvalidInputError("neighbourhoods were computed for another mesh")
    if variogram.spacing is not None and hoods.cell != variogram.spacing * CELL_PER_SPACING:
        raise InvalidInputError(f"neighbourhoods were computed for cells of {hoods.cell!r}, the variogram's spacing gives "
                                f"{variogram.spacing * CELL_PER_SPACING!r}")
    values = np.empty(hoods.positions.shape[0])
    rows = hoods.pattern.astype(np.int32)  # as the added points give theirs: one kernel for both, compiled and loaded once
    near, far = _void_distances(hoods.cell)
    _nodes_kriged_kernel(
        vertices, zv, hoods.centres, hoods.index, hoods.first, hoods.positions, hoods.corners, rows, _PATTERN_WEIGHTS,
        variogram.nugget / variogram.sill, 1.0 / variogram.range, MODELS.index(variogram.model),
        _clamps_inside(variogram), hoods.gap, hoods.fill.values(zv, values.size, variogram, hoods.gap), near, far,
        values,
    )
    _scatter_nodes(values, hoods.take, out)
    return out


LONG_EDGE = 12.0
"""Edges longer than this many point spacings are split for the smooth surface (:func:`smooth_plan`)..."""


LONG_EDGE_PIECE = 3.0
"""... into equal pieces of at most this many spacings."""


SMOOTH_GROUND_LONG_EDGE = 4.0
"""On smooth, nearly noise-free ground (:func:`_clamps_inside` false): edges longer than this many spacings are split..."""


SMOOTH_GROUND_PIECE = 2.0
"""... into equal pieces of at most this many spacings."""


def _long_edges(variogram: Variogram) -> tuple[float, float]:
    """``(longer_than, piece)`` in point spacings: which edges the smooth surface splits, and into what.

    A cubic patch spans its face: on a face many spacings long (the slivers
    along the hull, faces across a void) it cannot follow the ground between
    its nodes, however well they are kriged.  Measured
    (``bench/bench_accuracy.py``, RMSE change against the TIN): on lidR's
    smooth test the smooth surface goes from -91.7% to -97.0% with edges over
    4 spacings split (-95.9% at 12); the real surveys gain 0.05-0.4 points at
    12 spacings, but autzen_trim loses 1.9 points at 4 (faces of 5 spacings
    across its sparse patches, where kriging is worse than the patches).  So
    4 spacings on smooth ground, 12 elsewhere.
    """
    if _clamps_inside(variogram):
        return LONG_EDGE, LONG_EDGE_PIECE
    return SMOOTH_GROUND_LONG_EDGE, SMOOTH_GROUND_PIECE


class AddedPoints(NamedTuple):
    """The kriging systems of the points a :class:`Refinement` adds on long edges.

    The points are grouped in the cells of the nodes (``cell``, on the same
    multiples), one system per cell over the ``neighbours`` input vertices
    nearest its centre: a point's value depends only on the input vertices
    inside its cell's disk, whichever piece of a survey computes it.

    Attributes
    ----------
    order : (m,) the added points cell by cell
    first : (c + 1,) cell ``s`` holds the points ``order[first[s] .. first[s+1]-1]``
    centres : (c, 2) the cells' centres
    index : (c, k) their nearest input vertices, nearest first (``-1`` pads)
    radius : (c,) the distance from each centre to its last neighbour
    gap : (m,) the distance from each point (in the order of ``order``) to the nearest of its
        cell's neighbours, as :attr:`Neighbourhoods.gap`
    fill : VoidFill, the points in voids (rows in the order of ``order``) and their natural neighbours
    """

    order: NDArray[np.int64]
    first: NDArray[np.int64]
    centres: NDArray[np.float64]
    index: NDArray[np.int64]
    radius: NDArray[np.float64]
    gap: NDArray[np.float64]
    fill: VoidFill

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(c, 3)`` rows ``(x, y, r)``: the closed disks the added points' values read points from
        (the cells' neighbourhoods, then the circles of the voids' natural neighbours)."""
        return np.concatenate([np.column_stack([self.centres, self.radius]), self.fill.coordinates.disks])


class SmoothPlan(NamedTuple):
    """Everything the smooth surface of a mesh reads, known before any value.

    Computed by :func:`smooth_plan`, taken by :func:`smooth_surface`.

    Attributes
    ----------
    refinement : Refinement
        The mesh with its long edges split and their faces cut into triangles
        (:func:`meshcore.refine.refine_long_faces`); the input mesh itself when no edge is long.
    nodes : Neighbourhoods
        The refined mesh's nodes and their systems, over the input vertices only.
    added : AddedPoints
        The systems of the points the refinement added.
    """

    refinement: Refinement
    nodes: Neighbourhoods
    added: AddedPoints

    @property
    def disks(self) -> NDArray[np.float64]:
        """``(m, 3)`` rows ``(x, y, r)``: every closed disk the surface reads points from
        (a piece of a survey gets the whole survey's surface once it holds every point inside them)."""
        return np.concatenate([self.nodes.disks, self.added.disks])


class SmoothSurface(NamedTuple):
    """A mesh's smooth surface: cubic patches over its faces, its long faces cut first.

    Evaluated by :func:`meshcore.interpolate`, :func:`meshcore.gradient` and
    :func:`meshcore.rasterize` given as their ``surface`` with the mesh it was computed for.

    Attributes
    ----------
    mesh : Mesh
        The faces the patches lie on: the input mesh's faces, those with a
        long edge cut into triangles (:class:`meshcore.refine.Refinement`: a
        face cut keeps its row for its first triangle, the others follow);
        its vertices are the input mesh's, then the points added on long edges.
    z : (n_v + m,) the values at its vertices (the added points' kriged)
    nodes : (n_f', 12) the patches' node values, one row per face of ``mesh``
    parent : (n_f',) the input mesh's face each face lies in
    """

    mesh: Mesh
    z: NDArray[np.float64]
    nodes: NDArray[np.float64]
    parent: NDArray[np.int64]


def _radii(d2: NDArray[np.float64]) -> NDArray[np.float64]:
    """The distance from each centre to its last neighbour (squared distances of :func:`_nearest`)."""
    return np.sqrt(d2[:, -1]) if d2.shape[1] else np.zeros(d2.shape[0])


def _added_points(data: NDArray[np.float64], positions: NDArray[np.float64], cell: float, k: int) -> AddedPoints:
    """The systems of the points added at ``positions`` (their fill left to :func:`_void_fills`)."""
    order, first, centres = _cells(positions, cell)
    if centres.shape[0] == 0:
        return AddedPoints(order, first, centres, np.empty((0, k), dtype=np.int64), np.empty(0), np.empty(0), _NO_FILL)
    # the cells of the added points are few and scattered: searched around each, not over a grid of every vertex
    index, d2 = _nearest_around(data, centres, k, 6.0 * cell)
    gap = _gaps(data, index, first, np.ascontiguousarray(positions[order]), cell)
    return AddedPoints(order, first, np.ascontiguousarray(centres), index, _radii(d2), gap, _NO_FILL)


def _with_fills(vertices: NDArray[np.float64], data: int, nodes: Neighbourhoods, added: AddedPoints,
                ends: NDArray[np.int64], new: NDArray[np.float64] | None = None) -> tuple[Neighbourhoods, AddedPoints]:
    """``nodes`` and ``added`` with the natural neighbours of those in voids, found together
    (``vertices``: the refined mesh's, its first ``data`` the points; ``ends``: the added points' edges).

    With ``new`` (points added to the vertices since ``nodes.fill`` and
    ``added.fill`` were found), only the nodes in voids whose disks hold one
    of them are found again (no node joins the voids: a gap only shrinks as
    points are added)."""
    where = np.ascontiguousarray(vertices[data:][added.order])
    groups = ((nodes.positions, nodes.gap, nodes.index, nodes.first, nodes.corners),
              (where, added.gap, added.index, added.first, ends[added.order]))
    if new is None:
        fills = _void_fills(vertices, data, ends, nodes.cell, *groups)
        return nodes._replace(fill=fills[0]), added._replace(fill=fills[1])
    near, _ = _void_distances(nodes.cell)
    old = (nodes.fill, added.fill)
    rows = [np.flatnonzero(gap > near) for _, gap, *_ in groups]
    # each kept node's place among the old ones, and those whose disks hold a new point
    kept = [np.searchsorted(f.rows, r) for f, r in zip(old, rows)]
    again = []
    for f, k in zip(old, kept):
        holds = np.zeros(f.rows.size, dtype=bool)
        hit = _disks_holding(f.coordinates.disks[:, :2], f.coordinates.disks[:, 2], new)
        holds[f.coordinates.owner[hit]] = True
        again.append(holds[k])
    if not any(a.any() for a in again) and all(k.size == f.rows.size for f, k in zip(old, kept)):
        return nodes, added
    found = _void_fills(vertices, data, ends, nodes.cell, *groups, rows=[r[a] for r, a in zip(rows, again)])
    fills = []
    for f, r, k, a, fresh in zip(old, rows, kept, again, found):
        # the old rows of the nodes kept as they were, then the new ones, put back in order
        both = join_places(take_places(f.coordinates, k[~a]), fresh.coordinates)
        order = np.argsort(np.concatenate([np.flatnonzero(~a), np.flatnonzero(a)]), kind="stable")
        fills.append(VoidFill(r, take_places(both, order)))
    return nodes._replace(fill=fills[0]), added._replace(fill=fills[1])


def smooth_plan(mesh: Mesh, variogram: Variogram, neighbours: int = DEFAULT_NEIGHBOURS,
                previous: SmoothPlan | None = None, faces: ArrayLike | None = None) -> SmoothPlan:
    """The long faces cut and every kriging system of ``mesh``'s smooth surface (see :class:`SmoothPlan`).

    Edges longer than a few point spacings (:func:`_long_edges`, by the
    variogram) are split into equal pieces, decided and placed by the edge
    alone, so two pieces of a survey split a shared edge alike.  ``.disks``
    are the points the values will read.

    ``previous``: the plan, with the same variogram and ``neighbours``, of a
    mesh with the same faces whose vertices are the first of ``mesh``'s (as
    :func:`meshcore.mesh.with_vertices` adds points).  Only the systems whose
    disks hold one of the other vertices are searched again: the plan is
    the one ``mesh`` gets, in a fraction of the time (for the faces
    ``previous`` was made for).

    ``faces``: a mask of the faces whose patches are wanted (default: all),
    such as those a grid samples (:func:`meshcore.sampled_faces`).  The
    others get no nodes: their rows of the surface's nodes are NaN, so the
    surface is unknown inside them, and the systems only they would read are
    neither searched nor solved.  The nodes computed are those of the whole
    mesh's plan, bit for bit.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> mesh = meshcore.build_mesh(np.random.default_rng(1).random((50, 2)))
    >>> plan = smooth_plan(mesh, Variogram(0.0, 1.0, 0.5, spacing=0.15))
    >>> plan.refinement.mesh.faces.shape[0] >= mesh.faces.shape[0], bool(np.all(plan.disks[:, 2] > 0))
    (True, True)
    """
    k = _check_neighbours(neighbours)
    variogram = _check_variogram(variogram)
    vertices, mesh_faces = mesh_arrays(mesh)
    if previous is not None:
        extended = _extended_plan(previous, mesh, vertices, mesh_faces, k)
        if extended is not None:
            return extended
    spacing = _mesh_spacing(vertices, k) if variogram.spacing is None else variogram.spacing
    longer_than, piece = _long_edges(variogram)
    refinement = refine_long_faces(mesh, spacing, longer_than, piece)
    n = vertices.shape[0]
    wanted = None if faces is None else _face_mask(faces, mesh_faces.shape[0])[refinement.parent]
    nodes = _neighbourhoods(refinement.mesh, k, spacing, n, wanted, False)
    added_positions = np.ascontiguousarray(refinement.mesh.vertices[n:])
    added = _added_points(vertices, added_positions, nodes.cell, k)
    nodes, added = _with_fills(refinement.mesh.vertices, n, nodes, added, refinement.ends)
    return SmoothPlan(refinement, nodes, added)


def _extended_plan(previous: SmoothPlan, mesh: Mesh, vertices: NDArray[np.float64], faces: NDArray[np.int64],
                   k: int) -> SmoothPlan | None:
    """:func:`smooth_plan` of ``mesh`` from ``previous`` (see there); None when
    its systems have fewer than ``k`` neighbours, all searched again then."""
    refinement, nodes, added = previous
    refined = refinement.mesh
    m = refinement.t.shape[0]
    n_old = refined.vertices.shape[0] - m
    n = vertices.shape[0]
    n_f = faces.shape[0]
    if (n < n_old or refinement.parent.shape[0] < n_f or nodes.take.shape[0] != refinement.parent.shape[0]
            or not np.array_equal(refinement.parent[:n_f], np.arange(n_f))
            or not np.array_equal(refined.vertices[:n_old], vertices[:n_old])):
        raise InvalidInputError("previous must be the plan of a mesh with these faces and the first of these vertices")
    if nodes.index.shape[1] != min(k, n_old) or min(k, n_old) != min(k, n):
        return None
    if n == n_old:
        return previous
    grown = n - n_old
    new = vertices[n_old:]

    def shifted(index: NDArray) -> NDArray:
        """Indices of the refined mesh's vertices, its new points moved past the vertices added."""
        if not m:
            return index
        out = index.copy()
        out[out >= n_old] += grown
        return out

    def searched_again(centres, index, radius, search):
        """``index`` and ``radius`` with the systems whose disks hold a new vertex found again by ``search``."""
        again = _disks_holding(centres, radius, new)
        if not again.any():
            return index, radius
        index, radius = index.copy(), radius.copy()
        found, d2 = search(np.ascontiguousarray(centres[again]))
        index[again], radius[again] = found, _radii(d2)
        return index, radius

    if m:
        refined = Mesh(np.concatenate([vertices, refined.vertices[n_old:]]), shifted(refined.faces), mesh.input_to_vertex,
                       mesh.triangle_measure, mesh.quad_measure, mesh.merge, mesh.window, mesh.window_escapes)
    else:
        refined = mesh
    index, radius = searched_again(nodes.centres, nodes.index, nodes.radius, lambda c: _nearest(vertices, c, k))
    gap = nodes.gap if index is nodes.index else _gaps(vertices, index, nodes.first, nodes.positions, nodes.cell)
    nodes = nodes._replace(index=index, radius=radius, corners=shifted(nodes.corners), gap=gap)
    # as _added_points searches them
    index, radius = searched_again(added.centres, added.index, added.radius,
                                   lambda c: _nearest_around(vertices, c, k, 6.0 * nodes.cell))
    if index is not added.index:
        added_positions = np.ascontiguousarray(refined.vertices[n:][added.order])
        gap = _gaps(vertices, index, added.first, added_positions, nodes.cell)
        added = added._replace(index=index, radius=radius, gap=gap)
    # the voids' natural neighbours again, of the nodes whose disks hold a new vertex
    nodes, added = _with_fills(refined.vertices, n, nodes, added, refinement.ends, new)
    return SmoothPlan(refinement._replace(mesh=refined), nodes, added)


def smooth_surface(
    mesh: Mesh,
    z: ArrayLike,
    variogram: Variogram | None = None,
    neighbours: int = DEFAULT_NEIGHBOURS,
    plan: SmoothPlan | None = None,
) -> SmoothSurface:
    """The smooth surface of ``mesh``: its long faces cut, the points added there
    kriged, and the patches' nodes of the faces that gives (:func:`smooth_nodes`).

    The added points are kriged from their cells' systems, as the nodes are,
    and clamped to their edge's ends and neighbours; every system reads the
    input vertices only.  The surface passes through every vertex, is
    continuous across every edge and reproduces linear functions.

    Parameters
    ----------
    mesh : Mesh
    z : (n_v,) the value at every vertex
    variogram : Variogram, optional
        Fitted from the mesh's vertices when omitted.
    neighbours : int
        Points per kriging neighbourhood, 4 to 64.
    plan : SmoothPlan, optional
        From :func:`smooth_plan` for this mesh, variogram and ``neighbours``.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> xy = np.random.default_rng(2).random((60, 2))
    >>> mesh = meshcore.build_mesh(xy, "s3", "s4")
    >>> surface = smooth_surface(mesh, 2.0 * mesh.vertices[:, 0], Variogram(0.0, 1.0, 0.5))
    >>> surface.nodes.shape == (surface.mesh.faces.shape[0], 12)
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    variogram = fit_variogram(vertices, zv, neighbours=k) if variogram is None else _check_variogram(variogram)
    plan = smooth_plan(mesh, variogram, k) if plan is None else plan
    refinement = plan.refinement
    n = vertices.shape[0]
    refined = refinement.mesh
    if refinement.parent.shape[0] != refined.faces.shape[0] or (refined is not mesh and refined.vertices.shape[0] < n) or (
        refinement.parent.size and refinement.parent.max() >= faces.shape[0]
    ):
        raise InvalidInputError("plan was computed for another mesh")
    m = refined.vertices.shape[0] - n
    z_all = np.empty(n + m)
    z_all[:n] = zv
    if m:
        z_all[n:] = _krige_added(vertices, zv, variogram, plan.added, refined.vertices[n:], refinement.ends, refinement.t,
                                 plan.nodes.cell)
    nodes = smooth_nodes(refined, z_all, variogram, k, neighbourhoods=plan.nodes)
    return SmoothSurface(refined, z_all, nodes, refinement.parent)


def _krige_added(
    vertices: NDArray[np.float64], z: NDArray[np.float64], variogram: Variogram, added: AddedPoints,
    positions: NDArray[np.float64], ends: NDArray[np.int64], t: NDArray[np.float64], cell: float,
) -> NDArray[np.float64]:
    """The added points' values, kriged as the nodes are: each from its cell's system,
    clamped as they are (to the neighbours' and its edge's ends' range), those
    in voids blended into the fill; a singular system gives the linear value
    ``(1 - t) z[first] + t z[second]``."""
    n = positions.shape[0]
    order = added.order
    corners = np.full((n, 4), -1, dtype=np.int32)
    corners[:, :2] = ends[order]
    weights = np.zeros((n, 4))
    weights[:, 0] = 1.0 - t[order]
    weights[:, 1] = t[order]
    values = np.empty(n)
    near, far = _void_distances(cell)
    _nodes_kriged_kernel(
        vertices, z, added.centres, added.index, added.first, np.ascontiguousarray(positions[order]), corners,
        np.arange(n, dtype=np.int32), weights, variogram.nugget / variogram.sill, 1.0 / variogram.range,
        MODELS.index(variogram.model), _clamps_inside(variogram), added.gap, added.fill.values(z, n, variogram, added.gap),
        near, far, values,
    )
    out = np.empty(n)
    out[order] = values
    return out


@njit
def _scatter_nodes(values: np.ndarray, take: np.ndarray, out: np.ndarray) -> None:
    """``out[f, j] = values[take[f, j]]`` where ``take[f, j] >= 0``, else NaN (six times faster than a mask in numpy)."""
    for f in range(take.shape[0]):
        for j in range(take.shape[1]):
            t = take[f, j]
            out[f, j] = values[t] if t >= 0 else np.nan
