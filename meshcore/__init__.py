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

import sys
import types
from importlib import import_module
from typing import TYPE_CHECKING, Any

from .errors import InvalidInputError, InvalidMeshError, MeshError
from .options import MergeMethod, QuadMeasure, Surface, TriangleMeasure, parse_option

__version__ = "0.1.0"

#: where each name of the API lives: imported on first use, so that a caller
#: that needs only the options or the errors (a command line's flags) does not
#: load the kernels
_HOMES = {
    "build_mesh": "build",
    "classify_ground": "ground", "GroundParameters": "ground", "GroundResult": "ground",
    "gradient": "interpolate", "interpolate": "interpolate",
    "Mesh": "mesh",
    "incircle": "predicates", "orient2d": "predicates",
    "FaceQuadrature": "quadrature", "face_quadrature": "quadrature", "l2_errors": "quadrature",
    "MeasureSummary": "quality", "QualitySummary": "quality", "quality_summary": "quality",
    "s1": "quality", "s2": "quality", "s3": "quality", "s4": "quality",
    "rasterize": "rasterize",
    "Refinement": "refine", "refine_long_faces": "refine",
    "SmoothSurface": "smooth", "Variogram": "variogram", "fit_variogram": "variogram", "smooth_nodes": "smooth",
    "smooth_surface": "smooth",
    "convex_hull": "validate", "validate": "validate",
}

if TYPE_CHECKING:
    from . import kernels, tiles
    from .build import build_mesh
    from .ground import GroundParameters, GroundResult, classify_ground
    from .interpolate import gradient, interpolate
    from .mesh import Mesh
    from .predicates import incircle, orient2d
    from .quadrature import FaceQuadrature, face_quadrature, l2_errors
    from .quality import MeasureSummary, QualitySummary, quality_summary, s1, s2, s3, s4
    from .rasterize import rasterize
    from .refine import Refinement, refine_long_faces
    from .smooth import SmoothSurface, smooth_nodes, smooth_surface
    from .variogram import Variogram, fit_variogram
    from .validate import convex_hull, validate


class _Api(types.ModuleType):
    """The package: a submodule named as the function it defines (``rasterize``,
    ``interpolate``, ``validate``) does not take the function's name when it
    is imported."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _HOMES.get(name) == name:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Api


def __getattr__(name: str) -> Any:
    """A name of the API, or a submodule (``meshcore.tiles``, ``meshcore.kernels``), imported on first use."""
    home = _HOMES.get(name)
    if home is not None:
        value = getattr(import_module(f".{home}", __name__), name)
    else:
        try:
            value = import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_HOMES, "kernels", "tiles"})


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
