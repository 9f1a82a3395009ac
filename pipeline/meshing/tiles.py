"""Meshing one tile so that the tiles' pieces form one conforming mesh.

Each tile meshes its core plus buffer and keeps the piece of the mesh over the
Delaunay triangles whose centroid lies in its core (``build_mesh(window=...)``).
The Delaunay triangulation is unique, so the pieces of neighbouring tiles fit
exactly, provided each tile held every point inside the circumcircles of its
piece's triangles.  meshcore reports the circumcircles that leave the box the
tile holds; the tile then loads the points inside them (from the neighbours'
spill files) and rebuilds, until none is left ("certified").  Flips and merges
happen only between triangles of the same piece, so they never cross a seam.

With ``surface="smooth"`` the neighbourhood of every kriging system of the
piece (one per cell of nodes, and of the points added on its long edges) is
one more disk the tile must hold, loaded like an escaping circle, so
neighbouring tiles split their shared long edges alike and krig the nodes of
their shared edges from the same points, with the same values.  Only the
faces that hold a centre of the run's grid get nodes
(:func:`meshcore.tiles.sampled_faces`): the DEM samples the surface nowhere else,
and the mesh written carries no patch.  On a survey denser than its grid
that is a fraction of the faces (one in twelve for 8 points a square metre
at 1 m).  The piece saves those faces' nodes (``noded``: their rows), and
for the faces cut (:func:`meshcore.tiles.smooth_plan`) their triangles, nodes and
added points beside: the mesh written is the combined mesh, the DEM is drawn
from the smooth surface over the faces with nodes.

A tile's result is saved to the scratch folder: its vertices (the ones it owns
first, sorted by coordinates, for the global node numbering; then the other
corners of its faces) and its faces; the DEM pass and the mesh writer read
them back.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

import meshcore
from meshcore.kernels import empty

from ..config import MeshOptions
from ..errors import SeamError
from ..products import ProductSettings, TileContext
from ..products.points import from_columns, from_product_rows, product_row_width
from ..products.tile import tile_layers, warm_up
from ..tiling.scratch import Scratch
from ..tiling.windows import WindowSource, points_in_boxes, tile_points
from ..tiling.grid import TileGrid, intersect_boxes
from ..tiling.routing import PRODUCT_SPILL, load_tile_points, neighbour_tile_points, points_in_box
from .kernels import load_mesh_kernels, sample_grid_mesh
from .piece import MESH_ARRAYS, SURFACE_ARRAYS, Piece, PiecePart

__all__ = [
    "TileJob", "TileSummary", "mesh_tile", "dem_tile", "vertex_z", "held_box", "hull_near",
    "reached_tiles", "load_kernels", "load_surface_kernels",
]

DEFAULT_ASSUMED_ROUNDS = 8
"""The flip rounds a tile's certificate first allows the tiles around it.  On
the real samples the survey's flips end by round 3 to 9 (``bench/bench_tiling.py``);
a run checks the assumption after meshing and meshes again, assuming more, the
tiles around which a tile flipped later.  Fewer made more tiles mesh twice."""


@dataclass(frozen=True)
class HeldBefore:
    """What a tile held when it was meshed before: its boxes (the first held
    whole) and how far that first box had grown beyond its buffer
    (:attr:`TileSummary.held`, :attr:`TileSummary.grown`)."""

    boxes: tuple[tuple[float, float, float, float], ...]
    grown: float = 0.0


@dataclass(frozen=True)
class TileJob:
    """A small, picklable recipe for one tile's work (no open files)."""

    row: int
    col: int
    scratch: Scratch
    grid: TileGrid
    buffer: float
    extent: tuple[float, float, float, float]
    options: MeshOptions = MeshOptions()
    """The run's measures, surface, duplicates policy, longest edge and layers."""
    hull: NDArray[np.float64] | None = None
    """The global convex hull's points (x, y, z), added to every tile's points."""
    height_scale: float = 1.0
    """A height times this is in the horizontal unit (for slopes)."""
    reaching: tuple[tuple[int, int], ...] | None = None
    """For the DEM: the other tiles whose faces may cover this tile's cells
    (see :func:`reached_tiles`); None: the eight around it."""
    run_id: str = ""
    """Names the run: tiles' points read for this one are kept in memory for
    the other tiles of the same run (empty: never kept)."""
    variogram: meshcore.Variogram | None = None
    windows: tuple[WindowSource, ...] = ()
    """COPC inputs this tile reads by window (:mod:`pipeline.tiling.windows`), not from spill files."""
    assume_rounds: int = DEFAULT_ASSUMED_ROUNDS
    """The flip rounds the certificate allows the tiles around this one (see :func:`mesh_tile`)."""
    products: ProductSettings | None = None
    """The run's products (:mod:`pipeline.products`); None: ``layers`` of the DTM's mesh alone."""
    held_before: HeldBefore | None = None
    """A tile meshed again (assuming more flip rounds): what it held the first
    time.  It starts from those points rather than from its buffer: its piece
    is the same whatever it holds once certified, and the builds that found
    them are spared."""


@dataclass(frozen=True)
class TileSummary:
    row: int
    col: int
    points_owned: int
    vertices_owned: int
    duplicates: int
    faces: int
    quads: int
    expansions: int
    certified: bool
    """Always true from this version on (a piece that cannot be certified is an
    error); false in records of older runs that gave up."""
    seconds: float
    held: tuple[tuple[float, float, float, float], ...] = ()
    """The boxes whose points the tile held: its piece depends on no other point
    (besides the global hull's)."""
    reach: tuple[float, float, float, float] | None = None
    """The bounding box of the tile's faces that leave its box (None: none do).
    A sliver along the convex hull may cross several tiles."""
    points_held: int = 0
    """Points of the tile's own file (its window plus buffer)."""
    points_loaded: int = 0
    """Points read from other tiles beyond the buffer, to certify the piece."""
    window_counts: tuple[tuple[str, int, int, int, int, int], ...] = ()
    """What the tile counted of each window source: (path, read,
    filtered_class, filtered_withheld, outside_bbox, kept) of the nodes it owns."""
    last_flip_round: int = 0
    """The last flip round whose flips touched the tile's window (0: none)."""
    flip_blocks: tuple[tuple[int, ...], ...] = ()
    """The same per block of ``flip_blocks_box`` (rows from its lowest y), so
    that a tile near this one asks only of the blocks its held boxes meet
    (empty: a record of an older version, or no flips)."""
    flip_blocks_box: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    """The box the blocks cut: the tile's window where it meets the tile's points."""
    assumed_rounds: int = -1
    """The rounds after which its certificate assumes no flip near it (-1: a record of an older version)."""
    grown: float = 0.0
    """How far beyond its buffer the box it holds whole had to grow for the flips' certificate."""

    @property
    def latest_flip_round(self) -> int:
        """The last round whose flips touched this tile's window anywhere: no
        box gets a later one from :meth:`last_flip_round_in`."""
        return max([self.last_flip_round, *(max(row) for row in self.flip_blocks if row)])

    def last_flip_round_in(self, boxes: list) -> int:
        """The last round whose flips touched this tile's window inside the
        closed ``boxes`` (:func:`meshcore.tiles.last_flip_round_in`), or in its
        whole window when a record of an older version has no blocks."""
        if not self.flip_blocks:
            return self.last_flip_round
        return meshcore.tiles.last_flip_round_in(self.flip_blocks, self.flip_blocks_box, boxes)


def reached_tiles(grid: TileGrid, reach: tuple[float, float, float, float] | None, row: int, col: int) -> list[tuple[int, int]]:
    """The tiles whose cells the faces of tile (row, col) leaving its box may
    cover: those ``reach`` overlaps, or, unknown (None from an older record),
    the eight around it."""
    if reach is None:
        return [
            (r, c)
            for r in range(max(0, row - 1), min(grid.n_rows, row + 2))
            for c in range(max(0, col - 1), min(grid.n_cols, col + 2))
        ]
    return grid.tiles_meeting([reach])


def vertex_z(input_to_vertex: NDArray[np.int64], n_vertices: int, z: NDArray[np.float64], policy: str) -> NDArray[np.float64]:
    """z of every vertex from the z of the input points it merges, by ``policy``."""
    if policy == "lowest":
        out = np.full(n_vertices, np.inf)
        np.minimum.at(out, input_to_vertex, z)
    elif policy == "highest":
        out = np.full(n_vertices, -np.inf)
        np.maximum.at(out, input_to_vertex, z)
    elif policy == "mean":
        # float64 also for no point (numpy then counts in integers)
        out = np.bincount(input_to_vertex, weights=z, minlength=n_vertices).astype(np.float64, copy=False)
        out /= np.bincount(input_to_vertex, minlength=n_vertices)
    else:
        first = np.full(n_vertices, np.iinfo(np.int64).max)
        np.minimum.at(first, input_to_vertex, np.arange(z.size))
        out = z[first]
    return out


