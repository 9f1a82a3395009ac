"""The typed piece a tile saves: what is saved is what is loaded, a part of
it is loaded by naming its fields, and a selection keeps its faces whole."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.meshing.piece import Piece, PiecePart
from pipeline.tiling.scratch import Scratch


def _square_piece() -> Piece:
    # two triangles and a quadrangle over six vertices
    vertices = np.array([[0, 0, 1], [1, 0, 2], [2, 0, 3], [0, 1, 4], [1, 1, 5], [2, 1, 6]], dtype=np.float64)
    faces = np.array([[0, 1, 4, -1], [0, 4, 3, -1], [1, 2, 5, 4]], dtype=np.int32)
    return Piece(vertices=vertices, faces=faces, point_count=np.ones((2, 2), dtype=np.int32))


def test_saved_fields_load_back_and_unset_ones_are_not_written(tmp_path):
    scratch = Scratch(str(tmp_path / "work"))
    piece = _square_piece()
    piece.save(scratch, 3, 4, PiecePart.PIECE)
    back = Piece.load(scratch, 3, 4, ("vertices", "faces", "point_count"))
    for name in ("vertices", "faces", "point_count"):
        np.testing.assert_array_equal(getattr(back, name), getattr(piece, name))
    assert back.node_ids is None and back.nodes is None
    only = Piece.load(scratch, 3, 4, ("faces",))
    assert only.vertices is None and only.faces.shape == (3, 4)
    # the border was never written: the tile is not intact
    assert not Piece.intact(scratch, 3, 4)
    piece.select(np.array([True, False, True])).save(scratch, 3, 4, PiecePart.BORDER)
    assert Piece.intact(scratch, 3, 4) and not Piece.intact(scratch, 3, 4, ("node_ids",))
    with pytest.raises(ValueError, match="colour"):
        Piece.load(scratch, 3, 4, ("colour",))


def test_a_selection_keeps_the_vertices_its_faces_use_in_order():
    piece = _square_piece()
    part = piece.select(np.array([False, True, True]))
    # faces 1 and 2 use vertices 0, 1, 2, 3, 4, 5 but for none: all six; face 0 alone uses 0, 1, 4
    np.testing.assert_array_equal(part.faces, [[0, 4, 3, -1], [1, 2, 5, 4]])
    alone = piece.select(np.array([True, False, False]))
    np.testing.assert_array_equal(alone.vertices[:, 2], [1, 2, 5])
    np.testing.assert_array_equal(alone.faces, [[0, 1, 2, -1]])
    assert alone.point_count is None  # a selection is of the faces only
