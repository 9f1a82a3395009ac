"""Which tile column or row each coordinate falls in: the kernels behind :meth:`TileGrid.bins`."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

import meshcore
from meshcore.kernels import empty, larger, smaller

__all__ = ["bins", "bin_of"]


@meshcore.kernels.kernel
def bin_of(v: float, origin: float, inv_size: float, below: NDArray[np.float64], above: NDArray[np.float64]) -> int:
    """:meth:`TileGrid.bins` of one value: bin ``k`` is ``[below[k], above[k])``
    (the inner edges with -inf and +inf at the ends); no branch."""
    k = np.int64(smaller(larger((v - origin) * inv_size, 0.0), float(above.shape[0] - 1)))
    k += v >= above[k]
    k -= v < below[k]
    return k


@meshcore.kernels.kernel
def bins(values, origin, inv_size, below, above):
    out = empty(values.shape, dtype=np.intp)
    for i in range(values.shape[0]):
        out[i] = bin_of(values[i], origin, inv_size, below, above)
    return out