def held_box(grid: TileGrid, row: int, col: int, buffer: float) -> tuple[float, float, float, float]:
    """The box in which a tile holds every point, as routed: its window plus buffer.

    An outer tile's window, and so this box, reaches to infinity on its outer
    sides (past the grid lie only the points a stale header left out of it).
    """
    w = grid.window(row, col)
    return (w[0] - buffer, w[1] - buffer, w[2] + buffer, w[3] + buffer)


def hull_near(hull: NDArray[np.float64], box) -> NDArray[np.float64]:
    """The hull points (in order) that end a hull edge whose bounding box meets ``box``."""
    nxt = np.roll(hull, -1, axis=0)
    meets = (np.maximum(hull[:, 0], nxt[:, 0]) >= box[0]) & (np.minimum(hull[:, 0], nxt[:, 0]) <= box[2])
    meets &= (np.maximum(hull[:, 1], nxt[:, 1]) >= box[1]) & (np.minimum(hull[:, 1], nxt[:, 1]) <= box[3])
    keep = meets | np.roll(meets, 1)
    return hull[keep]


_U = 2.0**-53
"""The unit roundoff of float64: the boxes below are rounded outwards by bounds of their errors."""


def _disk_box_in(cx: float, cy: float, r: float, box: tuple[float, float, float, float]):
    """Bounding box of (disk ∩ box), rounded outwards, or None when they do not meet."""
    ok, *out = meshcore.certificate.disk_box_in(float(cx), float(cy), float(r), *(float(v) for v in box))
    return tuple(out) if ok else None


def _edge_sides(px: NDArray[np.float64], py: NDArray[np.float64], qx, qy) -> NDArray[np.float64]:
    """Cross product of each edge of the closed polygon ``(px, py)`` with the way
    from its start to each query point ``(qx[i], qy[i])``: row i is >= 0 on
    every edge when the point lies in the (counter-clockwise, convex) polygon."""
    ex, ey = np.roll(px, -1) - px, np.roll(py, -1) - py
    return ex[None, :] * (np.asarray(qy)[:, None] - py[None, :]) - ey[None, :] * (np.asarray(qx)[:, None] - px[None, :])


#: circles times hull vertices that :func:`_inside_hull` computes at once (about 100 MiB of
#: arrays): thousands of open disks of a smooth tile against the thousands of vertices of a hull
#: cut on a curve took 1.4 GiB at once
_HULL_CHUNK = 1 << 19


def _disk_boxes_in_hull(circles: NDArray[np.float64], hull_xy: NDArray[np.float64], box) -> list:
    """For each circle ``(cx, cy, r)``: the bounding box of (disk ∩ convex
    polygon ``hull_xy`` (counter-clockwise) ∩ ``box``), rounded outwards, or
    None when they do not meet (:func:`meshcore.certificate.lens_boxes`).

    No point lies outside the global hull, so the part of an escaping circle
    beyond it needs no points loaded: along a survey edge the circles of the
    slivers there reach far out of the hull but only a thin lens into it.
    """
    return [None if math.isnan(b[0]) else tuple(b) for b in _lens_array(circles, hull_xy, box).tolist()]


def _lens_array(circles: NDArray[np.float64], hull_xy: NDArray[np.float64], box) -> NDArray[np.float64]:
    """:func:`_disk_boxes_in_hull` as an ``(n, 4)`` array, a row of NaN for None."""
    return meshcore.certificate.lens_boxes(
        np.ascontiguousarray(circles, dtype=np.float64).reshape(-1, 3),
        np.ascontiguousarray(hull_xy, dtype=np.float64).reshape(-1, 2), np.array(box, dtype=np.float64),
    )


def _open_lenses(circles: NDArray[np.float64], hull_xy: NDArray[np.float64], box, held: list) -> list:
    """The circles whose lens in the hull (:func:`_disk_boxes_in_hull`) is not
    inside the held boxes: ``(index, the parts of its box outside them)``."""
    rows, boxes = _open_lens_rows(circles, hull_xy, box, held)
    return [(i, _uncovered(tuple(boxes[i].tolist()), held)) for i in rows.tolist()]


def _open_lens_rows(circles: NDArray[np.float64], hull_xy: NDArray[np.float64], box, held: list):
    """The rows of :func:`_open_lenses`' circles, and every circle's lens box
    (:func:`_lens_array`): without the parts, which only a load asks for."""
    if circles.shape[0] == 0:
        return np.empty(0, dtype=np.int64), np.empty((0, 4))
    boxes = _lens_array(circles, hull_xy, box)
    held_array = np.array(held, dtype=np.float64).reshape(-1, 4)
    open_ = ~np.isnan(boxes[:, 0])
    for h in held_array:  # most lie inside one held box: settled at once
        open_ &= ~((boxes[:, 0] >= h[0]) & (boxes[:, 1] >= h[1]) & (boxes[:, 2] <= h[2]) & (boxes[:, 3] <= h[3]))
    rows = np.flatnonzero(open_)
    return rows[_outside_boxes(np.ascontiguousarray(boxes[rows]), held_array)], boxes


@meshcore.kernels.kernel
def _outside_boxes(boxes: NDArray[np.float64], held: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether each box ``(x0, y0, x1, y1)`` has a part outside every one of
    the closed boxes ``held``: :func:`_uncovered` is not empty."""
    n, h = boxes.shape[0], held.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    # depth first: a part, and the first held box it may still meet; each level pushes at most 4
    stack = empty((4 * h + 4, 5))
    for i in range(n):
        stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3], stack[0, 4] = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3], 0.0
        top = 1
        while top > 0 and not out[i]:
            top -= 1
            p0, p1, p2, p3 = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
            j = np.int64(stack[top, 4])
            while j < h and (max(p0, held[j, 0]) > min(p2, held[j, 2]) or max(p1, held[j, 1]) > min(p3, held[j, 3])):
                j += 1
            if j == h:
                out[i] = True  # a part meets no held box
                break
            c0, c1, c2, c3 = max(p0, held[j, 0]), max(p1, held[j, 1]), min(p2, held[j, 2]), min(p3, held[j, 3])
            # up to four slabs of p around the cut (edges shared: closed boxes), as _uncovered cuts them
            for s0, s1, s2, s3, keep in ((p0, p1, p2, c1, p1 < c1), (p0, c3, p2, p3, c3 < p3),
                                         (p0, c1, c0, c3, p0 < c0), (c2, c1, p2, c3, c2 < p2)):
                if keep:
                    stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3], stack[top, 4] = s0, s1, s2, s3, j + 1.0
                    top += 1
    return out


def _beyond(boxes: list, box) -> float:
    """How far the farthest of ``boxes`` reaches beyond ``box``."""
    return max(max(box[0] - b[0], box[1] - b[1], b[2] - box[2], b[3] - box[3], 0.0) for b in boxes)


def _grown_box(box, by: float, extent) -> tuple[float, float, float, float]:
    """``box`` grown by ``by`` on every side, each side stopping at the infinite
    one past the survey's ``extent`` (nothing lies beyond it)."""
    lo_x, lo_y, hi_x, hi_y = box[0] - by, box[1] - by, box[2] + by, box[3] + by
    return (
        -math.inf if lo_x <= extent[0] else lo_x, -math.inf if lo_y <= extent[1] else lo_y,
        math.inf if hi_x >= extent[2] else hi_x, math.inf if hi_y >= extent[3] else hi_y,
    )


def _any_in_circles(points: NDArray[np.float64], circles: NDArray[np.float64]) -> bool:
    """Whether a point ``(x, y, ...)`` lies in a closed circle ``(x, y, r)`` (a radius
    not finite: any point).  The points are sorted by x and each circle tests
    those in its span of x: memory of the points only (one matrix of the points
    by the circles took 4.4 GiB a tile that loaded 390k points for 1,500 circles)."""
    if points.shape[0] == 0 or circles.shape[0] == 0:
        return False
    order = np.argsort(points[:, 0], kind="stable")
    xs, ys = points[order, 0], points[order, 1]
    for cx, cy, r in circles.tolist():
        if not r < math.inf:
            return True
        reach = r * (1.0 + 1e-9) + 8 * _U * abs(cx)  # the span rounded outwards
        lo, hi = np.searchsorted(xs, cx - reach, side="left"), np.searchsorted(xs, cx + reach, side="right")
        if lo < hi and bool(np.any((xs[lo:hi] - cx) ** 2 + (ys[lo:hi] - cy) ** 2 <= r * r)):
            return True
    return False


def _uncovered(box, held: list) -> list:
    """The parts of ``box`` (as boxes) outside every box of ``held``."""
    parts = [box]
    for h in held:
        rest = []
        for p in parts:
            cut = intersect_boxes(p, h)
            if cut is None:
                rest.append(p)
                continue
            # up to four slabs of p around the cut (edges shared: closed boxes)
            if p[1] < cut[1]:
                rest.append((p[0], p[1], p[2], cut[1]))
            if cut[3] < p[3]:
                rest.append((p[0], cut[3], p[2], p[3]))
            if p[0] < cut[0]:
                rest.append((p[0], cut[1], cut[0], cut[3]))
            if cut[2] < p[2]:
                rest.append((cut[2], cut[1], p[2], cut[3]))
        parts = rest
        if not parts:
            break
    return parts


def _clip_to_box(polygon: NDArray[np.float64], box) -> NDArray[np.float64]:
    """The convex polygon (k, 2) cut to the box (infinite sides allowed)."""
    pts = polygon
    for axis, bound, keep_above in ((0, box[0], True), (0, box[2], False), (1, box[1], True), (1, box[3], False)):
        if not math.isfinite(bound) or pts.shape[0] == 0:
            continue
        inside = pts[:, axis] >= bound if keep_above else pts[:, axis] <= bound
        if inside.all():
            continue
        out = []
        for k in range(pts.shape[0]):
            a, b = pts[k - 1], pts[k]
            ia, ib = inside[k - 1], inside[k]
            if ia != ib:  # the edge crosses the bound
                t = (bound - a[axis]) / (b[axis] - a[axis])
                cut = a + t * (b - a)
                cut[axis] = bound
                out.append(cut)
            if ib:
                out.append(b)
        pts = np.array(out).reshape(-1, 2)
    return pts


def _uncovered_corners(xy: NDArray[np.float64], window, hull_xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """The corners of the part of the tile's window inside the global hull
    ``hull_xy`` (counter-clockwise) that the convex hull of ``xy`` (a tile's
    points) leaves out, to within rounding (none: it covers that part; both
    are convex, so it covers it when it holds its corners).  Where it does not
    (a tile inside a data void wider than its buffer, or a building over a
    corner of its window), its triangulation has no triangle there and so no
    circle to say that points are missing: the points are looked for around
    those corners."""
    if hull_xy.shape[0] < 3:
        return np.empty((0, 2))
    need = _clip_to_box(hull_xy, window)
    if need.shape[0] == 0:
        return np.empty((0, 2))
    if xy.shape[0] < 3:
        return need
    h = meshcore.convex_hull(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]))
    hx, hy = xy[h, 0], xy[h, 1]
    scale = max(float(np.abs(hull_xy).max()), 1.0)
    tol = 1e-9 * scale * np.hypot(np.roll(hx, -1) - hx, np.roll(hy, -1) - hy)[None, :]
    return need[~(_edge_sides(hx, hy, need[:, 0], need[:, 1]) >= -tol).all(axis=1)]


