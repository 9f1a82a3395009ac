"""Memory bombs: header and chunk values that claim far more than the file holds.

Each case runs the whole ``terrain run`` in a child process whose data segment
is capped well below what the lie would make a reader allocate (gigabytes to
tens of gigabytes).  The job must end with the clear one-line error and exit
code 2; a reader that believed the lie would die of the cap instead.
"""

from __future__ import annotations

import os
import resource
import struct
import subprocess
import sys
from pathlib import Path

import laspy
import lazrs
import pytest

from pipeline.store import zarr_store as store

from .test_sources import LAMBERT93_ORIGIN, patch, write_las

CAP = 1536 * 2**20  # bytes of data segment the child may use

_OFFSET_TO_POINTS = 96
_N_VLRS = 100
_RECORD_LENGTH = 105
_START_OF_EVLRS = 235
_N_EVLRS = 243
_POINT_COUNT_14 = 247


def _run_capped(path: Path, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_DATA, (CAP, CAP))

    code = "import sys; from pipeline.cli import main; sys.exit(main(sys.argv[1:]))"
    args = [sys.executable, "-c", code, "run", str(path), "-o", str(tmp_path / "out.zarr"),
            "--resolution", "1", "--classes", "all", "--no-progress"]
    return subprocess.run(args, capture_output=True, text=True, timeout=120, preexec_fn=cap,
                          env={**os.environ, "NUMBA_DISABLE_JIT": "1"})


def _layer_sizes_at(data: bytes, chunk: int) -> int:
    """Byte offset of the layer sizes of layered LAZ ``chunk`` (point format 6, no extra bytes)."""
    (offset,) = struct.unpack_from("<I", data, _OFFSET_TO_POINTS)
    at, first_point, layers = offset + 8, 30, 9
    for _ in range(chunk):
        sizes = struct.unpack_from(f"<{layers}I", data, at + first_point + 4)
        at += first_point + 4 + 4 * layers + sum(sizes)
    return at + first_point + 4


def _layer_size_bomb(path: Path, chunk: int) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, _layer_sizes_at(bytes(data), chunk), 0xFFFF_FFF0)
    path.write_bytes(bytes(data))


def _chunk_table_bomb(path: Path) -> None:
    data = bytearray(path.read_bytes())
    (offset,) = struct.unpack_from("<I", data, _OFFSET_TO_POINTS)
    (table,) = struct.unpack_from("<q", data, offset)
    struct.pack_into("<I", data, table + 4, 0xFFFF_FFF0)
    path.write_bytes(bytes(data))


def _table_offset_bomb(path: Path) -> None:
    data = bytearray(path.read_bytes())
    (offset,) = struct.unpack_from("<I", data, _OFFSET_TO_POINTS)
    data[offset + 7] ^= 0x19  # the top byte of the chunk table offset
    path.write_bytes(bytes(data))


def _chunk_bytes_bomb(path: Path) -> None:
    """Rewrite the chunk table so that one chunk claims 2 GB."""
    header = laspy.open(path).header
    record = next(v for v in header.vlrs if v.user_id == "laszip encoded").record_data
    data = path.read_bytes()
    (offset,) = struct.unpack_from("<I", data, _OFFSET_TO_POINTS)
    (table,) = struct.unpack_from("<q", data, offset)
    with open(path, "rb") as fh:
        fh.seek(offset)
        entries = lazrs.read_chunk_table(fh, lazrs.LazVlr(record))
    entries[1] = (entries[1][0], 2_000_000_000)
    with open(path, "r+b") as fh:
        fh.truncate(table)
        fh.seek(table)
        lazrs.write_chunk_table(fh, entries, lazrs.LazVlr(record))


def _laszip_at(data: bytes) -> int:
    """Byte offset of the LASzip VLR's record data."""
    (header_size,) = struct.unpack_from("<H", data, 94)
    at = header_size
    while data[at + 2 : at + 16] != b"laszip encoded":
        at += 54 + struct.unpack_from("<H", data, at + 20)[0]
    return at + 54


def _chunk_size_bomb(path: Path) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, _laszip_at(bytes(data)) + 12, 100_000_000)
    path.write_bytes(bytes(data))


def _long_laszip_record_bomb(path: Path) -> None:
    """A chunk size bomb in a LASzip VLR whose length runs past the point data:
    laspy reads the record up to the point data all the same."""
    _chunk_size_bomb(path)
    data = bytearray(path.read_bytes())
    struct.pack_into("<H", data, _laszip_at(bytes(data)) - 54 + 20, 60_000)
    path.write_bytes(bytes(data))


def _item_size_bomb(path: Path) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into("<H", data, _laszip_at(bytes(data)) + 36, 31_774)  # the POINT14 item's size
    path.write_bytes(bytes(data))


CASES = {
    # name: (point format, version, suffix, how to corrupt, what the error says)
    "vlr count": (3, "1.2", ".las", lambda p: patch(p, _N_VLRS, "<I", 2_400_000_000), "VLRs"),
    "evlr count": (6, "1.4", ".las", lambda p: (patch(p, _START_OF_EVLRS, "<Q", 400),
                                                 patch(p, _N_EVLRS, "<I", 4_000_000_000)), "extended VLRs"),
    "chunk count": (6, "1.4", ".laz", _chunk_table_bomb, "chunk table"),
    "chunk table offset": (6, "1.4", ".laz", _table_offset_bomb, "chunk table should start"),
    "chunk byte count": (6, "1.4", ".laz", _chunk_bytes_bomb, "claim 2,"),
    "chunk size": (6, "1.4", ".laz", _chunk_size_bomb, "chunks of 100,000,000 points"),
    "item size": (6, "1.4", ".laz", _item_size_bomb, "31,774-byte points"),
    "chunk size, record past the points": (6, "1.4", ".laz", _long_laszip_record_bomb, "chunks of 100,000,000 points"),
    "layer size, first chunk": (6, "1.4", ".laz", lambda p: _layer_size_bomb(p, 0), "LAZ chunk 0"),
    "layer size, later chunk": (6, "1.4", ".laz", lambda p: _layer_size_bomb(p, 1), "LAZ chunk 1"),
    "point count (LAS)": (6, "1.4", ".las", lambda p: patch(p, _POINT_COUNT_14, "<Q", 2**62), "truncated"),
    "point count (LAZ)": (6, "1.4", ".laz", lambda p: patch(p, _POINT_COUNT_14, "<Q", 2**62), "LAZ"),
    "record length": (3, "1.2", ".las", lambda p: patch(p, _RECORD_LENGTH, "<H", 65535), ""),
}


@pytest.mark.parametrize("name", list(CASES))
def test_lying_counts_do_not_allocate_what_they_claim(tmp_path: Path, name: str) -> None:
    point_format, version, suffix, corrupt, words = CASES[name]
    path = write_las(tmp_path / f"bomb{suffix}", point_format=point_format, version=version, n=120_000,
                     crs="EPSG:2154", origin=LAMBERT93_ORIGIN).path
    corrupt(path)
    done = _run_capped(path, tmp_path)
    lines = [line for line in done.stderr.splitlines() if "error" in line.lower()]
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith(f"terrain: error: {path}: "), done.stderr
    assert words in lines[0], lines[0]
    attrs = store.read_attrs(tmp_path / "out.zarr")
    assert attrs is None or attrs["complete"] is False
