"""The global mesh from the tiles' pieces: node ids, and blocks of the store's arrays.

Every tile owns the nodes in its half-open window; a node's global id is its
owner tile's offset (tiles in row-major order) plus its rank in that tile's
table of owned points, sorted by coordinates.  Each task here works on the
scratch folder and the store alone, so the runner can spread them over Dask
workers: :func:`global_node_ids` finds the global id of every vertex of one
piece, and :func:`write_mesh_block` writes rows of whole chunks of the nodes
or faces (renumbering the faces' corners on the way).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

import meshcore
from meshcore.kernels import empty

from . import zarr_store as store
from ..errors import PipelineError
from ..tiling.scratch import Scratch
from ..meshing.piece import Piece, PiecePart
from ..meshing.tiles import TileJob, TileSummary
from ..tiling.grid import TileGrid

__all__ = ["mesh_offsets", "global_node_ids", "MeshBlock", "write_mesh_block"]


def mesh_offsets(grid: TileGrid, summaries: list[TileSummary]) -> tuple[np.ndarray, np.ndarray]:
    """Where each tile's nodes and faces start in the global arrays (tiles in row-major order)."""
    by_tile = {(s.row, s.col): s for s in summaries}
    order = grid.tiles()
    node_offsets = np.zeros(len(order) + 1, dtype=np.int64)
    face_offsets = np.zeros(len(order) + 1, dtype=np.int64)
    for k, key in enumerate(order):
        node_offsets[k + 1] = node_offsets[k] + by_tile[key].vertices_owned
        face_offsets[k + 1] = face_offsets[k] + by_tile[key].faces
    return node_offsets, face_offsets


def global_node_ids(job: TileJob, node_offsets: np.ndarray) -> None:
    """Save the global node id of every vertex of a piece, for the writer to
    renumber the piece's face corners with.

    A node's id is its owner tile's offset plus its rank in that tile's sorted
    table of owned points; every tile computes the same id for a shared node.
    A piece's vertex table starts with the vertices it owns, in that order;
    the others (near its edges) are looked up in their owners' tables.
    """
    grid = job.grid
    scratch = job.scratch
    v = Piece.load(scratch, job.row, job.col, ("vertices",)).vertices
    here = job.row * grid.n_cols + job.col
    owned = int(node_offsets[here + 1] - node_offsets[here])
    # the slot past the vertices stands for the -1 of a triangle's 4th corner
    gid = np.empty(v.shape[0] + 1, dtype=store.face_index_dtype(int(node_offsets[-1])))
    gid[:owned] = node_offsets[here] + np.arange(owned)
    gid[-1] = -1
    if v.shape[0] > owned:
        fx = np.ascontiguousarray(v[owned:, 0])
        fy = np.ascontiguousarray(v[owned:, 1])
        orow, ocol = grid.owner(fx, fy)
        owner = orow * grid.n_cols + ocol
        for number in np.unique(owner).tolist():
            sel = owner == number
            r, c = divmod(number, grid.n_cols)
            # a binary search in the (memory-mapped) table reads a few of its pages, not all
            table = Piece.load(scratch, r, c, ("vertices",)).vertices[: node_offsets[number + 1] - node_offsets[number]]
            idx = _sorted_rows(table, fx[sel], fy[sel])
            if number == here or np.any(idx < 0):
                raise PipelineError(f"tile {(job.row, job.col)}: a face corner is not owned by tile {(r, c)}")
            gid[owned + np.flatnonzero(sel)] = node_offsets[number] + idx
    Piece(node_ids=gid).save(scratch, job.row, job.col, PiecePart.PIECE)


@meshcore.kernels.kernel
def _sorted_rows(table: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.int64]:
    """Row of each point ``(x[i], y[i])`` in ``table`` (n, 2 or more: x, y, ...),
    sorted by x then y (a tile's owned vertices), or -1 where it is not there."""
    n = table.shape[0]
    out = empty(x.shape[0], dtype=np.int64)
    for i in range(x.shape[0]):
        lo, hi = 0, n
        while lo < hi:  # the first row not below the point
            mid = (lo + hi) >> 1
            if table[mid, 0] < x[i] or (table[mid, 0] == x[i] and table[mid, 1] < y[i]):
                lo = mid + 1
            else:
                hi = mid
        out[i] = lo if lo < n and table[lo, 0] == x[i] and table[lo, 1] == y[i] else -1
    return out


@dataclass(frozen=True)
class MeshBlock:
    """Rows ``[start, stop)`` of the mesh's node or face arrays, gathered from
    the tiles' pieces (whole chunks, so blocks write in parallel without locks)."""

    output: str
    scratch: Scratch
    tiles: tuple[tuple[int, int], ...]
    offsets: tuple[int, ...]
    what: str
    start: int
    stop: int

    def spans(self) -> list[tuple[int, int, int]]:
        """``(k, lo, hi)``: the rows ``[lo, hi)`` of the block that tile ``self.tiles[k]`` holds."""
        offsets = self.offsets
        first = int(np.searchsorted(offsets, self.start, side="right")) - 1
        out = []
        for k in range(first, len(self.tiles)):
            lo, hi = max(self.start, int(offsets[k])), min(self.stop, int(offsets[k + 1]))
            if lo >= self.stop:
                break
            if lo < hi:
                out.append((k, lo, hi))
        return out


def write_mesh_block(block: MeshBlock) -> tuple[str, int, int]:
    """Gather the block's rows from the pieces of the tiles they span and write
    them; returns (what, start, stop) for the runner to record.  A block of
    faces reads the global node ids that :func:`global_node_ids` gave those tiles."""
    offsets = np.asarray(block.offsets)
    parts = []
    for k, lo, hi in block.spans():
        arrays = ("vertices",) if block.what == "nodes" else ("faces", "node_ids")
        piece = Piece.load(block.scratch, *block.tiles[k], arrays)
        rows = slice(lo - offsets[k], hi - offsets[k])
        if block.what == "nodes":
            parts.append(np.asarray(piece.vertices[rows]))
        else:
            ids = np.asarray(piece.node_ids)
            faces = np.empty((hi - lo, 4), dtype=ids.dtype)
            _renumber(ids, np.asarray(piece.faces[rows]), faces)
            parts.append(faces)
    writer = store.MeshWriter.attach(block.output)
    if block.what == "nodes":
        xyz = np.concatenate(parts)
        writer.write_nodes(block.start, xyz[:, 0], xyz[:, 1], xyz[:, 2])
    else:
        writer.write_faces(block.start, np.concatenate(parts))
    return block.what, block.start, block.stop


@meshcore.kernels.kernel
def _renumber(node_ids: NDArray[np.integer], faces: NDArray[np.integer], out: NDArray[np.integer]) -> None:
    """``out[i, k] = node_ids[faces[i, k]]``: a piece's face corners as global
    node ids; a missing 4th corner (-1) takes the slot past the vertices (-1)."""
    last = node_ids.shape[0] - 1
    for i in range(faces.shape[0]):
        for k in range(4):
            f = faces[i, k]
            if f >= last:
                raise IndexError("a face corner past the piece's vertices")
            out[i, k] = node_ids[f if f >= 0 else last]
