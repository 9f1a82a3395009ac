"""Products: the layers a run writes, each declared once.

A product is a :class:`Product` in a module of its own (``dsm.py``,
``chm.py``, ...) and one line in :mod:`pipeline.products.registry`.  Its
declaration is all the store, the export, the STAC item, the preview, the
reader and the tile tasks know of it.

>>> from pipeline.products import names, product
>>> names()[:2], product("chm").needs
(('elevation', 'slope'), ('dsm', 'elevation'))
"""

from .declare import (
    ALL_BUT_NOISE, HEIGHT_UNITS, NOISE_CLASSES, PER_AREA_UNITS, Attribute, Preview, Product, Returns, Selection,
    TileContext,
)
from .points import ProductPoints
from .registry import PRODUCTS, names, product
from .settings import DSM_EDGE_SPACINGS, ProductSettings, layers_needed

__all__ = [
    "Product", "Preview", "Selection", "Returns", "Attribute", "TileContext", "ProductPoints", "ProductSettings",
    "PRODUCTS", "product", "names", "layers_needed", "NOISE_CLASSES", "ALL_BUT_NOISE", "HEIGHT_UNITS",
    "PER_AREA_UNITS", "DSM_EDGE_SPACINGS",
]
