"""The mesh kernels a tile needs, compiled on a few points of no tile.

Imports only numpy and meshcore: the processes that compile these kernels
beside a machine's first run (:mod:`pipeline.runs.compiling`) start in
0.4 s instead of the 0.8 s that importing the tiles' module takes.
"""

from __future__ import annotations

import numpy as np

import meshcore

__all__ = ["MESH_KERNEL_PARTS", "load_mesh_kernels", "sample_grid_mesh"]


MESH_KERNEL_PARTS = ("triangulation", "faces", "smooth")
"""The parts of :func:`load_mesh_kernels` that processes can compile side by side."""


def load_mesh_kernels(triangle_measure: str, quad_measure: str | None, merge: str, surface: str,
                      parts: tuple[str, ...] = MESH_KERNEL_PARTS) -> None:
    """The mesh kernels of :func:`~pipeline.meshing.tiles.load_kernels`: a tile's mesh (and its smooth
    nodes), or those of ``parts`` of it, each compiled without the others:
    ``"triangulation"`` and ``"faces"`` (the two stages of
    :func:`meshcore.tiles.load_kernels`; with the order of a piece's vertices) and
    ``"smooth"`` (the nodes and their long faces, on a mesh made here; only
    with ``surface="smooth"``).  The variogram's fit is left to the caller,
    which runs it before the tiles."""
    if "triangulation" in parts:
        meshcore.tiles.load_kernels("triangulation")
    if "faces" in parts:
        mesh = meshcore.tiles.load_kernels("faces", triangle_measure, quad_measure, merge)
        meshcore.tiles.lexicographic_order(mesh.vertices)
    if "smooth" in parts and surface == "smooth":
        mesh = sample_grid_mesh(8)
        z = mesh.vertices[:, 0] * 0.1 + np.sin(mesh.vertices[:, 1])
        meshcore.tiles.block_order(np.column_stack([mesh.vertices, z]), 1.0, (0.0, 0.0, 8.0, 8.0))
        # not fitted: the run fits its variogram itself, before its tiles.  Its
        # edges are 20 spacings long, split as long faces are: those kernels too
        variogram = meshcore.Variogram(nugget=0.01, sill=1.0, range=3.0, model="matern52", spacing=0.05)
        meshcore.smooth_surface(mesh, z, variogram)
        # and a plan for the faces a grid samples, grown by points its disks need, as a tile's is
        plan = meshcore.tiles.smooth_plan(mesh, variogram, faces=meshcore.tiles.sampled_faces(mesh, 0.0, 0.0, 2.0, 4, 4))
        meshcore.tiles.smooth_plan(meshcore.tiles.with_vertices(mesh, [[3.5, -0.5]]), variogram, previous=plan)


def sample_grid_mesh(n: int) -> meshcore.Mesh:
    """A mesh of an ``n`` x ``n`` grid, slightly jittered: quadrangles, and
    pairs of triangles on every third square."""
    k = np.arange(n * n)
    vertices = np.column_stack([k % n + 0.01 * (k * 7 % 5), k // n + 0.01 * (k * 3 % 7)])
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            if (i + j) % 3:
                faces.append([a, a + 1, a + n + 1, a + n])
            else:
                faces += [[a, a + 1, a + n + 1, -1], [a, a + n + 1, a + n, -1]]
    return meshcore.Mesh(vertices, np.array(faces, dtype=np.int64), np.arange(n * n))
