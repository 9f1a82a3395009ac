"""The tile protocol: what a caller that cuts a survey into tiles needs of
meshcore beyond its user API (:mod:`meshcore`).

A tile meshes the points it holds and proves that the faces it keeps do not
depend on the points it did not load:

* :class:`KnownRegion` says which parts of the plane the tile vouches for
  (held boxes, the survey's hull), and :class:`WindowCertificate` is what
  :func:`meshcore.build_mesh` answers with a window: the faces that stay
  doubtful, the circles that leave the held region, and the last flip round
  per block of the window (:func:`last_flip_round_in` reads it for a box);
* :func:`bounded_triangles` keeps the triangles whose circumcircle a margin
  holds (a surface drawn with a maximum edge is then the same in every tile),
  and :func:`highest_per_cell` the highest point of each grid cell (a DSM's
  points, the same in every tile that holds the cell);
* :func:`with_vertices` adds points that no face uses (a smooth surface's
  kriging neighbours loaded after the faces were certified);
* :func:`lexicographic_order` and :func:`block_order` sort points and
  vertices the way every tile sorts them;
* :func:`sampled_faces`, :func:`with_cut_faces` and :func:`cut_face_rows`
  restrict a raster or the smooth surface's cut faces to a tile's window;
* the smooth surface's per-tile pieces: :func:`smooth_plan`
  (:class:`SmoothPlan`, :class:`AddedPoints`), :func:`smooth_neighbourhoods`
  (:class:`Neighbourhoods`, :data:`DEFAULT_NEIGHBOURS`), :class:`VoidFill`,
  natural neighbours (:class:`NaturalCoordinates`), and the patch nodes a
  tile stores (:data:`NODES_PER_FACE`, :func:`linear_nodes`,
  :func:`node_deviations`, :func:`nodes_from_deviations`);
* compile plumbing: :func:`load_kernels` and :data:`KERNEL_STAGES` load or
  compile the mesh kernels ahead of the first tile, and
  :func:`kernels_compiled` says whether this machine's cache holds them.
  Kernels of a caller's own are written with :mod:`meshcore.kernels`.

docs/tiling.md and docs/architecture.md say how the pipeline uses them.
"""

from __future__ import annotations

from ._order import block_order, lexicographic_order
from .build import KERNEL_STAGES, load_kernels
from .certificate import KnownRegion, WindowCertificate, last_flip_round_in
from .mesh import bounded_triangles, with_vertices
from .natural import NaturalCoordinates, natural_coordinates, natural_values
from .patches import NODES_PER_FACE, linear_nodes, node_deviations, nodes_from_deviations
from .rasterize import highest_per_cell, sampled_faces
from .refine import cut_face_rows, with_cut_faces
from .kriging import DEFAULT_NEIGHBOURS
from .smooth import AddedPoints, Neighbourhoods, SmoothPlan, smooth_neighbourhoods, smooth_plan
from .voids import VoidFill

__all__ = [
    "KnownRegion",
    "WindowCertificate",
    "last_flip_round_in",
    "with_vertices",
    "bounded_triangles",
    "highest_per_cell",
    "lexicographic_order",
    "block_order",
    "sampled_faces",
    "with_cut_faces",
    "cut_face_rows",
    "smooth_plan",
    "SmoothPlan",
    "AddedPoints",
    "smooth_neighbourhoods",
    "Neighbourhoods",
    "DEFAULT_NEIGHBOURS",
    "VoidFill",
    "NaturalCoordinates",
    "natural_coordinates",
    "natural_values",
    "NODES_PER_FACE",
    "linear_nodes",
    "node_deviations",
    "nodes_from_deviations",
    "load_kernels",
    "KERNEL_STAGES",
    "kernels_compiled",
]


def kernels_compiled() -> bool:
    """Whether this machine's kernel cache holds meshcore's mesh kernels, as
    compiled from these sources (by any job since the install or upgrade).

    When not, the first :func:`meshcore.build_mesh` compiles them: about 13 s,
    which a caller may spend in other processes while it does other work (two
    of them, one per stage of :func:`load_kernels`, take half of that).
    """
    from ._jit import compiled_on_disk
    from .build import _faces_kernel
    from .delaunay import _sweep_kernel

    # the first and the last of build_mesh's kernels: its two stages (see load_kernels)
    return compiled_on_disk(_sweep_kernel) and compiled_on_disk(_faces_kernel)
