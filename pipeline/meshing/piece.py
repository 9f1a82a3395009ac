"""A tile's piece of the global mesh, as the work folder keeps it.

The mesh stage saves, for each tile, the faces its window owns (the
``piece``) and those of them that reach outside its box (the ``border``, which
the tiles around it read for their grids).  Each array is one ``.npy`` file,
so that a local reader maps only the slices it reads.  The store's assembly
adds the global node ids of the piece's vertices (``node_ids``).

Every reader and writer of pieces goes through :class:`Piece`: the arrays are
its fields, and a part of a piece is loaded by naming the fields it needs.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from ..tiling.grid import tile_dir
from ..tiling.scratch import Scratch

__all__ = ["Piece", "PiecePart", "MESH_ARRAYS", "SURFACE_ARRAYS"]


class PiecePart(StrEnum):
    """What a tile saves of its mesh."""

    PIECE = "piece"
    """The faces its window owns, the vertices they use (those it owns first,
    sorted by coordinates) and its per-cell counts."""
    BORDER = "border"
    """Those of its faces that reach outside its box, for the grids of the tiles around it."""


MESH_ARRAYS = ("vertices", "faces")
"""The arrays of the faces themselves."""

SURFACE_ARRAYS = ("nodes", "noded", "cut_faces", "cut_parent", "cut_nodes", "added")
"""The smooth surface's arrays (see :func:`pipeline.meshing.tiles.dem_tile`)."""


@dataclass(frozen=True)
class Piece:
    """A tile's faces and what goes with them; a field not loaded (or not made
    by this run) is None."""

    vertices: NDArray[np.float64] | None = None
    """(n, 3): x, y, z of the vertices the faces use."""
    faces: NDArray[np.int32] | None = None
    """(m, 4): corners as rows of ``vertices``; -1 as the fourth corner of a triangle."""
    point_count: NDArray[np.int32] | None = None
    """The tile's points per grid cell (the ``point_count`` layer), or (0, 0)."""
    node_ids: NDArray[np.int64] | None = None
    """The global node id of each vertex, then -1 (the store's assembly writes it)."""
    nodes: NDArray[np.float32] | None = None
    """Smooth surface: the patch nodes of the faces ``noded``, as deviations from the linear surface."""
    noded: NDArray[np.int32] | None = None
    """Smooth surface: the rows of the faces with nodes (those that hold a cell centre)."""
    cut_faces: NDArray[np.int32] | None = None
    """Smooth surface: the triangles of the long faces cut, corners past the vertices for ``added``."""
    cut_parent: NDArray[np.int32] | None = None
    """Smooth surface: the face each of ``cut_faces`` was cut from."""
    cut_nodes: NDArray[np.float32] | None = None
    """Smooth surface: the nodes of ``cut_faces``."""
    added: NDArray[np.float64] | None = None
    """Smooth surface: x, y, z of the points added on the long faces' edges."""

    def save(self, scratch: Scratch, row: int, col: int, part: PiecePart) -> None:
        """Write the fields that are set, one ``.npy`` each."""
        folder = f"{tile_dir(row, col)}/{PiecePart(part)}"
        scratch.save_many({f"{folder}/{f.name}.npy": getattr(self, f.name) for f in fields(self)
                           if getattr(self, f.name) is not None})

    @classmethod
    def load(cls, scratch: Scratch, row: int, col: int, arrays: tuple[str, ...],
             part: PiecePart = PiecePart.PIECE) -> Piece:
        """The fields ``arrays`` of a saved piece, memory-mapped when local (copy-on-write)."""
        return cls.load_many(scratch, [(row, col, part)], arrays)[0]

    @classmethod
    def load_many(cls, scratch: Scratch, pieces: list[tuple[int, int, PiecePart]], arrays: tuple[str, ...]) -> list[Piece]:
        """:meth:`load` of several ``(row, col, part)`` at once (on object storage, in concurrent requests)."""
        _check(arrays)
        wanted = [f"{tile_dir(r, c)}/{PiecePart(part)}/{name}.npy" for r, c, part in pieces for name in arrays]
        loaded = iter(scratch.load_many(wanted, mmap=True))
        return [cls(**{name: next(loaded) for name in arrays}) for _ in pieces]

    @staticmethod
    def intact(scratch: Scratch, row: int, col: int, extra: tuple[str, ...] = ()) -> bool:
        """Whether every array the mesh stage saved for the tile (and the
        ``extra`` ones of its piece) is still in the work folder."""
        _check(extra)
        wanted = {PiecePart.PIECE: {*MESH_ARRAYS, "point_count", *extra}, PiecePart.BORDER: set(MESH_ARRAYS)}
        for part, names in wanted.items():
            if not {f"{name}.npy" for name in names} <= set(scratch.names(f"{tile_dir(row, col)}/{part}")):
                return False
        return True

    def select(self, keep: NDArray[np.bool_]) -> Piece:
        """The faces ``keep``, with the vertices they use (kept in index order)
        and the faces renumbered to them; a missing fourth corner (-1) stays
        -1.  The nodes and the cut faces' triangles follow their faces; every
        added point is kept."""
        assert self.faces is not None and self.vertices is not None
        faces = np.compress(keep, self.faces, axis=0)
        used, inverse = np.unique(faces, return_inverse=True)  # -1 first when present
        has_gap = used.size > 0 and used[0] < 0
        used = used[int(has_gap):]
        out = Piece(vertices=np.take(self.vertices, used, axis=0), faces=inverse.reshape(faces.shape) - int(has_gap))
        row = np.cumsum(keep, dtype=np.int64) - 1  # a face kept: its row among those kept
        if self.nodes is not None and self.noded is not None:  # the faces with nodes among those kept
            noded = np.asarray(self.noded)
            mine = keep[noded]
            out = replace(out, nodes=np.compress(mine, self.nodes, axis=0),
                          noded=row[np.compress(mine, noded)].astype(np.int32))
        if self.cut_parent is not None:
            n_v = self.vertices.shape[0]
            mine = keep[self.cut_parent]
            corners = np.compress(mine, self.cut_faces, axis=0).astype(np.int64)
            old = corners < n_v  # a corner of the face cut (so among ``used``), else an added point
            corners[old] = np.searchsorted(used, corners[old])
            corners[~old] += used.size - n_v
            out = replace(out, cut_faces=corners.astype(np.int32),
                          cut_parent=row[np.compress(mine, self.cut_parent)].astype(np.int32),
                          cut_nodes=np.compress(mine, self.cut_nodes, axis=0), added=np.asarray(self.added))
        return out


_FIELDS = {f.name for f in fields(Piece)}


def _check(arrays: tuple[str, ...]) -> None:
    unknown = [name for name in arrays if name not in _FIELDS]
    if unknown:
        raise ValueError(f"not arrays of a piece: {unknown}")
