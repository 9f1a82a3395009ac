"""The work folder of a job, and the records that let a killed job resume.

A run keeps its intermediate files (spilled points, meshed pieces) in a work
folder beside the store and records each finished unit of work there: a routed
input file, a meshed tile, a written block of the mesh.  A record is written
only after the unit's files are complete (an atomic rename), so a job killed
at any moment and run again redoes only the units without a record.  DEM
tiles are recorded in the store itself (``tile_done``).  The folder is removed
when the store is complete.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import math
import os
import shutil
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from .errors import UsageError
from .urls import is_url

__all__ = ["WorkDir", "work_dir_for", "output_lock"]


_NPY_HEADER_LOCK = threading.Lock()


_MAP_ABOVE = 1 << 20
"""Work files up to this size are read, not memory-mapped: reading a small
file costs half as much as mapping it."""


def load_array(path: str | os.PathLike[str], mmap: bool = False) -> np.ndarray:
    """``np.load`` of a work file, safe in threads; memory-mapped (read only)
    with ``mmap`` when the file is larger than 1 MiB.

    numpy parses a ``.npy`` header with ``ast.literal_eval``, and CPython 3.11
    builds ASTs with interpreter-wide state: two threads parsing at once can
    fail with a spurious "AST constructor recursion depth mismatch"
    SystemError (CPython gh-106905).  Headers are parsed one at a time (a
    memory map costs only its header); the data is read outside the lock.
    """
    if mmap and os.path.getsize(path) > _MAP_ABOVE:
        with _NPY_HEADER_LOCK:
            return np.load(path, mmap_mode="r")
    with open(path, "rb") as handle:
        with _NPY_HEADER_LOCK:
            version = np.lib.format.read_magic(handle)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(handle)
        count = math.prod(shape)
        values = np.fromfile(handle, dtype=dtype, count=count)
    if values.size != count:
        raise OSError(f"{path}: truncated work file ({values.size} of {count} values)")
    return values.reshape(shape, order="F" if fortran else "C")


def work_dir_for(output: str, scratch_dir: str | None) -> Path:
    """``.NAME.work`` beside the store, or ``.NAME-HASH.work`` inside
    ``scratch_dir`` when given (HASH of the store's path: two stores of one
    name in different folders may share a scratch folder).  A store on object
    storage keeps its work folder on this machine: in ``scratch_dir``, or in
    the system's temporary folder."""
    if is_url(output):
        name = output.rstrip("/").rsplit("/", 1)[-1]
        digest = hashlib.sha1(output.encode()).hexdigest()[:10]
        return Path(os.path.abspath(scratch_dir or local_scratch())) / f".{name}-{digest}.work"
    out = Path(os.path.abspath(output))  # normalised: "a/../b.zarr" and "b.zarr" are one store
    if not scratch_dir:
        return out.parent / f".{out.name}.work"
    digest = hashlib.sha1(os.fsencode(out)).hexdigest()[:10]
    return Path(os.path.abspath(scratch_dir)) / f".{out.name}-{digest}.work"


def local_scratch() -> str:
    """Where work folders of stores on object storage go by default."""
    return os.path.join(tempfile.gettempdir(), "terrain-work")


@contextmanager
def output_lock(output: str) -> Iterator[None]:
    """Hold ``.NAME.lock`` beside the store for the length of a run: a second
    run on the same store fails at once instead of deleting the first one's
    work.  The lock is the operating system's (``flock``), so a run that dies
    releases it; the file is removed when the run ends."""
    if is_url(output):  # a lock on this machine: runs on other machines are not seen
        work = work_dir_for(output, None)
        path = work.with_name(work.name.removesuffix(".work") + ".lock")
    else:
        out = Path(os.path.abspath(output))
        path = out.parent / f".{out.name}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        handle = open(path, "a")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise UsageError(
                f"{output}: another run is writing this store (it holds {path}); wait for it to end or stop it"
            ) from None
        try:
            if os.stat(path).st_ino == os.fstat(handle.fileno()).st_ino:
                break  # the file is still the lock file: ours
        except FileNotFoundError:
            pass
        handle.close()  # a run ending removed it after we opened it: take the new one
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        handle.close()


class WorkDir:
    """The work folder of one job and its records of finished work."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def reset(self) -> None:
        """Start over: an empty folder."""
        shutil.rmtree(self.path, ignore_errors=True)
        self.path.mkdir(parents=True)

    def exists(self) -> bool:
        return (self.path / "records").is_dir()

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)

    def _record_path(self, stage: str, key: str) -> Path:
        return self.path / "records" / stage / f"{key}.json"

    def record(self, stage: str, key: str, payload: dict[str, Any], **arrays: np.ndarray) -> None:
        """Record a finished unit of work (with small arrays); atomic."""
        target = self._record_path(stage, key)
        target.parent.mkdir(parents=True, exist_ok=True)
        for name, value in arrays.items():
            tmp = target.with_name(f"{key}.{name}.tmp.npy")
            np.save(tmp, value)
            os.replace(tmp, target.with_name(f"{key}.{name}.npy"))
        tmp = target.with_suffix(".tmp")
        tmp.write_text(json.dumps(payload))
        os.replace(tmp, target)

    def recorded(self, stage: str, key: str, *arrays: str) -> dict[str, Any] | None:
        """The payload of a finished unit (arrays under their names), or None."""
        target = self._record_path(stage, key)
        try:
            payload = json.loads(target.read_text())
        except (OSError, ValueError):
            return None
        for name in arrays:
            payload[name] = load_array(target.with_name(f"{key}.{name}.npy"))
        return payload

    def forget_record(self, stage: str, key: str) -> None:
        """Drop one record and its arrays (that unit of work will be redone)."""
        target = self._record_path(stage, key)
        for path in target.parent.glob(f"{key}.*"):
            path.unlink()

    def rename_record(self, stage: str, old: str, new: str) -> None:
        """Move a record (and its arrays) to another key."""
        target = self._record_path(stage, old)
        for path in list(target.parent.glob(f"{old}.*")):
            path.rename(path.with_name(new + path.name[len(old):]))

    def forget(self, stage: str) -> None:
        """Drop every record of a stage (its work will be redone)."""
        shutil.rmtree(self.path / "records" / stage, ignore_errors=True)
