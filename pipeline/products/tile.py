"""One tile's layers: each product's function, in the order of what it needs."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..tiling.grid import tile_dir
from ..tiling.scratch import Scratch
from .declare import TileContext
from .points import ProductPoints, from_columns
from .registry import product
from .settings import ProductSettings

__all__ = ["tile_layers", "load_product_points", "PRODUCT_SPILL", "warm_up"]

PRODUCT_SPILL = "products"
"""The folder, in each tile's work folder, of the product points routed to it."""


def tile_layers(ctx: TileContext, settings: ProductSettings) -> dict[str, NDArray]:
    """The layers ``settings.layers`` of the tile of ``ctx``, computed with
    the layers they need (in registry order, so every need comes first)."""
    for name in settings.computed:
        if name not in ctx.layers:
            ctx.layers[name] = product(name).compute(ctx)
    return {name: ctx.layers[name] for name in settings.layers}


def load_product_points(scratch: Scratch, row: int, col: int, settings: ProductSettings) -> ProductPoints:
    """The product points routed to a tile (its cells plus the buffer), every source."""
    folder = f"{tile_dir(row, col)}/{PRODUCT_SPILL}"
    parts = [f"{folder}/{name}" for name in scratch.names(folder) if name.endswith(".npy")]
    width = 3 + len(settings.columns)
    array = np.concatenate(scratch.load_many(parts)) if parts else np.empty((0, width))
    return from_columns(array, settings.columns)


def warm_up(layers: tuple[str, ...]) -> None:
    """Load the compiled kernels of the products ``layers`` (those that declare some)."""
    for name in layers:
        run = product(name).warm_up
        if run is not None:
            run()
