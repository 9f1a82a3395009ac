"""Tiles -> meshes -> grids: one tile's piece and its certificate, the DEM of a
tile, and the run's variogram for the smooth surface.

Imports only ``pipeline.tiling``, ``pipeline.inputs`` and the shared basics.
"""
