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

from ._jit import kernel
from ._order import block_order, lexicographic_order
from .build import KERNEL_STAGES, build_mesh, load_kernels
from .certificate import KnownRegion, WindowCertificate
from .errors import InvalidInputError, InvalidMeshError, MeshError
from .ground import GroundParameters, GroundResult, classify_ground
from .interpolate import gradient, interpolate
from .mesh import Mesh, with_vertices
from .natural import NaturalCoordinates, natural_coordinates, natural_values
from .options import MergeMethod, QuadMeasure, Surface, TriangleMeasure, parse_option
from .patches import NODES_PER_FACE, linear_nodes, node_deviations, nodes_from_deviations
from .predicates import incircle, orient2d
from .quadrature import FaceQuadrature, face_quadrature, l2_errors
from .quality import MeasureSummary, QualitySummary, quality_summary, s1, s2, s3, s4
from .rasterize import rasterize, sampled_faces
from .refine import Refinement, cut_face_rows, refine_long_faces, with_cut_faces
from .smooth import (
    DEFAULT_NEIGHBOURS,
    AddedPoints,
    Neighbourhoods,
    SmoothPlan,
    SmoothSurface,
    Variogram,
    VoidFill,
    fit_variogram,
    smooth_neighbourhoods,
    smooth_nodes,
    smooth_plan,
    smooth_surface,
)
from .validate import convex_hull, validate

__version__ = "0.1.0"


def kernels_compiled() -> bool:
    """Whether this machine's kernel cache holds meshcore's mesh kernels, as
    compiled from these sources (by any job since the install or upgrade).

    When not, the first :func:`build_mesh` compiles them: about 13 s, which a
    caller may spend in other processes while it does other work (two of
    them, one per stage of :func:`load_kernels`, take half of that).
    """
    from ._jit import compiled_on_disk
    from .build import _faces_kernel
    from .delaunay import _sweep_kernel

    # the first and the last of build_mesh's kernels: its two stages (see load_kernels)
    return compiled_on_disk(_sweep_kernel) and compiled_on_disk(_faces_kernel)

__all__ = [
    "Mesh",
    "classify_ground",
    "GroundParameters",
    "GroundResult",
    "with_vertices",
    "build_mesh",
    "KnownRegion",
    "WindowCertificate",
    "load_kernels",
    "KERNEL_STAGES",
    "lexicographic_order",
    "block_order",
    "kernel",
    "kernels_compiled",
    "interpolate",
    "gradient",
    "rasterize",
    "sampled_faces",
    "smooth_nodes",
    "smooth_plan",
    "smooth_surface",
    "SmoothPlan",
    "SmoothSurface",
    "AddedPoints",
    "refine_long_faces",
    "Refinement",
    "with_cut_faces",
    "cut_face_rows",
    "fit_variogram",
    "smooth_neighbourhoods",
    "Neighbourhoods",
    "VoidFill",
    "NaturalCoordinates",
    "natural_coordinates",
    "natural_values",
    "Variogram",
    "Surface",
    "NODES_PER_FACE",
    "linear_nodes",
    "node_deviations",
    "nodes_from_deviations",
    "DEFAULT_NEIGHBOURS",
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
    "parse_option",
    "MeshError",
    "InvalidInputError",
    "InvalidMeshError",
]
