"""Files -> points: discovery, LAS/LAZ headers and their raw layout, CRS records
and the CRS plan, point streams.

The first layer above the shared basics (``pipeline.errors``, ``config``,
``urls``, ``logs``); it imports nothing from the layers after it.
"""
