"""End-to-end runs on synthetic LAZ surveys (analytic terrain, so errors are known)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

import meshcore
from pipeline.store import zarr_store as store
from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, terrain_height, write_survey

from .store_checks import face_set

SPEC = SurveySpec(points=60_000, files=3, width=300.0, height=200.0, seed=3)


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SPEC)
    return folder


def _run(survey, out, **kw):
    values = dict(inputs=(str(survey),), output=str(out), resolution=2.0, workers=2)
    values.update(kw)
    return run(RunConfig(**values), progress=False)


@pytest.fixture(scope="module")
def tiled(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("tiled") / "dem.zarr"
    report = _run(survey, out, tile_size=64.0, layers=("slope", "face_kind", "point_count"))
    return out, report


@pytest.fixture(scope="module")
def untiled(survey, tmp_path_factory):
    out = tmp_path_factory.mktemp("untiled") / "dem.zarr"
    report = _run(survey, out, tile_size=1024.0)
    return out, report


def test_report_accounts_for_every_point(tiled):
    _, report = tiled
    assert report.points_read == SPEC.points
    assert report.tiles > 4
    assert report.points_kept + report.filtered_class + report.filtered_withheld + report.outside_bbox == report.points_read
    assert report.vertices + report.duplicates == report.points_kept
    assert report.duplicates > 0
    assert report.tiles_uncertified == 0
    assert 0.2 < report.quad_share < 0.6


def test_dem_opens_with_xarray_and_matches_the_terrain(tiled):
    out, _ = tiled
    ds = xr.open_zarr(out)
    elev = ds["elevation"]
    assert elev.dims == ("y", "x") and elev.dtype == np.float32
    assert np.all(np.diff(ds["y"].values) < 0)
    assert "crs_wkt" in ds["spatial_ref"].attrs
    from pyproj import CRS

    assert CRS.from_wkt(ds["spatial_ref"].attrs["crs_wkt"]).to_epsg() == 2154
    gx, gy = np.meshgrid(ds["x"].values, ds["y"].values)
    truth = terrain_height(gx, gy, SPEC.origin)
    inside = (gx > SPEC.origin[0] + 2) & (gx < SPEC.origin[0] + SPEC.width - 2)
    inside &= (gy > SPEC.origin[1] + 2) & (gy < SPEC.origin[1] + SPEC.height - 2)
    ok = np.isfinite(elev.values)
    assert ok[inside].mean() > 0.999
    assert not ok[(gy > SPEC.origin[1] + SPEC.height + 2)].any()
    err = np.abs(elev.values[ok] - truth[ok])
    assert np.median(err) < 0.05
    assert set(np.unique(ds["face_kind"].values)) <= {0, 1, 2}
    assert int(ds["point_count"].values.sum()) > 0.9 * SPEC.points * SPEC.ground_share
    assert np.nanmax(ds["slope"].values) < 60


def test_stitched_mesh_is_one_conforming_mesh(tiled, untiled):
    out, report = tiled
    node_xy, node_z, faces = store.read_mesh(out)
    mesh = meshcore.Mesh(np.asarray(node_xy), np.asarray(faces), np.arange(len(node_xy)))
    meshcore.validate(mesh)  # conforming, CCW, convex quads, covers the hull, every vertex used
    assert len(node_xy) == report.vertices
    assert len(np.unique(node_xy[:, 0] + 1j * node_xy[:, 1])) == len(node_xy)
    ref_xy, _, ref_faces = store.read_mesh(untiled[0])
    assert len(ref_xy) == len(node_xy)
    same = len(face_set(node_xy, faces) & face_set(ref_xy, ref_faces)) / len(ref_faces)
    print(f"faces identical to the untiled run: {same:.4%}")
    # tiles here hold ~2,000 points each, so seams are a large share of the
    # mesh; bench/bench_pipeline.py measures the share at realistic sizes
    assert same >= 0.98
    a = xr.open_zarr(out)["elevation"].values
    b = xr.open_zarr(untiled[0])["elevation"].values
    rows = min(a.shape[0], b.shape[0])
    a, b = a[-rows:], b[-rows:]  # both grids start at the same south-west corner
    both = np.isfinite(a) & np.isfinite(b)
    assert (np.isfinite(a) == np.isfinite(b)).mean() > 0.999
    print(f"DEM cells identical: {(a[both] == b[both]).mean():.4%}")
    assert (a[both] == b[both]).mean() > 0.98


def test_mesh_group_opens_with_xugrid(tiled):
    xugrid = pytest.importorskip("xugrid")
    out, report = tiled
    uds = xugrid.UgridDataset(xr.open_zarr(out, group="mesh"))
    assert uds.ugrid.grid.n_face == report.faces


def test_cli_run(survey, tmp_path, capsys):
    out = tmp_path / "cli.zarr"
    code = main(["run", str(survey), "-o", str(out), "--resolution", "4", "--tile-size", "128", "--no-progress"])
    assert code == 0
    assert xr.open_zarr(out)["elevation"].shape[1] > 0
    capsys.readouterr()
    # a second run into the same store needs --overwrite: the library speaks of
    # its parameter, the command line of its flag
    assert main(["run", str(survey), "-o", str(out), "--resolution", "4", "--no-progress"]) == 2
    said = capsys.readouterr().err
    assert "pass --overwrite" in said and "overwrite=True" not in said
    from pipeline.errors import PipelineError

    with pytest.raises(PipelineError, match="pass overwrite=True"):
        run(RunConfig(inputs=(str(survey),), output=str(out), resolution=4.0))


def test_python_api_over_tiles(tiled):
    import pipeline

    out, report = tiled
    ts = pipeline.open(out)
    tiles = ts.tiles()
    assert len(tiles) == report.tiles
    counts = ts.map_tiles(lambda tile, mesh, z: int(mesh.faces.shape[0]))
    assert sum(counts) == report.faces
    busy = tiles[int(np.argmax(counts))]
    mesh, z = ts.tile_mesh(busy)
    assert mesh.faces.max() < len(mesh.vertices) and z.shape == (len(mesh.vertices),)
    window = ts.tile_dem(busy)
    r0, r1, c0, c1 = ts.grid.cell_slice(busy.row, busy.col)  # a tile of the northern row may be lower
    assert window["elevation"].shape == (r1 - r0, c1 - c0)


def test_tile_dem_is_the_tiles_block_at_a_resolution_not_exact_in_binary(tmp_path):
    import pipeline

    folder = tmp_path / "small"
    write_survey(folder, SurveySpec(points=8_000, files=1, width=50.0, height=30.0, seed=5))
    out = tmp_path / "r03.zarr"
    _run(folder, out, resolution=0.3, tile_size=19.2)
    ts = pipeline.open(out)
    whole = ts.dem()["elevation"].values
    t = ts.grid.tile_cells
    for tile in ts.tiles():
        window = ts.tile_dem(tile)["elevation"]
        r0, r1, c0, c1 = ts.grid.cell_slice(tile.row, tile.col)
        assert window.shape == (r1 - r0, c1 - c0)
        np.testing.assert_array_equal(window.values, whole[ts.grid.ny - r1 : ts.grid.ny - r0, c0:c1])
        x0, y0, x1, y1 = tile.box  # cell centres inside the tile's box
        assert x0 < float(window.x.min()) and float(window.x.max()) < x1 and y0 < float(window.y.min())
        assert float(window.y.max()) < y1 and r1 - r0 <= t


def _grid_of(path) -> dict:
    """What a store and its readers say of its grid, but for the chunk size:
    shape, x, y, the grid mapping, the STAC item's projection, a DEM window's
    coordinates through the Python API."""
    import json

    import pipeline

    with xr.open_zarr(path) as ds:
        grid = dict(ds.attrs["grid"])
        grid.pop("tile_cells")
        found = {"shape": ds["elevation"].shape, "x": ds["x"].values.tobytes(), "y": ds["y"].values.tobytes(),
                 "spatial_ref": dict(ds["spatial_ref"].attrs), "grid": grid}
    stac = json.loads(path.with_suffix(".stac.json").read_text())["properties"]
    found["stac"] = [stac[k] for k in ("proj:shape", "proj:transform", "proj:bbox")]
    x0, y0, x1, y1 = (float(v) for v in stac["proj:bbox"])
    window = pipeline.open(path).dem_window(x0, y1 - 10.0, x0 + 10.0, y1)  # the north-west corner
    found["window"] = (window["x"].values.tobytes(), window["y"].values.tobytes())
    return found


def _bits(path, layer: str) -> np.ndarray:
    """A layer's cells as stored, bit for bit (a float layer as unsigned integers)."""
    values = store.read_layer(path, layer)
    return values.view(f"u{values.dtype.itemsize}") if values.dtype.kind == "f" else values


