"""meshcore: combined triangle/quadrangle meshes for surface interpolation.

Pure numeric kernels over arrays: robust Delaunay triangulation, flips under a
triangle quality measure, elimination of diagonals under a quadrangle measure
("Surface design based upon a combined mesh"), interpolation and
rasterization of its linear/bilinear surface or of a smooth one (cubic
patches through every point, the paper's section 4).  No I/O.

>>> import numpy as np, meshcore
>>> rng = np.random.default_rng(0)
>>> mesh = meshcore.build_mesh(rng.random((200, 2)), "s3", "s4")
>>> meshcore.validate(mesh)
"""

from __future__ import annotations

from .build import build_mesh
from .errors import InvalidInputError, InvalidMeshError, MeshError
from .ground import GroundParameters, GroundResult, classify_ground
from .interpolate import gradient, interpolate
from .mesh import Mesh
from .options import MergeMethod, QuadMeasure, Surface, TriangleMeasure, parse_option
from .predicates import incircle, orient2d
from .quadrature import FaceQuadrature, face_quadrature, l2_errors
from .quality import MeasureSummary, QualitySummary, quality_summary, s1, s2, s3, s4
from .rasterize import rasterize
from .refine import Refinement, refine_long_faces
from .smooth import SmoothSurface, Variogram, fit_variogram, smooth_nodes, smooth_surface
from .validate import convex_hull, validate

__version__ = "0.1.0"


from . import kernels, tiles  # noqa: E402  (the kernel helpers for callers' own, and the tile protocol)

__all__ = [
    # meshes
    "Mesh",
    "build_mesh",
    "validate",
    "convex_hull",
    "quality_summary",
    "QualitySummary",
    "MeasureSummary",
    "s1",
    "s2",
    "s3",
    "s4",
    "TriangleMeasure",
    "QuadMeasure",
    "MergeMethod",
    "Surface",
    "parse_option",
    "orient2d",
    "incircle",
    # surfaces over them
    "interpolate",
    "gradient",
    "rasterize",
    "refine_long_faces",
    "Refinement",
    "smooth_nodes",
    "smooth_surface",
    "SmoothSurface",
    "fit_variogram",
    "Variogram",
    "face_quadrature",
    "FaceQuadrature",
    "l2_errors",
    # ground of unclassified clouds
    "classify_ground",
    "GroundParameters",
    "GroundResult",
    # errors
    "MeshError",
    "InvalidInputError",
    "InvalidMeshError",
]
"""The user API.  The tile protocol (certificates, orders, per-tile pieces of
the smooth surface, compile plumbing) is :mod:`meshcore.tiles`; kernels of a
caller's own are written with :mod:`meshcore.kernels`."""
