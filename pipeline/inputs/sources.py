"""Input layer: find LAS/LAZ files, read their headers, stream their points.

Every LAS version from 1.0 to 1.4 and every point format is read through
laspy (LAZ through lazrs; COPC files are read as plain LAZ). Points are
always streamed in chunks (``laspy.open(path).chunk_iterator(n)``); no
function here loads a whole file.

Anything wrong with a file (missing, unreadable, not LAS, truncated, corrupt
LAZ, non-finite coordinates) raises :class:`~pipeline.errors.InputFileError`
with a one-line message that starts with the file's path.

Examples
--------
>>> flt = PointFilter(classes=[2, 9])
>>> sorted(flt.classes), flt.keep_withheld
([2, 9], False)
>>> PointFilter.from_dict(flt.to_dict()) == flt
True
"""

from __future__ import annotations

import contextlib
import copy
import glob
import math
import os
import struct
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO

import laspy
import numpy as np
import pyproj
from laspy import DecompressionSelection
from numpy.typing import NDArray
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr
from pyproj.exceptions import CRSError

from ..products.attributes import Returns
from .crs import crs_label, same_crs
from .header import SourceInfo
from ..errors import InputFileError, StorageUnreachableError, UsageError, one_line, os_error_reason
from .layout import check_header, check_point_data
from ..urls import Location, as_location, is_url, open_input
from .. import urls

__all__ = [
    "LAS_SUFFIXES",
    "CopcNode",
    "PointChunk",
    "PointFilter",
    "class_counts",
    "discover_inputs",
    "file_digest",
    "iter_copc_nodes",
    "iter_points",
    "measured_bounds",
    "read_info",
    "with_measured_bounds",
]

#: Largest buffer of raw point records read at once (bytes).
CHUNK_BYTES = 64 * 2**20

#: File name endings (compared case-insensitively) picked up from directories and globs.
LAS_SUFFIXES = frozenset({".las", ".laz"})

_SIGNATURE = b"LASF"
_MIN_HEADER_BYTES = 227  # LAS 1.0-1.2 public header block
_GLOB_CHARS = frozenset("*?[")
_USER_DEFINED = 32767

# GeoTIFF keys (OGC 19-008r4) used to describe a CRS in LAS files.
_GT_MODEL_TYPE = 1024
_GEOGRAPHIC_TYPE = 2048
_PROJECTED_CS_TYPE = 3072
_VERTICAL_CS_TYPE = 4096
_VERTICAL_DATUM = 4098
_VERTICAL_UNITS = 4099
_WKT_RECORD_ID = 2112
_GEOKEY_RECORD_ID = 34735


# --------------------------------------------------------------------------- discovery


def discover_inputs(inputs: Sequence[str | os.PathLike[str]] | str | os.PathLike[str]) -> list[Location]:
    """Expand files, directories and glob patterns into a sorted list of LAS/LAZ files.

    Parameters
    ----------
    inputs
        Each item is a file (kept whatever its extension), a directory (all
        ``*.las``/``*.laz`` below it, any case, recursively) or a glob pattern
        (``**`` allowed; matched directories are expanded, matched files are
        kept when they end in .las/.laz). A single string is one input.
        URLs are taken the same way: an object, a prefix (``s3://bucket/survey/``)
        or a pattern (``s3://bucket/**/*.laz``).

    Returns
    -------
    list of Path or str
        Unique files as absolute paths, and objects as URLs (duplicates,
        including the same file reached twice, are dropped), sorted.

    Raises
    ------
    UsageError
        If ``inputs`` is empty.
    InputFileError
        If a named file or directory does not exist, a directory holds no
        LAS/LAZ file, or a pattern matches none.

    Examples
    --------
    >>> discover_inputs(["no/such/dir/*.laz"])
    Traceback (most recent call last):
    ...
    pipeline.errors.InputFileError: no/such/dir/*.laz: no .las/.laz file matches this pattern
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if len(inputs) == 0:
        raise UsageError("no input files given")
    found: dict[str, Location] = {}
    for item in inputs:
        text = os.fspath(item)
        if is_url(text):
            for url in urls.expand(str(urls.location(text)), LAS_SUFFIXES):
                found.setdefault(url, url)
            continue
        for path in _expand_one(text):
            # absolute: workers elsewhere (a cluster) and later runs from another folder see the same file
            found.setdefault(os.path.realpath(path), Path(os.path.abspath(path)))
    return sorted(found.values(), key=lambda p: p if isinstance(p, str) else p.as_posix())


def _expand_one(text: str) -> list[Path]:
    path = Path(text)
    if path.is_dir():
        files = _scan_dir(path)
        if not files:
            raise InputFileError(f"{text}: directory holds no .las/.laz file")
        return files
    if path.exists():
        return [path]
    if _GLOB_CHARS.intersection(text):
        files = []
        for match in sorted(glob.glob(text, recursive=True)):
            m = Path(match)
            if m.is_dir():
                files.extend(_scan_dir(m))
            elif _is_las_name(m):
                files.append(m)
        if not files:
            raise InputFileError(f"{text}: no .las/.laz file matches this pattern")
        return files
    raise InputFileError(f"{text}: no such file or directory")


def _scan_dir(directory: Path) -> list[Path]:
    files = []
    for root, dirs, names in os.walk(directory):
        dirs.sort()
        files.extend(Path(root) / name for name in sorted(names) if _is_las_name(Path(name)))
    return files


def _is_las_name(path: Path) -> bool:
    return path.suffix.lower() in LAS_SUFFIXES


# --------------------------------------------------------------------------- opening and errors


def _sniff(path: Location) -> int:
    """Check that ``path`` is a readable file starting with ``LASF``; return its size."""
    try:
        with _remote_errors(path), open_input(path) as fh:
            head = fh.read(len(_SIGNATURE))
            size = os.fstat(fh.fileno()).st_size if not is_url(path) else urls.size(path)
    except (InputFileError, StorageUnreachableError):  # a remote path's, already one line
        raise
    except OSError as exc:
        raise InputFileError(f"{path}: {_read_error(path, exc)}") from exc
    if not head:
        raise InputFileError(f"{path}: empty file (0 bytes)")
    if head != _SIGNATURE:
        raise InputFileError(f"{path}: not a LAS/LAZ file (bad signature {head!r})")
    check_header(path, size)
    return size


def _read_error(path: Location, exc: OSError) -> str:
    return urls.describe_os_error(exc, str(path)) if is_url(path) else os_error_reason(exc)


def _remote_errors(path: Location):
    """Errors of a remote ``path``'s transport as one line naming it (nothing for a local file)."""
    return urls.translated(str(path)) if is_url(path) else contextlib.nullcontext()


