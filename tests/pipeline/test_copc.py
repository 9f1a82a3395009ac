"""COPC inputs read by window: only the octree nodes that meet the window are
fetched (over s3, ranged requests), and the result is the plain LAZ run's."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("copclib")

from pipeline import urls  # noqa: E402
from pipeline.config import RunConfig  # noqa: E402
from pipeline.runs.runner import run  # noqa: E402
from pipeline.inputs.sources import PointFilter, iter_points  # noqa: E402
from pipeline.tools.synthetic import terrain_height  # noqa: E402

from .copc_files import nodes_meeting, plain_twin, write_copc  # noqa: E402
from .store_checks import assert_same_store  # noqa: E402

ORIGIN = (651000.0, 6861000.0)


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A COPC survey (sparse ground under canopy, a void) and its plain LAZ twin."""
    folder = tmp_path_factory.mktemp("copc")
    rng = np.random.default_rng(41)
    n = 150_000
    x = np.round(ORIGIN[0] + rng.random(n) * 600.0, 2)
    y = np.round(ORIGIN[1] + rng.random(n) * 400.0, 2)
    keep = (x - ORIGIN[0] - 300.0) ** 2 + (y - ORIGIN[1] - 200.0) ** 2 > 40.0**2  # a pond: no returns
    x, y = x[keep], y[keep]
    ground = rng.random(x.size) < 0.35
    z = np.round(terrain_height(x, y, ORIGIN) + np.where(ground, 0.0, rng.random(x.size) * 15.0 + 1.0), 2)
    copc = write_copc(folder / "survey.copc.laz", x, y, z, np.where(ground, 2, 5), depth=5,
                      intensity=rng.integers(0, 65536, x.size))
    return copc, plain_twin(copc, folder / "twin.laz")


def test_a_window_run_over_copc_is_the_plain_laz_run(survey, tmp_path):
    copc, twin = survey
    bbox = (ORIGIN[0] + 130.0, ORIGIN[1] + 90.0, ORIGIN[0] + 420.0, ORIGIN[1] + 310.0)
    stores, counts = {}, {}
    for name, path in (("copc", copc), ("twin", twin)):
        stores[name] = tmp_path / f"{name}.zarr"
        report = run(RunConfig(inputs=(str(path),), output=str(stores[name]), resolution=1.0, tile_size=64.0,
                               bbox=bbox, layers=("slope",), workers=2), progress=False)
        (f,) = report.files
        assert f["read"] == f["kept"] + f["filtered_class"] + f["filtered_withheld"] + f["outside_bbox"], f
        counts[name] = f
    assert_same_store(stores["copc"], stores["twin"])
    # whole nodes outside the bbox are never read: their points count as outside it, whatever their class
    copc_counts, twin_counts = counts["copc"], counts["twin"]
    assert copc_counts["kept"] == twin_counts["kept"] and copc_counts["read"] == twin_counts["read"]
    assert copc_counts["outside_bbox"] > twin_counts["outside_bbox"]


def test_a_window_run_over_copc_with_every_product_is_the_plain_laz_run(survey, tmp_path):
    """Products read their points with attributes in a routing pass, which
    reads a COPC file by window too: the nodes outside the bbox come as a
    chunk of points none kept, with no attribute."""
    copc, twin = survey
    bbox = (ORIGIN[0] + 130.0, ORIGIN[1] + 90.0, ORIGIN[0] + 420.0, ORIGIN[1] + 310.0)
    stores = {}
    for name, path in (("copc", copc), ("twin", twin)):
        stores[name] = tmp_path / f"{name}.zarr"
        report = run(RunConfig(inputs=(str(path),), output=str(stores[name]), resolution=1.0, tile_size=64.0,
                               bbox=bbox, layers=("dsm", "chm", "intensity", "density", "ground_density"),
                               workers=2), progress=False)
        (f,) = report.files
        assert f["products_only"] > 0
        assert f["read"] == (f["kept"] + f["filtered_class"] + f["filtered_withheld"] + f["outside_bbox"]
                             + f["products_only"]), f
    assert_same_store(stores["copc"], stores["twin"])


def test_a_copc_read_by_window_gives_each_point_its_own_intensity(tmp_path):
    """COPC is LAS 1.4 LAZ: intensity is a layer of its own, which a reader
    that leaves it compressed reads as each node's first intensity."""
    rng = np.random.default_rng(5)
    x, y = ORIGIN[0] + rng.random(20_000) * 200.0, ORIGIN[1] + rng.random(20_000) * 200.0
    intensity = rng.integers(0, 65536, x.size)
    copc = write_copc(tmp_path / "i.copc.laz", x, y, terrain_height(x, y, ORIGIN), np.full(x.size, 2), depth=3,
                      intensity=intensity)
    window = (ORIGIN[0] + 50.0, ORIGIN[1] + 50.0, ORIGIN[0] + 120.0, ORIGIN[1] + 150.0)
    chunks = list(iter_points(copc, PointFilter(), window=window, attributes=("intensity",)))
    got_x = np.concatenate([c.x for c in chunks])
    got_y = np.concatenate([c.y for c in chunks])
    got = np.concatenate([c.attributes["intensity"] for c in chunks])  # none for the nodes left unread
    assert sum(c.outside_window for c in chunks) > 0 and got.size > 1000
    # the points as written (rounded to the file's centimetre), matched by their coordinates
    keys = np.round(x * 100).astype(np.int64) * 10**9 + np.round(y * 100).astype(np.int64)
    order = np.argsort(keys)
    where = order[np.searchsorted(keys, np.round(got_x * 100).astype(np.int64) * 10**9
                                  + np.round(got_y * 100).astype(np.int64), sorter=order)]
    assert np.allclose(x[where], got_x, atol=0.006) and np.allclose(y[where], got_y, atol=0.006)
    assert np.array_equal(got, intensity[where].astype(np.float64))


