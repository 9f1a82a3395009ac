"""The work folder of a job, and the records that let a killed job resume.

A run keeps its intermediate files (spilled points, meshed pieces) in a work
folder beside the store (a :class:`~pipeline.tiling.scratch.Scratch`, on this disk or
on object storage) and records each finished unit of work there: a routed
input file, a meshed tile, a written block of the mesh.  A record is written
only after the unit's files are complete, and appears whole, so a job killed
at any moment and run again redoes only the units without a record.  DEM
tiles are recorded in the store itself (``tile_done``).  The folder is removed
when the store is complete.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import UsageError
from .scratch import Scratch
from ..urls import is_url

__all__ = ["WorkDir", "work_dir_for", "output_lock"]


def work_dir_for(output: str, scratch_dir: str | None, cluster: bool = False) -> str:
    """``.NAME.work`` beside the store, or ``.NAME-HASH.work`` inside
    ``scratch_dir`` when given (HASH of the store's path: two stores of one
    name in different folders may share a scratch folder); ``scratch_dir``
    may be a URL.

    A store on object storage keeps its work folder on this machine (in the
    system's temporary folder) when the run's workers are this process's
    threads, and beside the store on object storage when they are a
    ``cluster``'s, which may share no disk with this machine.
    """
    if is_url(output):
        name = output.rstrip("/").rsplit("/", 1)[-1]
        if cluster and not scratch_dir:
            return f"{output.rstrip('/').rsplit('/', 1)[0]}/.{name}.work"
        digest = hashlib.sha1(output.encode()).hexdigest()[:10]
        return _inside(scratch_dir or local_scratch(), f".{name}-{digest}.work")
    out = Path(os.path.abspath(output))  # normalised: "a/../b.zarr" and "b.zarr" are one store
    if not scratch_dir:
        return str(out.parent / f".{out.name}.work")
    digest = hashlib.sha1(os.fsencode(out)).hexdigest()[:10]
    return _inside(scratch_dir, f".{out.name}-{digest}.work")


def _inside(folder: str, name: str) -> str:
    if is_url(folder):
        return f"{folder.rstrip('/')}/{name}"
    return os.path.join(os.path.abspath(folder), name)


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
        work = Path(work_dir_for(output, None))
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


class Ledger(StrEnum):
    """The kinds of record in a work folder's ledger (``records/KIND/KEY.json``,
    arrays beside it): what each stage leaves when a unit of its work is done."""

    SOFTWARE = "software"
    """``sources``: the digest of the sources that wrote the folder (another version starts over)."""
    SURVEY = "survey"
    """``classes``: a survey-wide fallback of classes (:func:`pipeline.runs.resume.keep_all_but_noise`)."""
    ROUTE = "route"
    """One per input (:func:`source_key`): its counts, spill files and hull
    (:class:`~pipeline.tiling.routing.RouteResult`)."""
    SURFACE = "surface"
    """``variogram``: the smooth surface's variogram."""
    GROUND = "ground"
    """One per tile (:func:`~pipeline.tiling.grid.tile_key`): the ground stage's counts and the hull of its
    ground (:class:`~pipeline.meshing.ground.GroundSummary`)."""
    MESH = "mesh"
    """One per tile: its piece's summary (:class:`~pipeline.meshing.tiles.TileSummary`)."""
    WRITE = "write"
    """The store's mesh: ``created`` (the arrays' sizes), ``ids_TILE`` (a tile's global node ids), and
    ``WHAT_START`` (a block of whole chunks written)."""


def source_key(index: int) -> str:
    """An input's key in the ledger: its number in the job's inputs, six digits."""
    return f"{index:06d}"


class WorkDir:
    """The work folder of one job and its records of finished work."""

    def __init__(self, root: str | os.PathLike[str]):
        self.scratch = Scratch(root)

    @property
    def root(self) -> str:
        """The folder's path or URL (what tasks on workers are given)."""
        return self.scratch.root

    def reset(self) -> None:
        """Start over: an empty folder."""
        self.scratch.remove_tree()
        self.scratch.make()

    def exists(self) -> bool:
        return self.scratch.has_folder("records")

    def remove(self) -> None:
        self.scratch.remove_tree()

    def record(self, stage: Ledger, key: str, payload: dict[str, Any], **arrays: np.ndarray) -> None:
        """Record a finished unit of work (with small arrays); the payload is
        written last, so a record is whole or absent."""
        self.scratch.save_many({f"records/{stage}/{key}.{name}.npy": value for name, value in arrays.items()})
        self.scratch.write_text(f"records/{stage}/{key}.json", json.dumps(payload))

    def recorded(self, stage: Ledger, key: str, *arrays: str) -> dict[str, Any] | None:
        """The payload of a finished unit (arrays under their names), or None."""
        try:
            payload = json.loads(self.scratch.read_text(f"records/{stage}/{key}.json"))
        except (OSError, ValueError):
            return None
        loaded = self.scratch.load_many([f"records/{stage}/{key}.{name}.npy" for name in arrays])
        payload.update(zip(arrays, loaded))
        return payload

    def _files_of(self, stage: Ledger, key: str) -> list[str]:
        return [n for n in self.scratch.names(f"records/{stage}") if n.startswith(f"{key}.")]

    def forget_record(self, stage: Ledger, key: str) -> None:
        """Drop one record and its arrays (that unit of work will be redone)."""
        self.scratch.remove(f"records/{stage}/{name}" for name in self._files_of(stage, key))

    def rename_record(self, stage: Ledger, old: str, new: str) -> None:
        """Move a record (and its arrays) to another key."""
        for name in self._files_of(stage, old):
            self.scratch.rename(f"records/{stage}/{name}", f"records/{stage}/{new}{name[len(old):]}")

    def forget(self, stage: str) -> None:
        """Drop every record of a stage (its work will be redone)."""
        self.scratch.remove_tree(f"records/{stage}")

    def save(self, key: str, array: np.ndarray) -> None:
        """Keep an array of the whole job (the global hull) for the next run."""
        self.scratch.save(key, array)

    def load(self, key: str) -> np.ndarray | None:
        """An array :meth:`save` kept, or None."""
        try:
            return self.scratch.load(key)
        except FileNotFoundError:
            return None
