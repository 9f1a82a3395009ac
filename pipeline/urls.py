"""Inputs and stores named by URL (``s3://``, ``https://``, any fsspec protocol).

A local path stays a :class:`~pathlib.Path`; a URL stays a string all the way
to the task that opens it, which reads it through fsspec (s3fs for ``s3://``,
HTTP range requests for ``https://``).

Credentials and endpoints come the way s3fs and botocore take them: the
environment (``AWS_ACCESS_KEY_ID``, ``AWS_PROFILE``, ``AWS_ENDPOINT_URL``, ...)
and the AWS config files; or from ``storage_options`` (the job file's table),
which :func:`use_storage_options` keeps in this process only.  They are never
part of a URL, so no message, report or provenance carries them.

Examples
--------
>>> is_url("s3://bucket/survey/"), is_url("survey/a.laz"), is_url("file:///data/a.laz")
(True, False, False)
>>> location("https://example.org/a.copc.laz")
'https://example.org/a.copc.laz'
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

from .errors import InputFileError, StorageUnreachableError, UsageError, one_line


__all__ = [
    "Location",
    "as_location",
    "describe_os_error",
    "expand",
    "filesystem",
    "identity",
    "is_url",
    "location",
    "modified",
    "open_input",
    "options_for",
    "size",
    "storage_options",
    "translated",
    "unreachable",
    "unreachable_error",
    "use_storage_options",
    "version",
]

Location = Path | str
"""Where bytes live: a local path, or a URL (a string)."""

_SCHEME = re.compile(r"^([a-zA-Z][a-zA-Z0-9+.-]*)://")
_HTTP = frozenset({"http", "https"})
_GLOB_CHARS = frozenset("*?[")

#: the storage options this process applies to every non-HTTP filesystem
_OPTIONS: dict[str, Any] = {}

READ_BLOCK = 8 * 2**20
"""Bytes fetched per request when streaming a remote file's points (read ahead)."""

HEADER_BLOCK = 16 * 2**10
"""Bytes fetched per request when reading headers, VLRs and chunk tables."""

NODE_BLOCK = 0
"""Bytes read ahead per request when reading COPC nodes by window: none, each
request fetches just the bytes of the nodes (and hierarchy pages) it reads."""


def is_url(text: object) -> bool:
    """Whether ``text`` names a remote object (``file://`` is a local path)."""
    if not isinstance(text, str):
        return False
    match = _SCHEME.match(text)
    return match is not None and match.group(1).lower() != "file"


def protocol(url: str) -> str:
    match = _SCHEME.match(url)
    return match.group(1).lower() if match else "file"


def as_location(item: str | os.PathLike[str]) -> Location:
    """A URL as it is, anything else as a Path (relative stays relative)."""
    return item if is_url(item) else Path(item)  # type: ignore[return-value]


def location(item: str | os.PathLike[str]) -> Location:
    """A URL as given (after a check), anything else as an absolute path."""
    text = os.fspath(item)
    if is_url(text):
        _check_url(text)
        return text
    if text.startswith("file://"):
        text = text[len("file://"):]
    return Path(os.path.abspath(text))


def _check_url(url: str) -> None:
    head = url.split("://", 1)[1].split("/", 1)[0]
    if "@" in head:
        raise UsageError(
            f"{protocol(url)}://...@{head.rsplit('@', 1)[1]}: credentials in a URL would be written to logs and "
            "provenance; give them in the environment or in storage_options"
        )


def use_storage_options(options: Mapping[str, Any] | None) -> None:
    """Apply ``options`` (fsspec keyword arguments, e.g. ``endpoint_url``,
    ``key``, ``secret``, ``anon``) to every non-HTTP URL this process opens."""
    _OPTIONS.clear()
    _OPTIONS.update(dict(options or {}))


def storage_options() -> dict[str, Any]:
    """The options :func:`use_storage_options` set (a copy)."""
    return dict(_OPTIONS)


def options_for(url: str) -> dict[str, Any]:
    """The fsspec options of ``url``: :func:`storage_options`, except for
    HTTP(S), whose filesystem takes none of them (they are for object stores)."""
    return {} if protocol(url) in _HTTP else dict(_OPTIONS)


def filesystem(url: str) -> tuple[Any, str]:
    """The fsspec filesystem of ``url`` and the path inside it."""
    import fsspec

    options = options_for(url)
    try:
        return fsspec.core.url_to_fs(url, **options)
    except ImportError as exc:
        raise UsageError(f"{url}: reading {protocol(url)}:// needs {exc.name or 'its fsspec driver'} "
                         f"(pip install 'terrain-pipeline[cloud]')") from None
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{url}: {one_line(exc)}") from None


def describe_os_error(exc: BaseException, url: str) -> str:
    """What an error met while reading ``url`` means, for a one-line message."""
    text = one_line(exc)
    if isinstance(exc, FileNotFoundError):
        return "no such bucket" if "bucket does not exist" in text.lower() else "no such object"
    if isinstance(exc, PermissionError):
        return "access denied (check the credentials: AWS_ACCESS_KEY_ID, AWS_PROFILE or storage_options)"
    if isinstance(exc, IsADirectoryError):
        return "is a prefix (folder), not an object"
    return f"cannot read it ({type(exc).__name__}: {text})"