def _unreachable(path: Location, exc: BaseException) -> None:
    """Raise :class:`~pipeline.errors.StorageUnreachableError` if ``exc`` means
    the server of a remote ``path`` stopped answering (not a bad file)."""
    if isinstance(exc, StorageUnreachableError):
        raise exc
    cause = urls.unreachable(exc) if is_url(path) else None
    if cause is not None:
        raise urls.unreachable_error(str(path), cause) from None


def _header_error(path: Location, size: int, exc: Exception) -> InputFileError:
    """Turn whatever laspy raised while reading the header and VLRs into one clear line."""
    _unreachable(path, exc)
    msg = one_line(exc)
    if isinstance(exc, OSError):
        reason = _read_error(path, exc)
    elif isinstance(exc, laspy.errors.FileVersionNotSupported):
        reason = f"unsupported LAS version ({msg})"
    elif isinstance(exc, laspy.errors.PointFormatNotSupported):
        reason = f"unsupported point format ({msg})"
    elif isinstance(exc, laspy.errors.UnknownExtraType):
        reason = f"invalid extra-bytes description ({msg})"
    elif "too small" in msg.lower() or "to small" in msg.lower() or size < _MIN_HEADER_BYTES:
        reason = f"truncated header ({size} bytes; a LAS header needs at least {_MIN_HEADER_BYTES})"
    elif isinstance(exc, (ValueError, struct.error, EOFError)):
        reason = f"truncated or corrupt header/VLRs ({size} bytes; {msg})"
    elif isinstance(exc, laspy.errors.LaspyException):
        reason = f"invalid LAS header ({msg})"
    else:
        reason = f"cannot read the header ({type(exc).__name__}: {msg})"
    return InputFileError(f"{path}: {reason}")


def _points_error(path: Location, compressed: bool, done: int, total: int, exc: Exception) -> InputFileError:
    """Turn whatever laspy/lazrs raised while reading points into one clear line."""
    _unreachable(path, exc)
    msg = one_line(exc)
    where = f"after {done:,} of {total:,} points"
    if isinstance(exc, InputFileError):
        return exc
    if isinstance(exc, OSError):
        reason = _read_error(path, exc)
    elif compressed:
        reason = f"corrupt or truncated LAZ data {where} ({msg})"
    elif isinstance(exc, ValueError) and "buffer size" in msg:
        reason = f"point data is truncated {where} (the file ends inside a point record)"
    else:
        reason = f"cannot read points {where} ({type(exc).__name__}: {msg})"
    return InputFileError(f"{path}: {reason}")


@contextmanager
def _open(
    path: Location, selection: DecompressionSelection | None = None, streaming: bool = False
) -> Iterator[tuple[laspy.LasReader, int]]:
    """Open ``path`` with laspy, translating every failure into :class:`InputFileError`
    (``streaming``: to read its points, in large requests if it is remote)."""
    size = _sniff(path)
    selection = selection or DecompressionSelection.all()
    try:
        if is_url(path):  # a remote object (the reader closes it)
            stream = open_input(path, urls.READ_BLOCK if streaming else urls.HEADER_BLOCK)
            reader = laspy.open(stream, decompression_selection=selection, closefd=True)
        else:
            reader = laspy.open(os.fspath(path), decompression_selection=selection)
    except Exception as exc:
        raise _header_error(path, size, exc) from exc
    with reader:
        yield reader, size


def _records_available(header: laspy.LasHeader, size: int) -> int | None:
    """Whole point records present in an uncompressed file; None for LAZ (unknowable up front)."""
    if header.are_points_compressed:
        return None
    record = header.point_format.size
    start = int(header.offset_to_point_data)
    end = size
    # what follows the point records: EVLRs (1.4), waveform packets kept in the file (1.3+)
    if header.version.minor >= 4 and int(getattr(header, "number_of_evlrs", 0) or 0) > 0:
        end = min(end, max(start, int(header.start_of_first_evlr)))
    waveform = int(getattr(header, "start_of_waveform_data_packet_record", 0) or 0)
    if header.version.minor >= 3 and start < waveform < end and header.global_encoding.waveform_data_packets_internal:
        end = waveform
    return max(0, end - start) // record if record else None


def _point_counts(header: laspy.LasHeader, size: int) -> tuple[int, int | None]:
    """(points to read, whole records present or None for LAZ): the header's
    count, or the records' when it announces none (a count never filled in)."""
    announced = int(header.point_count)
    available = _records_available(header, size)
    return (available if announced == 0 and available else announced), available


def _chunks(path: Location, reader: laspy.LasReader, size: int, chunk_size: int) -> Iterator[Any]:
    """Yield laspy point records of at most ``chunk_size`` points, checking for short data."""
    check_point_data(path, size)
    header = reader.header
    compressed = bool(header.are_points_compressed)
    total, available = _point_counts(header, size)
    if total != header.point_count:  # laspy reads as many as its header says
        header.point_count = total
    if available is not None and available < total:
        raise InputFileError(
            f"{path}: point data is truncated: the file holds {available:,} of the "
            f"{total:,} points its header announces"
        )
    # a chunk never takes more than CHUNK_BYTES, whatever record length the header claims
    chunk_size = max(1, min(chunk_size, CHUNK_BYTES // max(1, header.point_format.size)))
    done = 0
    iterator = reader.chunk_iterator(chunk_size)
    while done < total:
        expected = min(chunk_size, total - done)
        try:
            chunk = next(iterator, None)
        except Exception as exc:
            raise _points_error(path, compressed, done, total, exc) from exc
        got = 0 if chunk is None else len(chunk)
        if got < expected:
            raise InputFileError(
                f"{path}: point data ends after {done + got:,} of the {total:,} points "
                "its header announces (truncated or corrupt file)"
            )
        done += got
        yield chunk


def _check_chunk_size(chunk_size: int) -> int:
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer)) or chunk_size <= 0:
        raise UsageError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    return int(chunk_size)


# --------------------------------------------------------------------------- header information