def test_the_grid_and_the_delaunay_dem_are_the_same_at_any_tile_size(tmp_path):
    """Any tile size and buffer gives the grid of the data's extent (no rows
    of no data up to a whole tile) and, for the Delaunay mesh, the same
    cells, bit for bit."""
    folder = tmp_path / "survey"
    write_survey(folder, SurveySpec(points=12_000, files=2, width=50.0, height=30.0, seed=8))
    layers = ("slope", "face_kind", "point_count")
    # 100 x 60 cells: tiles of 14, 25 and 40 cells (none divides the rows, one the columns), and one tile
    sizes = [(7.0, None), (12.5, 0.0), (20.0, 9.0), (1000.0, None)]
    stores = []
    for tile_size, buffer in sizes:
        out = tmp_path / f"tile{tile_size:g}.zarr"
        report = _run(folder, out, resolution=0.5, tile_size=tile_size, buffer=buffer, layers=layers,
                      triangle_measure="delaunay", quad_measure=None)
        assert report.tiles_uncertified == 0
        stores.append(out)
    reference = _grid_of(stores[-1])
    assert reference["shape"] == (61, 101)  # the data's 30 x 50 m at 0.5 m, whatever the tiles
    chunks = []
    for out in stores:
        assert _grid_of(out) == reference, out.name
        with xr.open_zarr(out) as ds:
            chunks.append(ds["elevation"].chunks)
        for layer in ("elevation", *layers):
            assert np.array_equal(_bits(out, layer), _bits(stores[-1], layer)), (out.name, layer)
    # chunks of a tile's size from the north-west corner: those of the southern row and the eastern column are partial
    assert chunks[0] == ((14,) * 4 + (5,), (14,) * 7 + (3,))
    assert chunks[1] == ((25,) * 2 + (11,), (25,) * 4 + (1,))
    assert chunks[-1] == ((61,), (101,))


