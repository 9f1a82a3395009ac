"""Ordering helpers shared by the kernels."""

from __future__ import annotations

import numpy as np

from ._jit import njit

__all__ = ["order_ties_by"]


@njit
def order_ties_by(order: np.ndarray, key: np.ndarray, tie: np.ndarray) -> None:
    """Within runs of equal ``key[order]``, reorder ``order`` by increasing ``tie``.

    ``order`` must already sort ``key``.  Short runs (the usual case for float
    keys of geometric data) are insertion-sorted; long ones (a grid, where many
    keys are equal) are sorted with a stable merge sort.
    """
    n = order.shape[0]
    k = 0
    while k < n:
        m = k + 1
        while m < n and key[order[m]] == key[order[k]]:
            m += 1
        if m - k > 32:
            run = order[k:m].copy()
            order[k:m] = run[np.argsort(tie[run], kind="mergesort")]
            k = m
            continue
        for i in range(k + 1, m):
            v = order[i]
            j = i - 1
            while j >= k and tie[order[j]] > tie[v]:
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = v
        k = m
