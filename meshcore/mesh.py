"""The combined mesh: vertices plus triangle and quadrangle faces (UGRID layout)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Mesh"]


@dataclass(frozen=True, eq=False)
class Mesh:
    """A conforming mesh of triangles and strictly convex quadrangles.

    Attributes
    ----------
    vertices : (n_v, 2) float64
        Distinct input points, in the order of their first occurrence.
    faces : (n_f, 4) int64
        Vertex indices, counter-clockwise; ``-1`` in column 3 marks a triangle
        (the UGRID convention for mixed meshes).
    input_to_vertex : (n,) int64
        The vertex of every input point: duplicates share one vertex.
    triangle_measure, quad_measure, merge : str or None
        The options the mesh was built with.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    input_to_vertex: NDArray[np.int64]
    triangle_measure: str = "delaunay"
    quad_measure: str | None = None
    merge: str = "greedy"

    @property
    def is_quad(self) -> NDArray[np.bool_]:
        """Boolean mask over faces, True for quadrangles."""
        return self.faces[:, 3] >= 0

    @property
    def n_triangles(self) -> int:
        return int(self.faces.shape[0] - np.count_nonzero(self.is_quad))

    @property
    def n_quads(self) -> int:
        return int(np.count_nonzero(self.is_quad))

    def __repr__(self) -> str:
        return (
            f"Mesh({self.vertices.shape[0]} vertices, {self.n_triangles} triangles, "
            f"{self.n_quads} quads, triangle_measure={self.triangle_measure!r}, "
            f"quad_measure={self.quad_measure!r}, merge={self.merge!r})"
        )