def test_cli_demo_and_zarr_format_2(tmp_path):
    from matplotlib.image import imread

    from pipeline.tools.synthetic import demo_spec

    assert main(["demo", "--out", str(tmp_path), "--points", "40000"]) == 0
    ds = xr.open_zarr(tmp_path / "dem.zarr")
    assert {"elevation", "slope", "face_kind", "point_count", "dsm", "chm", "intensity", "density",
            "ground_density"} <= set(ds.data_vars)
    report = ds.attrs["report"]
    # buildings, trees, noise: out of the DTM, read for the products
    assert report["products_only"] > 0.05 * report["points_read"]
    assert float(ds["chm"].max()) > 5.0
    spec = demo_spec()
    lx, ly, r = spec.lake
    x0, y0 = spec.origin
    elev = ds["elevation"]
    assert np.isnan(float(elev.sel(x=x0 + lx, y=y0 + ly, method="nearest")))  # the lake: no returns, no DEM
    assert np.isfinite(float(elev.sel(x=x0 + lx - r - 10, y=y0 + ly, method="nearest")))  # its shore
    # under the buildings the ground is bridged (they are smaller than max_edge)
    box = elev.sel(x=slice(x0 + 20, x0 + 780), y=slice(y0 + 580, y0 + 20))
    gx, gy = np.meshgrid(box["x"].values, box["y"].values)
    dry = (gx - x0 - lx) ** 2 + (gy - y0 - ly) ** 2 > (r + 10) ** 2
    assert np.isfinite(box.values[dry]).mean() > 0.999
    for name in ("dem.png", "mesh.png"):
        picture = imread(tmp_path / name)
        assert picture.shape[0] > 400 and picture.shape[1] > 600
        assert picture[..., :3].std() > 0.1  # not blank
    out = tmp_path / "v2.zarr"
    code = main(["run", str(tmp_path / "survey"), "-o", str(out), "--resolution", "4", "--zarr-format", "2", "--no-progress"])
    assert code == 0
    assert (out / ".zgroup").exists()
    assert np.isfinite(xr.open_zarr(out)["elevation"].values).any()


