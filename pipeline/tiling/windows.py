"""COPC inputs read by window, tile by tile, instead of being routed.

A COPC file in the run's CRS is never streamed into spill files: each tile
task reads the octree nodes that meet the box its points come from (its
window grown by the buffer, within the bbox), and takes from them exactly the
points routing would have given it (:func:`pipeline.tiling.routing.route_points`).
The tile tasks need no shared work folder for these files, and each fetches
only the bytes of the nodes it needs (ranged requests over HTTP and S3).

What routing learnt of a file in its single pass is learnt otherwise:

- its convex hull (every tile meshes with the global hull) by
  :func:`survey_hull`, which reads the octree level by level and skips every
  node inside the hull of the points read so far: the boundary's nodes only;
- its counts for the report (points read, filtered, kept) from the tiles:
  each node is counted by one tile, the one owning its centre (clamped into
  the bbox), which is among the tiles that read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .scratch import Scratch
from ..inputs.sources import PointFilter, file_digest, iter_copc_nodes
from .grid import TileGrid
from .routing import POINT_FATES, PointCounts, RouteResult, grow_hull, load_tile_points, points_in_box, route_points, spill_by_source

__all__ = [
    "WindowSource", "WindowCounts", "hull_copies", "points_in_boxes", "survey_hull", "tile_points", "window_points",
]

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class WindowSource:
    """A COPC input that tiles read by window (picklable: it crosses to workers)."""

    index: int
    path: str
    classes: tuple[int, ...] | None
    keep_withheld: bool
    bbox: Box | None

    @property
    def point_filter(self) -> PointFilter:
        return PointFilter(classes=None if self.classes is None else frozenset(self.classes),
                           keep_withheld=self.keep_withheld)


@dataclass(frozen=True)
class WindowCounts(PointCounts):
    """What one tile counted of one window source: the points of the nodes it owns."""

    def __add__(self, other: WindowCounts) -> WindowCounts:
        return WindowCounts(self.path, *(getattr(self, f) + getattr(other, f) for f in POINT_FATES))


def _margin(box: Box) -> float:
    """How far past ``box`` a node is still read: the rounding of voxel
    bounds and of the routing's own margins, with room to spare."""
    finite = [abs(v) for v in box if math.isfinite(v)]
    return 1e-9 * (max(finite, default=0.0) + 1.0)


def _query(box: Box, bbox: Box | None) -> Box | None:
    """``box`` grown by its margin, within ``bbox`` (grown too); None when they miss."""
    m = _margin(box)
    q = (box[0] - m, box[1] - m, box[2] + m, box[3] + m)
    if bbox is not None:
        mb = _margin(bbox)
        q = (max(q[0], bbox[0] - mb), max(q[1], bbox[1] - mb), min(q[2], bbox[2] + mb), min(q[3], bbox[3] + mb))
    if q[0] > q[2] or q[1] > q[3]:
        return None
    return q


def _in_bbox(x: NDArray, y: NDArray, bbox: Box | None) -> NDArray[np.bool_]:
    if bbox is None:
        return np.ones(x.shape, dtype=bool)
    return (x >= bbox[0]) & (x <= bbox[2]) & (y >= bbox[1]) & (y <= bbox[3])


def _node_owner(grid: TileGrid, bounds: Box, bbox: Box | None) -> tuple[int, int]:
    """The tile that counts a node: the owner of its centre, clamped into the bbox.

    That point lies in the node and in the bbox, so inside the owner's query:
    the owner reads the node.
    """
    cx = 0.5 * (bounds[0] + bounds[2])
    cy = 0.5 * (bounds[1] + bounds[3])
    if bbox is not None:
        cx = min(max(cx, bbox[0]), bbox[2])
        cy = min(max(cy, bbox[1]), bbox[3])
    rows, cols = grid.owner(np.array([cx]), np.array([cy]))
    return int(rows[0]), int(cols[0])


def window_points(
    source: WindowSource, grid: TileGrid, buffer: float, row: int, col: int, box: Box
) -> tuple[NDArray[np.float64], WindowCounts]:
    """The points of ``source`` routing would give tile (row, col), whose
    points come from ``box`` (its window grown by the buffer), and the counts
    of the nodes this tile owns."""
    counts = WindowCounts(source.path)
    query = _query(box, source.bbox)
    if query is None:
        return np.empty((0, 3)), counts
    parts = []
    for node in iter_copc_nodes(source.path, source.point_filter, window=query):
        p = node.points
        inside = _in_bbox(p.x, p.y, source.bbox)
        if _node_owner(grid, node.bounds, source.bbox) == (row, col):
            kept = int(np.count_nonzero(inside))
            counts = counts + WindowCounts(source.path, p.read, p.filtered_class, p.filtered_withheld, p.kept - kept, kept)
        if p.kept:
            parts.append((node.offset, np.column_stack([p.x[inside], p.y[inside], p.z[inside]])))
    if not parts:
        return np.empty((0, 3)), counts
    parts.sort(key=lambda part: part[0])  # file order, as a streaming read meets them
    points = np.concatenate([a for _, a in parts])
    return route_points(grid, buffer, points, row, col), counts


def tile_points(
    scratch: Scratch, windows: tuple[WindowSource, ...], grid: TileGrid, buffer: float, row: int, col: int, box: Box
) -> tuple[NDArray[np.float64], list[WindowCounts]]:
    """Every point of tile (row, col), whose points come from ``box``: the
    spill files of routed sources and the nodes of ``windows``, source after
    source in input order (as routing alone would give them), and what the
    tile counted of each window source."""
    if not windows:
        return load_tile_points(scratch, row, col), []
    by_source = spill_by_source(scratch, row, col)
    counts = []
    for source in windows:
        by_source[source.index], counted = window_points(source, grid, buffer, row, col, box)
        counts.append(counted)
    parts = [by_source[k] for k in sorted(by_source) if by_source[k].shape[0]]
    return (np.concatenate(parts) if parts else np.empty((0, 3))), counts


