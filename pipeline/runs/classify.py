"""``terrain classify``: the ground stage's classes written back into the
inputs, as LAZ files beside them in another folder.

The inputs go through a run's route and ground stages (the same stage as
``terrain run --classify-ground``, so the same ground at any tile size), with
each point's position in its file carried along.  Then each file is streamed
again and written as LAZ with only its classification changed: class 2 on the
ground, class 1 on points the file had as ground that are not; every other
point keeps its class (noise and withheld points are never classified).
Every other dimension, the VLRs and the EVLRs are copied as they are, byte
for byte and in their order, but the LAZ VLR (the written file's
compressor's own) and, of a COPC file, the octree's VLR and EVLR: the copy
is plain LAZ, whose chunks are not the octree's nodes.  A file is written
under a temporary name and renamed when whole.
"""

from __future__ import annotations

import copy
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import RunConfig
from ..errors import OutputWriteError, UsageError
from ..meshing.ground import CLASSIFIED, GROUND_COLUMNS
from ..tiling.checkpoint import WorkDir
from .cluster import close, connect
from .plan import plan_run

__all__ = ["ClassifyReport", "classify"]

_CHUNK = 2_000_000


@dataclass
class ClassifyReport:
    """What ``terrain classify`` did, file by file."""

    files: list[dict[str, Any]] = field(default_factory=list)
    """Per input: its path, the file written, and its points by what happened to their class."""
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def table(self) -> str:
        rows = []
        for f in self.files:
            rows.append(f"{f['output']}: {f['ground']:,} ground, {f['no_longer_ground']:,} no longer ground "
                        f"(now 1), {f['unchanged']:,} unchanged, of {f['points']:,}")
        rows.append(f"time: {self.seconds:.2f} s")
        return "\n".join(rows)


def _targets(paths: list[str], output_dir: Path, overwrite: bool) -> list[Path]:
    names = [Path(str(p).rstrip("/")).name for p in paths]
    stems = [n[: -len(".copc.laz")] if n.lower().endswith(".copc.laz") else os.path.splitext(n)[0] for n in names]
    seen: dict[str, str] = {}
    for stem, path in zip(stems, paths):
        if stem in seen:
            raise UsageError(f"{path} and {seen[stem]} would both be written as {output_dir / (stem + '.laz')}")
        seen[stem] = str(path)
    targets = [output_dir / f"{stem}.laz" for stem in stems]
    for target, path in zip(targets, paths):
        if Path(path).resolve() == target.resolve():
            raise UsageError(f"{path}: the output folder is the input's own; give another -o folder")
        if target.exists() and not overwrite:
            raise UsageError(f"{target} exists; give overwrite=True to replace it")
    return targets


def classify(
    inputs: tuple[str, ...] | list[str],
    output_dir: str | os.PathLike[str],
    *,
    tile_size: float | None = None,
    buffer: float | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    in_crs: str | None = None,
    override_crs: str | None = None,
    overwrite: bool = False,
    progress: bool | None = None,
) -> ClassifyReport:
    """Classify the ground of ``inputs`` and write each as LAZ into ``output_dir``.

    Files in one CRS are classified together (a survey cut into files gets
    the ground of the whole survey); files of another CRS apart, in theirs.
    ``in_crs`` is the CRS of files without a usable CRS record;
    ``override_crs`` that of every file, whatever its record says (a wrong
    one): all are then one survey.  Either only tells the filter the
    coordinates' unit (its sizes are in metres); the files written keep
    their own records.

    Raises
    ------
    UsageError
        For an output that exists (without ``overwrite``), two inputs of one
        name, or the output folder being an input's own.
    InputFileError
        For a file that cannot be read.
    """
    from ..inputs.crs import working_crs
    from ..inputs.sources import discover_inputs, read_info

    t0 = time.perf_counter()
    out = Path(output_dir)
    paths = [str(p) for p in discover_inputs(list(inputs))]
    targets = dict(zip(paths, _targets(paths, out, overwrite)))  # every clash said before any work
    out.mkdir(parents=True, exist_ok=True)
    groups: dict[str | None, list[Any]] = {}
    for path in paths:
        info = read_info(path)
        groups.setdefault(None if override_crs is not None else info.crs_wkt, []).append(info)
    report = ClassifyReport()
    for group in groups.values():
        # the filter's sizes are metres: files in degrees are classified in their UTM zone
        work_in = working_crs(group, in_crs, override_crs=override_crs)
        if work_in is not None:
            report.notes.append(f"{', '.join(str(i.path) for i in group)}: classified in {work_in[1]} ({work_in[0]}),"
                                " the files' CRS being in degrees; the files written keep their own coordinates")
        _classify_group([str(i.path) for i in group], out, targets, report, tile_size=tile_size, buffer=buffer,
                        workers=workers, scheduler=scheduler, in_crs=in_crs, override_crs=override_crs,
                        out_crs=None if work_in is None else work_in[0], progress=progress)
    report.seconds = time.perf_counter() - t0
    return report