def read_info(path: str | os.PathLike[str]) -> SourceInfo:
    """Read the header and VLRs of one LAS/LAZ file (fast: no point is decoded).

    Raises
    ------
    InputFileError
        If the file is missing, unreadable, not LAS/LAZ, or its header is truncated.
    """
    path = as_location(path)
    with _open(path) as (reader, size):
        header = reader.header
        try:
            return _info_from_header(path, size, header)
        except InputFileError:
            raise
        except Exception as exc:  # laspy trips over corrupt VLRs in many ways (e.g. ZeroDivisionError)
            raise _header_error(path, size, exc) from exc


def _info_from_header(path: Location, size: int, header: laspy.LasHeader) -> SourceInfo:
    notes: list[str] = []
    crs_wkt, crs_problem, z_unit, crs_notes = _parse_crs(header)
    notes.extend(crs_notes)

    pf = header.point_format
    extra_dims = tuple((d.name, _dtype_name(d.dtype)) for d in pf.extra_dimensions)
    n_eb_vlrs = sum(1 for v in _all_vlrs(header) if v.user_id == "LASF_Spec" and v.record_id == 4)
    if n_eb_vlrs > 1:
        notes.append(
            f"{n_eb_vlrs} extra-bytes VLRs (the LAS spec allows one): only the first is "
            "decoded, later dimensions appear as unnamed 'ExtraBytes'"
        )

    total, available = _point_counts(header, size)
    if total != header.point_count:
        notes.append(f"the header announces no points but the file holds {available:,} point records: all are read")
    elif available is not None and available < total:
        notes.append(f"point data is truncated: the file holds {available:,} of the {total:,} points announced")
    elif available is not None and available > total:
        notes.append(
            f"the file holds {available:,} point records but its header announces {total:,}: "
            f"only the announced ones are read ({available - total:,} left out)"
        )
    try:
        check_point_data(path, size)
    except InputFileError as exc:
        notes.append(str(exc).removeprefix(f"{path}: "))
    scales = tuple(float(s) for s in header.scales)
    offsets = tuple(float(o) for o in header.offsets)
    if not _usable_scaling(path, scales, offsets, total):
        notes.append(_scaling_problem(scales, offsets))
    if total == 0:
        notes.append("the header announces no points")

    is_copc = any(v.user_id == "copc" and v.record_id == 1 for v in header.vlrs)
    info = SourceInfo(
        path=path,
        size_bytes=size,
        version=f"{header.version.major}.{header.version.minor}",
        point_format=int(pf.id),
        point_count=total,
        bounds=tuple(float(v) for v in (*header.mins, *header.maxs)),  # type: ignore[arg-type]
        scales=scales,  # type: ignore[arg-type]
        offsets=offsets,  # type: ignore[arg-type]
        crs_wkt=crs_wkt,
        crs_problem=crs_problem,
        has_extra_bytes=bool(extra_dims),
        is_copc=is_copc,
        compressed=bool(header.are_points_compressed),
        z_unit=z_unit,
        extra_dims=extra_dims,
        notes=tuple(notes),
    )
    if not info.bounds_usable:
        info = replace(info, notes=(*info.notes, f"unusable header bounds {info.bounds}"))
    return info


def with_measured_bounds(info: SourceInfo, chunk_size: int = 2_000_000) -> SourceInfo:
    """``info`` with the bounds of its points, every one read (for a header
    whose bounds are unusable: NaN, min > max, never filled in)."""
    bounds = measured_bounds(info, chunk_size)
    if bounds is None:
        return info
    note = f"header bounds unusable: {bounds} measured from its points"
    return replace(info, bounds=bounds, notes=(*(n for n in info.notes if not n.startswith("unusable header")), note))