def points_in_boxes(source: WindowSource, boxes: list[Box], exclude: list[Box]) -> NDArray[np.float64]:
    """The kept points of ``source`` inside any of ``boxes`` (closed) and
    none of ``exclude``, each once, in file order: only the nodes that meet
    one of the boxes are read."""
    corners = np.array(boxes, dtype=np.float64).reshape(-1, 4)
    query = _query((*corners[:, :2].min(axis=0), *corners[:, 2:].max(axis=0)), source.bbox)
    if query is None:
        return np.empty((0, 3))

    def wanted(level: int, bounds: Box) -> bool:
        m = _margin(bounds)
        return bool(np.any((corners[:, 0] <= bounds[2] + m) & (corners[:, 2] >= bounds[0] - m)
                           & (corners[:, 1] <= bounds[3] + m) & (corners[:, 3] >= bounds[1] - m)))

    parts = []
    for node in iter_copc_nodes(source.path, source.point_filter, window=query, wanted=wanted):
        p = node.points
        if not p.kept:
            continue
        pts = np.column_stack([p.x, p.y, p.z])
        keep = np.zeros(p.kept, dtype=bool)
        for box in boxes:
            keep |= points_in_box(pts, box)
        keep &= _in_bbox(p.x, p.y, source.bbox)
        for held in exclude:
            keep &= ~points_in_box(pts, held)
        if np.any(keep):
            parts.append((node.offset, pts[keep]))
    parts.sort(key=lambda part: part[0])
    return np.concatenate([a for _, a in parts]) if parts else np.empty((0, 3))


def hull_copies(source: WindowSource, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Every kept point of ``source`` at one of the positions ``xy`` (n, 2),
    in file order: only the nodes whose voxel holds one of them are read."""
    if xy.shape[0] == 0:
        return np.empty((0, 3))
    order = np.argsort(xy[:, 0], kind="stable")
    sx = xy[order, 0]

    def wanted(level: int, bounds: Box) -> bool:
        m = _margin(bounds)
        lo = int(np.searchsorted(sx, bounds[0] - m, side="left"))
        hi = int(np.searchsorted(sx, bounds[2] + m, side="right"))
        ys = xy[order[lo:hi], 1]
        return bool(np.any((ys >= bounds[1] - m) & (ys <= bounds[3] + m)))

    key = xy[:, 0] + 1j * xy[:, 1]
    parts = []
    for node in iter_copc_nodes(source.path, source.point_filter, wanted=wanted):
        p = node.points
        at = np.isin(p.x + 1j * p.y, key) & _in_bbox(p.x, p.y, source.bbox)
        if np.any(at):
            parts.append((node.offset, np.column_stack([p.x[at], p.y[at], p.z[at]])))
    parts.sort(key=lambda part: part[0])
    return np.concatenate([a for _, a in parts]) if parts else np.empty((0, 3))


def survey_hull(source: WindowSource) -> RouteResult:
    """What a routing pass records of a file, for a window source: its kept
    points' convex hull (every copy of each hull point, for its z) and
    bounds, and its identity; no spill files.

    The octree is read level by level from the root; a node whose voxel lies
    inside the hull of the points read so far holds no point of the final
    hull, and is skipped with all its descendants.
    """
    hull = np.empty((0, 3))
    state = {"hull": hull}

    def wanted(level: int, bounds: Box) -> bool:
        return not _inside_hull(state["hull"], bounds)

    for node in iter_copc_nodes(source.path, source.point_filter, wanted=wanted):
        p = node.points
        inside = _in_bbox(p.x, p.y, source.bbox)
        if np.any(inside):
            state["hull"] = grow_hull(state["hull"], p.x[inside], p.y[inside], p.z[inside])
    hull = state["hull"]
    bounds = None
    if hull.shape[0]:
        bounds = (float(hull[:, 0].min()), float(hull[:, 1].min()), float(hull[:, 0].max()), float(hull[:, 1].max()))
    return RouteResult(source.path, bounds=bounds, sha256=file_digest(source.path), window=True, hull=hull)


def _inside_hull(hull: NDArray[np.float64], bounds: Box) -> bool:
    """Whether the box ``bounds`` (grown by its margin) lies strictly inside
    the convex polygon ``hull`` (counter-clockwise): then every point in it
    is inside the hull of any superset, never on it."""
    if hull.shape[0] < 3:
        return False
    m = _margin(bounds)
    corners = np.array([[bounds[0] - m, bounds[1] - m], [bounds[2] + m, bounds[1] - m],
                        [bounds[2] + m, bounds[3] + m], [bounds[0] - m, bounds[3] + m]])
    a = hull[:, :2]
    a = a[np.any(a != np.roll(a, -1, axis=0), axis=1)]  # repeated points make no edge
    if a.shape[0] < 3:
        return False
    b = np.roll(a, -1, axis=0)
    edge = b - a
    # the cross product of each edge with each corner, against a tolerance of its own rounding
    rel = corners[None, :, :] - a[:, None, :]
    cross = edge[:, None, 0] * rel[:, :, 1] - edge[:, None, 1] * rel[:, :, 0]
    scale = (np.abs(edge[:, None, 0] * rel[:, :, 1]) + np.abs(edge[:, None, 1] * rel[:, :, 0]))
    return bool(np.all(cross > 1e-9 * scale + 1e-300))