def test_a_copc_on_s3_fetches_only_the_nodes_its_window_needs(survey, tmp_path, monkeypatch):
    pytest.importorskip("s3fs")
    from .s3server import start_s3_server

    copc, twin = survey
    server = start_s3_server()
    opened = []
    real_open = urls.open_input

    def counted(where, block_size=urls.HEADER_BLOCK):
        handle = real_open(where, block_size)
        opened.append(handle.cache)  # the file drops it when closed
        return handle

    try:
        fs = server.filesystem()
        fs.mkdir("copc")
        fs.put_file(str(copc), "copc/survey.copc.laz")
        urls.use_storage_options({"key": server.key, "secret": server.secret, "endpoint_url": server.endpoint})
        keep_all = PointFilter(classes=None, keep_withheld=True)
        everything = next(iter_points(twin, keep_all, 10**7))
        for window in [(651100.0, 6861100.0, 651260.0, 6861260.0), (651300.0, 6861000.0, 651600.0, 6861200.0)]:
            opened.clear()
            with monkeypatch.context() as patch:  # every open of the inputs layer, headers included
                patch.setattr("pipeline.inputs.sources.open_input", counted)
                patch.setattr("pipeline.inputs.layout.open_input", counted)
                chunks = list(iter_points("s3://copc/survey.copc.laz", keep_all, 200_000, window=window))
            fetched = sum(cache.total_requested_bytes for cache in opened)
            needed, points = nodes_meeting(copc, window)
            assert needed < 0.5 * copc.stat().st_size  # a window, not the file
            assert fetched <= 1.5 * needed, (fetched, needed)
            assert sum(c.read for c in chunks) == everything.read
            assert sum(c.read - c.outside_window for c in chunks) == points
            x = np.concatenate([c.x for c in chunks])
            y = np.concatenate([c.y for c in chunks])
            inside = lambda a, b: (a >= window[0]) & (a <= window[2]) & (b >= window[1]) & (b <= window[3])  # noqa: E731
            mine = inside(x, y)
            theirs = inside(everything.x, everything.y)
            # the same points of the window, in the same (file) order
            assert np.array_equal(x[mine], everything.x[theirs]) and np.array_equal(y[mine], everything.y[theirs])
    finally:
        urls.use_storage_options(None)
        server.stop()


@pytest.fixture(scope="module")
def neighbour(survey):
    """A plain LAZ survey overlapping the COPC's east part (duplicates and seams across the two)."""
    import laspy
    from pyproj import CRS

    rng = np.random.default_rng(43)
    n = 60_000
    x = np.round(ORIGIN[0] + 450.0 + rng.random(n) * 350.0, 2)
    y = np.round(ORIGIN[1] + rng.random(n) * 400.0, 2)
    ground = rng.random(n) < 0.5
    z = np.round(terrain_height(x, y, ORIGIN) + np.where(ground, 0.0, 4.0), 2)
    las = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    las.header.scales, las.header.offsets = [0.01] * 3, [ORIGIN[0], ORIGIN[1], 0.0]
    las.header.add_crs(CRS.from_user_input("EPSG:2154"))
    las.x, las.y, las.z = x, y, z
    las.classification = np.where(ground, 2, 5).astype(np.uint8)
    path = survey[0].parent / "zz_neighbour.laz"  # after the COPC and its twin, in either run
    las.write(str(path))
    return path


def _counts(report) -> list[tuple]:
    keys = ("read", "filtered_class", "filtered_withheld", "outside_bbox", "kept")
    return [tuple(f[k] for k in keys) for f in report.files]


