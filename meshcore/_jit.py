"""One place for the compiler settings of every kernel.

Kernels are compiled once and cached on disk (``cache=True``) and release the
GIL (``nogil=True``) so that dask threads run them in parallel.  ``fastmath``
stays off: the exact predicates rely on IEEE round-to-nearest arithmetic.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numba

__all__ = ["njit", "drop_stale_kernels"]

njit = numba.njit(cache=True, nogil=True, error_model="numpy")

#: the name of the file, beside the cached kernels, that says which sources they were compiled from
SOURCES_STAMP = "meshcore-sources.sha256"


def drop_stale_kernels(folders: list[Path] | None = None) -> None:
    """Delete cached kernels compiled from other sources of this package.

    numba checks only the file a kernel is defined in: a kernel that inlines
    one from another module (the flip and merge kernels call the quality
    measures) would keep running the old code after that module changed, as
    after a ``git pull`` in an editable install.  The cache is dropped when a
    digest of all the package's sources differs from the one it was built
    with.  Called once, when the package is imported, before any kernel runs;
    ``folders`` defaults to the cache folders of the package's kernels.
    """
    digest = sources_digest()
    for folder in kernel_cache_folders() if folders is None else folders:
        stamp = folder / SOURCES_STAMP
        try:
            if stamp.read_text() == digest:
                continue
        except OSError:
            pass
        try:
            for stale in [*folder.glob("*.nbi"), *folder.glob("*.nbc")]:
                stale.unlink(missing_ok=True)
            folder.mkdir(parents=True, exist_ok=True)
            stamp.write_text(digest)
        except OSError:  # a read-only install: its files were all written together
            pass


def sources_digest() -> str:
    """SHA-256 of the package's Python sources."""
    here = Path(__file__).parent
    return hashlib.sha256(b"".join(p.read_bytes() for p in sorted(here.glob("*.py")))).hexdigest()


def kernel_cache_folders() -> list[Path]:
    """Where numba caches the kernels of the package's imported modules."""
    folders = set()
    for name, module in list(sys.modules.items()):
        if name.startswith(f"{__package__}.") and module is not None:
            for value in vars(module).values():
                cache = getattr(value, "_cache", None)
                if isinstance(value, numba.core.registry.CPUDispatcher) and hasattr(cache, "_cache_path"):
                    folders.add(Path(cache._cache_path))
    return sorted(folders)
