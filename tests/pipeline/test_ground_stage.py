"""The ground stage: an unclassified survey's ground classified in the run,
the same at any tiling, counted point by point, and recorded in the store.

The scene is meshcore's synthetic one (buildings up to 60 m across, trees,
shrubs, a cliff, a 40-degree valley side, a bridge deck and low outliers),
written as a LAS file whose every point is of class 1.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
import xarray as xr
from laspy.vlrs.vlrlist import VLRList
from pyproj import CRS

from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.store import zarr_store as store

from ..meshcore.test_ground import GROUND, OUTLIER, X0, Y0, _scene, _terrain
from .store_checks import face_set

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"


@pytest.fixture(scope="module")
def survey(tmp_path_factory) -> tuple[Path, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scene as one LAS file of class 1 (with a first class-2 point or two
    would make it classified): path, x, y, z, label."""
    rng = np.random.default_rng(7)
    x, y, z, label, _ = _scene(rng, density=1.5)
    path = _write_unclassified(tmp_path_factory.mktemp("ground") / "scene.laz", x, y, z)
    return path, x, y, z, label


def _write_unclassified(path: Path, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> Path:
    """One LAZ file of these points in Lambert-93, all of class 1, single returns."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([X0, Y0, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.ones(x.size, dtype=np.uint8)
    las.return_number = np.ones(x.size, dtype=np.uint8)
    las.number_of_returns = np.ones(x.size, dtype=np.uint8)
    las.write(path)
    return path


def _run(path: Path, out: Path, **kw):
    config = RunConfig(inputs=(str(path),), output=str(out), resolution=kw.pop("resolution", 2.0), workers=2, **kw)
    return run(config, progress=False)


def test_an_unclassified_survey_gets_a_terrain_model_of_its_ground(tmp_path, survey):
    path, x, y, z, label = survey
    report = _run(path, tmp_path / "o.zarr", layers=("elevation", "ground_density"))
    assert any("the ground was classified" in n for n in report.notes), report.notes
    # every point is in the output or counted with its reason
    assert report.points_kept + report.not_ground + report.filtered_class == report.points_read == x.size
    assert report.low_outliers >= 0.8 * np.count_nonzero(label == OUTLIER)
    ds = xr.open_zarr(tmp_path / "o.zarr")
    gx, gy = np.meshgrid(ds["x"].values - X0, ds["y"].values - Y0)
    dem = ds["elevation"].values
    truth = _terrain(gx, gy)
    inside = np.isfinite(dem) & (gx > 5) & (gx < 295) & (gy > 5) & (gy < 245)  # off the survey's edges
    inside &= ~((np.abs(gx - 150) < 3) & (gy < 122))  # and off the cliff, where any TIN cuts the corner
    error = np.abs(dem - truth)[inside]
    # the buildings, trees and deck are gone: the DTM lies on the ground, not on roofs 4-14 m up
    assert np.sqrt(np.mean(error**2)) < 0.5, np.sqrt(np.mean(error**2))
    assert np.quantile(error, 0.99) < 2.5
    # ground_density counts the classified ground: none on the 60 x 40 m flat roof, some elsewhere
    density = ds["ground_density"].values
    roof = (gx > 25) & (gx < 75) & (gy > 145) & (gy < 175)
    assert density[roof].max() == 0 and density[inside].mean() > 0.3
    prov = store.read_attrs(tmp_path / "o.zarr")["provenance"]
    assert prov["ground_classification"]["method"] == "smrf-tin"
    assert set(prov["ground_classification"]["parameters"]) >= {"cell", "max_window", "slope", "threshold"}


_CLASSIFIED = dict(classify_ground=True, layers=("elevation", "ground_density"))


@pytest.fixture(scope="module")
def whole(survey, tmp_path_factory):
    """The survey classified in one tile: its report and store."""
    out = tmp_path_factory.mktemp("whole") / "whole.zarr"
    return _run(survey[0], out, tile_size=400.0, **_CLASSIFIED), out


@pytest.mark.parametrize("tile_size,buffer", [(40.0, 0.0), (60.0, 6.0), (100.0, 20.0)])
def test_the_ground_is_the_same_at_any_tiling(tmp_path, survey, whole, tile_size, buffer):
    tiled = _run(survey[0], tmp_path / "tiled.zarr", tile_size=tile_size, buffer=buffer, **_CLASSIFIED)
    whole, whole_store = whole
    assert tiled.tiles > 4 and whole.tiles == 1
    assert (tiled.points_kept, tiled.not_ground, tiled.low_outliers) == (whole.points_kept, whole.not_ground,
                                                                          whole.low_outliers)
    a, b = xr.open_zarr(tmp_path / "tiled.zarr"), xr.open_zarr(whole_store)
    for name in ("x", "y", "elevation", "ground_density"):
        assert np.array_equal(a[name].values, b[name].values, equal_nan=True), name
    node_a, _, faces_a = store.read_mesh(tmp_path / "tiled.zarr")
    node_b, _, faces_b = store.read_mesh(whole_store)
    assert face_set(np.asarray(node_a), faces_a) == face_set(np.asarray(node_b), faces_b)


def test_a_sparse_survey_is_filtered_on_cells_of_its_spacing_at_any_tiling(tmp_path):
    """1,500 points over 3 x 3 km (77 m apart), three in ten on trees 8-25 m
    up: the run measures the spacing from every point routed, so the cells
    (and the classes) are the same at any tiling, and the trees are not
    ground."""
    rng = np.random.default_rng(7)
    n = 1500
    x, y = rng.uniform(0, 3000, (2, n)) + np.array([[X0], [Y0]])
    ground = 200 + 0.02 * (x - X0) + 10 * np.sin((y - Y0) / 500)
    tree = rng.random(n) < 0.3
    z = np.round(ground + np.where(tree, rng.uniform(8, 25, n), rng.normal(0, 0.05, n)), 2)
    path = _write_unclassified(tmp_path / "sparse.laz", x, y, z)
    whole = _run(path, tmp_path / "whole.zarr", classify_ground=True, resolution=10.0, tile_size=4000.0)
    parameters = lambda name: store.read_attrs(tmp_path / name)["provenance"]["ground_classification"]["parameters"]  # noqa: E731
    prov = parameters("whole.zarr")
    assert 30.0 < prov["cell"] < 45.0 and prov["max_window"] > 4 * 50.0
    # with a buffer, the tiles hold copies of their neighbours' points: the spacing counts each point once
    for name, buffer in (("tiled.zarr", 0.0), ("buffered.zarr", 120.0)):
        tiled = _run(path, tmp_path / name, classify_ground=True, resolution=10.0, tile_size=500.0, buffer=buffer)
        assert whole.tiles == 1 and tiled.tiles > 20
        assert whole.not_ground == tiled.not_ground and 0.9 * tree.sum() < whole.not_ground < 1.2 * tree.sum()
        assert parameters(name) == prov
        a, b = xr.open_zarr(tmp_path / name), xr.open_zarr(tmp_path / "whole.zarr")
        assert np.array_equal(a["elevation"].values, b["elevation"].values, equal_nan=True)


def test_the_products_read_the_points_the_ground_stage_routed(tmp_path, survey):
    """With the ground classified, the route stage spills the products' points with the columns the DEM
    stage reads (a DSM and a CHM over the classified DTM), at any tiling."""
    path = survey[0]
    common = dict(classify_ground=True, layers=("elevation", "dsm", "chm", "ground_density"))
    tiled = _run(path, tmp_path / "tiled.zarr", tile_size=60.0, buffer=20.0, **common)
    whole = _run(path, tmp_path / "whole.zarr", tile_size=400.0, **common)
    assert tiled.tiles > 4 and whole.tiles == 1
    a, b = xr.open_zarr(tmp_path / "tiled.zarr"), xr.open_zarr(tmp_path / "whole.zarr")
    for name in common["layers"]:
        assert np.array_equal(a[name].values, b[name].values, equal_nan=True), name
    chm = a["chm"].values
    assert np.nanmax(chm) > 8.0  # the roofs and crowns stand above the classified ground
    assert np.nanmedian(chm) < 0.5


def test_classify_ground_ignores_the_files_classes(tmp_path, survey):
    path, x, y, z, label = survey
    las = laspy.read(path)
    las.classification = np.where(label == GROUND, 6, 2).astype(np.uint8)  # a wrong classification
    wrong = tmp_path / "wrong.laz"
    las.write(wrong)
    own = _run(wrong, tmp_path / "own.zarr")  # the files' class 2: roofs and trees
    classified = _run(wrong, tmp_path / "classified.zarr", classify_ground=True)
    assert own.points_kept == np.count_nonzero(label != GROUND)
    assert classified.points_kept + classified.not_ground == x.size
    assert abs(classified.points_kept - np.count_nonzero(label == GROUND)) < 0.1 * np.count_nonzero(label == GROUND)


def test_the_command_line_flag(tmp_path, survey, capsys):
    path = survey[0]
    assert main(["run", str(path), "-o", str(tmp_path / "c.zarr"), "--resolution", "2", "--classify-ground",
                 "--tile-size", "100", "--quiet"]) == 0
    prov = store.read_attrs(tmp_path / "c.zarr")["provenance"]
    assert prov["parameters"]["classify_ground"] is True and "ground_classification" in prov


def test_a_run_stopped_in_the_ground_stage_resumes_to_the_same_store(tmp_path, survey, monkeypatch):
    from pipeline.meshing import ground
    from pipeline.runs import runner

    path = survey[0]
    real = ground.classify_block
    calls = []

    def stopped(job):
        calls.append(job)
        if len(calls) == 2:
            raise RuntimeError("power cut")
        return real(job)

    monkeypatch.setattr(runner, "classify_block", stopped)
    # blocks of one tile (the default blocks are some 900 m across: the survey would be one)
    monkeypatch.setattr(runner, "ground_blocks", lambda grid, points, margin: ground.ground_blocks(grid, points, 10.0))
    config = RunConfig(inputs=(str(path),), output=str(tmp_path / "r.zarr"), resolution=2.0, tile_size=40.0,
                       classify_ground=True, workers=1)
    with pytest.raises(Exception, match="power cut"):
        run(config, progress=False)
    monkeypatch.setattr(runner, "classify_block", real)
    resumed = run(config, progress=False)
    whole = _run(path, tmp_path / "w.zarr", classify_ground=True, tile_size=400.0)
    assert (resumed.points_kept, resumed.not_ground) == (whole.points_kept, whole.not_ground)
    a, b = (xr.open_zarr(tmp_path / name)["elevation"].values for name in ("r.zarr", "w.zarr"))
    np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(not SHARED.is_dir(), reason="needs ../shared/data")
def test_a_shared_sample_without_its_classes_is_the_same_tiled_and_untiled(tmp_path):
    las = laspy.read(SHARED / "startinpy_small_extrabytes.laz")
    truth = np.asarray(las.classification) == 2
    las.classification = np.ones(len(las.points), dtype=np.uint8)
    path = tmp_path / "plain.laz"
    las.write(path)
    tiled = _run(path, tmp_path / "t.zarr", resolution=0.5, tile_size=10.0)
    whole = _run(path, tmp_path / "w.zarr", resolution=0.5)
    assert tiled.tiles >= 16
    a, b = (xr.open_zarr(tmp_path / name)["elevation"].values for name in ("t.zarr", "w.zarr"))
    np.testing.assert_array_equal(a, b)
    # near the survey's own ground: as many points, within a sixth
    assert abs(whole.points_kept - truth.sum()) < truth.sum() / 6


def _with_extras(path: Path, out: Path, classes: np.ndarray) -> Path:
    """The survey as LAS 1.4 with an extra-bytes dimension, a VLR of its own, an EVLR, and ``classes``."""
    las = laspy.read(path)
    las.add_extra_dim(laspy.ExtraBytesParams(name="deviation", type=np.float32, description="residual"))
    las.deviation = np.linspace(-1, 1, len(las.points)).astype(np.float32)
    las.intensity = np.arange(len(las.points)) % 65536
    las.classification = classes
    las.header.vlrs.append(laspy.VLR(user_id="terrain_test", record_id=7, description="kept as is",
                                     record_data=b"\x01\x02\x03 payload"))
    las.evlrs = VLRList([laspy.VLR(user_id="terrain_test", record_id=8, description="an evlr", record_data=b"z" * 100)])
    las.write(out)
    return out


def test_terrain_classify_changes_only_the_classes(tmp_path, survey):
    path, x, y, z, label = survey
    rng = np.random.default_rng(1)
    classes = rng.choice(np.array([1, 2, 5, 6, 7], dtype=np.uint8), size=x.size)  # a wrong classification
    source = _with_extras(path, tmp_path / "in.las", classes)
    assert main(["classify", str(source), "-o", str(tmp_path / "out"), "--quiet"]) == 0
    _only_the_classes_changed(source, tmp_path / "out" / "in.laz")
    a, b = laspy.read(source), laspy.read(tmp_path / "out" / "in.laz")
    before, after = np.asarray(a.classification), np.asarray(b.classification)
    ground = after == 2
    assert not ground[before == 7].any()  # noise is never classified
    changed = before != after
    # only two moves: to ground, or from ground to 1
    assert set(np.unique(after[changed]).tolist()) <= {1, 2}
    assert (after[changed & ~ground] == 1).all() and (before[changed & ~ground] == 2).all()
    # the same ground as the run's stage, point for point
    run_report = _run(source, tmp_path / "r.zarr", classify_ground=True)
    assert run_report.points_kept == int(ground.sum())
    # and mostly the scene's ground (labels known)
    assert np.mean(ground[(label == GROUND) & (before != 7)]) > 0.9 and np.mean(ground[(label != GROUND) & (before != 7)]) < 0.1


def _raw_records(path: Path) -> tuple[list[bytes], list[bytes]]:
    """Each VLR and EVLR of a LAS/LAZ file as its bytes, header and payload,
    in the file's order, without the LAZ VLR (the compressor's own settings)
    and COPC's records."""
    data = path.read_bytes()
    vlrs, at = [], int.from_bytes(data[94:96], "little")
    for _ in range(int.from_bytes(data[100:104], "little")):
        length = int.from_bytes(data[at + 20:at + 22], "little")
        vlrs.append(data[at:at + 54 + length])
        at += 54 + length
    evlrs = []
    if data[25] >= 4:
        at = int.from_bytes(data[235:243], "little")
        for _ in range(int.from_bytes(data[243:247], "little") if at else 0):
            length = int.from_bytes(data[at + 20:at + 28], "little")
            evlrs.append(data[at:at + 60 + length])
            at += 60 + length
    def kept(record: bytes) -> bool:
        user = record[2:18].rstrip(b"\0")
        return user != b"copc" and (user, int.from_bytes(record[18:20], "little")) != (b"laszip encoded", 22204)
    return [r for r in vlrs if kept(r)], [r for r in evlrs if kept(r)]


