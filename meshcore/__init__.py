"""meshcore: combined triangle/quadrangle meshes for surface interpolation.

Pure numeric kernels over arrays: robust Delaunay triangulation, flips under a
triangle quality measure, elimination of diagonals under a quadrangle measure
("Surface design based upon a combined mesh"), linear/bilinear interpolation
and rasterization.  No I/O.

>>> import numpy as np, meshcore
>>> rng = np.random.default_rng(0)
>>> mesh = meshcore.build_mesh(rng.random((200, 2)), "s3", "s4")
>>> meshcore.validate(mesh)
"""

from __future__ import annotations

from ._jit import drop_stale_kernels
from ._order import lexicographic_order
from .build import build_mesh
from .errors import InvalidInputError, InvalidMeshError, MeshError
from .interpolate import gradient, interpolate
from .mesh import Mesh
from .options import MergeMethod, QuadMeasure, TriangleMeasure
from .predicates import incircle, orient2d
from .quadrature import FaceQuadrature, face_quadrature, l2_errors
from .quality import MeasureSummary, QualitySummary, quality_summary, s1, s2, s3, s4
from .rasterize import rasterize
from .validate import convex_hull, validate

drop_stale_kernels()

__version__ = "0.1.0"

__all__ = [
    "Mesh",
    "build_mesh",
    "lexicographic_order",
    "interpolate",
    "gradient",
    "rasterize",
    "validate",
    "convex_hull",
    "s1",
    "s2",
    "s3",
    "s4",
    "quality_summary",
    "face_quadrature",
    "l2_errors",
    "FaceQuadrature",
    "QualitySummary",
    "MeasureSummary",
    "orient2d",
    "incircle",
    "TriangleMeasure",
    "QuadMeasure",
    "MergeMethod",
    "MeshError",
    "InvalidInputError",
    "InvalidMeshError",
]