def measured_bounds(info: SourceInfo, chunk_size: int = 2_000_000) -> tuple[float, ...] | None:
    """The bounds ``(xmin, ymin, zmin, xmax, ymax, zmax)`` of the file's points,
    every one read (None when it holds none)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for chunk in iter_points(info.path, PointFilter(classes=None, keep_withheld=True), chunk_size):
        if chunk.x.size:
            xyz = (chunk.x, chunk.y, chunk.z)
            lo = np.minimum(lo, [a.min() for a in xyz])
            hi = np.maximum(hi, [a.max() for a in xyz])
    if not np.isfinite(lo).all():
        return None
    return tuple(float(v) for v in (*lo, *hi))


def _dtype_name(dtype: Any) -> str:
    dt = np.dtype(dtype)
    if dt.shape:
        return f"{dt.base.name}[{','.join(map(str, dt.shape))}]"
    return dt.name


def _all_vlrs(header: laspy.LasHeader) -> list[Any]:
    return [*header.vlrs, *(header.evlrs or [])]


def _decoded(records: list, record_id: int, kind: type, what: str, problems: list[str]):
    """The ``records`` with ``record_id`` that laspy decoded as ``kind``, in
    order; each one it could not decode is noted in ``problems``."""
    for rec in records:
        if rec.record_id != record_id:
            continue
        if not isinstance(rec, kind):
            problems.append(f"{what} present but could not be decoded")
            continue
        yield rec


def _parse_crs(header: laspy.LasHeader) -> tuple[str | None, str | None, str | None, list[str]]:
    """Return (WKT2, problem, z unit, notes) from the WKT and GeoTIFF records.

    The WKT record is preferred (laspy's choice, and the only one LAS 1.4
    point formats 6-10 allow); GeoTIFF keys are the fallback. Unlike laspy,
    this tells "no CRS record" from "a record that cannot be used".
    """
    records = [v for v in _all_vlrs(header) if v.user_id == "LASF_Projection"]
    problems: list[str] = []
    notes: list[str] = []

    wkt_crs: pyproj.CRS | None = None
    for rec in _decoded(records, _WKT_RECORD_ID, WktCoordinateSystemVlr, "WKT record", problems):
        text = (rec.string or "").strip().strip("\x00").strip()
        if not text:
            problems.append("WKT record present but empty")
            continue
        try:
            wkt_crs = pyproj.CRS.from_wkt(text)
            break
        except CRSError:
            shown = text if len(text) <= 40 else text[:37] + "..."
            problems.append(f'WKT record present but unparsable: "{shown}"')

    geo_crs: pyproj.CRS | None = None
    z_unit: str | None = None
    for rec in _decoded(records, _GEOKEY_RECORD_ID, GeoKeyDirectoryVlr, "GeoTIFF key directory", problems):
        geo_crs, z_unit, problem, geo_notes = _crs_from_geokeys(rec)
        notes.extend(geo_notes)
        if problem:
            problems.append(problem)
        break

    crs = wkt_crs or geo_crs
    if wkt_crs is not None and geo_crs is not None and not same_crs(wkt_crs, geo_crs):
        notes.append(
            f"GeoTIFF keys ({crs_label(geo_crs)}) disagree with the WKT record ({crs_label(wkt_crs)}); using the WKT"
        )
    if crs is None:
        return None, ("; ".join(problems) or None), z_unit, notes
    if problems:
        notes.extend(f"ignored: {p}" for p in problems)
    if crs.is_compound and len(crs.sub_crs_list) > 1:
        z_unit = crs.sub_crs_list[1].axis_info[0].unit_name
    return crs.to_wkt(), None, z_unit, notes


def _crs_from_geokeys(
    rec: GeoKeyDirectoryVlr,
) -> tuple[pyproj.CRS | None, str | None, str | None, list[str]]:
    """(CRS, z unit, problem, notes) from a GeoTIFF key directory (EPSG codes only)."""
    keys = {k.id: k.value_offset for k in rec.geo_keys if k.tiff_tag_location == 0 and k.id != 0}
    notes: list[str] = []
    horizontal: pyproj.CRS | None = None
    problem: str | None = None
    for key_id, kind in ((_PROJECTED_CS_TYPE, "projected"), (_GEOGRAPHIC_TYPE, "geographic")):
        code = keys.get(key_id)
        if code is None or code == 0:
            continue
        if code == _USER_DEFINED:
            problem = f"GeoTIFF keys describe a user-defined {kind} CRS (code 32767), which cannot be read"
            break
        try:
            horizontal = pyproj.CRS.from_epsg(code)
            problem = None
            break
        except CRSError:
            problem = f"GeoTIFF {kind} CRS code {code} is not a known EPSG code"
            break
    if horizontal is None and problem is None:
        problem = "GeoTIFF key directory present but names no CRS"

    z_unit = None
    unit_code = keys.get(_VERTICAL_UNITS)
    if unit_code:
        z_unit = _epsg_unit_name(unit_code)
    vertical: pyproj.CRS | None = None
    v_code = keys.get(_VERTICAL_CS_TYPE)
    if v_code and v_code != _USER_DEFINED:
        try:
            vertical = pyproj.CRS.from_epsg(v_code)
        except CRSError:
            vertical = None
        if vertical is None or not vertical.is_vertical:
            note = f"GeoTIFF VerticalCSTypeGeoKey {v_code} is not a vertical CRS code (ignored)"
            datum_code = keys.get(_VERTICAL_DATUM)
            if datum_code and _is_vertical_crs_code(datum_code):
                note += f"; VerticalDatumGeoKey holds {datum_code}, a vertical CRS code: the two keys look swapped"
            if z_unit:
                note += f"; z unit per VerticalUnitsGeoKey: {z_unit}"
            notes.append(note)
            vertical = None
    if horizontal is not None and vertical is not None and not horizontal.is_compound:
        horizontal = pyproj.crs.CompoundCRS(
            name=f"{horizontal.name} + {vertical.name}", components=[horizontal, vertical]
        )
    return horizontal, z_unit, problem, notes


def _is_vertical_crs_code(code: int) -> bool:
    try:
        return bool(pyproj.CRS.from_epsg(code).is_vertical)
    except CRSError:
        return False


def _epsg_unit_name(code: int) -> str:
    from pyproj.database import get_units_map

    for unit in get_units_map(auth_name="EPSG").values():
        if unit.code == str(code):
            return str(unit.name)
    return f"EPSG unit {code}"


# --------------------------------------------------------------------------- points


_CLASS_SELECTION = DecompressionSelection.base().decompress_classification()
_POINT_SELECTION = DecompressionSelection.base().decompress_z().decompress_classification().decompress_flags()
# what _POINT_SELECTION decompresses past x, y, z and the flags (point_index is no dimension)
_IN_POINT_SELECTION = frozenset({"classification", "return_number", "number_of_returns", "point_index"})
# the LAZ layer (point formats 6 to 10) of each other attribute: a layer left compressed
# does not read as zeros but as the first value of its chunk, over and over
_ATTRIBUTE_LAYERS = {"intensity": DecompressionSelection.INTENSITY}


def _point_selection(attributes: Sequence[str]) -> DecompressionSelection:
    """The layers of a LAS 1.4 LAZ file to decompress for x, y, z, the
    classes, the flags and ``attributes`` (every layer for a name not known
    here); files of other point formats decompress every field anyway."""
    selection = _POINT_SELECTION
    for name in attributes:
        if name not in _IN_POINT_SELECTION:
            selection |= _ATTRIBUTE_LAYERS.get(name, DecompressionSelection.all())
    return selection


def class_counts(path: str | os.PathLike[str], chunk_size: int = 2_000_000) -> dict[int, int]:
    """Count the points of each classification code, streaming the file.

    Returns
    -------
    dict
        ``{class code: count}`` for the codes present, in increasing order.

    Raises
    ------
    InputFileError
        If the file cannot be read to its end.
    """
    path = as_location(path)
    chunk_size = _check_chunk_size(chunk_size)
    counts = np.zeros(256, dtype=np.int64)
    with _open(path, _CLASS_SELECTION, streaming=True) as (reader, size):
        for chunk in _chunks(path, reader, size, chunk_size):
            counts += np.bincount(np.asarray(chunk.classification, dtype=np.uint8), minlength=256)
    return {int(c): int(counts[c]) for c in np.flatnonzero(counts)}


@dataclass(frozen=True)
class PointFilter:
    """Which points :func:`iter_points` keeps.

    Parameters
    ----------
    classes
        Classification codes to keep (0-255), or None for all classes.
    keep_withheld
        Keep points whose *withheld* flag is set (dropped by default).
    returns
        Which returns to keep (:class:`~pipeline.inputs.attributes.Returns`):
        ``all`` (default), ``first``, ``last`` or ``single``.

    Examples
    --------
    >>> PointFilter(classes={2}).to_dict()
    {'classes': [2], 'keep_withheld': False}
    >>> PointFilter(classes=[300])
    Traceback (most recent call last):
    ...
    pipeline.errors.UsageError: classification codes must be in 0-255, got [300]
    """

    classes: frozenset[int] | None = None
    keep_withheld: bool = False
    returns: Returns = Returns.ALL

    def __post_init__(self) -> None:
        if self.classes is not None:
            if isinstance(self.classes, (str, bytes)) or not isinstance(self.classes, Iterable):
                raise UsageError(f"classes must be a set of integers or None, got {self.classes!r}")
            values = list(self.classes)
            if not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) for c in values):
                raise UsageError(f"classification codes must be integers, got {sorted(values, key=str)}")
            bad = sorted(int(c) for c in values if not 0 <= c <= 255)
            if bad:
                raise UsageError(f"classification codes must be in 0-255, got {bad}")
            object.__setattr__(self, "classes", frozenset(int(c) for c in values))
        if not isinstance(self.keep_withheld, (bool, np.bool_)):
            raise UsageError(f"keep_withheld must be True or False, got {self.keep_withheld!r}")
        object.__setattr__(self, "keep_withheld", bool(self.keep_withheld))
        object.__setattr__(self, "returns", Returns.parse(self.returns))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (inverse of :meth:`from_dict`); ``returns`` only when not all."""
        out: dict[str, Any] = {
            "classes": None if self.classes is None else sorted(self.classes),
            "keep_withheld": self.keep_withheld,
        }
        if self.returns is not Returns.ALL:
            out["returns"] = self.returns.value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PointFilter:
        """Rebuild from :meth:`to_dict` output."""
        unknown = set(data) - {"classes", "keep_withheld", "returns"}
        if unknown:
            raise UsageError(f"unknown PointFilter fields {sorted(unknown)}; valid: classes, keep_withheld, returns")
        classes = data.get("classes")
        return cls(
            classes=None if classes is None else frozenset(classes),
            keep_withheld=data.get("keep_withheld", False),
            returns=data.get("returns", Returns.ALL),
        )