def test_tiles_read_a_copc_by_window_with_no_routing_pass_and_make_the_plain_laz_store(
    survey, neighbour, tmp_path, monkeypatch
):
    from pipeline.runs import runner
    from pipeline.meshing import tiles

    copc, twin = survey
    routed = []
    real_route = runner._route
    monkeypatch.setattr(runner, "_route", lambda job: routed.append(job.path) or real_route(job))
    searched = []  # certification beyond the buffer: read straight from the nodes that meet its bands
    real_search = tiles.points_in_boxes
    monkeypatch.setattr(tiles, "points_in_boxes", lambda *a: searched.append(a[1]) or real_search(*a))
    common = dict(resolution=1.0, tile_size=80.0, layers=("slope", "point_count", "face_kind"), workers=2)
    windowed = run(RunConfig(inputs=(str(copc), str(neighbour)), output=str(tmp_path / "w.zarr"), **common),
                   progress=False)
    assert routed == [str(neighbour)]  # the COPC never went through a routing pass
    assert searched, "no tile searched beyond its buffer: the window search went untested"
    routed.clear()
    plain = run(RunConfig(inputs=(str(twin), str(neighbour)), output=str(tmp_path / "p.zarr"), **common),
                progress=False)
    assert routed == [str(twin), str(neighbour)]
    assert_same_store(tmp_path / "w.zarr", tmp_path / "p.zarr")
    assert _counts(windowed) == _counts(plain)  # each node counted once, by one tile
    for field in ("points_read", "points_kept", "filtered_class", "duplicates", "vertices", "faces", "quads"):
        assert getattr(windowed, field) == getattr(plain, field), field
    assert windowed.tiles > 20


def test_each_tile_fetches_about_the_nodes_it_needs_from_a_copc_on_s3(survey, neighbour, tmp_path, monkeypatch):
    pytest.importorskip("s3fs")
    import threading

    import zarr

    from pipeline.meshing import tiles
    from pipeline.meshing.tiles import held_box
    from pipeline.tiling.grid import TileGrid

    from .s3server import start_s3_server

    copc, twin = survey
    server = start_s3_server()
    fetched: dict[int, int] = {}
    per_tile: dict[tuple[int, int], int] = {}
    real_open = urls.open_input

    def counted(where, block_size=urls.HEADER_BLOCK):
        handle = real_open(where, block_size)
        if urls.is_url(where):
            me = threading.get_ident()
            real_close = handle.close

            def close():
                fetched[me] = fetched.get(me, 0) + handle.cache.total_requested_bytes
                real_close()
            handle.close = close
        return handle

    real_points = tiles.tile_points

    def tile_points(scratch, windows, grid, buffer, row, col, box):
        me = threading.get_ident()
        before = fetched.get(me, 0)
        out = real_points(scratch, windows, grid, buffer, row, col, box)
        if windows:  # the run over s3, not the reference over the twin
            per_tile[(row, col)] = fetched.get(me, 0) - before
        return out

    try:
        fs = server.filesystem()
        fs.mkdir("copc")
        fs.put_file(str(copc), "copc/survey.copc.laz")
        monkeypatch.setattr("pipeline.inputs.sources.open_input", counted)
        monkeypatch.setattr(tiles, "tile_points", tile_points)
        config = RunConfig(inputs=("s3://copc/survey.copc.laz",), output=str(tmp_path / "s3.zarr"), resolution=1.0,
                           tile_size=200.0, workers=2,
                           storage_options={"key": server.key, "secret": server.secret, "endpoint_url": server.endpoint})
        report = run(config, progress=False)
        (f,) = report.files
        twin_chunks = list(iter_points(twin, PointFilter(classes=frozenset(config.classes))))
        assert f["read"] == sum(c.read for c in twin_chunks)  # every point counted, by one tile
        assert f["kept"] == sum(c.kept for c in twin_chunks) == report.points_kept
        assert f["read"] == f["kept"] + f["filtered_class"] + f["filtered_withheld"] + f["outside_bbox"]
        provenance = zarr.open_group(str(tmp_path / "s3.zarr"), mode="r").attrs["provenance"]
        grid, buffer = TileGrid.from_dict(provenance["grid"]), float(provenance["buffer"])
        ratios = []
        for (r, c), got in sorted(per_tile.items()):
            needed, _ = nodes_meeting(copc, held_box(grid, r, c, buffer))
            ratios.append(got / needed)
        assert len(ratios) == report.tiles
        assert max(ratios) <= 1.5, ratios
    finally:
        urls.use_storage_options(None)
        server.stop()



def test_a_copc_survey_never_classified_gets_the_ground_of_its_plain_twin(tmp_path):
    rng = np.random.default_rng(43)
    n = 20_000
    x = np.round(ORIGIN[0] + rng.random(n) * 200.0, 2)
    y = np.round(ORIGIN[1] + rng.random(n) * 150.0, 2)
    z = np.round(terrain_height(x, y, ORIGIN), 2)
    noise = rng.random(n) < 0.02
    copc = write_copc(tmp_path / "raw.copc.laz", x, y, z, np.where(noise, 7, 1), depth=4)
    twin = plain_twin(copc, tmp_path / "raw.laz")
    stores = {}
    for name, path in (("copc", copc), ("twin", twin)):
        stores[name] = tmp_path / f"{name}.zarr"
        report = run(RunConfig(inputs=(str(path),), output=str(stores[name]), resolution=1.0, tile_size=64.0,
                               workers=2), progress=False)
        assert any("input point(s) of the default classes (2, ground)" in note for note in report.notes), report.notes
        assert report.points_read == n and report.filtered_class == int(noise.sum())
        assert report.points_kept + report.not_ground == n - int(noise.sum())
        assert report.points_kept > 0.95 * (n - int(noise.sum()))  # bare terrain: nearly every point is ground
    assert_same_store(stores["copc"], stores["twin"])