def _only_the_classes_changed(source: Path, written: Path) -> None:
    a, b = laspy.read(source), laspy.read(written)  # the written file decompresses whole
    assert len(a.points) == len(b.points)
    for dim in a.point_format.dimension_names:
        if dim != "classification":
            np.testing.assert_array_equal(np.asarray(a[dim]), np.asarray(b[dim]), err_msg=dim)
    assert _raw_records(source) == _raw_records(written)


@pytest.mark.skipif(not SHARED.is_dir(), reason="needs ../shared/data")
@pytest.mark.parametrize("name, flags", [
    # COPC: written as plain LAZ, its octree's records left out, the LAZ VLR the writer's own (a copy of
    # the source's variable chunk size made a file that would not decompress); its record is wrong (geocentric)
    ("lone_star_wrong_crs_geocentric.copc.laz", ["--override-crs", "EPSG:32612"]),
    # its extra-bytes VLR first, which the writer rebuilds and puts last
    ("startinpy_small_extrabytes.laz", []),
    # two extra-bytes VLRs (the spec allows one), of which the writer kept one
    ("extra_byte_blocks_lambert93.laz", []),
    # a WKT record without its terminating null, which the writer would add
    ("warsaw_small_broken_crs.las", ["--in-crs", "EPSG:2180"]),
    # in degrees: classified in its UTM zone, written in its own coordinates
    ("geographic_epsg4326.las", []),
])
def test_terrain_classify_keeps_a_shared_samples_records_byte_for_byte(tmp_path, capsys, name, flags):
    assert main(["classify", str(SHARED / name), "-o", str(tmp_path), *flags]) == 0
    written = next(tmp_path.glob("*.laz"))
    _only_the_classes_changed(SHARED / name, written)
    assert np.count_nonzero(np.asarray(laspy.read(written).classification) == 2) > 0
    if name.startswith("geographic"):
        assert "classified in WGS 84 / UTM zone 15N (EPSG:32615)" in capsys.readouterr().err


