"""The one list of products: a new layer is one module and one line here.

The order is the layers' order in the store, the CLI and the export
(elevation first; the layers a run always had before the others).
"""

from __future__ import annotations

from ..errors import UsageError
from .chm import CHM
from .declare import Product
from .density import DENSITY
from .dsm import DSM
from .elevation import ELEVATION
from .face_kind import FACE_KIND
from .ground_density import GROUND_DENSITY
from .intensity import INTENSITY
from .point_count import POINT_COUNT
from .slope import SLOPE

__all__ = ["PRODUCTS", "product", "names"]

PRODUCTS: tuple[Product, ...] = (
    ELEVATION,
    SLOPE,
    FACE_KIND,
    POINT_COUNT,
    DSM,
    CHM,
    INTENSITY,
    DENSITY,
    GROUND_DENSITY,
)

_BY_NAME = {p.name: p for p in PRODUCTS}


def names() -> tuple[str, ...]:
    """Every product's name, in registry order."""
    return tuple(_BY_NAME)


def product(name: str) -> Product:
    """The product named ``name``; a :class:`UsageError` lists the valid names."""
    try:
        return _BY_NAME[str(name)]
    except KeyError:
        raise UsageError(f"unknown layer {name!r}; valid layers: {', '.join(_BY_NAME)}") from None
