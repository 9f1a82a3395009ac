"""Points -> tiles: the grid, routing to spill files, COPC windows per tile,
and the work folder (its I/O and its records).

Imports only ``pipeline.inputs`` and the shared basics.
"""