def _classify_group(paths: list[str], out: Path, targets: dict[str, Path], report: ClassifyReport, *,
                    tile_size, buffer, workers, scheduler, in_crs, override_crs, out_crs, progress) -> None:
    """Classify files of one CRS together (:func:`classify`)."""
    from . import resume
    from .runner import RunReport, _ground_stage, _route_stage, ground_parameters

    # the run's plan over the files as they are (files in degrees: in out_crs), cells of one unit only size the tiles
    config = RunConfig(inputs=tuple(paths), output=str(out / ".terrain-classify.zarr"), resolution=1.0,
                       tile_size=tile_size, buffer=buffer, workers=workers, scheduler=scheduler, in_crs=in_crs,
                       override_crs=override_crs, out_crs=out_crs, classify_ground=True)
    plan = plan_run(config)
    show = sys.stderr.isatty() if progress is None else progress
    report.notes.extend(plan.notes)
    work = WorkDir(tempfile.mkdtemp(prefix=".terrain-classify-", dir=out))
    resume._start_work(work)
    client, cluster = connect(config)
    try:
        run_report = RunReport()
        columns = (*GROUND_COLUMNS, "point_index")
        routed = _route_stage(plan, work, client, show, run_report, ground_columns=columns)
        _ground_stage(plan, work, client, routed, show, run_report, ground_parameters(plan, routed), columns=columns)
        report.notes.extend(run_report.notes)
        for index, path in enumerate(plan.paths):
            report.files.append(_write(str(path), targets[str(path)], _ground_positions(work, index)))
    finally:
        close(client, cluster)
        work.remove()


def _ground_positions(work: WorkDir, index: int) -> np.ndarray:
    """The positions in input ``index`` of its ground points, from every tile."""
    arrays = work.scratch.load_many(work.scratch.glob(f"tiles/*/{CLASSIFIED}/{index:06d}.npy"))
    return np.concatenate(arrays).astype(np.int64) if arrays else np.empty(0, dtype=np.int64)


_LASZIP = ("laszip encoded", 22204)
"""The LAZ VLR: the compressor's own settings (its chunk size), never the source's."""


def _vlr_table(head: bytes) -> list[tuple[bytes, int, int, int]]:
    """``(user_id, record_id, data offset, data length)`` of each VLR in a LAS header's bytes."""
    header_size = int.from_bytes(head[94:96], "little")
    count = int.from_bytes(head[100:104], "little")
    out, at = [], header_size
    for _ in range(count):
        if at + 54 > len(head):
            break
        user_id = head[at + 2:at + 18]
        record_id = int.from_bytes(head[at + 18:at + 20], "little")
        length = int.from_bytes(head[at + 20:at + 22], "little")
        out.append((user_id, record_id, at + 54, length))
        at += 54 + length
    return out