def test_terrain_classify_is_the_same_at_any_tiling(tmp_path, survey):
    path = survey[0]
    assert main(["classify", str(path), "-o", str(tmp_path / "a"), "--quiet"]) == 0
    assert main(["classify", str(path), "-o", str(tmp_path / "b"), "--tile-size", "40", "--buffer", "3",
                 "--quiet"]) == 0
    a, b = laspy.read(tmp_path / "a" / "scene.laz"), laspy.read(tmp_path / "b" / "scene.laz")
    np.testing.assert_array_equal(np.asarray(a.classification), np.asarray(b.classification))


def test_terrain_classify_refuses_to_overwrite_or_to_write_over_its_input(tmp_path, survey, capsys):
    path = survey[0]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "scene.laz").write_bytes(b"keep me")
    assert main(["classify", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "scene.laz exists; give --overwrite to replace it" in err, err
    assert (tmp_path / "out" / "scene.laz").read_bytes() == b"keep me"
    assert main(["classify", str(path), "-o", str(path.parent)]) == 2
    assert "the output folder is the input's own" in capsys.readouterr().err
    assert main(["classify", str(path), "-o", str(tmp_path / "out"), "--overwrite", "--quiet"]) == 0
    assert len(laspy.read(tmp_path / "out" / "scene.laz").points) == len(laspy.read(path).points)


def test_a_tiles_spill_rows_are_found_in_the_blocks_cloud():
    """The ground stage finds each row of a tile's spill files in the block's
    cloud: its own rows by position, its buffer's copies (near an edge, or,
    were one elsewhere, anywhere) by value; a row in no tile loaded is an error."""
    from pipeline.meshing.ground import _CloudRows, _own_rows, _owned
    from pipeline.tiling.grid import TileGrid

    grid = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=100, nx=200, ny=100)
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(0, 200, 3000).round(2), rng.uniform(0, 100, 3000).round(2),
                              rng.uniform(0, 9, 3000).round(2), np.ones(3000), np.ones(3000)])
    points[:10] = points[10:20]  # exact copies
    left, right = points[points[:, 0] < 100.0], points[points[:, 0] >= 100.0]
    buffer = 5.0
    # tile (0, 0)'s spill in two parts: its own points and the copies of (0, 1)'s within the buffer; one
    # more copy from deep inside (0, 1), where no buffer reaches (only found by the search of every row)
    deep = right[right[:, 0] > 150.0][:1]
    parts = [left[: len(left) // 2], np.concatenate([left[len(left) // 2:], right[right[:, 0] < 100.0 + buffer], deep])]
    rng.shuffle(parts[1])
    own = {(0, 0): _own_rows(grid, 0, 0, parts), (0, 1): _own_rows(grid, 0, 1, [right])}
    loaded = {(0, 0): _owned(parts, own[(0, 0)], 5), (0, 1): _owned([right], own[(0, 1)], 5)}
    columns = np.concatenate([loaded[(0, 0)], loaded[(0, 1)]], axis=1)
    lookup = _CloudRows(grid, columns.T, {(0, 0): 0, (0, 1): loaded[(0, 0)].shape[1]}, buffer + 1e-6)
    for part, at in zip(parts, lookup.rows((0, 0), parts, own[(0, 0)])):
        assert (at >= 0).all() and np.array_equal(columns.T[at], part)
    assert lookup.everywhere is not None  # the deep copy was searched for among every row
    stray = [np.array([[500.0, 50.0, 1.0, 1.0, 1.0]])]  # in no tile of the cloud
    with pytest.raises(RuntimeError, match="no tile the block loaded"):
        _CloudRows(grid, columns.T, {(0, 0): 0}, buffer).rows((0, 0), stray, [np.array([False])])
