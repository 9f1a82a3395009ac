"""One tile's layers: each product's function, in the order of what it needs."""

from __future__ import annotations

from numpy.typing import NDArray

from .declare import TileContext
from .registry import product
from .settings import ProductSettings

__all__ = ["tile_layers", "warm_up"]


def tile_layers(ctx: TileContext, settings: ProductSettings) -> dict[str, NDArray]:
    """The layers ``settings.layers`` of the tile of ``ctx``, computed with
    the layers they need (in registry order, so every need comes first)."""
    for name in settings.computed:
        if name not in ctx.layers:
            ctx.layers[name] = product(name).compute(ctx)
    return {name: ctx.layers[name] for name in settings.layers}


def warm_up(layers: tuple[str, ...]) -> None:
    """Load the compiled kernels of the products ``layers`` (those that declare some)."""
    for name in layers:
        run = product(name).warm_up
        if run is not None:
            run()
