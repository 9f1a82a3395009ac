"""The files of a job's work folder: a folder on this machine, or a prefix on
object storage (``s3://bucket/.dem.zarr.work``) that every worker of a
cluster without a shared disk reads and writes.

A :class:`Scratch` is named by its root (a path or a URL, a string: it
crosses to Dask workers as it is) and speaks of keys, ``/``-separated paths
below the root (``tiles/00001_00002/000000_000000.npy``).  Arrays are stored
as ``.npy``: on a local disk large ones are memory-mapped; on object storage
each is one object, written whole (an object appears complete or not at all)
and read with one request, many at once where a caller asks for many.
"""

from __future__ import annotations

import errno
import io
import math
import os
import re
import shutil
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from .. import urls

__all__ = ["Scratch", "load_array"]


_NPY_HEADER_LOCK = threading.Lock()

_MAP_ABOVE = 1 << 20
"""Local arrays up to this size are read, not memory-mapped: reading a small
file costs half as much as mapping it."""


def _short_write(exc: OSError, path: Path, size: int) -> OSError:
    """The error of a write that stopped short.  numpy reports one with no
    errno (``"56 requested and 0 written"``); the file system says why: no
    room left (``ENOSPC``, with the free space it reports), else the original."""
    if exc.errno is not None:
        return exc
    try:
        room = os.statvfs(path.parent)
        free = room.f_bavail * room.f_frsize
    except OSError:
        return exc
    if free < size:
        return OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} ({free:,} bytes free, {size:,} to write)")
    return exc


def load_array(path: str | os.PathLike[str], mmap: bool = False) -> np.ndarray:
    """``np.load`` of a local ``.npy`` file, safe in threads; memory-mapped
    with ``mmap`` when the file is larger than 1 MiB.

    The map is copy-on-write: the file is never changed, and the array is
    writable like a loaded one, so kernels are compiled for one array type
    (a read-only array is another, compiled again)."""
    if mmap and os.path.getsize(path) > _MAP_ABOVE:
        with _NPY_HEADER_LOCK:
            return np.load(path, mmap_mode="c")
    with open(path, "rb") as handle:
        return _read_npy(handle, str(path), file=True)


_SAVED_HEADER = re.compile(
    rb"\{'descr': '([<>|=][a-zA-Z]\d{1,2})', 'fortran_order': (True|False), 'shape': \(((?:\d+, ?)*\d*)\), \} *\n"
)
"""The header ``np.save`` writes for an array of a plain dtype."""


def _saved_header(handle: BinaryIO) -> tuple[tuple[int, ...], bool, np.dtype] | None:
    """The shape, order and dtype of a ``.npy`` header as ``np.save`` writes
    it, read without numpy's parser (and its lock); ``None`` for any other
    (the stream is then where it was)."""
    start = handle.tell()
    magic = handle.read(10)
    if len(magic) == 10 and magic[:6] == b"\x93NUMPY" and magic[6] == 1:
        size = int.from_bytes(magic[8:10], "little")
        match = _SAVED_HEADER.fullmatch(handle.read(size))
        if match is not None:
            dims = match.group(3).replace(b" ", b"").rstrip(b",")
            shape = tuple(int(d) for d in dims.split(b",")) if dims else ()
            return shape, match.group(2) == b"True", np.dtype(match.group(1).decode())
    handle.seek(start)
    return None


def _read_npy(handle: BinaryIO, name: str, file: bool = False) -> np.ndarray:
    """The array of an open ``.npy`` stream.

    The header ``np.save`` writes is read with a pattern.  Any other goes to
    numpy, which parses it with ``ast.literal_eval``; CPython 3.11 builds ASTs
    with interpreter-wide state, and two threads parsing at once can fail with
    a spurious "AST constructor recursion depth mismatch" SystemError (CPython
    gh-106905), so those headers are parsed one at a time.  (A run of many
    small tiles reads tens of thousands of work files: numpy's parser was 8%
    of its time.)  The data is read outside the lock.
    """
    header = _saved_header(handle)
    if header is None:
        with _NPY_HEADER_LOCK:
            version = np.lib.format.read_magic(handle)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            header = read(handle)
    shape, fortran, dtype = header
    count = math.prod(shape)
    if file:
        values = np.fromfile(handle, dtype=dtype, count=count)
    else:
        values = np.frombuffer(handle.read(count * dtype.itemsize), dtype=dtype, count=-1).copy()
    if values.size != count:
        raise OSError(f"{name}: truncated work file ({values.size} of {count} values)")
    return values.reshape(shape, order="F" if fortran else "C")


