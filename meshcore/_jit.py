"""One place for the compiler settings of every kernel.

Kernels are compiled once and cached on disk (``cache=True``) and release the
GIL (``nogil=True``) so that dask threads run them in parallel.  ``fastmath``
stays off: the exact predicates rely on IEEE round-to-nearest arithmetic.
"""

from __future__ import annotations

import numba

__all__ = ["njit"]

njit = numba.njit(cache=True, nogil=True, error_model="numpy")
