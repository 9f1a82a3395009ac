"""Tests of pipeline.inputs.sources: discovery, header info, class counts, streamed points, bad files."""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from laspy.vlrs.known import WktCoordinateSystemVlr
from numpy.testing import assert_allclose, assert_array_equal

from pipeline.errors import InputFileError, PipelineError, UsageError
from pipeline.inputs.sources import (
    PointChunk,
    PointFilter,
    SourceInfo,
    class_counts,
    discover_inputs,
    iter_points,
    read_info,
)

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"

# Byte offsets in the LAS public header block.
_VERSION_MINOR = 25
_LEGACY_POINT_COUNT = 107
_X_SCALE = 131
_X_OFFSET = 155
_POINT_COUNT_14 = 247


@dataclass(frozen=True)
class Written:
    """What a synthetic file holds, to compare with what is read back."""

    path: Path
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    classification: np.ndarray
    withheld: np.ndarray


LAMBERT93_ORIGIN = (700_000.0, 6_600_000.0)
"""Lambert-93's origin (central France): where a file with a Lambert-93 record
may lie.  The default origin of :func:`write_las` lies in the Sahara for it,
which a run refuses as a record its coordinates contradict."""


def write_las(
    path: Path,
    *,
    point_format: int = 3,
    version: str = "1.2",
    n: int = 300,
    crs: pyproj.CRS | str | None = None,
    classes: tuple[int, ...] = (1, 2, 2, 6),
    withheld_every: int = 0,
    extra_dims: tuple[tuple[str, str], ...] = (),
    origin: tuple[float, float] = (500_000.0, 4_000_000.0),
    spread: float = 100.0,
    seed: int = 0,
) -> Written:
    """Write a small LAS (or LAZ, by the suffix) file with known points."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([origin[0], origin[1], 0.0])
    for name, dtype in extra_dims:
        header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=dtype))
    if crs is not None:
        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    x = np.round(origin[0] + rng.uniform(0, spread, n), 2)
    y = np.round(origin[1] + rng.uniform(0, spread, n), 2)
    z = np.round(rng.uniform(-5, 50, n), 2)
    cls = np.resize(np.array(classes, dtype=np.uint8), n)
    withheld = np.zeros(n, dtype=bool)
    if withheld_every:
        withheld[::withheld_every] = True
    las.x, las.y, las.z = x, y, z
    las.classification = cls
    las.withheld = withheld
    las.write(path, do_compress=path.suffix.lower() == ".laz")
    return Written(path, x, y, z, cls, withheld)


def patch(path: Path, offset: int, fmt: str, value: float | int) -> None:
    """Overwrite one header field in place."""
    data = bytearray(path.read_bytes())
    struct.pack_into(fmt, data, offset, value)
    path.write_bytes(bytes(data))


def sample(name: str) -> Path:
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"real sample {name} not available (looked in {DATA})")
    return path


def assert_names(exc: pytest.ExceptionInfo[BaseException], path: Path | str) -> None:
    message = str(exc.value)
    assert message.startswith(f"{path}: "), message
    assert "\n" not in message


# --------------------------------------------------------------------------- discover_inputs


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """tmp/{b.las, a.LAZ, notes.txt, sub/c.Las, sub/deeper/d.laz}."""
    (tmp_path / "sub" / "deeper").mkdir(parents=True)
    for rel in ("b.las", "a.LAZ", "notes.txt", "sub/c.Las", "sub/deeper/d.laz"):
        (tmp_path / rel).write_bytes(b"LASF")
    return tmp_path


def test_discover_directory_is_recursive_case_insensitive_and_sorted(tree: Path) -> None:
    found = discover_inputs([tree])
    assert found == sorted(found, key=lambda p: p.as_posix())
    assert [p.relative_to(tree).as_posix() for p in found] == ["a.LAZ", "b.las", "sub/c.Las", "sub/deeper/d.laz"]


def test_discover_glob_with_double_star(tree: Path) -> None:
    found = discover_inputs([str(tree / "**" / "*.laz")])
    assert [p.name for p in found] == ["d.laz"]  # the pattern itself is case-sensitive
    found = discover_inputs([str(tree / "sub" / "*")])
    assert [p.name for p in found] == ["c.Las", "d.laz"]  # matched directories are expanded


def test_discover_removes_duplicates(tree: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tree)
    found = discover_inputs(["b.las", "./b.las", str(tree / "b.las"), ".", "*.las"])
    assert len(found) == 4
    assert len({os.path.realpath(p) for p in found}) == 4


def test_discover_keeps_an_explicit_file_whatever_its_suffix(tree: Path) -> None:
    assert discover_inputs([tree / "notes.txt"]) == [tree / "notes.txt"]


def test_discover_accepts_a_single_string(tree: Path) -> None:
    assert discover_inputs(str(tree / "b.las")) == [tree / "b.las"]


def test_discover_missing_file(tmp_path: Path) -> None:
    missing = tmp_path / "missing.las"
    with pytest.raises(InputFileError) as exc:
        discover_inputs([missing])
    assert_names(exc, missing)
    assert "no such file" in str(exc.value)


def test_discover_glob_matching_nothing(tree: Path) -> None:
    pattern = str(tree / "*.xyz")
    with pytest.raises(InputFileError) as exc:
        discover_inputs([str(tree / "b.las"), pattern])
    assert_names(exc, pattern)
    assert "matches" in str(exc.value)


def test_discover_directory_without_las(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError) as exc:
        discover_inputs([tmp_path / "empty"])
    assert_names(exc, tmp_path / "empty")


def test_discover_nothing_given() -> None:
    with pytest.raises(UsageError):
        discover_inputs([])


# --------------------------------------------------------------------------- read_info


FORMATS = [
    pytest.param(0, "1.2", ".las", "EPSG:32631", id="pf0-1.2-geotiff"),
    pytest.param(1, "1.2", ".las", None, id="pf1-1.2-nocrs"),
    pytest.param(3, "1.3", ".las", "EPSG:2154", id="pf3-1.3-geotiff"),
    pytest.param(6, "1.4", ".las", "EPSG:2154", id="pf6-1.4-wkt"),
    pytest.param(8, "1.4", ".laz", "EPSG:7415", id="pf8-1.4-laz-compound"),
]


@pytest.mark.parametrize(("point_format", "version", "suffix", "crs"), FORMATS)
def test_read_info_fields(tmp_path: Path, point_format: int, version: str, suffix: str, crs: str | None) -> None:
    w = write_las(tmp_path / f"f{suffix}", point_format=point_format, version=version, crs=crs, n=250)
    info = read_info(w.path)
    assert info.path == w.path
    assert info.size_bytes == w.path.stat().st_size
    assert (info.version, info.point_format, info.point_count) == (version, point_format, 250)
    assert info.compressed is (suffix == ".laz")
    assert info.is_copc is False
    assert info.scales == (0.01, 0.01, 0.01)
    assert info.offsets == (500_000.0, 4_000_000.0, 0.0)
    expected = (w.x.min(), w.y.min(), w.z.min(), w.x.max(), w.y.max(), w.z.max())
    assert_allclose(info.bounds, expected, atol=0.006)
    if crs is None:
        assert info.crs_wkt is None and info.crs_problem is None
    else:
        assert info.crs_problem is None
        assert info.crs_wkt is not None and info.crs_wkt.lstrip().startswith(("PROJCRS", "COMPOUNDCRS"))
        assert pyproj.CRS.from_wkt(info.crs_wkt).equals(pyproj.CRS(crs), ignore_axis_order=True)
    assert info.has_extra_bytes is False
    assert SourceInfo.from_dict(info.to_dict()) == info


def test_read_info_las_1_0(tmp_path: Path) -> None:
    w = write_las(tmp_path / "old.las", point_format=1, version="1.1", n=10)
    patch(w.path, _VERSION_MINOR, "<B", 0)
    info = read_info(w.path)
    assert (info.version, info.point_count) == ("1.0", 10)
    assert sum(chunk.read for chunk in iter_points(w.path)) == 10


def test_read_info_extra_bytes(tmp_path: Path) -> None:
    w = write_las(tmp_path / "eb.laz", point_format=6, version="1.4", extra_dims=(("height", "f8"), ("normal", "3f4")))
    info = read_info(w.path)
    assert info.has_extra_bytes
    assert info.extra_dims == (("height", "float64"), ("normal", "float32[3]"))
    assert info.to_dict()["extra_dims"][0] == {"name": "height", "dtype": "float64"}


@pytest.mark.parametrize(("wkt", "problem"), [("''", "unparsable"), ("", "empty")])
def test_read_info_broken_wkt(tmp_path: Path, wkt: str, problem: str) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.vlrs.append(WktCoordinateSystemVlr(wkt))
    las = laspy.LasData(header)
    las.x, las.y, las.z = [1.0], [2.0], [3.0]
    path = tmp_path / "bad_wkt.las"
    las.write(path)
    info = read_info(path)
    assert info.crs_wkt is None
    assert info.crs_problem is not None and problem in info.crs_problem


def test_read_info_flags_copc_and_reads_it_as_laz(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.vlrs.insert(0, laspy.VLR("copc", 1, "copc info", bytes(160)))  # what marks a COPC file
    las = laspy.LasData(header)
    las.x, las.y, las.z = [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]
    path = tmp_path / "cloud.copc.laz"
    las.write(path)
    info = read_info(path)
    assert info.is_copc and info.compressed
    assert discover_inputs([tmp_path]) == [path]
    assert [c.kept for c in iter_points(path)] == [2]


# --------------------------------------------------------------------------- class_counts and iter_points


@pytest.mark.parametrize("point_format", [0, 1, 3, 6, 8])
def test_class_counts(tmp_path: Path, point_format: int) -> None:
    version = "1.4" if point_format >= 6 else "1.2"
    w = write_las(tmp_path / "c.las", point_format=point_format, version=version, classes=(2, 2, 2, 5, 9), n=101)
    values, counts = np.unique(w.classification, return_counts=True)
    assert class_counts(w.path, chunk_size=17) == dict(zip(values.tolist(), counts.tolist()))
    assert class_counts(w.path) == {2: 61, 5: 20, 9: 20}


@pytest.mark.parametrize(
    ("point_format", "suffix"), [(0, ".las"), (1, ".las"), (3, ".laz"), (6, ".las"), (8, ".laz")]
)
def test_iter_points_filters_classes_and_withheld(tmp_path: Path, point_format: int, suffix: str) -> None:
    version = "1.4" if point_format >= 6 else "1.2"
    w = write_las(
        tmp_path / f"p{suffix}", point_format=point_format, version=version, classes=(1, 2, 2, 6, 7), withheld_every=3
    )
    chunks = list(iter_points(w.path, PointFilter(classes=frozenset({2, 6})), chunk_size=64))
    assert all(isinstance(c, PointChunk) for c in chunks)
    assert [c.read for c in chunks] == [64, 64, 64, 64, 44]
    keep = ~w.withheld & np.isin(w.classification, [2, 6])
    assert sum(c.filtered_withheld for c in chunks) == int(w.withheld.sum())
    assert sum(c.filtered_class for c in chunks) == int((~w.withheld & ~np.isin(w.classification, [2, 6])).sum())
    assert sum(c.kept for c in chunks) == int(keep.sum())
    for axis in "xyz":
        got = np.concatenate([getattr(c, axis) for c in chunks])
        assert got.dtype == np.float64
        assert_allclose(got, getattr(w, axis)[keep], atol=1e-6)


def test_iter_points_keep_withheld_and_all_classes(tmp_path: Path) -> None:
    w = write_las(tmp_path / "p.las", point_format=6, version="1.4", withheld_every=2, n=50)
    chunks = list(iter_points(w.path, PointFilter(keep_withheld=True)))
    assert len(chunks) == 1
    assert (chunks[0].read, chunks[0].kept, chunks[0].filtered_class, chunks[0].filtered_withheld) == (50, 50, 0, 0)
    default = next(iter_points(w.path))
    assert default.kept == 25 and default.filtered_withheld == 25


def test_iter_points_las_and_laz_agree(tmp_path: Path) -> None:
    a = write_las(tmp_path / "same.las", point_format=8, version="1.4", seed=3)
    b = write_las(tmp_path / "same.laz", point_format=8, version="1.4", seed=3)
    za = np.concatenate([c.z for c in iter_points(a.path, chunk_size=50)])
    zb = np.concatenate([c.z for c in iter_points(b.path, chunk_size=70)])
    assert_array_equal(za, zb)


def test_iter_points_checks_arguments_eagerly(tmp_path: Path) -> None:
    with pytest.raises(UsageError):
        iter_points(tmp_path / "not-opened-yet.las", chunk_size=0)
    with pytest.raises(UsageError):
        iter_points(tmp_path / "x.las", point_filter={2})  # type: ignore[arg-type]


def test_point_filter_validation_and_round_trip() -> None:
    flt = PointFilter(classes=[2, 9], keep_withheld=True)
    assert flt.classes == frozenset({2, 9})
    assert PointFilter.from_dict(flt.to_dict()) == flt
    assert PointFilter().to_dict() == {"classes": None, "keep_withheld": False}
    with pytest.raises(UsageError, match="0-255"):
        PointFilter(classes=[-1])
    with pytest.raises(UsageError):
        PointFilter(classes="2")  # type: ignore[arg-type]
    with pytest.raises(UsageError, match="unknown"):
        PointFilter.from_dict({"class": [2]})


# --------------------------------------------------------------------------- bad files


def _raises_for_all(path: Path) -> list[pytest.ExceptionInfo[InputFileError]]:
    """read_info, class_counts and iter_points all raise InputFileError naming ``path``."""
    infos = []
    for call in (read_info, class_counts, lambda p: list(iter_points(p))):
        with pytest.raises(InputFileError) as exc:
            call(path)
        assert isinstance(exc.value, OSError) and isinstance(exc.value, PipelineError)
        assert_names(exc, path)
        infos.append(exc)
    return infos


def test_text_file_named_las(tmp_path: Path) -> None:
    path = tmp_path / "readme.las"
    path.write_text("this is not a point cloud\n")
    exc = _raises_for_all(path)[0]
    assert "not a LAS/LAZ file (bad signature b'this')" in str(exc.value)


def test_wrong_magic(tmp_path: Path) -> None:
    path = tmp_path / "zip.las"
    path.write_bytes(b"PK\x03\x04" + bytes(400))
    exc = _raises_for_all(path)[0]
    assert str(exc.value) == f"{path}: not a LAS/LAZ file (bad signature b'PK\\x03\\x04')"


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.laz"
    path.touch()
    assert "empty" in str(_raises_for_all(path)[0].value)


@pytest.mark.parametrize("keep", [100, 230, 600])
def test_truncated_header_or_vlrs(tmp_path: Path, keep: int) -> None:
    w = write_las(tmp_path / "full.las", point_format=6, version="1.4", crs="EPSG:2154")
    cut = tmp_path / "cut.las"
    cut.write_bytes(w.path.read_bytes()[:keep])
    assert "truncated" in str(_raises_for_all(cut)[0].value)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_truncated_point_data(tmp_path: Path, suffix: str) -> None:
    w = write_las(tmp_path / f"full{suffix}", n=5000)
    data = w.path.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: len(data) - len(data) // 3])
    info = read_info(cut)
    assert info.point_count == 5000  # the header is intact
    if suffix == ".laz":  # the cut took the chunk table: a note, not an error, until points are read
        assert any("chunk table should start" in note for note in info.notes), info.notes
    for call in (class_counts, lambda p: list(iter_points(p, chunk_size=1000))):
        with pytest.raises(InputFileError) as exc:
            call(cut)
        assert_names(exc, cut)
        assert "truncated" in str(exc.value)


@pytest.mark.parametrize(
    ("point_format", "version", "suffix", "offset", "fmt"),
    [(3, "1.2", ".las", _LEGACY_POINT_COUNT, "<I"), (6, "1.4", ".las", _POINT_COUNT_14, "<Q"),
     (6, "1.4", ".laz", _POINT_COUNT_14, "<Q")],
)
def test_header_count_larger_than_data(
    tmp_path: Path, point_format: int, version: str, suffix: str, offset: int, fmt: str
) -> None:
    w = write_las(tmp_path / f"short{suffix}", point_format=point_format, version=version, n=1000)
    patch(w.path, offset, fmt, 1500)
    info = read_info(w.path)
    assert info.point_count == 1500
    if suffix == ".las":
        assert any("1,000 of the 1,500" in note for note in info.notes)
    with pytest.raises(InputFileError) as exc:
        for _ in iter_points(w.path, chunk_size=400):
            pass
    assert_names(exc, w.path)


def test_header_count_smaller_than_data_is_a_note_in_the_run_report(tmp_path: Path) -> None:
    from pipeline.config import RunConfig
    from pipeline.runs.runner import run

    w = write_las(tmp_path / "long.las", point_format=6, version="1.4", n=1000, crs="EPSG:2154", classes=(2,),
                  origin=LAMBERT93_ORIGIN)
    patch(w.path, _POINT_COUNT_14, "<Q", 700)
    info = read_info(w.path)
    assert info.point_count == 700
    assert any("holds 1,000 point records but its header announces 700" in note for note in info.notes), info.notes
    assert sum(chunk.read for chunk in iter_points(w.path)) == 700
    report = run(RunConfig(inputs=(str(w.path),), output=str(tmp_path / "o.zarr"), resolution=5.0), progress=False)
    assert report.points_read == 700
    assert any(note.startswith(f"{w.path}: ") and "300 left out" in note for note in report.notes), report.notes


@pytest.mark.parametrize(("version", "point_format"), [("1.2", 3), ("1.4", 6)])
def test_a_point_count_never_filled_in_reads_every_record(tmp_path: Path, version: str, point_format: int) -> None:
    w = write_las(tmp_path / "unfilled.las", point_format=point_format, version=version, n=500)
    patch(w.path, _LEGACY_POINT_COUNT, "<I", 0)
    if version == "1.4":
        patch(w.path, _POINT_COUNT_14, "<Q", 0)
    info = read_info(w.path)
    assert info.point_count == 500
    assert any("announces no points but the file holds 500 point records" in n for n in info.notes), info.notes
    chunks = list(iter_points(w.path, PointFilter(classes=None), chunk_size=120))
    assert sum(c.read for c in chunks) == 500
    assert np.array_equal(np.concatenate([c.x for c in chunks]), w.x[~w.withheld])


def test_evlrs_after_the_points_are_not_counted_as_records(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_crs(pyproj.CRS("EPSG:2154"))
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(50.0), np.arange(50.0) * 2, np.zeros(50)
    las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("test", 1, "a trailing record", bytes(3000))])
    las.write(tmp_path / "evlr.las")
    info = read_info(tmp_path / "evlr.las")
    assert info.point_count == 50 and not any("point records" in note for note in info.notes), info.notes


def _write_variable_chunks(path: Path, sizes: tuple[int, ...]) -> Written:
    """A LAZ file whose chunks hold different numbers of points, as COPC writes them."""
    import io

    import lazrs

    w = write_las(path, point_format=6, version="1.4", n=sum(sizes), crs="EPSG:2154")
    data = w.path.read_bytes()
    (offset,) = struct.unpack_from("<I", data, 96)
    head = bytearray(data[:offset])
    vlr = lazrs.LazVlr.new_for_compression(6, 0, True)
    at = head.find(b"laszip encoded") - 2
    head[at + 54 : at + 54 + len(vlr.record_data())] = vlr.record_data()
    raw = laspy.read(w.path).points.array.tobytes()
    size = len(raw) // sum(sizes)
    out = io.BytesIO()
    out.write(bytes(head))
    compressor = lazrs.LasZipCompressor(out, vlr)
    compressor.reserve_offset_to_chunk_table()
    start = 0
    for n in sizes:
        compressor.compress_many(raw[start * size : (start + n) * size])
        compressor.finish_current_chunk()
        start += n
    compressor.done()
    w.path.write_bytes(out.getvalue())
    return w


def test_variable_sized_laz_chunks_are_read(tmp_path: Path) -> None:
    w = _write_variable_chunks(tmp_path / "copc-like.laz", (7000, 13000, 10000))
    assert read_info(w.path).notes == ()
    chunks = list(iter_points(w.path, chunk_size=4000, point_filter=PointFilter(classes=None)))
    assert_allclose(np.concatenate([c.x for c in chunks]), w.x, rtol=0, atol=1e-6)
    assert_allclose(np.concatenate([c.z for c in chunks]), w.z, rtol=0, atol=1e-6)


def test_corrupt_laz_chunk(tmp_path: Path) -> None:
    w = write_las(tmp_path / "c.laz", point_format=6, version="1.4", n=120_000)
    data = bytearray(w.path.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    w.path.write_bytes(bytes(data))
    with pytest.raises(InputFileError) as exc:
        for _ in iter_points(w.path, chunk_size=50_000):
            pass
    assert_names(exc, w.path)
    assert "LAZ" in str(exc.value)


@pytest.mark.parametrize(("scale", "shown"), [(float("nan"), "nan"), (0.0, "0.0")])
def test_an_unusable_scale_factor_is_an_error_not_a_broken_axis(tmp_path: Path, scale: float, shown: str) -> None:
    w = write_las(tmp_path / "scale.las", n=10)
    patch(w.path, _X_SCALE, "<d", scale)  # NaN coordinates, or every x the offset
    for read in (read_info, lambda path: list(iter_points(path))):
        with pytest.raises(InputFileError, match=rf"unusable scale factors \({shown}, 0\.01, 0\.01\)") as exc:
            read(w.path)
        assert_names(exc, w.path)


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        (_X_SCALE, 1e-310, "unusable scale factors"),  # 1 / scale overflows
        (_X_SCALE, -5e-324, "unusable scale factors"),
        (_X_SCALE, 1e300, "give infinite coordinates"),
        (_X_OFFSET, float("inf"), "unusable offsets"),
        (_X_OFFSET, float("nan"), "unusable offsets"),
    ],
)
def test_header_numbers_are_checked_before_any_arithmetic(tmp_path: Path, field: int, value: float, problem: str) -> None:
    # the Python API as the command line: one error naming the file, never an
    # OverflowError or a coordinate of inf
    w = write_las(tmp_path / "numbers.las", n=10)
    patch(w.path, field, "<d", value)
    for read in (read_info, lambda path: list(iter_points(path))):
        with pytest.raises(InputFileError, match=problem) as exc:
            read(w.path)
        assert_names(exc, w.path)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    missing = tmp_path / "missing.laz"
    assert "no such file" in str(_raises_for_all(missing)[0].value)
    assert isinstance(_raises_for_all(missing)[0].value, OSError)
    assert "directory" in str(_raises_for_all(tmp_path)[0].value)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root ignores file permissions")
def test_unreadable_file(tmp_path: Path) -> None:
    w = write_las(tmp_path / "locked.las", n=10)
    w.path.chmod(0)
    try:
        assert "permission denied" in str(_raises_for_all(w.path)[0].value)
    finally:
        w.path.chmod(0o644)


def test_permission_error_is_explained_even_as_root(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    w = write_las(tmp_path / "locked.las", n=10)

    def denied(*args: object, **kwargs: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("pipeline.urls.open", denied, raising=False)  # where inputs are opened
    with pytest.raises(InputFileError) as exc:
        read_info(w.path)
    assert_names(exc, w.path)
    assert "permission denied" in str(exc.value)


# --------------------------------------------------------------------------- real samples (../shared/data)

REAL = [
    # name, points, ground (class 2), version, point format
    ("autzen_trim.las", 110_000, 26_107, "1.2", 3),
    ("ign_semis_lambert93.laz", 289_055, 152_678, "1.4", 6),
    ("extra_byte_blocks_lambert93.laz", 697_721, 683_023, "1.4", 8),
    ("startinpy_small_extrabytes.laz", 39_233, 18_392, "1.4", 8),
    ("plane_many_duplicates.laz", 28_185, 0, "1.2", 3),
    ("4_6_crop_us_feet.las", 23_875, 9_003, "1.2", 3),
    ("geographic_epsg4326.las", 5_380, 0, "1.2", 0),
    ("warsaw_small_broken_crs.las", 3_000, 1_381, "1.2", 3),
    ("no_crs_color.las", 1_065, 276, "1.2", 3),
    ("single_point.laz", 1, 0, "1.4", 8),
]


@pytest.mark.parametrize(("name", "points", "ground", "version", "point_format"), REAL)
def test_real_sample_counts(name: str, points: int, ground: int, version: str, point_format: int) -> None:
    path = sample(name)
    info = read_info(path)
    assert (info.point_count, info.version, info.point_format) == (points, version, point_format)
    counts = class_counts(path)
    assert sum(counts.values()) == points
    assert counts.get(2, 0) == ground


def test_real_sample_streamed_ground_points() -> None:
    path = sample("ign_semis_lambert93.laz")
    chunks = list(iter_points(path, PointFilter(classes=frozenset({2})), chunk_size=100_000))
    assert sum(c.read for c in chunks) == 289_055
    assert sum(c.kept for c in chunks) == 152_678
    info = read_info(path)
    x = np.concatenate([c.x for c in chunks])
    assert info.bounds[0] - 0.01 <= x.min() and x.max() <= info.bounds[3] + 0.01


def test_real_sample_broken_crs() -> None:
    info = read_info(sample("warsaw_small_broken_crs.las"))
    assert info.crs_wkt is None
    assert info.crs_problem is not None and "WKT" in info.crs_problem


def test_real_sample_without_crs() -> None:
    info = read_info(sample("no_crs_color.las"))
    assert info.crs_wkt is None and info.crs_problem is None


def test_real_sample_extra_bytes() -> None:
    info = read_info(sample("startinpy_small_extrabytes.laz"))
    assert [name for name, _ in info.extra_dims] == ["Deviation", "Reflectance", "Amplitude"]
    info = read_info(sample("extra_byte_blocks_lambert93.laz"))
    assert info.has_extra_bytes
    assert any("extra-bytes VLRs" in note for note in info.notes)


def test_real_sample_single_point() -> None:
    path = sample("single_point.laz")
    chunks = list(iter_points(path))
    assert [c.read for c in chunks] == [1] and chunks[0].kept == 1
    info = read_info(path)
    assert_allclose([chunks[0].x[0], chunks[0].y[0], chunks[0].z[0]], info.bounds[:3])


# --------------------------------------------------------------------------- terrain info (pipeline.tools.info)


def test_info_report_and_json(tmp_path: Path) -> None:
    import json

    from pipeline.tools.info import info_json, info_report

    w = write_las(tmp_path / "a.laz", point_format=6, version="1.4", crs="EPSG:2154", classes=(2, 2, 6),
                  extra_dims=(("height", "f4"),), n=30)
    bad = tmp_path / "b.las"
    bad.write_text("not a las file")
    with pytest.raises(InputFileError) as exc:
        info_report([tmp_path])
    assert_names(exc, bad)

    entries = info_json([tmp_path], keep_going=True)
    json.dumps(entries)
    assert [e["path"] for e in entries] == [str(w.path), str(bad)]
    assert entries[0]["classes"] == [{"code": 2, "name": "ground", "count": 20},
                                     {"code": 6, "name": "building", "count": 10}]
    assert (entries[0]["crs_epsg"], entries[0]["horizontal_unit"]) == (2154, "metre")
    assert entries[1]["error"].startswith(f"{bad}: not a LAS/LAZ file")

    text = info_report([w.path])
    for expected in (str(w.path), "1.4, point format 6, LAZ", "30", "ground", "EPSG:2154", "height (float32)"):
        assert expected in text


def _same_points(path: Path, scale: float, offset: tuple[float, float], z_shift: float) -> None:
    rng = np.random.default_rng(21)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([scale, scale, 0.01])
    header.offsets = np.array([offset[0], offset[1], 0.0])
    las = laspy.LasData(header)
    las.x = 651_000.0 + np.round(rng.uniform(0, 100, 3000), 2)
    las.y = 6_861_000.0 + np.round(rng.uniform(0, 100, 3000), 2)
    las.z = np.round(rng.uniform(0, 10, 3000), 2) + z_shift
    las.write(path)


def test_one_coordinate_is_one_float_whatever_the_files_offset_and_scale(tmp_path: Path) -> None:
    # overlapping strips from different tools: other offsets, other scales
    layouts = [(0.01, (0.0, 0.0)), (0.01, (651_000.0, 6_861_000.0)), (0.001, (650_000.37, 6_860_999.99)),
               (0.01, (-123.45, 17.0)), (1e-4, (651_034.5678, 6_861_060.5944)), (1e-7, (650_999.1234567, 6_860_999.7654321))]
    read = []
    for k, (scale, offset) in enumerate(layouts):
        _same_points(tmp_path / f"{k}.las", scale, offset, 0.0)
        chunk = next(iter_points(tmp_path / f"{k}.las", PointFilter(classes=None)))
        read.append(chunk)
    for chunk in read[1:]:
        assert np.array_equal(chunk.x, read[0].x) and np.array_equal(chunk.y, read[0].y)
    # and it is the float nearest the decimal the file stores
    assert np.array_equal(read[0].x, np.round(read[0].x, 2)) and np.array_equal(read[2].y, np.round(read[2].y, 2))


def test_a_point_in_two_files_of_other_offsets_is_one_vertex(tmp_path: Path) -> None:
    from pipeline.config import RunConfig
    from pipeline.runs.runner import run

    folder = tmp_path / "pair"
    folder.mkdir()
    _same_points(folder / "a.las", 0.01, (0.0, 0.0), 0.0)
    _same_points(folder / "b.las", 0.01, (651_000.0, 6_861_000.0), 1.0)  # the same x, y, one metre higher
    common = dict(resolution=1.0, tile_size=32.0, classes=None, in_crs="EPSG:2154")
    both = run(RunConfig(inputs=(str(folder),), output=str(tmp_path / "ab.zarr"), **common), progress=False)
    one = run(RunConfig(inputs=(str(folder / "a.las"),), output=str(tmp_path / "a.zarr"), **common), progress=False)
    assert both.duplicates == 3000 and both.vertices == one.vertices == 3000
    import xarray as xr

    np.testing.assert_array_equal(  # the lowest of each pair: file a's
        xr.open_zarr(tmp_path / "ab.zarr")["elevation"].values, xr.open_zarr(tmp_path / "a.zarr")["elevation"].values
    )
