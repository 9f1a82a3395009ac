"""Grids and meshes -> the store: the Zarr schema, DEM and mesh writers and
readers, the mesh assembled from the tiles' pieces, COG export and STAC.

Imports only the layers before it (``meshing``, ``tiling``, ``inputs``) and
the shared basics.
"""