@pytest.mark.parametrize("bounds", ["zero", "nan", "swapped"])
def test_unusable_header_bounds_are_measured_from_the_points(tmp_path, bounds):
    import struct

    folder = tmp_path / "survey"
    paths = write_survey(folder, SurveySpec(points=20_000, files=2, width=200.0, height=100.0, seed=8))
    bad = paths[1]
    data = bytearray(bad.read_bytes())
    fields = list(struct.unpack_from("<6d", data, 179))  # max x, min x, max y, min y, max z, min z
    fields = {"zero": [0.0] * 6, "nan": [math.nan, *fields[1:]], "swapped": [fields[1], fields[0], *fields[2:]]}[bounds]
    struct.pack_into("<6d", data, 179, *fields)
    bad.write_bytes(bytes(data))
    report = _run(folder, tmp_path / "dem.zarr", tile_size=64.0)
    assert any(note.startswith(f"{bad}: header bounds unusable") for note in report.notes), report.notes
    reference = _run(write_survey(tmp_path / "good", SurveySpec(points=20_000, files=2, width=200.0, height=100.0,
                                                                seed=8))[0].parent, tmp_path / "good.zarr", tile_size=64.0)
    assert report.vertices == reference.vertices and report.faces == reference.faces
    a = xr.open_zarr(tmp_path / "dem.zarr")["elevation"].values
    np.testing.assert_array_equal(a, xr.open_zarr(tmp_path / "good.zarr")["elevation"].values)


def test_a_stale_header_keeps_every_point_in_one_conforming_mesh(tmp_path):
    """Header bounds that understate the points (edited files): the mesh holds
    every point, the report adds up and says which file, the DEM keeps the
    header's extent."""
    import struct

    folder = tmp_path / "survey"
    paths = write_survey(folder, SurveySpec(points=30_000, files=2, width=300.0, height=200.0, seed=5))
    stale = paths[0]
    data = bytearray(stale.read_bytes())
    (min_x,) = struct.unpack_from("<d", data, 187)
    struct.pack_into("<d", data, 187, min_x + 60.0)  # the west strip: 60 m of points beyond its header's min x
    stale.write_bytes(bytes(data))
    out = tmp_path / "dem.zarr"
    report = _run(folder, out, tile_size=64.0)
    assert report.vertices + report.duplicates == report.points_kept
    assert any(note.startswith(f"{stale}: ") and "beyond the bounds its header announces" in note
               for note in report.notes), report.notes
    node_xy, _, faces = store.read_mesh(out)
    meshcore.validate(meshcore.Mesh(np.asarray(node_xy), np.asarray(faces), np.arange(len(node_xy))))
    assert len(node_xy) == report.vertices
    reference = tmp_path / "whole.zarr"
    whole = _run(folder, reference, tile_size=1024.0)
    assert whole.vertices == report.vertices


