"""pipeline: LAS/LAZ archives -> tiled combined meshes on Dask -> one DEM and mesh in Zarr.

>>> import pipeline
>>> cfg = pipeline.RunConfig(inputs=("survey/",), output="dem.zarr", resolution=1.0)
>>> cfg.resolution
1.0
"""

from __future__ import annotations

from .api import Tile, TiledStore, open_store
from .config import RunConfig
from .errors import CrsError, InputFileError, PipelineError, UsageError
from .runner import RunReport, run

open = open_store  # noqa: A001 - pipeline.open(store) mirrors xarray.open_zarr

__all__ = [
    "run",
    "RunConfig",
    "RunReport",
    "open",
    "open_store",
    "TiledStore",
    "Tile",
    "PipelineError",
    "UsageError",
    "InputFileError",
    "CrsError",
]
