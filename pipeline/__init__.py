"""pipeline: LAS/LAZ archives -> tiled combined meshes on Dask -> one DEM and mesh in Zarr.

>>> import pipeline
>>> cfg = pipeline.RunConfig(inputs=("survey/",), output="dem.zarr", resolution=1.0)
>>> cfg.resolution
1.0
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .config import RunConfig
from .errors import CrsError, InputFileError, PipelineError, UsageError

if TYPE_CHECKING:
    from .api import Tile, TiledStore, open_store
    from .runs.runner import RunReport, run

    open = open_store  # noqa: A001

#: what is imported on first use: the command line starts without the
#: kernels, Zarr and xarray, which ``terrain --help`` never needs
_LAZY = {
    "run": ("runs.runner", "run"),
    "RunReport": ("runs.runner", "RunReport"),
    "open": ("api", "open_store"),  # pipeline.open(store) mirrors xarray.open_zarr
    "open_store": ("api", "open_store"),
    "TiledStore": ("api", "TiledStore"),
    "Tile": ("api", "Tile"),
}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    module, attribute = _LAZY[name]
    value = getattr(importlib.import_module(f"{__name__}.{module}"), attribute)
    globals()[name] = value
    return value

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