def _sparse_rim(job: TileJob, own: NDArray[np.float64], box) -> list:
    """Boxes beyond the finite sides of ``box`` (the tile's window plus
    buffer) where its own points along that side are so sparse that the
    flips' doubt from the rim would cross the buffer into the window.

    Doubt spreads about one ring of triangles a round for the rounds a tile
    assumes (and the merges read two more); a ring is about
    :data:`_RING_SPACINGS` local point spacings wide.  The buffer is 12 of the
    survey's mean spacings, which holds that where the points are as dense as
    the mean, but not beside the trees and buildings of a town, whose ground
    is sparse: there nearly every tile meshed twice, for a few hundred points
    a search then found at its rim.  Each cell of a buffer's side along the
    rim whose spacing says the doubt reaches farther than the buffer gets a
    box that far beyond it (at most :data:`_RIM_BUFFERS` buffers): held from
    the first build, as a later search would have held them."""
    g = job.grid
    step = max(job.buffer, g.resolution)
    ext = job.extent
    lo = np.array([max(box[0], ext[0]), max(box[1], ext[1])])
    hi = np.array([min(box[2], ext[2]), min(box[3], ext[3])])
    if own.shape[0] == 0 or np.any(hi <= lo):
        return []
    n = np.maximum(1, np.ceil((hi - lo) / step).astype(np.int64))
    ij = np.clip(((own[:, :2] - lo) / step).astype(np.int64), 0, n - 1)
    counts = np.bincount(ij[:, 1] * n[0] + ij[:, 0], minlength=int(n[0] * n[1])).reshape(n[1], n[0])
    spacing = step / np.sqrt(np.maximum(counts, 1))
    beyond = np.minimum((job.assume_rounds + 2) * _RING_SPACINGS * spacing, _RIM_BUFFERS * step) - step
    out = []
    for side, finite, cells in ((0, box[0] > ext[0], beyond[:, 0]), (1, box[1] > ext[1], beyond[0, :]),
                                (2, box[2] < ext[2], beyond[:, -1]), (3, box[3] < ext[3], beyond[-1, :])):
        if not finite:
            continue
        boxes = []
        for m in np.flatnonzero(cells > 0).tolist():
            d = float(cells[m])
            if side in (0, 2):
                y0, y1 = float(lo[1] + m * step), float(min(lo[1] + (m + 1) * step, hi[1]))
                boxes.append((box[0] - d, y0, box[0], y1) if side == 0 else (box[2], y0, box[2] + d, y1))
            else:
                x0, x1 = float(lo[0] + m * step), float(min(lo[0] + (m + 1) * step, hi[0]))
                boxes.append((x0, box[1] - d, x1, box[1]) if side == 1 else (x0, box[3], x1, box[3] + d))
        out.extend(_merge_boxes(boxes))  # side by side along one side: a strip as deep as its deepest cell
    return out


def _held_from_the_start(job: TileJob, own: NDArray[np.float64], box) -> tuple[list, float]:
    """The boxes a tile holds beyond ``box`` (its window plus buffer) before
    its first build, and how far its box held whole has grown: a tile meshed
    again, what it held the first time (the box held whole first, the others
    merged, so that a tile meshed again and again does not pile them up);
    else the sparse stretches of its rim (:func:`_sparse_rim`)."""
    before = job.held_before
    if before is None:
        return _sparse_rim(job, own, box), 0.0
    if not before.boxes:
        return [], 0.0
    first = tuple(before.boxes[0])
    rest = [b for b in _merge_boxes([tuple(b) for b in before.boxes[1:]]) if _uncovered(b, [first])]
    return [first, *rest], before.grown


def _merge_boxes(boxes: list) -> list:
    """Boxes whose union holds ``boxes``: overlapping ones become their bounding
    box, until none overlap.  The circles of a data void ask for hundreds of
    overlapping boxes; held as they are, each circle's :func:`_uncovered` would
    cut every box by every other."""
    out: list = []
    for box in sorted(boxes):
        while True:
            for k, other in enumerate(out):
                if intersect_boxes(box, other) is not None:
                    box = (min(box[0], other[0]), min(box[1], other[1]), max(box[2], other[2]), max(box[3], other[3]))
                    del out[k]
                    break
            else:
                break
        out.append(box)
    return out


def _edge_bands(job: TileJob, box: tuple[float, float, float, float]) -> list:
    """Strips along the data extent's edges that the tile's box reaches, a
    buffer deep (with the smooth surface, at least four point spacings) and
    one tile longer than the box on either side.

    Near a straight survey edge the Delaunay triangles are slivers whose
    circumcircles reach far along the edge, just inside it, and whose flips
    read their neighbours for rounds: the slivers that meet the window are
    as long as the gaps between the points on the edge.  Holding these
    strips from the start spares most edge tiles a second build.
    """
    x0, y0, x1, y1 = job.extent
    reach = min(job.grid.tile_size, 32.0 * job.buffer)
    # the lenses of the slivers' circles inside the survey are centimetres deep, but their flips read
    # the triangles a few rings around, round after round: on the throughput bench's corner tiles a
    # twentieth of the buffer left 5-8 circles open (4-6 builds), a buffer none
    depth = job.buffer
    if job.options.surface == "smooth" and job.variogram is not None and job.variogram.spacing is not None:
        # the nodes of those slivers are kriged from disks of about 2.3
        # spacings around cells of 1.4: 4 spacings hold them
        depth = max(depth, 4.0 * job.variogram.spacing)
    lo_x, hi_x = max(x0, box[0] - reach), min(x1, box[2] + reach)
    lo_y, hi_y = max(y0, box[1] - reach), min(y1, box[3] + reach)
    hull = None if job.hull is None else job.hull[:, :2]
    bands = _slanted_bands(hull, box, depth, (lo_x, lo_y, hi_x, hi_y), job.extent)
    if box[1] <= y0:
        a, b = _along_hull(hull, 1, y0, depth, lo_x, hi_x)
        bands.append((a, y0, b, min(y1, y0 + depth)))
    if box[3] >= y1:
        a, b = _along_hull(hull, 1, y1, depth, lo_x, hi_x)
        bands.append((a, max(y0, y1 - depth), b, y1))
    if box[0] <= x0:
        a, b = _along_hull(hull, 0, x0, depth, lo_y, hi_y)
        bands.append((x0, a, min(x1, x0 + depth), b))
    if box[2] >= x1:
        a, b = _along_hull(hull, 0, x1, depth, lo_y, hi_y)
        bands.append((max(x0, x1 - depth), a, x1, b))
    return bands