def _write_ground(path, x, y, z, origin=(0.0, 0.0)):
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([origin[0], origin[1], 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.full(np.size(x), 2, dtype=np.uint8)
    las.write(path)
    return path


def _cells_inside_hull(ds, x, y):
    """The DEM's cell centres strictly inside the convex hull of the points."""
    from scipy.spatial import ConvexHull

    o = np.array([x.min(), y.min()])
    facets = ConvexHull(np.c_[x, y] - o).equations
    gx, gy = np.meshgrid(ds.x.values - o[0], ds.y.values - o[1])
    return (facets[:, :2] @ np.c_[gx.ravel(), gy.ravel()].T + facets[:, 2:] < -1e-6).all(axis=0).reshape(gx.shape)


def test_a_hull_sliver_across_several_tiles_leaves_no_hole_in_the_dem(tmp_path):
    """A long thin triangle along the convex hull covers cells of tiles two and
    more away from the tile that owns it: their DEM must still read it."""
    rng = np.random.default_rng(1)
    x = np.r_[np.round(rng.uniform(0, 400, 4000), 2), 0, 400, 0, 400, 200]
    y = np.r_[np.round(rng.uniform(0, 100, 4000), 2), 0, 0, 100, 100, 104]  # a low roof above the data
    path = _write_ground(tmp_path / "roof.las", x, y, 10 + 0.01 * x + 0.02 * y)
    out = tmp_path / "dem.zarr"
    _run(path, out, resolution=1.0, tile_size=20.0, in_crs="EPSG:2154")
    ds = xr.open_zarr(out)
    inside = _cells_inside_hull(ds, x, y)
    assert inside[ds.y.values > 100.0].sum() > 600  # cells under the roof, across the tiles of the top row
    assert np.isfinite(ds.elevation.values[inside]).all()


def test_a_void_wider_than_the_buffer_is_bridged_as_in_one_piece(tmp_path):
    """Tiles inside a data void (a building, a lake with --classes 2) own no
    points and hold none within their buffer: they must reach across the void
    for the triangles that span it, as an untiled run has them."""
    rng = np.random.default_rng(3)
    p = np.round(rng.uniform(0, 150, (11_000, 2)), 2)
    p = p[~((np.abs(p[:, 0] - 75) < 37) & (np.abs(p[:, 1] - 75) < 37))]  # a 74 m void; the buffer is ~17 m
    path = _write_ground(tmp_path / "void.las", p[:, 0], p[:, 1], 20 + 0.1 * p[:, 0] + 0.05 * p[:, 1])
    out = tmp_path / "dem.zarr"
    report = _run(path, out, resolution=1.0, tile_size=10.0, in_crs="EPSG:2154")
    assert report.tiles_uncertified == 0
    node_xy, _, faces = store.read_mesh(out)
    meshcore.validate(meshcore.Mesh(np.asarray(node_xy), np.asarray(faces), np.arange(len(node_xy))))
    ds = xr.open_zarr(out)
    inside = _cells_inside_hull(ds, p[:, 0], p[:, 1])
    assert np.isfinite(ds.elevation.values[inside]).all()


def test_repeated_points_on_the_hull_leave_no_gap_between_tiles(tmp_path):
    """Points repeated at one x, y (overlapping strips): the stitched mesh still
    covers the convex hull, and the DEM has data wherever the hull does."""
    rng = np.random.default_rng(5)
    x = np.round(rng.uniform(1000, 1300, 20_000), 2)
    y = np.round(rng.uniform(5000, 5250, 20_000), 2)
    again = rng.integers(0, x.size, 3000)
    x, y = np.r_[x, x[again]], np.r_[y, y[again]]
    path = _write_ground(tmp_path / "strips.las", x, y, 50 + 0.05 * (x - 1000), origin=(1000.0, 5000.0))
    out = tmp_path / "dem.zarr"
    report = _run(path, out, resolution=1.0, tile_size=40.0, in_crs="EPSG:2154")
    node_xy, _, faces = store.read_mesh(out)
    meshcore.validate(meshcore.Mesh(np.asarray(node_xy), np.asarray(faces), np.arange(len(node_xy))))
    assert len(node_xy) == report.vertices
    ds = xr.open_zarr(out)
    inside = _cells_inside_hull(ds, x, y)
    assert inside.sum() > 0.9 * 300 * 250
    assert np.isfinite(ds.elevation.values[inside]).all()


def test_a_local_run_maps_its_tasks_over_threads_and_stops_at_the_first_failure(tmp_path):
    """Without a scheduler a run's tasks go to a pool of this process's
    threads (no in-process Dask cluster to start): they run side by side, a
    failed task raises from the stage after the tasks not yet started are
    cancelled and those running have ended, and closing the pool ends its
    threads."""
    import threading
    import time

    from pipeline.runs.cluster import LocalThreads, Progress, close, connect, map_tasks

    pool, extra = connect(RunConfig(inputs=("x.las",), output=str(tmp_path / "o.zarr"), resolution=1.0, workers=2))
    assert isinstance(pool, LocalThreads) and pool.threads == 2 and extra is None
    both = threading.Barrier(2, timeout=10)  # passes only when two tasks run at once
    names = map_tasks(pool, lambda i: both.wait() >= 0 and threading.current_thread().name, [0, 1],
                      Progress("t", 2, False), lambda _: 0)
    assert len(set(names)) == 2
    started, ended = [], []

    def task(i):
        started.append(i)
        if i == 0:
            raise ValueError("tile 0 failed")
        time.sleep(0.3)  # the other tasks are still running when the stage is given up
        ended.append(i)
        return i

    with pytest.raises(ValueError, match="tile 0 failed"):
        map_tasks(pool, task, list(range(50)), Progress("t", 50, False), lambda _: 0)
    # no task of the failed stage is left running: a resume started next in this process would race with it
    assert sorted(ended) == sorted(i for i in started if i != 0) and ended
    close(pool, extra)
    for t in threading.enumerate():
        if t.name.startswith("terrain-"):
            t.join(timeout=10)
    assert not [t for t in threading.enumerate() if t.name.startswith("terrain-")]
    assert len(started) <= 3  # the two running and one taken at the failure; the rest were cancelled


def test_a_task_mapped_after_others_starts_when_they_end_without_waiting_for_the_rest():
    """``map_tasks(after=)``: the DEM of a tile that shares chunks with its
    neighbours waits for them alone.  C waits for A and B, and starts while D,
    which started before it, still runs (sets of tasks one after the other
    would have made it wait for D too)."""
    import time

    from pipeline.runs.cluster import LocalThreads, Progress, close, map_tasks

    t: dict[tuple[str, str], float] = {}

    def task(item: tuple[str, float]) -> str:
        name, seconds = item
        t[name, "start"] = time.perf_counter()
        time.sleep(seconds)
        t[name, "end"] = time.perf_counter()
        return name

    pool = LocalThreads(2)
    ended = []
    names = map_tasks(pool, task, [("A", 0.2), ("B", 0.3), ("D", 1.5), ("C", 0.0)], Progress("t", 4, False),
                      lambda _: 0, lambda item, name: ended.append(name), after={3: [0, 1]})
    close(pool, None)
    assert names == ["A", "B", "D", "C"] and sorted(ended) == sorted(names)
    assert t["C", "start"] >= max(t["A", "end"], t["B", "end"])
    assert t["C", "start"] < t["D", "end"] and ended.index("C") < ended.index("D")


def test_the_dem_of_a_tile_waits_only_for_the_tiles_that_write_parts_of_its_chunks():
    from pipeline.runs.runner import _dem_order
    from pipeline.tiling.grid import TileGrid

    class Job:
        def __init__(self, row, col):
            self.row, self.col = row, col

    grid = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=10, nx=25, ny=35)  # 4 x 3 tiles, 35 % 10 rows
    assert grid.rows_share_chunks and (grid.n_rows, grid.n_cols) == (4, 3)
    jobs = [Job(r, c) for r in range(4) for c in range(3) if (r, c) != (0, 1)]  # (0, 1) written by a run before
    tasks = [("dem", j) for j in jobs] + [("number", Job(r, c)) for r in range(4) for c in range(3)]
    order = _dem_order(grid, tasks)
    where = {(j.row, j.col): i for i, j in enumerate(jobs)}
    assert order == {where[1, 0]: [where[0, 0], where[2, 0]], where[1, 1]: [where[2, 1]],
                     where[1, 2]: [where[0, 2], where[2, 2]], where[3, 0]: [where[2, 0]],
                     where[3, 1]: [where[2, 1]], where[3, 2]: [where[2, 2]]}
    aligned = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=10, nx=25, ny=40)
    assert not aligned.rows_share_chunks and _dem_order(aligned, tasks) == {}
    # the mesh's blocks: one of faces waits for the numbering of the tiles it spans (but those numbered before)
    from pipeline.store.assemble import MeshBlock

    tiles = tuple(grid.tiles())
    offsets = tuple(range(0, 100 * len(tiles) + 1, 100))  # 100 faces (and nodes) a tile
    blocks = [MeshBlock("o.zarr", None, tiles, offsets, what, start, stop)
              for what, start, stop in (("nodes", 0, 1200), ("faces", 150, 450), ("faces", 1000, 1200))]
    assert [t for k, _, _ in blocks[1].spans() for t in [tiles[k]]] == [tiles[1], tiles[2], tiles[3], tiles[4]]
    tasks = tasks[:len(jobs)] + [t for t in tasks[len(jobs):] if t[1].row > 0] + [("write", b) for b in blocks]
    number = {(j.row, j.col): i for i, (what, j) in enumerate(tasks) if what == "number"}
    order = _dem_order(aligned, tasks)
    assert order == {len(tasks) - 2: [number[tiles[3]], number[tiles[4]]],
                     len(tasks) - 1: [number[tiles[10]], number[tiles[11]]]}