def _npy_bytes(array: NDArray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


class Scratch:
    """A work folder's files, below ``root`` (a local path or a URL)."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        text = os.fspath(root)
        self.remote = urls.is_url(text)
        self.root = text.rstrip("/") if self.remote else os.path.abspath(text)

    def __repr__(self) -> str:
        return f"Scratch({self.root!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Scratch) and other.root == self.root

    def __hash__(self) -> int:
        return hash(self.root)

    def __reduce__(self):  # a root crosses to workers; each opens its own filesystem
        return (Scratch, (self.root,))

    # -- where keys live ------------------------------------------------------
    def where(self, key: str) -> str:
        """The path or URL of ``key``."""
        return f"{self.root}/{key}" if key else self.root

    def path(self, key: str = "") -> Path:
        """The local path of ``key`` (local work folders only)."""
        assert not self.remote, "a work folder on object storage has no local path"
        return Path(self.root, key) if key else Path(self.root)

    def _fs(self) -> tuple[Any, str]:
        fs, root = urls.filesystem(self.root)
        return fs, root.rstrip("/")

    def _keys(self, fs_paths: Iterable[str], root: str) -> list[str]:
        return sorted(p[len(root) + 1:] for p in fs_paths if p.startswith(root + "/"))

    # -- arrays ---------------------------------------------------------------
    def save(self, key: str, array: NDArray) -> None:
        """Write one array; a reader sees the whole of it or nothing."""
        self.save_many({key: array})

    def save_many(self, arrays: Mapping[str, NDArray]) -> None:
        """Write several arrays (on object storage, in concurrent requests)."""
        if not arrays:
            return
        if self.remote:
            fs, root = self._fs()
            fs.pipe({f"{root}/{key}": _npy_bytes(value) for key, value in arrays.items()})
            return
        for key, value in arrays.items():
            target = self.path(key)
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.with_name(f".{target.name}.tmp")  # not listed as an array if left by a crash
            with open(tmp, "wb") as handle:
                try:
                    np.save(handle, value)
                except OSError as exc:
                    raise _short_write(exc, tmp, value.nbytes) from exc
            os.replace(tmp, target)

    def load(self, key: str, mmap: bool = False) -> np.ndarray:
        """One array (``mmap``: a local file larger than 1 MiB is mapped, copy-on-write)."""
        return self.load_many([key], mmap)[0]

    def load_many(self, keys: list[str], mmap: bool = False) -> list[np.ndarray]:
        """Several arrays, in the order of ``keys``; a missing one is FileNotFoundError."""
        if not self.remote:
            return [load_array(self.path(key), mmap=mmap) for key in keys]
        if not keys:
            return []
        fs, root = self._fs()
        names = [f"{root}/{key}" for key in keys]
        found = fs.cat(names, on_error="return") if len(names) > 1 else {names[0]: fs.cat_file(names[0])}
        out = []
        for name in names:
            data = found.get(name)
            if isinstance(data, BaseException):
                raise data
            if data is None:
                raise FileNotFoundError(self.where(name[len(root) + 1:]))
            out.append(_read_npy(io.BytesIO(data), self.root + name[len(root):]))
        return out

    # -- text -----------------------------------------------------------------
    def write_text(self, key: str, text: str) -> None:
        """Write a small text file; a reader sees the whole of it or nothing."""
        if self.remote:
            fs, root = self._fs()
            fs.pipe_file(f"{root}/{key}", text.encode())
            return
        target = self.path(key)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, target)

    def read_text(self, key: str) -> str:
        """A text file's content; FileNotFoundError when it is not there."""
        if self.remote:
            fs, root = self._fs()
            return fs.cat_file(f"{root}/{key}").decode()
        return self.path(key).read_text()

    # -- listing --------------------------------------------------------------
    def names(self, folder: str) -> list[str]:
        """The names of the files directly inside ``folder``, sorted (none when it is missing)."""
        if self.remote:
            fs, root = self._fs()
            try:
                found = fs.ls(f"{root}/{folder}", detail=True, refresh=True)
            except FileNotFoundError:
                return []
            return sorted(i["name"].rsplit("/", 1)[-1] for i in found if i.get("type") == "file")
        try:
            return sorted(e.name for e in os.scandir(self.path(folder)) if e.is_file())
        except (FileNotFoundError, NotADirectoryError):
            return []

    def has_folder(self, folder: str) -> bool:
        """Whether ``folder`` holds anything (on object storage: any key below it)."""
        if self.remote:
            fs, root = self._fs()
            try:
                return bool(fs.ls(f"{root}/{folder}", detail=False, refresh=True))
            except FileNotFoundError:
                return False
        return self.path(folder).is_dir()

    def glob(self, pattern: str) -> list[str]:
        """The keys matching ``pattern`` (``*`` within one level), sorted."""
        if self.remote:
            fs, root = self._fs()
            fs.invalidate_cache()
            return self._keys(fs.glob(f"{root}/{pattern}"), root)
        return sorted(str(p.relative_to(self.root)) for p in Path(self.root).glob(pattern))

    # -- removing and renaming --------------------------------------------------
    def remove(self, keys: Iterable[str]) -> None:
        """Delete files (the missing ones are already gone)."""
        keys = list(keys)
        if not keys:
            return
        if self.remote:
            fs, root = self._fs()
            try:
                fs.rm([f"{root}/{key}" for key in keys])
            except FileNotFoundError:
                pass
            return
        for key in keys:
            try:
                self.path(key).unlink()
            except FileNotFoundError:
                pass

    def remove_tree(self, folder: str = "") -> None:
        """Delete everything below ``folder`` (the whole work folder by default)."""
        if self.remote:
            fs, root = self._fs()
            target = f"{root}/{folder}" if folder else root
            try:
                fs.rm(target, recursive=True)
            except FileNotFoundError:
                pass
            fs.invalidate_cache()
            return
        shutil.rmtree(self.path(folder), ignore_errors=True)

    def rename(self, old: str, new: str) -> None:
        """Move one file to another key (on object storage: a copy, then a delete)."""
        if self.remote:
            fs, root = self._fs()
            fs.mv(f"{root}/{old}", f"{root}/{new}")
            return
        os.replace(self.path(old), self.path(new))

    def make(self) -> None:
        """Create the folder (on object storage: check that its bucket exists)."""
        if not self.remote:
            Path(self.root).mkdir(parents=True, exist_ok=True)
            return
        fs, root = self._fs()
        bucket = root.split("/", 1)[0]
        if urls.protocol(self.root) == "s3" and not fs.exists(bucket):
            raise FileNotFoundError(f"{self.root}: no such bucket")