def _slanted_bands(hull: NDArray[np.float64] | None, box, depth: float, reach, extent) -> list:
    """Boxes that hold a strip ``depth`` deep inside the survey along each hull
    edge that passes within ``depth`` of ``box`` and does not run along a side
    of the ``extent`` (a survey cut on a slanted line), from ``reach`` (a box)
    on.  Its slivers are those of a straight side, turned: without the strip,
    a tile that a slanted edge crosses meshes twice.  A slanted piece of edge
    is cut into boxes about ``depth`` across its run, so the boxes hold little
    beyond the strip; consecutive small ones are joined."""
    if hull is None or hull.shape[0] < 3 or not depth > 0.0:
        return []
    x0, y0, x1, y1 = extent
    p, q = hull, np.roll(hull, -1, axis=0)
    on_side = np.zeros(p.shape[0], dtype=bool)
    for axis, side in ((0, x0), (0, x1), (1, y0), (1, y1)):
        on_side |= _along_side(p, q, axis, side, depth)
    near = (box[0] - depth, box[1] - depth, box[2] + depth, box[3] + depth)
    _, _, meets = _clip_segments(p, q, near)
    rows = np.flatnonzero(meets & ~on_side)
    if rows.size == 0:
        return []
    slack = depth / 16.0
    t0, t1, meets = _clip_segments(p[rows], q[rows], reach)
    out: list = []
    pieces_area: list = []  # the areas of the pieces each box of ``out`` joins
    for i, lo, hi, ok in zip(rows, t0, t1, meets):
        if not ok:
            continue
        d = q[i] - p[i]
        length = float(np.hypot(d[0], d[1]))
        if length == 0.0:
            continue
        inward = np.array([-d[1], d[0]]) * (depth / length)  # the hull runs counter-clockwise
        pieces = max(1, math.ceil(float(min(abs(d[0]), abs(d[1]))) * (hi - lo) / depth))
        for k in range(pieces):
            a = p[i] + d * (lo + (hi - lo) * k / pieces)
            b = p[i] + d * (lo + (hi - lo) * (k + 1) / pieces)
            corners = np.array([a, b, a + inward, b + inward])
            # and a little past the edge: a lens's box is known to its rounding, not to the hull's bits
            lo_xy, hi_xy = corners.min(axis=0) - slack, corners.max(axis=0) + slack
            piece = intersect_boxes((*lo_xy, *hi_xy), extent)
            if piece is None:
                continue
            if out:  # the last box and this piece as one box, when it is not much larger than its pieces
                last = out[-1]
                joined = (min(last[0], piece[0]), min(last[1], piece[1]), max(last[2], piece[2]), max(last[3], piece[3]))
                if _area(joined) <= 1.5 * (pieces_area[-1] + _area(piece)):
                    out[-1] = joined
                    pieces_area[-1] += _area(piece)
                    continue
            out.append(piece)
            pieces_area.append(_area(piece))
    return out


def _area(box) -> float:
    return (box[2] - box[0]) * (box[3] - box[1])


def _clip_segments(p: NDArray[np.float64], q: NDArray[np.float64], box):
    """The parameters ``t0 <= t1`` in [0, 1] of the part of each segment ``p + t (q - p)``
    inside the closed ``box`` (Liang-Barsky), and whether there is one."""
    t0, t1 = np.zeros(p.shape[0]), np.ones(p.shape[0])
    ok = np.ones(p.shape[0], dtype=bool)
    for axis in (0, 1):
        lo, hi = box[axis], box[axis + 2]
        d = q[:, axis] - p[:, axis]
        flat = d == 0.0
        ok &= ~flat | ((p[:, axis] >= lo) & (p[:, axis] <= hi))
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (lo - p[:, axis]) / d, (hi - p[:, axis]) / d
        t0 = np.where(flat, t0, np.maximum(t0, np.minimum(a, b)))
        t1 = np.where(flat, t1, np.minimum(t1, np.maximum(a, b)))
    return t0, t1, ok & (t0 <= t1)


def _along_hull(hull: NDArray[np.float64] | None, axis: int, side: float, depth: float, lo: float, hi: float):
    """``lo, hi`` grown to the ends of the hull edges that run within ``depth`` of
    the extent's side ``axis = side`` and overlap the span: a straight survey edge
    holds few points exactly on it, and the slivers on a hull edge between two
    of them (hundreds of metres apart) meet every tile along it."""
    if hull is None or hull.shape[0] < 2:
        return lo, hi
    p, q = hull, np.roll(hull, -1, axis=0)
    on_side = _along_side(p, q, axis, side, depth)
    a, b = np.minimum(p[:, 1 - axis], q[:, 1 - axis])[on_side], np.maximum(p[:, 1 - axis], q[:, 1 - axis])[on_side]
    meets = (b >= lo) & (a <= hi)  # (the edges they then reach run on along the side: not taken)
    # and ``depth`` past the ends: a sliver's lens is known to its rounding, not to the end's bits
    return (min(lo, float(a[meets].min(initial=lo)) - depth), max(hi, float(b[meets].max(initial=hi)) + depth))


def _along_side(p: NDArray[np.float64], q: NDArray[np.float64], axis: int, side: float, depth: float) -> NDArray[np.bool_]:
    """Whether each edge ``p -> q`` runs within ``depth`` of the extent's side ``axis = side``
    (the edges whose strip the extent's side bands hold)."""
    return (np.abs(p[:, axis] - side) <= depth) & (np.abs(q[:, axis] - side) <= depth)


class _HeldRegion(meshcore.tiles.KnownRegion):
    """What a tile holds, for meshcore's certificate: the box it holds whole,
    the global hull, and its other held boxes (a circle is vouched for when its
    part inside the hull lies in them)."""

    def __init__(self, held: list, hull: NDArray[np.float64], extent) -> None:
        super().__init__(box=tuple(held[0]), hull=hull if hull.shape[0] >= 3 else None)
        object.__setattr__(self, "_held", list(held))
        object.__setattr__(self, "_extent", extent)

    def covers(self, circles: NDArray[np.float64]) -> NDArray[np.bool_]:
        out = np.zeros(circles.shape[0], dtype=bool)
        cx, cy, r = circles[:, 0], circles[:, 1], circles[:, 2]
        held = np.array(self._held, dtype=np.float64).reshape(-1, 4)
        for box in held[1:]:  # a circle inside one held box needs no clipping to the hull
            out |= (cx - r >= box[0]) & (cy - r >= box[1]) & (cx + r <= box[2]) & (cy + r <= box[3])
        # a circle inside the hull reaching past every held box's bounds holds points not held: most
        # circles of the rim of what is held, settled without clipping each one to the hull
        lo, hi = held[:, :2].min(axis=0), held[:, 2:].max(axis=0)
        past = np.isfinite(r) & ((cx - r < lo[0]) | (cy - r < lo[1]) | (cx + r > hi[0]) | (cy + r > hi[1]))
        rest = np.flatnonzero(~out & past)
        if rest.size and self.hull is not None:
            past[:] = False
            past[rest[_inside_hull(circles[rest], self.hull)]] = True
        rest = np.flatnonzero(~out & ~past)
        if rest.size:
            hull = self.hull if self.hull is not None else np.empty((0, 2))
            out[rest] = True
            out[rest[_open_lens_rows(circles[rest], hull, self._extent, self._held)[0]]] = False
        return out


