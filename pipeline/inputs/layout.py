"""Raw checks of a LAS/LAZ file's layout, made before any reader trusts its counts.

Readers allocate what a header claims: laspy makes room for every VLR the
header counts, lazrs for every chunk its chunk table counts and, in LAS 1.4
layered LAZ (point formats 6-10), for every layer size a chunk claims, zeroing
the buffer before it finds the file too short.  One corrupt 590-byte file could
so cost gigabytes.  The checks here read the few raw bytes those counts
live in and refuse any count the file cannot hold, so that memory stays
bounded by the file's size whatever its header says.  :func:`check_header`
runs before a reader opens the file, :func:`check_point_data` before points
are decoded (so that ``terrain info`` still describes a truncated LAZ file).

The layered walk follows the chunks exactly as a sequential LAZ reader does:
each chunk is its first point raw, a point count, one byte size per layer and
the layers themselves, and the next chunk starts where the last layer ends.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import BinaryIO

import lazrs

from ..errors import InputFileError, StorageUnreachableError, os_error_reason
from ..urls import Location, describe_os_error, is_url, open_input, translated

__all__ = ["MAX_CHUNK_BYTES", "check_header", "check_point_data"]

#: Largest decompressed LAZ chunk accepted (bytes): chunk size times point record length.
MAX_CHUNK_BYTES = 64 * 2**20

_VLR_HEADER_BYTES = 54
_EVLR_HEADER_BYTES = 60
_LASZIP_USER_ID = b"laszip encoded"
_LASZIP_RECORD_ID = 22204
_LAYERED_CHUNKED = 3  # LASzip compressor: LAS 1.4 layered chunks
_VARIABLE_CHUNK_SIZE = 0xFFFFFFFF
_MIN_CHUNK_BYTES = 20  # a chunk holds at least its first point raw, and no point record is shorter

# LAS 1.4 LASzip item types -> layers per item (BYTE14 has one layer per byte)
_POINT14, _RGB14, _RGBNIR14, _WAVEPACKET14, _BYTE14 = 10, 11, 12, 13, 14
_LAYERS = {_POINT14: 9, _RGB14: 1, _RGBNIR14: 2, _WAVEPACKET14: 1}


def check_header(path: Location, size: int) -> None:
    """Refuse a header whose counts exceed what the file holds, before any reader sees it.

    Checks the VLR and EVLR counts, where the point data starts and, for LAZ,
    how many chunks the chunk table claims (the LAZ reader reads the table
    when the file is opened).

    Parameters
    ----------
    path
        The file (named in the error).
    size
        Its size in bytes.

    Raises
    ------
    InputFileError
        One line naming the file and the count that cannot be.
    """
    with _reading(path) as fh:
        head = _Head.read(fh)
        if head is None:
            return  # too short for a header: the reader reports the truncation
        if head.offset > size:
            # laspy reads what it can of cut VLRs without complaint; the CRS or LAZ VLR may be lost
            raise InputFileError(
                f"{path}: truncated header/VLRs (the file is {size:,} bytes but its point data "
                f"should start at byte {head.offset:,})"
            )
        room = max(0, head.offset - head.header_size)
        if head.n_vlrs * _VLR_HEADER_BYTES > room:
            raise InputFileError(
                f"{path}: corrupt header: it claims {head.n_vlrs:,} VLRs, but only {room:,} bytes lie "
                "between the header and the point data"
            )
        if head.n_evlrs and (head.evlr_start > size or head.n_evlrs * _EVLR_HEADER_BYTES > size - head.evlr_start):
            raise InputFileError(
                f"{path}: corrupt header: it claims {head.n_evlrs:,} extended VLRs at byte "
                f"{head.evlr_start:,} of a {size:,}-byte file"
            )
        table = _chunk_table_offset(fh, head, size) if head.compressed and head.offset + 8 <= size else None
        if table is not None and table <= size - 8:
            fh.seek(table)
            _, chunks = struct.unpack("<II", fh.read(8))
            data = max(0, table - head.offset - 8)
            if chunks * _MIN_CHUNK_BYTES > data:
                raise InputFileError(
                    f"{path}: corrupt LAZ chunk table (it claims {chunks:,} chunks in {data:,} bytes of point data)"
                )


def check_point_data(path: Location, size: int) -> None:
    """Refuse LAZ point data whose description, chunk table or chunks claim more than the file holds.

    Run before points are decoded (the header is checked by :func:`check_header`).
    Checks that the LASzip items make points of the header's record length,
    that the chunk table lies inside the file and its chunks fit before it,
    and walks every layered chunk (LAS 1.4 point formats) to check that its
    layers end before the chunk table.  Plain LAS point data needs no check: its
    reads are bounded by the file's size.

    Raises
    ------
    InputFileError
        One line naming the file and what cannot be.
    """
    with _reading(path) as fh:
        head = _Head.read(fh)
        if head is None or not head.compressed or head.offset + 8 > size:
            return
        table = _chunk_table_offset(fh, head, size)
        if table is not None and table > size - 8:
            raise InputFileError(
                f"{path}: truncated or corrupt LAZ file: its chunk table should start at byte {table:,}, "
                f"beyond the end of the {size:,}-byte file"
            )
        laszip = _laszip_record(fh, head)
        if laszip is None or len(laszip) < 34:
            return  # the reader refuses a missing or short LASzip record itself
        compressor, chunk_size, items = _laszip_items(path, laszip, head.record_length)
        if table is not None:
            _check_chunk_table(fh, path, laszip, head.offset, table)
        if compressor == _LAYERED_CHUNKED and chunk_size:  # point-wise chunks size no buffer from the file
            end = size if table is None else table
            _check_layers(fh, path, items, chunk_size, head.offset + 8, end, head.point_count)


@contextmanager
def _reading(path: Location) -> Iterator[BinaryIO]:
    try:
        with translated(str(path)) if is_url(path) else nullcontext(), open_input(path) as fh:
            yield fh
    except (InputFileError, StorageUnreachableError):
        raise
    except OSError as exc:
        reason = describe_os_error(exc, str(path)) if is_url(path) else os_error_reason(exc)
        raise InputFileError(f"{path}: {reason}") from exc


@dataclass(frozen=True)
class _Head:
    """The header fields the checks need."""

    header_size: int
    offset: int
    n_vlrs: int
    compressed: bool
    record_length: int
    point_count: int
    evlr_start: int
    n_evlrs: int

    @classmethod
    def read(cls, fh: BinaryIO) -> _Head | None:
        raw = fh.read(375)
        if len(raw) < 227:
            return None
        header_size, offset, n_vlrs, point_format, record_length, legacy_count = struct.unpack_from(
            "<HIIBHI", raw, 94
        )
        evlr_start, n_evlrs, count = 0, 0, legacy_count
        if raw[25] >= 4 and len(raw) >= 255:
            evlr_start, n_evlrs, count = struct.unpack_from("<QIQ", raw, 235)
        return cls(header_size, offset, n_vlrs, bool(point_format & 0xC0), record_length,
                   count or legacy_count, evlr_start, n_evlrs)


def _chunk_table_offset(fh: BinaryIO, head: _Head, size: int) -> int | None:
    """Where the LAZ chunk table starts, found as lazrs finds it; None when there is none.

    The table offset is the first 8 bytes of the point data or, when a writer
    could not go back to fill them in, the last 8 bytes of the file.  An offset
    far beyond the file makes lazrs lose its place in the point data and read
    layer sizes from the middle of a chunk.
    """
    fh.seek(head.offset)
    (table,) = struct.unpack("<q", fh.read(8))
    if table <= head.offset:
        fh.seek(size - 8)
        (table,) = struct.unpack("<q", fh.read(8))
        if table <= head.offset:
            return None  # no chunk table: the chunks are read one after another
    return table


def _check_chunk_table(fh: BinaryIO, path: Location, laszip: bytes, offset: int, table: int) -> None:
    """Refuse a chunk table whose chunks add up to more bytes than lie before it.

    The parallel LAZ reader allocates each chunk's byte count before reading
    it.  A table that cannot be decoded at all is left alone: readers then fall
    back to reading the chunks one after another.
    """
    fh.seek(offset)
    try:
        entries = lazrs.read_chunk_table(fh, lazrs.LazVlr(laszip))
    except (lazrs.LazrsError, OSError, ValueError, OverflowError):
        return
    room = table - offset - 8
    claimed = sum(byte_count for _, byte_count in entries)
    if claimed > room:
        raise InputFileError(
            f"{path}: corrupt LAZ chunk table: its {len(entries):,} chunks claim {claimed:,} bytes, "
            f"but the point data holds {room:,}"
        )


def _laszip_record(fh: BinaryIO, head: _Head) -> bytes | None:
    """The LASzip VLR's record data, or None when the file has none."""
    at, offset = head.header_size, head.offset
    for _ in range(head.n_vlrs):
        fh.seek(at)
        raw = fh.read(_VLR_HEADER_BYTES)
        if len(raw) < _VLR_HEADER_BYTES:
            return None
        user_id = raw[2:18].split(b"\0", 1)[0]  # as laspy reads it: up to the first NUL
        record_id, length = struct.unpack_from("<HH", raw, 18)
        at += _VLR_HEADER_BYTES
        if user_id == _LASZIP_USER_ID and record_id == _LASZIP_RECORD_ID:
            # a length past the point data is read as laspy reads it: up to the point data
            return fh.read(max(0, min(length, offset - at)))
        at += length
    return None


