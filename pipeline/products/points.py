"""The points the products read, as they travel from the reader to a tile.

The reader decodes x, y, z and only the attributes the run's products
declared (:attr:`ProductSettings.columns <pipeline.products.settings.ProductSettings.columns>`);
the router writes them to each tile's product spill files as one float64
array of columns ``x, y, z, *columns`` (every attribute is a small integer,
exact in a float64), and a tile reads them back as :class:`ProductPoints`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .declare import Selection

__all__ = ["ProductPoints", "as_columns", "from_columns"]


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


def as_columns(x: NDArray, y: NDArray, z: NDArray, attributes: Mapping[str, NDArray],
               columns: Sequence[str]) -> NDArray[np.float64]:
    """The spill array ``(n, 3 + len(columns))`` of points and their attributes, in ``columns`` order."""
    out = np.empty((x.shape[0], 3 + len(columns)))
    out[:, 0], out[:, 1], out[:, 2] = x, y, z
    for k, name in enumerate(columns):
        out[:, 3 + k] = attributes[name]
    return out


def from_columns(array: NDArray[np.float64], columns: Sequence[str]) -> ProductPoints:
    """:class:`ProductPoints` of a spill array written by :func:`as_columns`."""
    array = np.asarray(array).reshape(-1, 3 + len(columns))
    return ProductPoints(array[:, 0], array[:, 1], array[:, 2],
                         {name: array[:, 3 + k] for k, name in enumerate(columns)})