def _source_records(source: str) -> tuple[list[Any], list[Any]]:
    """The VLRs and the EVLRs of ``source`` as raw records, their bytes as
    they are (the LAS writer would serialise a parsed WKT, GeoTIFF or
    extra-bytes record anew), in their order, without the LAZ VLR and, of a
    COPC file, COPC's records."""
    import laspy

    from ..urls import open_input

    with open_input(source) as stream:
        head = stream.read(375)
        stream.seek(0)
        head = stream.read(int.from_bytes(head[96:100], "little"))  # to the point data: every VLR
        evlrs = _evlrs(stream, head)
    table = _vlr_table(head)
    copc = any((_text(user_id), record_id) == ("copc", 1) for user_id, record_id, _, _ in table)

    def kept(user_id: str, record_id: int) -> bool:
        return (user_id, record_id) != _LASZIP and not (copc and user_id == "copc")

    vlrs = [laspy.VLR(_text(user_id), record_id, _text(head[at - 32:at]), head[at:at + length])
            for user_id, record_id, at, length in table if kept(_text(user_id), record_id)]
    return vlrs, [e for e in evlrs if kept(e.user_id, e.record_id)]


def _evlrs(stream: Any, head: bytes) -> list[Any]:
    """The EVLRs of a LAS 1.4 file open as ``stream`` (``head``: its header's bytes), as raw records."""
    import laspy

    if head[25] < 4 or len(head) < 375:
        return []
    at, count = int.from_bytes(head[235:243], "little"), int.from_bytes(head[243:247], "little")
    out = []
    for _ in range(count if at else 0):
        stream.seek(at)
        record = stream.read(60)
        if len(record) < 60:
            break
        length = int.from_bytes(record[20:28], "little")
        out.append(laspy.VLR(_text(record[2:18]), int.from_bytes(record[18:20], "little"), _text(record[28:60]),
                             stream.read(length)))
        at += 60 + length
    return out


def _text(field: bytes) -> str:
    return field.split(b"\0", 1)[0].decode("ascii", errors="replace")


def _write(path: str, target: Path, ground: np.ndarray) -> dict[str, Any]:
    """Stream ``path`` into ``target`` (LAZ) with the classes of ``ground`` (positions) set."""
    import laspy
    from laspy.vlrs.vlrlist import VLRList

    from ..urls import is_url, open_input

    partial = target.with_name(f".{target.name}.partial")
    counts = {"points": 0, "ground": 0, "no_longer_ground": 0}
    ground = np.unique(ground)
    source = open_input(path) if is_url(path) else os.fspath(path)
    try:
        vlrs, evlrs = _source_records(path)
        with laspy.open(source) as reader:
            header = copy.deepcopy(reader.header)  # the reader's keeps the LAZ VLR it decompresses by
            # a COPC file's octree is not this file's (written as plain LAZ): its VLR and EVLR are left out
            header.vlrs = VLRList(vlrs)
            header.vlrs.extract("ExtraBytesVlr")  # the one the header made from the point format: the source's is kept
            with laspy.open(partial, mode="w", header=header, do_compress=True) as writer:
                start = 0
                for points in reader.chunk_iterator(_CHUNK):
                    n = len(points)
                    lo, hi = np.searchsorted(ground, [start, start + n])
                    is_ground = np.zeros(n, dtype=bool)
                    is_ground[ground[lo:hi] - start] = True
                    cls = np.asarray(points.classification).copy()
                    lost = (cls == 2) & ~is_ground
                    cls[is_ground] = 2
                    cls[lost] = 1
                    points.classification = cls
                    writer.write_points(points)
                    counts["points"] += n
                    counts["ground"] += int(is_ground.sum())
                    counts["no_longer_ground"] += int(lost.sum())
                    start += n
                if evlrs:
                    writer.write_evlrs(VLRList(evlrs))
        os.replace(partial, target)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise OutputWriteError(f"{target}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    counts["unchanged"] = counts["points"] - counts["ground"] - counts["no_longer_ground"]
    return {"path": path, "output": str(target), **counts}