def _laszip_items(path: Location, laszip: bytes, record_length: int) -> tuple[int, int, list[tuple[int, int]]]:
    """The compressor, chunk size and (type, size) items of a LASzip record.

    The items must add up to the header's point record length: the reader sizes
    its buffers by the items, the chunk cap by the header.  The parallel LAZ
    reader holds one whole decompressed chunk, so fixed chunks are capped at
    :data:`MAX_CHUNK_BYTES` (LASzip's default chunk of 50,000 points takes
    under 4 MiB).
    """
    compressor, _, _, _, _, _, chunk_size = struct.unpack_from("<HHBBHII", laszip, 0)
    (n_items,) = struct.unpack_from("<H", laszip, 32)
    items = [struct.unpack_from("<HH", laszip, 34 + 6 * i) for i in range(min(n_items, (len(laszip) - 34) // 6))]
    described = sum(item_size for _, item_size in items)
    if described != record_length:
        raise InputFileError(
            f"{path}: corrupt LAZ description: its items make {described:,}-byte points, "
            f"but the header's point record length is {record_length:,}"
        )
    if chunk_size != _VARIABLE_CHUNK_SIZE and chunk_size * record_length > MAX_CHUNK_BYTES:
        raise InputFileError(
            f"{path}: corrupt LAZ description: chunks of {chunk_size:,} points would take "
            f"{chunk_size * record_length / 2**20:,.0f} MiB each once decompressed "
            f"(at most {MAX_CHUNK_BYTES // 2**20} MiB is accepted)"
        )
    return compressor, chunk_size, items


def _check_layers(
    fh: BinaryIO, path: Location, items: list[tuple[int, int]], chunk_size: int, start: int, end: int, points: int
) -> int | None:
    """Walk the layered chunks from ``start``; refuse one whose layers run past ``end``.

    Returns the byte after the last chunk walked, or None when nothing was walked.
    """
    first_point = sum(item_size for _, item_size in items)
    layers = sum(item_size if kind == _BYTE14 else _LAYERS.get(kind, 0) for kind, item_size in items)
    head_bytes = first_point + 4 + 4 * layers
    at, chunk, remaining = start, 0, points
    while remaining > 0 and at < end:
        fh.seek(at)
        raw = fh.read(head_bytes)
        if len(raw) < head_bytes:
            return None  # a truncated chunk: the reader reports it without allocating
        (count,) = struct.unpack_from("<I", raw, first_point)
        sizes = struct.unpack_from(f"<{layers}I", raw, first_point + 4)
        body = sum(sizes)
        if at + head_bytes + body > end:
            raise InputFileError(
                f"{path}: corrupt LAZ chunk {chunk:,} at byte {at:,}: its layers claim {body:,} bytes, "
                f"but only {max(0, end - at - head_bytes):,} remain before "
                + ("the chunk table" if end < fh.seek(0, 2) else "the end of the file")
            )
        at += head_bytes + body
        chunk += 1
        remaining -= max(1, count) if chunk_size == _VARIABLE_CHUNK_SIZE else chunk_size
    return at