@dataclass(frozen=True, eq=False)
class PointChunk:
    """The points kept from one chunk of a file, and how many were dropped.

    ``read == kept + filtered_withheld + filtered_class + filtered_returns + outside_window``:
    withheld points are counted in ``filtered_withheld`` whatever their class;
    ``filtered_class`` counts the remaining points outside the kept classes,
    ``filtered_returns`` those of the kept classes that the return filter drops.

    Parameters
    ----------
    x, y, z
        Scaled coordinates (float64) of the kept points, in file units.
    read
        Points read from the file for this chunk.
    filtered_class
        Points dropped for their classification.
    filtered_withheld
        Points dropped for their withheld flag.
    outside_window
        Points of COPC nodes outside the ``window`` of :func:`iter_points`,
        never read (``read`` counts them too).
    filtered_returns
        Points dropped by the return filter.
    attributes
        The kept points' attributes asked of :func:`iter_points`, by name.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    read: int
    filtered_class: int
    filtered_withheld: int
    outside_window: int = 0
    filtered_returns: int = 0
    attributes: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def kept(self) -> int:
        """Number of points kept."""
        return int(self.x.shape[0])


def iter_points(
    path: str | os.PathLike[str],
    point_filter: PointFilter | None = None,
    chunk_size: int = 2_000_000,
    window: tuple[float, float, float, float] | None = None,
    attributes: Sequence[str] = (),
) -> Iterator[PointChunk]:
    """Stream the filtered points of one file in chunks of at most ``chunk_size`` points.

    Arguments are checked at once; the file is opened at the first ``next()``.
    A chunk is yielded for every chunk read, even when all its points were
    filtered out, so that the counts add up to the header's point count.

    Parameters
    ----------
    path
        LAS/LAZ file.
    point_filter
        Which points to keep; default: every class, withheld points dropped.
    chunk_size
        Points read per chunk.
    window
        ``(xmin, ymin, xmax, ymax)`` in file units: only points in it are
        wanted.  A COPC file then reads just the octree nodes that meet it
        (over HTTP, ranged requests for just those bytes); the points of the
        other nodes come as one chunk of ``outside_window`` points, none kept.
        Other files are read whole: the caller filters.
    attributes
        Point attributes (:class:`~pipeline.inputs.attributes.Attribute`
        names) to decode for the kept points, in ``PointChunk.attributes``
        (as the record's integers: ``point_index`` as float64); none by
        default: x, y, z only.

    Raises
    ------
    InputFileError
        If the file cannot be opened, its point data ends before the header's
        point count, a LAZ chunk is corrupt, or a coordinate is NaN/inf after
        scaling.
    UsageError
        If ``chunk_size`` is not a positive integer.
    """
    point_filter = PointFilter() if point_filter is None else point_filter
    if not isinstance(point_filter, PointFilter):
        raise UsageError(f"point_filter must be a PointFilter, got {type(point_filter).__name__}")
    if window is not None:
        window = tuple(float(v) for v in window)  # type: ignore[assignment]
        if len(window) != 4 or not all(math.isfinite(v) for v in window) or window[0] > window[2] or window[1] > window[3]:
            raise UsageError(f"window must be (xmin, ymin, xmax, ymax) with min <= max, got {window!r}")
    from ..products.attributes import Attribute

    attributes = tuple(Attribute(a).value for a in attributes)
    return _iter_points(as_location(path), point_filter, _check_chunk_size(chunk_size), window, attributes)


#: the largest magnitude a stored coordinate (a 32-bit integer) can have
_STORED_MAX = 2.0**31


def _scaling_problem(scales: tuple[float, ...], offsets: tuple[float, ...]) -> str | None:
    """Why these scale factors and offsets cannot decode coordinates, or None.

    Every number the decoding takes from the header is checked for finiteness
    and range before any arithmetic: a scale must be finite and non-zero, and
    so must its reciprocal (the decoder divides by it); an offset must be
    finite; and no stored integer may scale to an infinite coordinate.
    """
    if not all(math.isfinite(s) and s != 0 and math.isfinite(1.0 / s) for s in scales):
        return f"unusable scale factors {scales}"
    if not all(math.isfinite(o) for o in offsets):
        return f"unusable offsets {offsets}"
    if not all(math.isfinite(abs(s) * _STORED_MAX + abs(o)) for s, o in zip(scales, offsets)):
        return f"scale factors {scales} and offsets {offsets} give infinite coordinates"
    return None


def _usable_scaling(path: Location, scales: tuple[float, ...], offsets: tuple[float, ...], points: int) -> bool:
    """Whether the header's scale factors and offsets decode coordinates
    (:func:`_scaling_problem`); unusable ones are an error for a file with
    points."""
    problem = _scaling_problem(scales, offsets)
    if problem is None:
        return True
    if points:
        raise InputFileError(f"{path}: {problem}: its coordinates cannot be decoded")
    return False


def _decoder(scale: float, offset: float) -> Callable[[NDArray[np.integer]], NDArray[np.float64]]:
    """Stored integers to coordinates, the same float for the same coordinate
    in every file (whatever its offset).

    ``X * scale + offset`` rounds twice, at offsets that differ from file to
    file, so one point of two overlapping files can come out an ulp apart
    and escape duplicate merging.  When the offset is a whole number of
    scale steps, ``X + offset / scale`` is an exact integer ``k``, and the
    coordinate is ``k / (1 / scale)`` rounded once: with a scale like 0.01 the
    float nearest the decimal value itself, whatever the scale of the file.
    """
    steps = offset / scale if scale else math.nan
    per_unit = 1.0 / scale if scale else math.inf  # inf for a scale so small: the plain decoding below
    # offset / scale is off a whole number by its own rounding at most (a few ulps of it)
    on_lattice = math.isfinite(steps) and abs(steps - round(steps)) <= max(1e-6, 8.0 * math.ulp(steps))
    if not (on_lattice and abs(steps) < 2.0**52 - 2.0**32 and abs(per_unit) < 2.0**52):
        return lambda stored: stored * scale + offset  # off the lattice: as the header says
    shift = float(round(steps))
    whole = abs(per_unit - round(per_unit)) <= 4.0 * math.ulp(per_unit)  # 1 / 0.01, not 1 / 0.010000000009
    divisor = float(round(per_unit))

    def decode(stored: NDArray[np.integer]) -> NDArray[np.float64]:
        values = stored.astype(np.float64)
        values += shift  # exact: integers below 2**53
        if whole:
            values /= divisor
        else:
            values *= scale
        return values

    return decode


def _iter_points(
    path: Location, point_filter: PointFilter, chunk_size: int, window: tuple[float, float, float, float] | None,
    attributes: tuple[str, ...] = (),
) -> Iterator[PointChunk]:
    keep_class: np.ndarray | None = None
    if point_filter.classes is not None:
        keep_class = np.zeros(256, dtype=bool)
        keep_class[sorted(point_filter.classes)] = True
    if window is not None:
        windowed = _window_chunks(path, chunk_size, window, attributes)
        header = next(windowed)  # None: not a COPC file
        if header is not None:
            yield from _kept_chunks(path, header, windowed, keep_class, point_filter, attributes)
            return
    with _open(path, _point_selection(attributes), streaming=True) as (reader, size):
        chunks = ((chunk, 0) for chunk in _chunks(path, reader, size, chunk_size))
        yield from _kept_chunks(path, reader.header, chunks, keep_class, point_filter, attributes)


def _kept_chunks(path: Location, header: laspy.LasHeader, chunks: Iterator[tuple[Any, int]],
                 keep_class: np.ndarray | None, point_filter: PointFilter,
                 attributes: tuple[str, ...]) -> Iterator[PointChunk]:
    scales = tuple(float(s) for s in header.scales)
    offsets = tuple(float(o) for o in header.offsets)
    if not _usable_scaling(path, scales, offsets, int(header.point_count)):
        return  # no points to decode
    decoders = [_decoder(s, o) for s, o in zip(scales, offsets)]
    start = 0  # the chunk's first point's position in the file (a windowed COPC file: in the nodes' order)
    for chunk, unread in chunks:
        if unread:
            yield PointChunk(x=np.empty(0), y=np.empty(0), z=np.empty(0), read=unread, filtered_class=0,
                             filtered_withheld=0, outside_window=unread,
                             attributes={name: np.empty(0) for name in attributes})
            start += unread
            continue
        yield _kept(path, header, chunk, decoders, keep_class, point_filter.keep_withheld, point_filter.returns,
                    attributes, start)
        start += len(chunk)


def _kept(path: Location, header: laspy.LasHeader, chunk: Any, decoders: list, keep_class: np.ndarray | None,
          keep_withheld: bool, returns: Returns = Returns.ALL, attributes: tuple[str, ...] = (),
          start: int = 0) -> PointChunk:
    """The points of one chunk of records that the filter keeps, decoded, and the counts of the others."""
    n = len(chunk)
    keep = np.ones(n, dtype=bool)
    filtered_withheld = 0
    if not keep_withheld:
        withheld = np.asarray(chunk.withheld).astype(bool)
        filtered_withheld = int(np.count_nonzero(withheld))
        keep &= ~withheld
    filtered_class = 0
    if keep_class is not None:
        in_class = keep_class[np.asarray(chunk.classification, dtype=np.uint8)]
        filtered_class = int(np.count_nonzero(keep & ~in_class))
        keep &= in_class
    filtered_returns = 0
    if returns is not Returns.ALL:
        by_return = returns.mask(np.asarray(chunk.return_number), np.asarray(chunk.number_of_returns))
        filtered_returns = int(np.count_nonzero(keep & ~by_return))
        keep &= by_return
    every = bool(keep.all())  # the usual case: no copy of the kept points
    xyz = []
    for axis, decode in zip("xyz", decoders):
        stored = np.asarray(getattr(chunk, axis.upper()))
        values = decode(stored if every else stored[keep])
        if not np.isfinite(values).all():
            raise InputFileError(
                f"{path}: non-finite {axis} coordinate after scaling "
                f"(scales {[float(v) for v in header.scales]}, offsets {[float(v) for v in header.offsets]})"
            )
        xyz.append(values)
    kept_attributes = {}
    for name in attributes:
        if name == "point_index":
            kept_attributes[name] = np.flatnonzero(keep) + float(start)
        else:  # the record's own integers (the LAS widths: 8 or 16 bits)
            values = np.asarray(getattr(chunk, name))
            kept_attributes[name] = values.copy() if every else values[keep]
    return PointChunk(x=xyz[0], y=xyz[1], z=xyz[2], read=n, filtered_class=filtered_class,
                      filtered_withheld=filtered_withheld, filtered_returns=filtered_returns,
                      attributes=kept_attributes)


def _is_copc(header: laspy.LasHeader) -> bool:
    return any(v.user_id == "copc" and v.record_id == 1 for v in header.vlrs)


def _declares_copc(path: Location) -> bool:
    """Whether the header of ``path`` has COPC's info VLR (a header that
    cannot be read raises :class:`InputFileError`)."""
    with _open(path) as (reader, _):
        return _is_copc(reader.header)


def _window_chunks(path: Location, chunk_size: int, window: tuple[float, float, float, float],
                   attributes: Sequence[str] = ()) -> Iterator[Any]:
    """For a COPC file: its header, then ``(None, n)`` with the ``n`` points of
    the octree nodes that miss ``window`` (closed, x and y; never read), then
    the records of the nodes that meet it, in file order, in chunks of about
    ``chunk_size`` points.  For any other file: None, and nothing more."""
    from laspy.copc import Bounds, CopcReader, load_octree_for_query

    size = _sniff(path)
    stream = open_input(path, urls.NODE_BLOCK)
    try:
        with _remote_errors(path):
            try:
                reader = CopcReader(stream, close_fd=False, decompression_selection=_point_selection(attributes))
            except Exception as exc:
                # laspy: the first VLR is not COPC's info, or there is no VLR at all
                if "copc" in one_line(exc).lower() or not _declares_copc(path):
                    yield None
                    return
                raise _header_error(path, size, exc) from exc
            box = Bounds(mins=np.array([window[0], window[1], -np.inf]), maxs=np.array([window[2], window[3], np.inf]))
            nodes = load_octree_for_query(reader.source, reader.copc_info, reader.root_page, query_bounds=box)
        header = reader.header
        nodes = sorted((n for n in nodes if n.point_count > 0), key=lambda n: n.offset)
        total = int(header.point_count)
        unread = total - sum(int(n.point_count) for n in nodes)
        if unread < 0:
            raise InputFileError(f"{path}: the COPC hierarchy counts more points than the header announces ({total:,})")
        yield header
        yield None, unread
        group: list[Any] = []
        held = 0
        for k, node in enumerate(nodes):
            group.append(node)
            held += int(node.point_count)
            if held >= chunk_size or k == len(nodes) - 1:
                try:
                    with _remote_errors(path):
                        records = reader._fetch_and_decompress_points_of_nodes(group)
                except Exception as exc:
                    raise _points_error(path, True, 0, total, exc) from exc
                if len(records) != held:
                    raise InputFileError(f"{path}: COPC nodes hold {len(records):,} points where the hierarchy says {held:,}")
                yield records, 0
                group, held = [], 0
    finally:
        stream.close()


@dataclass(frozen=True, eq=False)
class CopcNode:
    """One octree node of a COPC file, as :func:`iter_copc_nodes` reads it.

    Parameters
    ----------
    level
        Depth in the octree (0: the root).
    offset
        Where its points start in the file (nodes in file order: by offset).
    bounds
        ``(xmin, ymin, xmax, ymax)`` of the node's voxel, in file units: every
        point of the node lies in it.
    points
        The node's points that the filter keeps, and the counts of the others.
    """

    level: int
    offset: int
    bounds: tuple[float, float, float, float]
    points: PointChunk


def iter_copc_nodes(
    path: str | os.PathLike[str],
    point_filter: PointFilter | None = None,
    window: tuple[float, float, float, float] | None = None,
    wanted: Callable[[int, tuple[float, float, float, float]], bool] | None = None,
) -> Iterator[CopcNode]:
    """The octree nodes of a COPC file that meet ``window`` (closed, in file
    units; every node when None), level by level from the root, each with its
    filtered points.  Only those nodes' bytes are fetched (over HTTP, ranged
    requests).

    ``wanted(level, bounds)``, asked of each node of a level just before the
    level is read, may leave a node out: a caller that learns from one level
    which nodes of the next it needs (a convex hull) reads no others.

    Raises
    ------
    InputFileError
        If the file is not COPC, or a node cannot be read.
    """
    point_filter = PointFilter() if point_filter is None else point_filter
    if window is not None:
        window = tuple(float(v) for v in window)  # type: ignore[assignment]
        if len(window) != 4 or any(math.isnan(v) for v in window) or window[0] > window[2] or window[1] > window[3]:
            raise UsageError(f"window must be (xmin, ymin, xmax, ymax) with min <= max, got {window!r}")
    return _copc_nodes(as_location(path), point_filter, window, wanted)


def _copc_nodes(path: Location, point_filter: PointFilter, window, wanted) -> Iterator[CopcNode]:
    keep_class: np.ndarray | None = None
    if point_filter.classes is not None:
        keep_class = np.zeros(256, dtype=bool)
        keep_class[sorted(point_filter.classes)] = True
    size = _sniffed(path)
    stream = open_input(path, urls.NODE_BLOCK)
    try:
        with _remote_errors(path):
            try:
                copc = _copc_file(path, stream)
            except Exception as exc:
                if "copc" in one_line(exc).lower():
                    raise InputFileError(f"{path}: not a COPC file (no COPC info record)") from None
                raise _header_error(path, size, exc) from exc
            nodes = copc.nodes_meeting(stream, window)
        header = copc.reader.header
        scales = tuple(float(v) for v in header.scales)
        offsets = tuple(float(v) for v in header.offsets)
        if not _usable_scaling(path, scales, offsets, int(header.point_count)):
            return
        decoders = [_decoder(sc, of) for sc, of in zip(scales, offsets)]
        total = int(header.point_count)
        chosen = (point_filter.classes, point_filter.keep_withheld, point_filter.returns)
        levels: dict[int, list[_Node]] = {}
        for node in nodes:
            levels.setdefault(node.level, []).append(node)
        for level in sorted(levels):
            group = sorted((n for n in levels[level] if wanted is None or wanted(level, n.bounds)),
                           key=lambda n: n.offset)
            kept = {n.key: copc.decoded(n.key, chosen) for n in group}
            missing = [n for n in group if kept[n.key] is None]
            if missing:
                try:
                    with _remote_errors(path):
                        records = copc.fetch(stream, missing)
                except Exception as exc:
                    raise _points_error(path, True, 0, total, exc) from exc
                held = sum(n.point_count for n in missing)
                if len(records) != held:
                    raise InputFileError(
                        f"{path}: COPC nodes hold {len(records):,} points where the hierarchy says {held:,}"
                    )
                start = 0
                for node in missing:  # the records come in file order, node after node
                    stop = start + node.point_count
                    kept[node.key] = copc.keep(node.key, chosen, _kept(path, header, records[start:stop], decoders,
                                                                       keep_class, point_filter.keep_withheld,
                                                                       point_filter.returns))
                    start = stop
            for node in group:
                yield CopcNode(level, node.offset, node.bounds, kept[node.key])
    finally:
        stream.close()


@dataclass(frozen=True)
class _Node:
    """One octree node with points: its key (level, x, y, z), where its
    compressed points are, and its voxel's (xmin, ymin, xmax, ymax)."""

    key: tuple[int, int, int, int]
    offset: int
    byte_size: int
    point_count: int
    bounds: tuple[float, float, float, float]

    @property
    def level(self) -> int:
        return self.key[0]