def test_a_sparse_survey_in_tiny_tiles_reads_each_tile_once_and_meshes_as_one_piece(tmp_path, monkeypatch):
    """Clusters of points with wide voids between them, in tiles far smaller
    than the voids: every empty tile searches outward through hundreds of
    tiles.  Each tile's file is read once for the whole search (it was read
    again for every tile and every round), and the stitched mesh is still the
    untiled one."""
    from pipeline.meshing import tiles
    from pipeline.tiling import routing as tiling

    rng = np.random.default_rng(4)
    centres = rng.uniform(0, 120, (6, 2))
    p = np.round(np.concatenate([c + rng.normal(0, 4, (25, 2)) for c in centres]), 2)
    path = _write_ground(tmp_path / "sparse.las", p[:, 0], p[:, 1], 20 + 0.1 * p[:, 0])
    reads = []
    real_load = tiling.load_tile_points
    monkeypatch.setattr(tiling, "load_tile_points", lambda *a: reads.append(a[1:]) or real_load(*a))
    monkeypatch.setattr(tiles, "_LOAD_BATCH", 40)  # the points read are tested in several batches
    # the Delaunay triangulation is unique: tiled and untiled runs must agree on every face
    delaunay = dict(resolution=1.0, in_crs="EPSG:2154", triangle_measure="delaunay", quad_measure="none")
    tiled = _run(path, tmp_path / "tiled.zarr", tile_size=8.0, workers=1, **delaunay)
    assert tiled.tiles_uncertified == 0
    assert tiled.tiles > 60
    assert len(reads) > 30  # the voids were searched
    assert len(reads) == len(set(reads)) <= tiled.tiles
    monkeypatch.setattr(tiling, "load_tile_points", real_load)
    _run(path, tmp_path / "whole.zarr", tile_size=4096.0, **delaunay)

    def faces(out):
        xy, _, f = store.read_mesh(out)
        xy, f = np.asarray(xy), np.asarray(f)
        meshcore.validate(meshcore.Mesh(xy, f, np.arange(len(xy))))
        return face_set(xy, f)

    assert faces(tmp_path / "tiled.zarr") == faces(tmp_path / "whole.zarr")