def _inside_hull(circles: NDArray[np.float64], hull: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether each circle ``(x, y, r)`` lies inside the convex polygon ``hull``
    (counter-clockwise), by a margin larger than rounding: its centre at least
    ``r`` inside every edge's line."""
    px, py = np.ascontiguousarray(hull[:, 0]), np.ascontiguousarray(hull[:, 1])
    length = np.hypot(np.roll(px, -1) - px, np.roll(py, -1) - py)
    step = max(1, _HULL_CHUNK // max(hull.shape[0], 1))
    out = np.empty(circles.shape[0], dtype=bool)
    for k in range(0, circles.shape[0], step):
        c = circles[k:k + step]
        sides = _edge_sides(px, py, c[:, 0], c[:, 1]) / np.where(length > 0, length, 1.0)[None, :]
        margin = c[:, 2] * (1.0 + 1e-9) + 1e-9 * (np.abs(c[:, 0]) + np.abs(c[:, 1]))
        out[k:k + step] = (sides >= margin[:, None]).all(axis=1)
    return out


#: the side of :func:`meshcore.tiles.block_order`'s cells, in point spacings, for the smooth surface
#: (measured on 125k random points: 4 spacings 0.04 s faster a tile than 2 or 32, and than the random order)
_BLOCK_SPACINGS = 4.0

#: points of other tiles' files tested together by :func:`_load_boxes` (bounds its memory)
_LOAD_BATCH = 1_000_000

_RING_SPACINGS = 0.6
"""How far a ring of Delaunay triangles reaches, in local point spacings
(one over the square root of the density); see :func:`_sparse_rim`."""

_RIM_BUFFERS = 4.0
"""The farthest a sparse rim is held from the first build, in buffers."""

_STEP_SPACINGS = 2.0
"""The least a tile's searches grow by, in mean spacings of the points it holds (see :attr:`_Certifying.step`)."""

_FIRST_REACH_BUFFERS = 8.0
"""How far beyond the box held whole (in buffers, at most a tile) a tile
first loads the points of the circles it cannot vouch for; twice as far each
round after.  A triangle across a void has a circle as wide as the void, and
the few points nearest to what is held usually break it: on a town of 4M
points, a tile's first search a tile wide loaded 794,000 points into one
circle of 695 m and meshed them in four builds of 1.1M points; from 8 buffers (42 m), it
loaded 65,000, and the mesh stage took 8.7-9.1 s instead of 11.8-12.6 s."""


def _load_boxes(job: TileJob, boxes: list, exclude: list) -> NDArray[np.float64]:
    """Points inside any of ``boxes``, read once from each tile that owns some,
    minus the points inside the boxes already held."""
    g = job.grid
    corners = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    union = (*corners[:, :2].min(axis=0), *corners[:, 2:].max(axis=0))
    # each tile's file cut to the boxes' union, then the other tests at once
    # over a batch of tiles (a void's search reads hundreds of small ones)
    out, parts, source, batch = [], [], [], 0
    for window_source in job.windows:  # read straight from the nodes that meet the boxes: each point once
        pts = points_in_boxes(window_source, boxes, exclude)
        if pts.shape[0]:
            out.append(pts)
    for r, c in g.tiles_meeting(corners):
        pts = neighbour_tile_points(job.scratch, r, c, job.run_id)
        if pts.shape[0] == 0:
            continue
        pts = np.compress(points_in_box(pts, union), pts, axis=0)
        if pts.shape[0]:
            parts.append(pts)
            source.append((r, c, pts.shape[0]))
            batch += pts.shape[0]
        if batch >= _LOAD_BATCH:
            out.append(_owned_in_boxes(g, parts, source, boxes, exclude))
            parts, source, batch = [], [], 0
    if parts:
        out.append(_owned_in_boxes(g, parts, source, boxes, exclude))
    return np.concatenate(out) if out else np.empty((0, 3))


def _owned_in_boxes(g: TileGrid, parts: list, source: list, boxes: list, exclude: list) -> NDArray[np.float64]:
    """The points of ``parts`` (read from the tiles ``source`` lists, with their
    counts) inside any of ``boxes`` and none of ``exclude``, each taken from its
    owner's file only (a tile's file also holds its neighbours' points within
    the buffer)."""
    pts = np.concatenate(parts)
    keep = np.zeros(pts.shape[0], dtype=bool)
    for box in boxes:
        keep |= points_in_box(pts, box)
    for held in exclude:
        keep &= ~points_in_box(pts, held)
    orow, ocol = g.owner(pts[:, 0], pts[:, 1])
    counts = [n for _, _, n in source]
    keep &= (orow == np.repeat([r for r, _, _ in source], counts)) & (ocol == np.repeat([c for _, c, _ in source], counts))
    return np.compress(keep, pts, axis=0)


def _start_points(job: TileJob, held: list) -> tuple[NDArray[np.float64], list, NDArray[np.float64], int]:
    """The tile's own points (its window plus buffer), what it counted of its
    window sources, and the points it meshes first: its own, the global hull's
    near it, and the bands along the survey's straight edges (their boxes join
    ``held``), with how many of those were read beyond the buffer."""
    g = job.grid
    own, counted = tile_points(job.scratch, job.windows, g, job.buffer, job.row, job.col, held[0])
    points = own
    if job.hull is not None and job.hull.shape[0]:
        # the ends of the global hull's edges that pass the tile make the tile's
        # hull the global one where it matters, so no part of its window is
        # left outside its triangulation
        hull = hull_near(job.hull, held[0])
        points = np.concatenate([own, hull[~points_in_box(hull, held[0])]])
    bands = _edge_bands(job, held[0])
    loaded = 0  # points read beyond the buffer
    if bands:
        extra = _load_boxes(job, bands, held)
        loaded += extra.shape[0]
        points = np.concatenate([points, extra])
        held.extend(bands)
    return own, counted, points, loaded


class _Certifying:
    """A tile's mesh while its piece is being certified: the points it holds,
    the boxes they fill (``held[0]`` the box held whole), the mesh of those
    points and, for the smooth surface once the faces are certified, its plan.

    ``meshed`` are the mesh's input points, in its order: ``points[:len(meshed)]``;
    the others were loaded since, and lie in no circle of its faces.
    """

    def __init__(self, job: TileJob, held: list, points: NDArray[np.float64], loaded: int, grown: float = 0.0) -> None:
        self.job = job
        self.window = job.grid.window(job.row, job.col)
        self.held = held
        self.points = points
        self.loaded = loaded
        self.expansions = 0
        self.hull_xy = np.empty((0, 2)) if job.hull is None else np.ascontiguousarray(job.hull[:, :2])
        self.smooth = job.options.surface == "smooth"
        self.mesh, self.meshed = self._build()
        # the smooth surface's long faces and kriging systems over ``mesh``, once
        # its faces are certified: every point held is then outside their
        # circles, and joins the mesh as a vertex that no face uses
        self.plan = None
        self.sampled = None  # with the plan: the faces that hold a centre of the grid, the only ones given nodes
        # what stays true while the mesh grows: its points' hull covering the
        # window (points are only ever added)
        self.covered = False
        self.grown = grown  # how far the box held whole grew beyond the buffer, for the certificate

    @property
    def step(self) -> float:
        """How far the searches grow at a time: the buffer (at least a cell),
        or :data:`_STEP_SPACINGS` mean spacings of the points held where that
        is more (a buffer set below a sparse survey's spacing): growing by a
        buffer at a time, a tile of a survey whose points lie 40 buffers
        apart meshed again dozens of times before it held a neighbour."""
        job, ext, box = self.job, self.job.extent, self.held[0]
        w = min(box[2], ext[2]) - max(box[0], ext[0])
        h = min(box[3], ext[3]) - max(box[1], ext[1])
        spacing = math.sqrt(max(w, 0.0) * max(h, 0.0) / max(self.points.shape[0], 1))
        return max(job.buffer, job.grid.resolution, _STEP_SPACINGS * spacing)

    def _build(self):
        """The mesh of ``points``, and the points in the order it was given them."""
        job, points = self.job, self.points
        if self.smooth:
            # near in the plane, near in memory: the smooth surface's kernels read every vertex's neighbours
            # (random file orders made them 10-20% slower); the mesh is the same in any order
            points = np.take(points, meshcore.tiles.block_order(points, _BLOCK_SPACINGS * job.variogram.spacing, self.held[0]), axis=0)
        mesh = meshcore.build_mesh(
            points[:, :2], job.options.triangle_measure, job.options.quad_measure, job.options.merge, window=self.window,
            known=_HeldRegion(self.held, self.hull_xy, job.extent), assume_rounds=job.assume_rounds,
        )
        return mesh, points

    def rebuild(self) -> None:
        """Mesh every point held again; the smooth plan starts over."""
        (self.mesh, self.meshed), self.plan = self._build(), None

    def _hold_as_vertices(self) -> None:
        """``mesh`` and ``meshed`` with the points loaded since the build as vertices that no face uses."""
        since = self.points[self.meshed.shape[0]:]
        self.mesh, self.meshed = meshcore.tiles.with_vertices(self.mesh, since[:, :2]), np.concatenate([self.meshed, since])

    def _hold(self, boxes: list) -> NDArray[np.float64]:
        """Load the points of ``boxes`` not held yet; the boxes count as held."""
        extra = _load_boxes(self.job, boxes, self.held)
        self.held.extend(boxes)
        return extra

    def open_circles(self) -> tuple[list, list, bool, bool]:
        """The circles (and the smooth plan's disks) not yet vouched for, the
        boxes to load for them this round, whether the mesh still leaves a gap
        in the window, and whether this round's reach spans the survey."""
        g, ext, held = self.job.grid, self.job.extent, self.held
        # circles not yet vouched for; their points are loaded from near to
        # far (a sliver's circle can span the survey, though a few nearby
        # points usually break it)
        circles = []
        requests = []
        reach = min(g.tile_size, _FIRST_REACH_BUFFERS * self.step) * 2.0**self.expansions
        near = (held[0][0] - reach, held[0][1] - reach, held[0][2] + reach, held[0][3] + reach)
        everywhere = near[0] <= ext[0] and near[1] <= ext[1] and near[2] >= ext[2] and near[3] >= ext[3]
        wanted = self.mesh.window_escapes
        if self.plan is not None:  # the smoother's neighbourhoods must be held too
            wanted = np.concatenate([wanted, _open_disks(self.plan.disks, held[0])])
        for i, rest in _open_lenses(wanted, self.hull_xy, ext, held):
            circles.append(tuple(wanted[i]))
            requests.extend(b for b in (intersect_boxes(p, near) for p in rest) if b is not None)
        corners = np.empty((0, 2)) if self.covered else _uncovered_corners(self.meshed[:, :2], self.window, self.hull_xy)
        self.covered = corners.shape[0] == 0
        gap = not self.covered
        if gap:
            # points beyond a void: looked for around the corners left out, a
            # buffer away, then twice as far each time (a box of a tile's size
            # around what is held loaded most of a town's survey for one
            # building over a corner)
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            around = _grown_box((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
                                self.step * 2.0**self.expansions, ext)
            requests.extend(_uncovered(around, held))
            everywhere = everywhere and all(math.isinf(v) for v in around)
        return circles, requests, gap, everywhere

    def hold_doubt(self) -> None:
        """The flips and merges of the window's faces read triangles the tile may not have as the
        survey has them: hold the circles their doubt came from, with a :attr:`step` around each (doubt
        from the rim of what is held spreads a few rings a round), and a wider box where it came
        from a hull edge of the tile's points; then mesh again."""
        job, ext, held = self.job, self.job.extent, self.held
        cert = self.mesh.certificate
        step = self.step
        margin = step * 2.0 ** min(self.expansions, 4)  # a chain of voids: ever more margin
        wants = [] if cert.open_edges else [
            (max(ext[0], b[0] - margin), max(ext[1], b[1] - margin), min(ext[2], b[2] + margin),
             min(ext[3], b[3] + margin))
            for b in _disk_boxes_in_hull(cert.blocking, self.hull_xy, ext) if b is not None
        ]
        fresh = _merge_boxes([part for want in wants for part in _uncovered(want, held)])
        if not fresh:
            wider = _grown_box(held[0], max(step, self.grown), ext)
            if wider == held[0]:
                raise SeamError(
                    f"tile ({job.row}, {job.col}): its piece cannot be certified although it holds every "
                    "point of the survey (its flips or merges read triangles it does not have)"
                )
            self.grown += max(step, self.grown)
            fresh = _uncovered(wider, held)
        else:
            wider = held[0]
            self.grown = max(self.grown, _beyond(fresh, held[0]))
        self.expansions += 1
        extra = self._hold(fresh) if fresh else np.empty((0, 3))
        held[0] = wider  # after the load, which reads only what was not held
        self.loaded += extra.shape[0]
        self.points = np.concatenate([self.points, extra])
        self.rebuild()

    def plan_smooth(self) -> None:
        """The smooth surface's plan over the certified faces that hold a centre of the grid."""
        g = self.job.grid
        self._hold_as_vertices()
        self.sampled = meshcore.tiles.sampled_faces(self.mesh, g.x0, g.y0, g.resolution, g.nx, g.ny)
        self.plan = meshcore.tiles.smooth_plan(self.mesh, self.job.variogram, faces=self.sampled)

    def load_open(self, requests: list, circles: list, gap: bool) -> None:
        """Load the points of ``requests`` for the open ``circles`` (or the
        ``gap``), and mesh again, or extend the plan, as they require."""
        extra = self._hold(_merge_boxes(requests))
        if extra.shape[0] == 0:
            return
        self.loaded += extra.shape[0]
        # kept even when no circle holds it: its box now counts as held, so a
        # circle of a later build that reaches it is vouched for by it
        self.points = np.concatenate([self.points, extra])
        if self.plan is not None and not gap:
            # the faces' circles are held, and the points lie outside what was
            # held: vertices, kriged from where a disk holds them
            self._hold_as_vertices()
            self.plan = meshcore.tiles.smooth_plan(self.mesh, self.job.variogram, previous=self.plan)
        elif gap or _any_in_circles(extra, np.array(circles).reshape(-1, 3)):
            # a loaded point lies in a circle, or may close the gap: build again
            self.rebuild()


def _certify(work: _Certifying) -> None:
    """Load points and mesh again until every circle of the window's faces is
    vouched for, the window is covered, the flips' certificate holds and, for
    the smooth surface, every kriging disk is held too."""
    job = work.job
    while True:
        circles, requests, gap, everywhere = work.open_circles()
        if not (circles or gap):
            if not work.mesh.certificate.certified:
                work.hold_doubt()
                continue
            if work.smooth and work.plan is None:
                work.plan_smooth()
                continue
            return
        work.expansions += 1
        if not requests:
            if everywhere:
                # every point that could lie in the circles is held: only a bug gets here
                raise SeamError(
                    f"tile ({job.row}, {job.col}): its piece cannot be certified although it holds every point "
                    f"its {len(circles)} open circle(s) or neighbourhood(s) reach (gap in its window: {gap})"
                )
            continue  # what is missing lies farther than this round reaches
        work.load_open(requests, circles, gap)


@dataclass(frozen=True)
class _PieceTables:
    """A certified mesh as the tile's piece: vertex heights, the vertex order of
    the piece's table and the map to it, the faces in it, and what the tile owns."""

    z: NDArray[np.float64]
    order: NDArray[np.int64]
    remap: NDArray[np.int32]
    faces: NDArray[np.int32]
    points_owned: int
    vertices_owned: int


def _piece_tables(job: TileJob, mesh: meshcore.Mesh, meshed: NDArray[np.float64], own: NDArray[np.float64]) -> _PieceTables:
    g = job.grid
    xy = mesh.vertices
    z = vertex_z(mesh.input_to_vertex, xy.shape[0], meshed[:, 2], job.options.duplicates)

    orow, ocol = g.owner(xy[:, 0], xy[:, 1])
    owned = (orow == job.row) & (ocol == job.col)
    # counted in the tile's own points: a hull point can be added twice, and
    # every point the tile owns is among its own
    porow, pocol = g.owner(own[:, 0], own[:, 1])
    points_owned = int(np.count_nonzero((porow == job.row) & (pocol == job.col)))
    vertices_owned = int(np.count_nonzero(owned))

    # the piece's vertex table: the vertices it owns first, sorted by
    # coordinates (their global node ids follow that order, and the store's
    # nodes are these rows), then the others its faces use, in index order
    n = xy.shape[0]
    owned_order = np.flatnonzero(owned)
    # rows of (n, k) arrays are gathered with np.take: ten times faster than xy[index]
    owned_order = owned_order[meshcore.tiles.lexicographic_order(np.take(xy, owned_order, axis=0))]
    # one slot past the vertices stands for the -1 of a triangle's 4th corner
    used_mask = np.zeros(n + 1, dtype=bool)
    used_mask[mesh.faces.ravel()] = True
    order = np.concatenate([owned_order, np.flatnonzero(used_mask[:n] & ~owned)])
    remap = np.full(n + 1, -1, dtype=np.int32)
    remap[order] = np.arange(order.size, dtype=np.int32)
    faces = remap[mesh.faces]
    return _PieceTables(z, order, remap, faces, points_owned, vertices_owned)


def _save_piece_and_border(job: TileJob, work: _Certifying, tables: _PieceTables, own: NDArray[np.float64]) -> NDArray[np.float64]:
    """Save the piece and its faces that leave the tile's box (``border``);
    returns the border's vertices."""
    mesh, faces = work.mesh, tables.faces
    vertices = np.column_stack([np.take(mesh.vertices, tables.order, axis=0), tables.z[tables.order]])
    # the smooth surface's arrays: from the neighbourhoods held, the same in every tile
    surface = {}
    if work.smooth:
        surface = _piece_surface(meshcore.smooth_surface(mesh, tables.z, job.variogram, plan=work.plan), mesh.faces,
                                 tables.z, tables.remap, work.sampled)
    piece = Piece(vertices=vertices, faces=faces, **surface)
    counts = _point_counts(job, own) if "point_count" in job.options.layers else np.zeros((0, 0), dtype=np.int32)
    replace(piece, point_count=counts).save(job.scratch, job.row, job.col, PiecePart.PIECE)
    border = piece.select(_reaching_out(vertices, faces, job.grid.box(job.row, job.col)))
    border.save(job.scratch, job.row, job.col, PiecePart.BORDER)
    return border.vertices


def mesh_tile(job: TileJob) -> TileSummary:
    """Mesh one tile's piece and save it to the scratch folder."""
    t0 = time.perf_counter()
    held = [held_box(job.grid, job.row, job.col, job.buffer)]
    own, counted, points, loaded = _start_points(job, held)
    more, grown = _held_from_the_start(job, own, held[0])
    if more:
        extra = _load_boxes(job, more, held)
        loaded += extra.shape[0]
        points = np.concatenate([points, extra])
        # meshed again: the box held first grew from this tile's box, so holds it (every point in it is loaded now)
        held = list(more) if job.held_before is not None else [*held, *more]
    work = _Certifying(job, held, points, loaded, grown)
    _certify(work)
    tables = _piece_tables(job, work.mesh, work.meshed, own)
    border_v = _save_piece_and_border(job, work, tables, own)
    faces = tables.faces
    return TileSummary(
        row=job.row,
        col=job.col,
        points_owned=tables.points_owned,
        vertices_owned=tables.vertices_owned,
        duplicates=tables.points_owned - tables.vertices_owned,
        faces=int(faces.shape[0]),
        quads=int(np.count_nonzero(faces[:, 3] >= 0)),
        expansions=work.expansions,
        certified=True,
        points_held=int(own.shape[0]),
        points_loaded=work.loaded,
        window_counts=tuple((c.path, c.read, c.filtered_class, c.filtered_withheld, c.outside_bbox, c.kept) for c in counted),
        seconds=time.perf_counter() - t0,
        held=tuple(tuple(float(v) for v in box) for box in work.held),
        last_flip_round=work.mesh.certificate.last_flip_round,
        flip_blocks=tuple(tuple(int(v) for v in row) for row in work.mesh.certificate.flip_blocks),
        flip_blocks_box=tuple(float(v) for v in work.mesh.certificate.flip_blocks_box),
        assumed_rounds=job.assume_rounds,
        grown=work.grown,
        reach=None if border_v.shape[0] == 0 else (
            *(float(v) for v in border_v[:, :2].min(axis=0)), *(float(v) for v in border_v[:, :2].max(axis=0))
        ),
    )


def _point_counts(job: TileJob, own: NDArray[np.float64]) -> NDArray[np.int32]:
    g = job.grid
    r0, r1, c0, c1 = g.cell_slice(job.row, job.col)
    i = np.floor((own[:, 0] - g.x0) / g.resolution).astype(np.int64) - c0
    j = np.floor((own[:, 1] - g.y0) / g.resolution).astype(np.int64) - r0
    ok = (i >= 0) & (i < c1 - c0) & (j >= 0) & (j < r1 - r0)
    counts = np.zeros((r1 - r0, c1 - c0), dtype=np.int32)
    np.add.at(counts, (j[ok], i[ok]), 1)
    return counts


def _open_disks(disks: NDArray[np.float64], box) -> NDArray[np.float64]:
    """The kriging disks ``(x, y, r)`` not inside ``box``, each radius rounded
    up (the disk is closed: a point on it may be the last neighbour)."""
    if disks.shape[0] == 0:
        return disks
    x, y, radius = disks[:, 0], disks[:, 1], disks[:, 2]
    r = radius * (1.0 + 1e-9) + 8 * _U * (np.abs(x) + np.abs(y) + radius)
    inside = (x - r >= box[0]) & (y - r >= box[1]) & (x + r <= box[2]) & (y + r <= box[3])
    return np.column_stack([x[~inside], y[~inside], r[~inside]])


def _reaching_out(vertices, faces, box) -> NDArray[np.bool_]:
    """Which faces reach outside the tile's box (its neighbours' DEM needs them)."""
    if faces.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    return _corner_outside(~points_in_box(vertices, box), faces)


@meshcore.kernels.kernel
def _corner_outside(outside, faces):
    """Whether any corner of each face (-1: no fourth corner) is ``outside``: one pass over the faces."""
    out = empty(faces.shape[0], dtype=np.bool_)
    for i in range(faces.shape[0]):
        d = faces[i, 3]
        out[i] = outside[faces[i, 0]] | outside[faces[i, 1]] | outside[faces[i, 2]] | ((d >= 0) and outside[d])
    return out


def _piece_surface(surface: meshcore.SmoothSurface, faces: NDArray[np.int64], z: NDArray[np.float64],
                   remap: NDArray[np.int32], sampled: NDArray[np.bool_]) -> dict[str, NDArray]:
    """A tile's smooth surface as its piece saves it, beside the faces ``faces``
    (over vertices with values ``z``, renumbered to the piece's by ``remap``),
    of which those ``sampled`` have nodes.

    ``noded``: those faces' rows, ``nodes``: their nodes (a face cut: its
    first triangle's); ``cut_faces``, ``cut_parent``, ``cut_nodes``: the
    triangles of the faces cut, each face's first triangle first, their
    corners numbered past the piece's vertices for the points ``added``
    (x, y, z).  The nodes are single-precision deviations from the linear
    surface (half the bytes), restored bit-identically on both sides of every
    edge by :func:`_local_mesh`.
    """
    n_f, n_v = faces.shape[0], z.shape[0]
    noded = np.flatnonzero(sampled)
    rows = meshcore.tiles.cut_face_rows(surface.parent, n_f)
    # a face kept has the same corners and values in both meshes: the same deviations
    wanted = np.concatenate([noded, rows])
    deviations = meshcore.tiles.node_deviations(np.take(surface.mesh.faces, wanted, axis=0), surface.z,
                                          np.take(surface.nodes, wanted, axis=0))
    corners = surface.mesh.faces[rows, :3].astype(np.int64)
    old = corners < n_v
    corners[old] = remap[corners[old]]
    corners[~old] += int(np.count_nonzero(remap[:n_v] >= 0)) - n_v
    return {
        "nodes": deviations[:noded.size],
        "noded": noded.astype(np.int32),
        "cut_faces": corners.astype(np.int32),
        "cut_parent": surface.parent[rows].astype(np.int32),
        "cut_nodes": deviations[noded.size:],
        "added": np.column_stack([surface.mesh.vertices[n_v:], surface.z[n_v:]]),
    }


def _local_mesh(job: TileJob) -> tuple[meshcore.Mesh, NDArray[np.float64], NDArray[np.int8], meshcore.SmoothSurface | None]:
    """The faces of this tile and its neighbours that overlap the tile's cells
    (smooth surface: those of them that have nodes, the only ones that hold a
    cell centre), as one mesh, with z, the faces' kinds and (smooth surface)
    the surface over them."""
    g = job.grid
    box = g.box(job.row, job.col)
    smooth = job.options.surface == "smooth"
    parts = []
    # the tile's own piece first: its faces need no shift
    around = job.reaching if job.reaching is not None else reached_tiles(g, None, job.row, job.col)
    neighbours = [t for t in around if t != (job.row, job.col)]
    arrays = (*MESH_ARRAYS, *SURFACE_ARRAYS) if smooth else MESH_ARRAYS
    tiles = [(job.row, job.col), *neighbours]
    pieces = Piece.load_many(
        job.scratch, [(r, c, PiecePart.PIECE if k == 0 else PiecePart.BORDER) for k, (r, c) in enumerate(tiles)], arrays)
    for (r, c), piece in zip(tiles, pieces):
        f = piece.faces
        if f.shape[0] == 0:
            continue
        keep = None
        if (r, c) != (job.row, job.col):
            v = piece.vertices
            corner = np.maximum(f, 0)
            fx = np.where(f >= 0, np.take(v[:, 0], corner), np.nan)
            fy = np.where(f >= 0, np.take(v[:, 1], corner), np.nan)
            keep = (np.nanmax(fx, 1) >= box[0]) & (np.nanmin(fx, 1) <= box[2])
            keep &= (np.nanmax(fy, 1) >= box[1]) & (np.nanmin(fy, 1) <= box[3])
        if smooth:
            # the faces with nodes: those that hold a cell centre, so the only ones the DEM reads
            noded = np.zeros(f.shape[0], dtype=bool)
            noded[piece.noded] = True
            keep = noded if keep is None else keep & noded
        parts.append(piece if keep is None else piece.select(keep))
    if not parts:
        empty = meshcore.Mesh(np.empty((0, 2)), np.empty((0, 4), dtype=np.int64), np.empty(0, dtype=np.int64))
        z = np.empty(0)
        return empty, z, np.empty(0, dtype=np.int8), _smooth_surface(empty, z, parts) if smooth else None
    # a corner shared with a neighbour's face appears once per piece, with the
    # same coordinates and z: interpolation needs no merged vertex table
    offsets = np.cumsum([0] + [p.vertices.shape[0] for p in parts])
    v = np.concatenate([p.vertices for p in parts])
    faces = np.concatenate([np.where(p.faces >= 0, p.faces + o, -1) if o else p.faces for p, o in zip(parts, offsets)])
    kinds = np.concatenate([(p.faces[:, 3] >= 0).astype(np.int8) + 1 for p in parts])
    mesh = meshcore.Mesh(np.ascontiguousarray(v[:, :2]), faces, np.arange(v.shape[0]))
    z = np.ascontiguousarray(v[:, 2])
    # the faces in the pieces' order: a cell centre on an edge two faces share reads the face that comes
    # first by coordinates, whatever the order (meshcore.rasterize)
    return mesh, z, kinds, _smooth_surface(mesh, z, parts) if smooth else None


def _smooth_surface(mesh: meshcore.Mesh, z: NDArray[np.float64], parts: list[Piece]) -> meshcore.SmoothSurface:
    """The smooth surface over ``mesh`` (the faces of ``parts``, in order, every
    one with nodes), from the arrays of :func:`_piece_surface`: each face in
    its row (a face cut: its first triangle), then the other triangles of the
    faces cut."""
    n_v, n_f = z.shape[0], mesh.faces.shape[0]
    added = [np.asarray(p.added) for p in parts]
    tris, parent, cut_nodes = [], [], []
    vertex_offset, face_offset, added_offset = 0, 0, n_v
    for p, a in zip(parts, added):
        n_here = p.vertices.shape[0]
        if p.cut_parent.shape[0]:
            c = np.asarray(p.cut_faces, dtype=np.int64)
            tris.append(np.where(c < n_here, c + vertex_offset, c - n_here + added_offset))
            parent.append(np.asarray(p.cut_parent, dtype=np.int64) + face_offset)
            cut_nodes.append(np.asarray(p.cut_nodes))
        vertex_offset += n_here
        face_offset += p.faces.shape[0]
        added_offset += a.shape[0]
    deviations = (np.concatenate([p.nodes for p in parts]) if parts
                  else np.empty((0, meshcore.tiles.NODES_PER_FACE), dtype=np.float32))
    if not parent:  # nothing cut: the mesh's own faces
        return meshcore.SmoothSurface(mesh, z, meshcore.tiles.nodes_from_deviations(mesh.faces, z, deviations), np.arange(n_f))
    cut_parent = np.concatenate(parent)
    triangles = np.concatenate(tris)
    cut_faces = np.column_stack([triangles, np.full(triangles.shape[0], -1, dtype=np.int64)])
    faces, parents = meshcore.tiles.with_cut_faces(mesh.faces, cut_faces, cut_parent)
    rows, _ = meshcore.tiles.with_cut_faces(deviations, np.concatenate(cut_nodes), cut_parent)
    added_xyz = np.concatenate(added)
    vertices = np.concatenate([mesh.vertices, added_xyz[:, :2]])
    z_all = np.concatenate([z, added_xyz[:, 2]])
    refined = meshcore.Mesh(vertices, faces, np.arange(vertices.shape[0]))
    return meshcore.SmoothSurface(refined, z_all, meshcore.tiles.nodes_from_deviations(faces, z_all, rows), parents)


def dem_tile(job: TileJob) -> dict[str, NDArray]:
    """The DEM layers of one tile's cells (south-up), from the stitched faces
    around it and, for the products that read points, the points routed to it."""
    mesh, z, kinds, smooth = _local_mesh(job)
    settings = job.products or ProductSettings.for_run(job.options.layers, None, "all", cell=job.grid.resolution)
    ctx = TileContext(
        job.grid, job.row, job.col, settings, mesh=mesh, z=z, kinds=kinds,
        surface={"surface": job.options.surface if smooth is None else smooth}, height_scale=job.height_scale,
        max_edge=job.options.max_edge,
        load_points=lambda: from_product_rows(
            load_tile_points(job.scratch, job.row, job.col, PRODUCT_SPILL, product_row_width(settings.columns)),
            settings.columns,
        ),
        load_piece=lambda name: getattr(Piece.load(job.scratch, job.row, job.col, (name,)), name),
        load_dtm_points=lambda: from_columns(load_tile_points(job.scratch, job.row, job.col), ()),
    )
    return tile_layers(ctx, settings)


def load_kernels(job: TileJob) -> None:
    """Run the kernels of a tile's mesh and DEM once, on a few points of no
    tile, with the job's measures: a thread that the route stage leaves idle
    loads them from the compiled cache meanwhile (0.1 s of a one-file job), so
    the first tiles start at once.  Reads and writes nothing."""
    o = job.options
    load_mesh_kernels(o.triangle_measure, o.quad_measure, o.merge, o.surface)
    load_surface_kernels(o.max_edge, o.surface, o.layers)


def load_surface_kernels(max_edge: float | None, surface: str, layers: tuple[str, ...] = ()) -> None:
    """The DEM kernels of :func:`load_kernels` (and ``layers``'), and those a
    piece's faces reaching its neighbours need, on a mesh of three faces made
    here (so that they compile without the mesh kernels); with the smooth
    surface, the variogram's fit too."""
    vertices = np.array([[0.0, 0.0], [4.0, 0.0], [8.0, 0.0], [0.0, 4.0], [4.0, 4.0], [8.0, 5.0], [2.0, 8.0]])
    faces = np.array([[0, 1, 4, 3], [1, 2, 5, -1], [3, 4, 6, -1]])
    mesh = meshcore.Mesh(vertices, faces, np.arange(vertices.shape[0]))
    z = vertices[:, 0] * 0.1 + np.sin(vertices[:, 1])
    if surface != "smooth" or "face_kind" in layers:  # the linear surface's kernel: the DEM's, or the face kinds'
        meshcore.rasterize(mesh, z, 0.0, 0.0, 1.0, 8, 8, max_edge=max_edge)
    if surface == "smooth":  # the run's variogram is fitted (its sample merged) before the tiles
        meshcore.tiles.lexicographic_order(vertices)
        grid = sample_grid_mesh(8).vertices
        meshcore.fit_variogram(grid, grid[:, 0] * 0.1 + np.sin(grid[:, 1]), neighbours=meshcore.tiles.DEFAULT_NEIGHBOURS)
    # a piece's table of vertices (x, y, z) and its faces, as mesh_tile saves them
    table = np.column_stack([vertices, z])
    _reaching_out(table, faces.astype(np.int32), (0.0, 0.0, 4.0, 4.0))
    table.flags.writeable = False  # points as read back from the scratch folder
    points_in_box(table, (0.0, 0.0, 4.0, 4.0))
    if surface != "smooth":
        warm_up(tuple(layers))  # the products' own kernels (the slope's gradient)
    if surface == "smooth":
        nodes = meshcore.tiles.linear_nodes(mesh.faces, z)
        nodes = meshcore.tiles.nodes_from_deviations(mesh.faces, z, meshcore.tiles.node_deviations(mesh.faces, z, nodes))
        smooth = meshcore.SmoothSurface(mesh, z, nodes, np.arange(faces.shape[0]))
        meshcore.rasterize(mesh, z, 0.0, 0.0, 1.0, 8, 8, max_edge=max_edge, surface=smooth)
        meshcore.gradient(mesh, z, vertices[:3, 0], vertices[:3, 1], surface=smooth)