class _CopcFile:
    """What this process knows of one version of a COPC file: its header and
    VLRs, the hierarchy pages read so far, and recently decoded nodes (each
    node's points are decoded once, however many tiles' windows meet it)."""

    def __init__(self, reader: Any) -> None:
        self.reader = reader
        info = reader.copc_info
        self.origin = tuple(float(c) - float(info.halfsize) for c in info.center[:2])
        self.extent = tuple(float(c) + float(info.halfsize) for c in info.center[:2])
        self.entries: dict[tuple[int, int, int, int], tuple[int, int, int]] = {}
        self._add_page(reader.root_page)
        self._lock = threading.Lock()
        self._decoded: OrderedDict[tuple, PointChunk] = OrderedDict()
        self._decoded_bytes = 0

    def _add_page(self, page: Any) -> None:
        for key, entry in page.entries.items():
            self.entries[(key.level, key.x, key.y, key.z)] = (int(entry.offset), int(entry.byte_size),
                                                              int(entry.point_count))

    def _bounds(self, key: tuple[int, int, int, int]) -> tuple[float, float, float, float]:
        # as laspy's VoxelKey.bounds computes them: mins + index * side
        side = (self.extent[0] - self.origin[0]) / 2 ** key[0]
        return (self.origin[0] + key[1] * side, self.origin[1] + key[2] * side,
                self.origin[0] + (key[1] + 1) * side, self.origin[1] + (key[2] + 1) * side)

    def nodes_meeting(self, stream: BinaryIO, window) -> list[_Node]:
        """The nodes with points whose voxel meets ``window`` (closed; all when None)."""
        from laspy.copc import HierarchyPage

        out = []
        unvisited = [(0, 0, 0, 0)]
        while unvisited:
            key = unvisited.pop()
            bounds = self._bounds(key)
            if window is not None and not _meets(bounds, window):
                continue
            entry = self.entries.get(key)
            if entry is None:
                continue
            offset, byte_size, count = entry
            if count == -1:  # its entries are in a page not read yet
                stream.seek(offset)
                page = HierarchyPage.from_bytes(stream.read(byte_size))
                with self._lock:
                    self._add_page(page)
                    if self.entries.get(key, entry)[2] == -1:
                        self.entries[key] = (0, 0, 0)  # a page that does not describe its own root
                unvisited.append(key)
                continue
            if count > 0:
                out.append(_Node(key, offset, byte_size, count, bounds))
            level, x, y, z = key
            if count >= 0:
                unvisited.extend((level + 1, 2 * x + (d & 1), 2 * y + ((d >> 1) & 1), 2 * z + ((d >> 2) & 1))
                            for d in range(8))
        return out

    def fetch(self, stream: BinaryIO, nodes: list[_Node]) -> Any:
        """The records of ``nodes`` (in file order), fetched in as few requests as they allow."""
        from types import SimpleNamespace

        reader = copy.copy(self.reader)  # the same header; its own stream
        reader.source = stream
        return reader._fetch_and_decompress_points_of_nodes(
            [SimpleNamespace(offset=n.offset, byte_size=n.byte_size, point_count=n.point_count) for n in nodes]
        )

    #: bytes of decoded points a process keeps per file
    BUDGET = 128 * 2**20

    def decoded(self, key: tuple, chosen: tuple) -> PointChunk | None:
        with self._lock:
            found = self._decoded.get((key, chosen))
            if found is not None:
                self._decoded.move_to_end((key, chosen))
            return found

    def keep(self, key: tuple, chosen: tuple, chunk: PointChunk) -> PointChunk:
        for a in (chunk.x, chunk.y, chunk.z):
            a.flags.writeable = False  # shared by every tile that reads the node
        size = 3 * chunk.x.nbytes
        with self._lock:
            if (key, chosen) not in self._decoded and size <= self.BUDGET // 8:
                self._decoded[(key, chosen)] = chunk
                self._decoded_bytes += size
                while self._decoded_bytes > self.BUDGET:
                    _, old = self._decoded.popitem(last=False)
                    self._decoded_bytes -= 3 * old.x.nbytes
        return chunk


