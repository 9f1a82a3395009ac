"""The points the products read, as they travel from the reader to a tile.

The reader decodes x, y, z and only the attributes the run's products
declared (:attr:`ProductSettings.columns <pipeline.products.settings.ProductSettings.columns>`);
the router writes them to each tile's product spill files as one float64
array of rows ``x, y, z, code`` (:func:`as_product_rows`): the attributes are
small integers of at most 16 bits, and ``code`` holds them all side by side
(:data:`ATTRIBUTE_BITS`), an integer under ``2**32``, exact in a float64.  A
tile reads them back as :class:`ProductPoints` (:func:`from_product_rows`).
With one float64 an attribute, the rows of the three a run with every product
needs were 1.5 times as wide: the route stage spent 0.04-0.07 s on them on a
700k-point file, 0.02-0.04 s with the code.

:func:`attribute_columns` and :func:`from_columns` are the general form (a
float64 column each, any integer below ``2**53``: a point's index in its
file), which the ground stage's spill files use.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .declare import Selection

__all__ = ["ProductPoints", "ATTRIBUTE_BITS", "attribute_columns", "from_columns", "product_code", "as_product_rows",
           "from_product_rows", "product_row_width"]

ATTRIBUTE_BITS: dict[str, tuple[int, int]] = {
    "classification": (0, 8),
    "return_number": (8, 4),
    "number_of_returns": (12, 4),
    "intensity": (16, 16),
}
"""Where each attribute lies in a product row's ``code``: its lowest bit and
its width, those of the LAS point record (a class of 8 bits in formats 6-10,
return numbers of 4, a 16-bit intensity)."""


@dataclass(frozen=True)
class ProductPoints:
    """Points with the attributes the products asked for (by name)."""

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    z: NDArray[np.float64]
    attributes: Mapping[str, NDArray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def take(self, keep: NDArray[np.bool_]) -> ProductPoints:
        return ProductPoints(self.x[keep], self.y[keep], self.z[keep], {k: v[keep] for k, v in self.attributes.items()})

    def selected(self, selection: Selection) -> ProductPoints:
        """The points of ``selection`` (the attributes held say which)."""
        keep = selection.mask(len(self), self.attributes)
        return self if keep.all() else self.take(keep)


def attribute_columns(attributes: Mapping[str, NDArray], columns: Sequence[str], n: int) -> NDArray[np.float64]:
    """The ``columns`` of ``attributes`` ``(n, len(columns))``, as float64: a
    spill row's columns after x, y, z (:func:`from_columns` reads them back)."""
    out = np.empty((n, len(columns)))
    for k, name in enumerate(columns):
        out[:, k] = attributes[name]
    return out


def from_columns(array: NDArray[np.float64], columns: Sequence[str]) -> ProductPoints:
    """:class:`ProductPoints` of spill rows x, y, z and :func:`attribute_columns`."""
    array = np.asarray(array).reshape(-1, 3 + len(columns))
    return ProductPoints(array[:, 0], array[:, 1], array[:, 2],
                         {name: array[:, 3 + k] for k, name in enumerate(columns)})


def product_row_width(columns: Sequence[str]) -> int:
    """Floats in a product row for points with ``columns``: x, y, z and the code (none without attributes)."""
    return 3 + (1 if columns else 0)


def product_code(attributes: Mapping[str, NDArray], columns: Sequence[str], n: int) -> NDArray[np.float64] | None:
    """The ``columns`` of ``attributes`` packed into one code a point
    (:data:`ATTRIBUTE_BITS`), as float64: a product row's column after x, y, z;
    None without columns (the rows are x, y, z)."""
    if not columns:
        return None
    code = np.zeros(n, dtype=np.uint32)
    for name in columns:
        shift, width = ATTRIBUTE_BITS[name]
        value = np.asarray(attributes[name])
        if value.size and int(value.max()) >> width:
            raise ValueError(f"{name} holds {int(value.max())}, over the {width} bits a product row keeps")
        code |= value.astype(np.uint32) << np.uint32(shift)
    return code.astype(np.float64)


def as_product_rows(x: NDArray, y: NDArray, z: NDArray, attributes: Mapping[str, NDArray],
                    columns: Sequence[str]) -> NDArray[np.float64]:
    """The product spill array ``(n, product_row_width(columns))``: x, y, z and
    :func:`product_code` (the router writes the same rows, gathering the
    columns straight into each tile's: :func:`~pipeline.tiling.routing.route_rows`)."""
    code = product_code(attributes, columns, x.shape[0])
    return np.column_stack([x, y, z] if code is None else [x, y, z, code]).astype(np.float64)


def from_product_rows(array: NDArray[np.float64], columns: Sequence[str]) -> ProductPoints:
    """:class:`ProductPoints` of a spill array written by :func:`as_product_rows`."""
    array = np.asarray(array).reshape(-1, product_row_width(columns))
    attributes: dict[str, NDArray] = {}
    if columns:
        code = array[:, 3].astype(np.uint32)
        for name in columns:
            shift, width = ATTRIBUTE_BITS[name]
            value = (code >> np.uint32(shift)) & np.uint32((1 << width) - 1)
            attributes[name] = value.astype(np.uint8 if width <= 8 else np.uint16)
    return ProductPoints(array[:, 0], array[:, 1], array[:, 2], attributes)
