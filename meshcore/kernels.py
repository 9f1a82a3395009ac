"""Kernels written as meshcore's are, for packages built on it.

:func:`kernel` compiles a function with meshcore's settings.  In a kernel,
:func:`empty`, :func:`zeros`, :func:`full` and :func:`empty_like` create
arrays, and :func:`smaller` and :func:`larger` take the smaller and the larger
of two numbers, as numpy and ``min``/``max`` do, but written in place: numba
compiles its own versions as functions of their own for each combination of
types a process meets, which is time a machine's first run spends compiling.
Called from Python they are numpy's and Python's.
"""

from __future__ import annotations

from ._jit import empty, empty_like, full, kernel, larger, smaller, zeros

__all__ = ["kernel", "empty", "zeros", "full", "empty_like", "smaller", "larger"]