#: transport errors that mean "the server did not answer", not "the object is bad"
_UNREACHABLE = frozenset({"ConnectionError", "HTTPClientError", "ClientConnectionError", "ServerTimeoutError"})


def unreachable(exc: BaseException | None) -> BaseException | None:
    """The error in ``exc``'s chain that says a server could not be reached, or None."""
    seen = 0
    while exc is not None and seen < 16:
        if isinstance(exc, (ConnectionError, TimeoutError)):
            return exc
        for cls in type(exc).__mro__:
            if cls.__name__ in _UNREACHABLE and cls.__module__.split(".")[0] in ("botocore", "aiohttp"):
                return exc
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return None


def unreachable_error(where: str, exc: BaseException) -> StorageUnreachableError:
    return StorageUnreachableError(
        f"{where}: the server stopped answering ({type(exc).__name__}: {one_line(exc)}); "
        "run the same command again once it is back: finished work is kept"
    )


_TRANSPORTS = frozenset({"aiohttp", "botocore", "aiobotocore", "fsspec", "s3fs"})


@contextmanager
def translated(url: str) -> Iterator[None]:
    """Errors met while reading ``url`` as one line naming it: a server that
    does not answer is :class:`StorageUnreachableError`, anything else about
    the object :class:`InputFileError`."""
    try:
        yield
    except (InputFileError, StorageUnreachableError):
        raise
    except Exception as exc:
        cause = unreachable(exc)
        if cause is not None:
            raise unreachable_error(url, cause) from None
        if isinstance(exc, OSError) or type(exc).__module__.split(".")[0] in _TRANSPORTS:
            raise InputFileError(f"{url}: {describe_os_error(exc, url)}") from None
        raise


def open_input(where: Location, block_size: int = HEADER_BLOCK) -> BinaryIO:
    """``where`` opened for reading: a local file, or a remote object read
    ahead ``block_size`` bytes per request (:data:`READ_BLOCK` to stream points)."""
    if not is_url(where):
        return open(where, "rb")
    with translated(str(where)):
        fs, path = filesystem(str(where))
        return fs.open(path, "rb", block_size=block_size, cache_type="readahead")


def size(where: Location) -> int:
    """Bytes in the file or object."""
    if not is_url(where):
        return os.stat(where).st_size
    with translated(str(where)):
        fs, path = filesystem(str(where))
        return int(fs.size(path))


def modified(where: Location) -> float | None:
    """The file's modification time (seconds since the epoch); None where an object store keeps none."""
    if not is_url(where):
        return os.stat(where).st_mtime
    with translated(str(where)):
        fs, path = filesystem(str(where))
        try:
            return fs.modified(path).timestamp()
        except (NotImplementedError, AttributeError, KeyError):
            return None


def version(where: Location) -> dict[str, Any]:
    """What tells a later run whether an input changed: a file's time stamp, an
    object's ETag (the same bytes uploaded again are the same object)."""
    if is_url(where):
        return {"mtime": None, "etag": identity(str(where))}
    return {"mtime": modified(where)}


def identity(where: str) -> str:
    """What names a remote object's content without reading it: its ETag (which
    changes with every new upload) and size."""
    with translated(where):
        fs, path = filesystem(where)
        info = fs.info(path)
    tag = str(info.get("ETag") or info.get("etag") or info.get("checksum") or "").strip('"')
    return f"etag:{tag}:{info.get('size')}" if tag else f"size:{info.get('size')}:{modified(where)}"


def expand(text: str, wanted: frozenset[str]) -> list[str]:
    """A URL of an object, a prefix (every object below it whose name ends in
    one of ``wanted``) or a glob pattern, as the objects' URLs, sorted."""
    with translated(text):
        fs, path = filesystem(text)
        if _GLOB_CHARS.intersection(path):
            names = sorted(p for p in fs.glob(path) if _wanted(p, wanted))
            if not names:
                raise InputFileError(f"{text}: no .las/.laz object matches this pattern")
        elif path.endswith("/") or fs.isdir(path):
            names = sorted(p for p in fs.find(path) if _wanted(p, wanted))
            if not names:
                raise InputFileError(f"{text}: the prefix holds no .las/.laz object")
        elif fs.exists(path):
            return [text]
        else:
            bucket = path.split("/", 1)[0]
            if protocol(text) == "s3" and not fs.exists(bucket):
                raise InputFileError(f"{text}: no such bucket")
            raise InputFileError(f"{text}: no such object or prefix")
    # s3fs lists names without their protocol; HTTP listings are whole URLs
    return [name if protocol(text) in _HTTP else f"{protocol(text)}://{name}" for name in names]


def _wanted(name: str, suffixes: frozenset[str]) -> bool:
    return os.path.splitext(name.rstrip("/"))[1].lower() in suffixes