_OPENED: dict[tuple, _CopcFile] = {}


def _copc_file(path: Location, stream: BinaryIO) -> _CopcFile:
    """What this process knows of ``path`` (read from ``stream`` the first
    time): later tiles fetch only hierarchy pages and nodes not seen yet."""
    from laspy.copc import CopcReader

    key = (str(path), tuple(sorted(urls.version(path).items())))
    with _KNOWN_LOCK:
        known = _OPENED.get(key)
    if known is None:
        known = _CopcFile(CopcReader(stream, close_fd=False, decompression_selection=_POINT_SELECTION))
        with _KNOWN_LOCK:
            if len(_OPENED) > 16:
                _OPENED.clear()
            known = _OPENED.setdefault(key, known)
    return known


_SNIFFED: dict[tuple, int] = {}
_KNOWN_LOCK = threading.Lock()


def _sniffed(path: Location) -> int:
    """:func:`_sniff` once per version of a file in this process: a tile's
    window read of a COPC file checked by an earlier tile costs no more
    header requests."""
    key = (str(path), tuple(sorted(urls.version(path).items())))
    with _KNOWN_LOCK:
        size = _SNIFFED.get(key)
    if size is None:
        size = _sniff(path)
        with _KNOWN_LOCK:
            if len(_SNIFFED) > 4096:
                _SNIFFED.clear()
            _SNIFFED[key] = size
    return size


def _meets(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> bool:
    """Whether two closed boxes ``(xmin, ymin, xmax, ymax)`` meet."""
    return a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex): its identity whatever its time stamps.
    A remote object's is its ETag and size (:func:`pipeline.urls.identity`),
    not a second download."""
    import hashlib

    if is_url(path):
        return urls.identity(str(path))
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()
