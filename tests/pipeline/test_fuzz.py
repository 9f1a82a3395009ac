"""Fuzzing the readers: mutated LAS/LAZ bytes and headers never crash or hang.

Every case must either read or fail with an :class:`InputFileError` (a one-line
message naming the file); anything else, or a case taking longer than its time
limit, is a failure.  ``TERRAIN_FUZZ_CASES`` sets the number of cases (a few
hundred by default; thousands on demand), ``TERRAIN_FUZZ_SEED`` the seed.
"""

from __future__ import annotations

import os
import resource
import signal
import struct
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from pipeline.errors import InputFileError
from pipeline.inputs.sources import iter_points, read_info
from pipeline.tools.synthetic import SurveySpec, write_survey

from .test_sources import write_las

CASES = int(os.environ.get("TERRAIN_FUZZ_CASES", "300"))
SEED = int(os.environ.get("TERRAIN_FUZZ_SEED", "20261123"))
TIME_LIMIT = 10  # seconds per case
SHARED = Path(__file__).parents[3] / "shared" / "data"

# header fields worth lying in (offset, struct format)
FIELDS = [
    (94, "<H"),  # header size
    (96, "<I"),  # offset to point data
    (100, "<I"),  # number of VLRs
    (104, "<B"),  # point format
    (105, "<H"),  # point record length
    (107, "<I"),  # legacy point count
    (131, "<d"), (139, "<d"), (147, "<d"),  # scales
    (155, "<d"), (163, "<d"), (171, "<d"),  # offsets
    (179, "<d"), (187, "<d"), (195, "<d"), (203, "<d"),  # max/min x, y
    (235, "<Q"),  # start of EVLRs (1.4)
    (243, "<I"),  # number of EVLRs (1.4)
    (247, "<Q"),  # point count (1.4)
]
EXTREMES = [0, 1, 2**31 - 1, 2**32 - 1, 2**63 - 1, -1, float("nan"), float("inf"), -float("inf"), 1e300, 1e-300]


def _seeds(tmp_path: Path) -> list[bytes]:
    out = [
        write_las(tmp_path / "a.las", point_format=1, version="1.2", n=2000).path.read_bytes(),
        write_las(tmp_path / "b.laz", point_format=6, version="1.4", n=60_000, crs="EPSG:2154").path.read_bytes(),
        write_las(tmp_path / "c.las", point_format=3, version="1.3", n=500, extra_dims=(("amp", "f4"),)).path.read_bytes(),
    ]
    if SHARED.is_dir():
        for name in ("single_point.laz", "warsaw_small_broken_crs.las", "startinpy_small_extrabytes.laz"):
            if (SHARED / name).exists():
                out.append((SHARED / name).read_bytes())
    return out


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    buf = bytearray(data)
    kind = int(rng.integers(0, 6))
    if kind == 0:  # flip bytes anywhere
        for i in rng.integers(0, len(buf), int(rng.integers(1, 64))):
            buf[i] ^= int(rng.integers(1, 256))
    elif kind == 1:  # flip bytes in the header and VLRs
        for i in rng.integers(0, min(len(buf), 2000), int(rng.integers(1, 16))):
            buf[i] ^= int(rng.integers(1, 256))
    elif kind == 2:  # truncate
        buf = buf[: int(rng.integers(0, len(buf)))]
    elif kind == 3:  # a header field set to an extreme value
        for _ in range(int(rng.integers(1, 4))):
            offset, fmt = FIELDS[int(rng.integers(0, len(FIELDS)))]
            value = EXTREMES[int(rng.integers(0, len(EXTREMES)))]
            try:
                packed = struct.pack(fmt, value if fmt == "<d" else int(value) % (1 << (8 * struct.calcsize(fmt))))
            except (ValueError, OverflowError, struct.error):
                continue
            if offset + len(packed) <= len(buf):
                buf[offset : offset + len(packed)] = packed
    elif kind == 4:  # garbage spliced into the VLR area
        at = int(rng.integers(100, min(len(buf), 2000)))
        buf[at:at] = rng.integers(0, 256, int(rng.integers(1, 5000)), dtype=np.uint8).tobytes()
    else:  # a block of the point data repeated or zeroed
        a = int(rng.integers(0, len(buf)))
        b = min(len(buf), a + int(rng.integers(1, 20000)))
        buf[a:b] = bytes(b - a) if rng.random() < 0.5 else buf[a:b][::-1]
    return bytes(buf)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout


def _read_all(path: Path) -> int:
    info = read_info(path)
    n = 0
    for chunk in iter_points(path, chunk_size=50_000):
        n += chunk.read
    assert n <= max(info.point_count, 0) + 1  # never more points than the file holds
    return n


def test_mutated_files_read_or_fail_cleanly(tmp_path):
    seeds = _seeds(tmp_path)
    rng = np.random.default_rng(SEED)
    failures, outcomes = [], {"read": 0, "refused": 0}
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for case in range(CASES):
            seed = seeds[case % len(seeds)]
            path = tmp_path / f"case{case % 7}.{'laz' if seed[104] & 0x80 or seed[104] > 5 else 'las'}"
            path.write_bytes(_mutate(seed, rng))
            signal.alarm(TIME_LIMIT)
            try:
                _read_all(path)
                outcomes["read"] += 1
            except InputFileError as exc:
                outcomes["refused"] += 1
                message = str(exc)
                if str(path) not in message or "\n" in message:
                    failures.append((case, "message", message))
            except _Timeout:
                failures.append((case, "timeout", f"over {TIME_LIMIT} s"))
            except Exception as exc:  # noqa: BLE001 - any other exception is the finding
                failures.append((case, type(exc).__name__, str(exc)[:200]))
            finally:
                signal.alarm(0)
    finally:
        signal.signal(signal.SIGALRM, previous)
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) * 1024
    print(f"{CASES} cases: {outcomes}; failures {len(failures)}; peak RSS grew {grown / 2**20:.0f} MiB")
    assert not failures, failures[:10]
    assert outcomes["refused"] > CASES // 4 and outcomes["read"] > 0
    # lying headers, chunk tables and layer sizes do not make the readers
    # allocate what they claim (pipeline.inputs.layout checks them against the file's
    # size first; chunks are capped in bytes): 3,000 cases grow the peak by ~15 MiB
    assert grown < 256 * 2**20


@pytest.mark.parametrize("case", range(8))
def test_mutated_files_through_the_whole_job(tmp_path, case, capsys):
    rng = np.random.default_rng(SEED + case)
    folder = tmp_path / "survey"
    paths = write_survey(folder, SurveySpec(points=12_000, files=2, width=120.0, height=80.0, seed=case))
    paths[case % 2].write_bytes(_mutate(paths[case % 2].read_bytes(), rng))
    code = main(["run", str(folder), "-o", str(tmp_path / "o.zarr"), "--resolution", "2", "--no-progress"])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    assert "Traceback" not in err
    if code == 2:
        errors = [line for line in err.splitlines() if "error" in line.lower()]
        assert len(errors) == 1 and errors[0].startswith("terrain: error:"), err
