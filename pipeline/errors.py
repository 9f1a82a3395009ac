"""The error hierarchy of the pipeline: every error raised on purpose is a ``PipelineError``.

Each subclass also inherits the builtin that fits, so callers that only know
the builtins (``except OSError``, ``except ValueError``) still catch them.
Messages are one line; errors about a file start with the file's path.
"""

from __future__ import annotations

__all__ = [
    "CrsError", "GridTooLargeError", "InputFileError", "OutputWriteError", "PipelineError", "SeamError",
    "StorageUnreachableError", "StoreError", "UsageError",
    "one_line", "os_error_reason",
]


class PipelineError(Exception):
    """Root of all errors raised by the pipeline."""


class UsageError(PipelineError, ValueError):
    """A command-line argument or parameter is invalid."""


class GridTooLargeError(UsageError):
    """The inputs' extent at the resolution gives a DEM above ``max_cells`` (or
    wider than a float spans)."""


class InputFileError(PipelineError, OSError):
    """An input file is missing, unreadable, or not a valid LAS/LAZ file.

    The message is one line, starting with the path, then the problem:
    ``"data/a.las: not a LAS/LAZ file (bad signature b'PK\\x03\\x04')"``.

    Examples
    --------
    >>> err = InputFileError("data/a.las: truncated header (100 bytes)")
    >>> isinstance(err, OSError), str(err)
    (True, 'data/a.las: truncated header (100 bytes)')
    """

    def __init__(self, message: str) -> None:
        # OSError's constructor interprets 2-5 positional arguments as
        # (errno, strerror, ...); with a single message it behaves like Exception.
        super().__init__(message)


class CrsError(PipelineError, ValueError):
    """A coordinate reference system is missing, unparsable, inconsistent or unsuitable."""


class OutputWriteError(PipelineError, OSError):
    """Writing the output failed (disk full, read-only target, ...).  The store
    is left incomplete and resumable: the same command resumes once the cause
    is fixed."""

    def __init__(self, message: str) -> None:
        super().__init__(message)


class StoreError(PipelineError, OSError):
    """The output store cannot be created, opened or completed.

    The message is one line and starts with the store's path.
    """

    def __init__(self, message: str) -> None:
        # One argument: OSError would read 2-5 as (errno, strerror, ...).
        super().__init__(message)


class StorageUnreachableError(PipelineError, OSError):
    """An object store or web server stopped answering part way through a run
    (refused connections, time-outs, a dropped connection).  Nothing is
    marked complete, and no input is skipped for it: the same command
    resumes once the server is back."""

    def __init__(self, message: str) -> None:
        super().__init__(message)


class SeamError(PipelineError, RuntimeError):
    """A tile's piece of the mesh cannot be shown to fit its neighbours'.

    On valid input this never happens (every tile's search for the points its
    seams depend on ends once it holds them all): it is a bug, reported with
    the tile, and the store is left incomplete.
    """


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type's name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__


def os_error_reason(exc: OSError) -> str:
    """What an OSError met while reading an input file means, for a one-line message."""
    if isinstance(exc, FileNotFoundError):
        return "no such file"
    if isinstance(exc, IsADirectoryError):
        return "is a directory, not a LAS/LAZ file"
    if isinstance(exc, PermissionError):
        return "permission denied (cannot read the file)"
    return f"cannot read the file ({exc.strerror or exc})"
