"""Tests of pipeline.store.zarr_store: the DEM layers, the UGRID mesh group, and the store's errors."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import xugrid
from numpy.testing import assert_allclose, assert_array_equal
from pyproj import CRS

from pipeline.errors import UsageError
from pipeline.store.zarr_store import (
    MeshWriter,
    StoreError,
    create_store,
    finalize_store,
    open_dem,
    read_attrs,
    read_dem_window,
    read_mesh,
    read_tile_mesh,
    write_tile,
)
from pipeline.tiling.grid import TileGrid

CRS_WKT = CRS.from_epsg(2154).to_wkt()
LAYERS = ("elevation", "slope", "face_kind", "point_count")
FORMATS = pytest.mark.parametrize("zarr_format", [3, 2])


@pytest.fixture
def grid() -> TileGrid:
    """2 tile rows x 3 tile columns of 8 cells; the east column is 4 cells wide."""
    return TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=20, ny=16, tile_cells=8)


def south_up(grid: TileGrid) -> dict[str, np.ndarray]:
    """Known layers over the whole grid, south-up, with a few no-data cells."""
    row, col = np.mgrid[0 : grid.ny, 0 : grid.nx]
    elevation = (100.0 * row + col).astype(np.float32)
    elevation[0, 0] = np.nan  # south-west corner
    elevation[grid.ny - 1, grid.nx - 1] = np.nan  # north-east corner
    return {
        "elevation": elevation,
        "slope": (row + col / 100.0).astype(np.float32),
        "face_kind": ((row + col) % 3).astype(np.int8),
        "point_count": (row * col).astype(np.int32),
    }


def tile_of(layers: dict[str, np.ndarray], grid: TileGrid, row: int, col: int) -> dict[str, np.ndarray]:
    t = grid.tile_cells
    return {name: a[row * t : (row + 1) * t, col * t : (col + 1) * t] for name, a in layers.items()}


def new_store(path: Path, grid: TileGrid, zarr_format: int, layers=LAYERS) -> Path:
    attrs = {"software": "test", "inputs": ["a.laz"]}
    create_store(path, grid, CRS_WKT, layers=layers, attrs=attrs, zarr_format=zarr_format)
    return path


# --------------------------------------------------------------------------
# The grid in the store
# --------------------------------------------------------------------------


def test_grid_coordinates_are_cell_centres_north_up(grid):
    assert_allclose(grid.x, 700_001.0 + 2.0 * np.arange(20))
    assert_allclose(grid.y, 6_600_031.0 - 2.0 * np.arange(16))
    assert grid.geotransform == (700_000.0, 2.0, 0.0, 6_600_032.0, 0.0, -2.0)
    assert (grid.n_rows, grid.n_cols) == (2, 3)
    assert TileGrid.from_dict(json.loads(json.dumps(grid.to_dict()))) == grid


@FORMATS
def test_the_store_and_its_provenance_keep_their_grid_key_orders(tmp_path, grid, zarr_format):
    # one grid type, two orders: those every store written so far has, so that its attributes keep their bytes
    store_order = ["x0", "y0", "resolution", "nx", "ny", "tile_cells"]
    provenance_order = ["x0", "y0", "resolution", "tile_cells", "nx", "ny"]
    assert list(grid.to_store_attr()) == store_order and list(grid.to_dict()) == provenance_order
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    assert list(read_attrs(path)["grid"]) == store_order
    assert read_attrs(path)["grid"] == {"x0": 700000.0, "y0": 6600000.0, "resolution": 2.0, "nx": 20, "ny": 16,
                                        "tile_cells": 8}
    for data in (grid.to_store_attr(), grid.to_dict()):  # either order reads back
        assert TileGrid.from_dict(json.loads(json.dumps(data))) == grid
    with pytest.raises(UsageError, match="TileGrid.from_dict"):
        TileGrid.from_dict({"x0": 0.0})


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"resolution": 0.0}, "resolution must be > 0"),
        ({"nx": 0}, "nx must be an integer >= 1"),
        ({"tile_cells": 2.5}, "tile_cells must be an integer"),
    ],
)
def test_grid_rejects_invalid_values(grid, change, message):
    with pytest.raises(UsageError, match=message):
        TileGrid(**(grid.to_dict() | change))


# --------------------------------------------------------------------------
# The DEM
# --------------------------------------------------------------------------


@FORMATS
def test_a_tile_of_zeros_and_nan_is_stored_not_left_to_the_fill_value(tmp_path, grid, zarr_format):
    # a v2 array with no fill value (face_kind, point_count) leaves missing
    # chunks undefined to older readers: every tile written must be on disk
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    t = grid.tile_cells
    empty = {"elevation": np.full((t, t), np.nan, np.float32), "slope": np.full((t, t), np.nan, np.float32),
             "face_kind": np.zeros((t, t), np.int8), "point_count": np.zeros((t, t), np.int32)}
    write_tile(path, grid, 1, 1, empty)
    for name in LAYERS:
        chunk = "0.1" if zarr_format == 2 else "c/0/1"  # north-up: tile row 1 is chunk row 0
        assert (path / name / chunk).is_file(), name


@FORMATS
def test_tiles_written_concurrently_read_back_north_up(tmp_path, grid, zarr_format):
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    layers = south_up(grid)
    tiles = [(r, c) for r in range(grid.n_rows) for c in range(grid.n_cols) if (r, c) != (1, 0)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        list(pool.map(lambda rc: write_tile(path, grid, *rc, tile_of(layers, grid, *rc)), tiles))
    for name, values in south_up(grid).items():
        assert_array_equal(layers[name], values)  # the input is not flipped in place

    ds = open_dem(path)
    expected = {name: a[::-1].copy() for name, a in layers.items()}
    unwritten = (slice(0, 8), slice(0, 8))  # tile (1, 0) is the north-west chunk
    expected["elevation"][unwritten] = np.nan
    expected["slope"][unwritten] = np.nan
    expected["face_kind"][unwritten] = 0
    expected["point_count"][unwritten] = 0
    for name, values in expected.items():
        assert ds[name].dims == ("y", "x")
        assert ds[name].dtype == values.dtype, name  # integers stay integers: no masking
        assert ds[name].encoding["chunks"] == (8, 8)
        assert ds[name].chunks == ((8, 8), (8, 8, 4))
        assert_array_equal(ds[name].values, values, err_msg=name)
    assert np.isnan(ds["elevation"].values[-1, 0]) and np.isnan(ds["elevation"].values[0, -1])
    assert_allclose(ds["x"].values, grid.x)
    assert_allclose(ds["y"].values, grid.y)
    assert (np.diff(ds["y"].values) < 0).all()
    assert float(ds["elevation"].sel(x=700_005.0, y=6_600_001.0)) == 2.0  # south row, third column


def _write_in_parity_waves(path, grid: TileGrid, layers: dict[str, np.ndarray], tiles) -> None:
    """Write tiles from four threads, as the run does: those of even rows, then those of odd rows."""
    for parity in (0, 1):
        wave = [(r, c) for r, c in tiles if r % 2 == parity]
        with ThreadPoolExecutor(max_workers=4) as pool:
            list(pool.map(lambda rc: write_tile(path, grid, *rc, tile_of(layers, grid, *rc)), wave))


@FORMATS
def test_a_grid_of_partial_tile_rows_holds_the_data_rows_only(tmp_path, zarr_format):
    # 13 rows of 8-cell tiles: the northern tile row is 5 cells high, and the
    # chunks, counted from the north edge, each hold parts of two tile rows
    grid = TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=20, ny=13, tile_cells=8)
    assert grid.rows_share_chunks and (grid.n_rows, grid.n_cols) == (2, 3)
    assert grid.box(1, 2) == (700_032.0, 6_600_016.0, 700_040.0, 6_600_026.0)
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    layers = south_up(grid)
    _write_in_parity_waves(path, grid, layers, grid.tiles())
    with open_dem(path) as ds:
        for name, values in layers.items():
            assert ds[name].shape == (13, 20)
            assert ds[name].chunks == ((8, 5), (8, 8, 4)), name  # partial chunks at the south and east edges
            assert_array_equal(ds[name].values, values[::-1], err_msg=name)
        assert_array_equal(ds["y"].values, grid.y)
        assert float(ds["y"][0]) == 6_600_025.0 and float(ds["y"][-1]) == 6_600_001.0


@FORMATS
def test_a_store_grown_north_by_rows_that_are_not_whole_chunks_is_the_store_of_the_grown_grid(tmp_path, zarr_format):
    """Its chunks are written again from the cells they now hold: the same
    bytes as a store made at the grown grid from the same tiles."""
    from pipeline.store.zarr_store import grow_store

    from .store_checks import chunk_files

    before = TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=20, ny=13, tile_cells=8)
    after = TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=25, ny=19, tile_cells=8)
    layers = south_up(after)
    kept = south_up(after)
    for name, values in kept.items():  # what the smaller grid holds: its own cells of the same layers
        values[before.ny:] = np.nan if values.dtype.kind == "f" else 0
        values[:, before.nx:] = np.nan if values.dtype.kind == "f" else 0
    grown = new_store(tmp_path / "grown.zarr", before, zarr_format)
    _write_in_parity_waves(grown, before, {k: v[: before.ny, : before.nx] for k, v in layers.items()}, before.tiles())
    grow_store(grown, before, after)
    with open_dem(grown) as ds:
        assert_array_equal(ds["y"].values, after.y)
        for name, values in kept.items():
            assert_array_equal(ds[name].values, values[::-1], err_msg=name)
    reference = new_store(tmp_path / "reference.zarr", after, zarr_format)
    _write_in_parity_waves(reference, after, kept, after.tiles())
    assert chunk_files(grown) == chunk_files(reference)


@FORMATS
def test_georeferencing_attributes_for_cf_gdal_and_rioxarray(tmp_path, grid, zarr_format):
    ds = open_dem(new_store(tmp_path / "dem.zarr", grid, zarr_format))
    assert "spatial_ref" in ds.coords  # rioxarray reads the grid mapping from the coordinates
    gm = ds["spatial_ref"].attrs
    assert CRS.from_wkt(gm["crs_wkt"]) == CRS.from_epsg(2154)
    assert gm["spatial_ref"] == gm["crs_wkt"]
    assert gm["grid_mapping_name"] == "lambert_conformal_conic"
    assert CRS.from_cf(gm) == CRS.from_epsg(2154)
    assert tuple(float(v) for v in gm["GeoTransform"].split()) == grid.geotransform
    for name in LAYERS:
        var = ds[name]
        assert (var.attrs.get("grid_mapping") or var.encoding.get("grid_mapping")) == "spatial_ref"
        assert CRS.from_wkt(var.attrs["_CRS"]["wkt"]) == CRS.from_epsg(2154)  # GDAL < 3.9
    for name in ("elevation", "slope"):  # the nodata value rioxarray exports, in both formats
        assert np.isnan(ds[name].encoding["_FillValue"]), name
    for name in ("face_kind", "point_count"):  # counts and codes: every value is data
        assert "_FillValue" not in ds[name].encoding, name
    assert ds["x"].attrs["standard_name"] == "projection_x_coordinate"
    assert ds["y"].attrs["standard_name"] == "projection_y_coordinate"
    assert ds["x"].attrs["units"] == ds["y"].attrs["units"] == "metre"
    assert ds.attrs["Conventions"] == "CF-1.8 UGRID-1.0"
    assert ds.attrs["software"] == "test" and ds.attrs["inputs"] == ["a.laz"]
    assert TileGrid.from_dict(ds.attrs["grid"]) == grid
    if zarr_format == 3:
        assert "consolidated_metadata" in json.loads((tmp_path / "dem.zarr" / "zarr.json").read_text())
    else:
        assert (tmp_path / "dem.zarr" / ".zmetadata").exists()


@FORMATS
def test_the_readmes_netcdf_export_keeps_values_and_crs(tmp_path, grid, zarr_format):
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    layers = south_up(grid)
    for row in range(2):
        for col in range(3):
            write_tile(path, grid, row, col, tile_of(layers, grid, row, col))
    finalize_store(path, {"report": {"points": {"kept": 1}}})
    ds = xr.open_zarr(path)
    ds.attrs.clear()
    for v in ds.variables.values():
        v.attrs.pop("_CRS", None)
    ds.to_netcdf(tmp_path / "dem.nc", engine="scipy")
    back = xr.open_dataset(tmp_path / "dem.nc", engine="scipy")
    assert CRS.from_cf(back["spatial_ref"].attrs) == CRS.from_epsg(2154)
    for name in LAYERS:
        np.testing.assert_array_equal(back[name].values, xr.open_zarr(path)[name].values)


def test_store_without_crs_keeps_the_geotransform(tmp_path, grid):
    create_store(tmp_path / "dem.zarr", grid, None, attrs={})
    ds = open_dem(tmp_path / "dem.zarr")
    assert "crs_wkt" not in ds["spatial_ref"].attrs
    assert tuple(float(v) for v in ds["spatial_ref"].attrs["GeoTransform"].split()) == grid.geotransform
    assert "units" not in ds["x"].attrs


def test_read_dem_window_selects_cell_centres_in_the_box(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation",))
    layers = south_up(grid)
    write_tile(path, grid, 0, 1, tile_of({"elevation": layers["elevation"]}, grid, 0, 1))
    window = read_dem_window(path, 700_016.0, 6_600_000.0, 700_020.5, 6_600_004.0)
    assert_allclose(window["x"].values, [700_017.0, 700_019.0])
    assert_allclose(window["y"].values, [6_600_003.0, 6_600_001.0])
    assert_array_equal(window["elevation"].values, [[108.0, 109.0], [8.0, 9.0]])


def test_write_tile_checks_shape_layer_and_dtype(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation", "face_kind"))
    with pytest.raises(UsageError, match=r"expected \(8, 4\)"):
        write_tile(path, grid, 0, 2, {"elevation": np.zeros((8, 8))})
    with pytest.raises(UsageError, match="valid layers: elevation, slope, face_kind, point_count"):
        write_tile(path, grid, 0, 0, {"height": np.zeros((8, 8))})
    with pytest.raises(UsageError, match="cannot store float64 values as int8"):
        write_tile(path, grid, 0, 0, {"face_kind": np.zeros((8, 8))})
    with pytest.raises(UsageError, match="outside the grid"):
        write_tile(path, grid, 2, 0, {"elevation": np.zeros((8, 8))})
    with pytest.raises(StoreError, match="no array 'slope'"):
        write_tile(path, grid, 0, 0, {"slope": np.zeros((8, 8))})


def test_a_tile_is_marked_written_with_its_layers_and_never_without(tmp_path, grid):
    from pipeline.store.zarr_store import tiles_done

    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation", "face_kind"))
    values = np.arange(64, dtype=np.float32).reshape(8, 8)
    write_tile(path, grid, 0, 0, {"elevation": values}, mark_done=True)
    write_tile(path, grid, 1, 1, {"elevation": values})  # written, not marked
    with pytest.raises(UsageError, match="cannot store float64 values as int8"):  # refused: nothing written
        write_tile(path, grid, 1, 0, {"elevation": values, "face_kind": np.zeros((8, 8))}, mark_done=True)
    done = tiles_done(path)
    assert done[0, 0] and done.sum() == 1
    with open_dem(path) as ds:
        assert_array_equal(ds.elevation.values[::-1][:8, :8], values)


# --------------------------------------------------------------------------
# Errors on creation
# --------------------------------------------------------------------------


def test_existing_path_that_is_not_a_store_is_refused(tmp_path, grid):
    path = tmp_path / "report.txt"
    path.write_text("keep me")
    with pytest.raises(StoreError, match="report.txt: exists and is not a Zarr store") as info:
        create_store(path, grid, CRS_WKT, attrs={}, overwrite=True)
    assert isinstance(info.value, OSError)
    assert path.read_text() == "keep me"
    folder = tmp_path / "folder"
    folder.mkdir()
    (folder / "data.bin").write_bytes(b"\0")
    with pytest.raises(StoreError, match="exists and is not a Zarr store"):
        create_store(folder, grid, CRS_WKT, attrs={}, overwrite=True)
    assert (folder / "data.bin").exists()


@FORMATS
def test_existing_store_needs_overwrite(tmp_path, grid, zarr_format):
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format)
    with pytest.raises(StoreError, match="overwrite=True"):
        create_store(path, grid, CRS_WKT, attrs={}, zarr_format=zarr_format)
    create_store(path, grid, CRS_WKT, attrs={"second": True}, zarr_format=5 - zarr_format, overwrite=True)
    ds = open_dem(path)
    assert ds.attrs["second"] is True and "software" not in ds.attrs
    assert list(ds.data_vars) == ["elevation"]


def test_a_replaced_store_is_deleted_beside_the_new_one(tmp_path, grid):
    from pipeline.store.zarr_store import finish_removals

    path = new_store(tmp_path / "dem.zarr", grid, 3)
    (path / "elevation" / "c").mkdir(parents=True, exist_ok=True)
    (path / "elevation" / "c" / "0").write_bytes(b"a chunk of the old store")
    stopped = tmp_path / ".dem.zarr.replaced-left"  # left by a process stopped while deleting
    stopped.mkdir()
    (stopped / "zarr.json").write_text("{}")
    create_store(path, grid, CRS_WKT, attrs={"second": True}, overwrite=True)
    finish_removals()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.zarr"]
    assert not (path / "elevation" / "c" / "0").exists()
    assert open_dem(path).attrs["second"] is True


def test_overwrite_deletes_only_a_store_of_zarrs_files(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3)
    (path / "notes.csv").write_text("keep me")  # a user's file beside the store's
    with pytest.raises(StoreError, match=r"dem.zarr: holds files that are not Zarr's \(notes.csv\)"):
        create_store(path, grid, CRS_WKT, attrs={}, overwrite=True)
    assert (path / "notes.csv").read_text() == "keep me" and (path / "elevation").is_dir()
    (path / "notes.csv").unlink()
    (path / "figures").mkdir()  # a user's folder too
    with pytest.raises(StoreError, match=r"holds files that are not Zarr's \(figures\)"):
        create_store(path, grid, CRS_WKT, attrs={}, overwrite=True)
    (path / "figures").rmdir()
    link = tmp_path / "link.zarr"
    link.symlink_to(path)
    with pytest.raises(StoreError, match="link.zarr: is a symbolic link"):
        create_store(link, grid, CRS_WKT, attrs={}, overwrite=True)
    create_store(path, grid, CRS_WKT, attrs={"second": True}, overwrite=True)
    assert open_dem(link).attrs["second"] is True


def test_create_store_checks_its_arguments(tmp_path, grid):
    with pytest.raises(UsageError, match="JSON-serialisable"):
        create_store(tmp_path / "a.zarr", grid, CRS_WKT, attrs={"when": object()})
    with pytest.raises(UsageError, match="unknown layer 'height'"):
        create_store(tmp_path / "a.zarr", grid, CRS_WKT, layers=("height",), attrs={})
    assert not (tmp_path / "a.zarr").exists()


# --------------------------------------------------------------------------
# The mesh
# --------------------------------------------------------------------------

# Two tiles: tile 0 owns nodes 0-4 (a quad and a triangle), tile 1 owns nodes
# 5-6 and its faces use nodes 2 and 4 of tile 0.
NODE_X = np.array([0.0, 1.0, 2.0, 0.0, 1.5, 3.0, 3.0]) + 700_000.0
NODE_Y = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 1.0]) + 6_600_000.0
NODE_Z = np.array([10.0, 11.0, 12.0, 13.0, 14.0, 15.0, 16.0])
FACES = np.array([[0, 1, 4, 3], [1, 2, 4, -1], [2, 5, 6, 4], [4, 6, 3, -1]])
NODE_OFFSETS = [0, 5, 7]
FACE_OFFSETS = [0, 2, 4]


def write_two_piece_mesh(path: Path) -> None:
    with MeshWriter(path, n_nodes=7, n_faces=4) as mesh:
        for t in (1, 0):  # any order
            n0, n1 = NODE_OFFSETS[t : t + 2]
            f0, f1 = FACE_OFFSETS[t : t + 2]
            mesh.write_nodes(n0, NODE_X[n0:n1], NODE_Y[n0:n1], NODE_Z[n0:n1])
            mesh.write_faces(f0, FACES[f0:f1])
        mesh.set_tiles([0, 0], [0, 1], NODE_OFFSETS, FACE_OFFSETS)


@FORMATS
def test_mesh_opens_with_xugrid(tmp_path, grid, zarr_format):
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format, layers=("elevation",))
    write_two_piece_mesh(path)
    uds = xugrid.UgridDataset(xr.open_zarr(path, group="mesh"))
    mesh = uds.ugrid.grid
    assert (mesh.n_node, mesh.n_face) == (7, 4)
    assert_array_equal(mesh.face_node_connectivity, FACES)
    assert mesh.fill_value == -1
    assert_allclose(mesh.node_x, NODE_X)
    assert_allclose(mesh.node_y, NODE_Y)
    assert mesh.crs == CRS.from_epsg(2154)
    z = uds["node_z"]
    assert z.dims == (mesh.node_dimension,)
    assert_allclose(z.values, NODE_Z)
    assert z.ugrid.grid is mesh
    assert float(z.mean()) == pytest.approx(NODE_Z.mean())
    assert_array_equal(uds["tile_node_offset"].values, NODE_OFFSETS)


@FORMATS
def test_read_mesh_and_tile_mesh(tmp_path, grid, zarr_format):
    path = new_store(tmp_path / "dem.zarr", grid, zarr_format, layers=("elevation",))
    write_two_piece_mesh(path)
    xy, z, faces = read_mesh(path)
    assert_allclose(xy, np.column_stack([NODE_X, NODE_Y]))
    assert_allclose(z, NODE_Z)
    assert_array_equal(faces, FACES)

    for tile in (1, (0, 1)):
        xy, z, faces = read_tile_mesh(path, tile)
        ids = np.array([2, 3, 4, 5, 6])  # owned 5, 6 plus 2, 3, 4 of tile 0
        assert_allclose(xy, np.column_stack([NODE_X[ids], NODE_Y[ids]]))
        assert_allclose(z, NODE_Z[ids])
        assert_array_equal(np.where(faces >= 0, ids[faces], -1), FACES[2:])
    xy, z, faces = read_tile_mesh(path, 0)
    assert_array_equal(faces, FACES[:2])
    assert_allclose(z, NODE_Z[:5])


def test_mesh_writer_refuses_an_incomplete_mesh(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation",))
    mesh = MeshWriter(path, n_nodes=7, n_faces=4)
    mesh.write_nodes(0, NODE_X[:5], NODE_Y[:5], NODE_Z[:5])
    mesh.write_faces(0, FACES)
    with pytest.raises(UsageError, match="outside"):
        mesh.write_nodes(5, NODE_X, NODE_Y, NODE_Z)
    with pytest.raises(UsageError, match="-1 only in the 4th column"):
        mesh.write_faces(0, [[0, -1, 2, 3]])
    with pytest.raises(UsageError, match="non-decreasing offsets from 0 to 7"):
        mesh.set_tiles([0, 0], [0, 1], [0, 5, 6], FACE_OFFSETS)
    mesh.set_tiles([0, 0], [0, 1], NODE_OFFSETS, FACE_OFFSETS)
    with pytest.raises(StoreError, match=r"mesh nodes \[5, 7\) were never written"):
        mesh.close()


def test_attached_writers_fill_slices_the_creating_writer_records(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation",))
    mesh = MeshWriter(path, n_nodes=7, n_faces=4)
    MeshWriter.attach(path).write_nodes(0, NODE_X[:5], NODE_Y[:5], NODE_Z[:5])
    MeshWriter.attach(path).write_nodes(5, NODE_X[5:], NODE_Y[5:], NODE_Z[5:])
    MeshWriter.attach(path).write_faces(0, FACES)
    mesh.set_tiles([0, 0], [0, 1], NODE_OFFSETS, FACE_OFFSETS)
    mesh.record("nodes", 0, 5)
    mesh.record("faces", 0, 4)
    with pytest.raises(StoreError, match=r"mesh nodes \[5, 7\) were never written"):
        mesh.close()  # the writer trusts only what it was told
    mesh.record("nodes", 5, 7)
    mesh.close()
    xy, z, faces = read_mesh(path)
    assert_allclose(z, NODE_Z)
    assert_array_equal(faces, FACES)
    assert faces.dtype == np.int32


def test_finalize_updates_attrs_appends_history_and_consolidates(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation",))
    write_two_piece_mesh(path)
    finalize_store(path, {"report": {"tiles": 6}}, history={"run": 1})
    finalize_store(path, {"software": "test 2"}, history={"run": 2})
    attrs = open_dem(path).attrs
    assert attrs["report"] == {"tiles": 6} and attrs["software"] == "test 2"
    assert attrs["run_history"] == [{"run": 1}, {"run": 2}]
    metadata = json.loads((path / "zarr.json").read_text())["consolidated_metadata"]["metadata"]
    assert {"elevation", "mesh", "mesh/face_nodes"} <= set(metadata)
    assert json.loads((path / "zarr.json").read_text())["attributes"]["run_history"][-1] == {"run": 2}


def test_finalize_removes_writes_a_killed_process_left_unfinished(tmp_path, grid):
    path = new_store(tmp_path / "dem.zarr", grid, 3, layers=("elevation",))
    chunk = next(p for p in (path / "x").rglob("*") if p.is_file() and p.name != "zarr.json")
    # what zarr's local store leaves when killed between writing and renaming
    stray = [path / f"zarr.{'a1' * 16}.partial", chunk.with_name(f"{chunk.name}.{'0f' * 16}.partial")]
    for p in stray:
        p.write_bytes(b"half")
    kept = path / "elevation" / "notes.partial"  # not zarr's pattern: not ours to delete
    kept.write_bytes(b"x")
    finalize_store(path, {"complete": True})
    assert not any(p.exists() for p in stray)
    assert kept.exists()
    assert open_dem(path).attrs["complete"] is True


def _grow_and_check(where: str, zarr_format: int) -> None:
    """A store of 2 x 3 tiles grown by a tile row north and a column east
    (and 4 more cells in the old east column): every tile written reads back
    where it was, the new cells are no data, and the coordinates and
    GeoTransform follow.  Shared with the object-storage run below."""
    from pipeline.store.zarr_store import grow_store, tiles_done, mark_tile_done

    before = TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=20, ny=16, tile_cells=8)
    after = TileGrid(x0=700_000.0, y0=6_600_000.0, resolution=2.0, nx=28, ny=24, tile_cells=8)
    create_store(where, before, CRS_WKT, layers=("elevation", "face_kind"), attrs={"run": 1}, zarr_format=zarr_format)
    written = {}
    for r in range(before.n_rows):
        for c in range(before.n_cols):
            width = min(8, before.nx - 8 * c)
            values = np.full((8, width), 100.0 * r + c, dtype=np.float32)
            write_tile(where, before, r, c, {"elevation": values, "face_kind": np.full((8, width), r + 1, np.int8)})
            mark_tile_done(where, r, c)
            written[(r, c)] = values
    grow_store(where, before, after)
    with open_dem(where) as ds:
        assert ds.elevation.shape == (24, 28)
        assert_array_equal(ds.x.values, after.x)
        assert_array_equal(ds.y.values, after.y)
        assert ds.spatial_ref.attrs["GeoTransform"] == " ".join(repr(v) for v in after.geotransform)
        south_up = ds.elevation.values[::-1]
        for (r, c), values in written.items():
            cells = south_up[8 * r:8 * r + 8, 8 * c:8 * c + values.shape[1]]
            assert_array_equal(cells, values)
        assert np.isnan(south_up[16:]).all()  # the new tile row
        assert np.isnan(south_up[:, 20:]).all()  # the new columns, and the old east column's new cells
        kind = ds.face_kind.values[::-1]
        assert (kind[:16, :20] == np.repeat([1, 2], 8)[:, None]).all()
    done = tiles_done(where)
    assert done.shape == (3, 4) and done[:2, :3].all() and not done[2:].any() and not done[:, 3:].any()


@FORMATS
def test_a_store_grows_north_and_east_keeping_its_chunk_files(tmp_path, zarr_format):
    path = tmp_path / "grow.zarr"
    _grow_and_check(str(path), zarr_format)
    files = sorted(p for p in (path / "elevation").rglob("*") if p.is_file() and not p.name.startswith((".z", "zarr")))
    assert len(files) == 6  # the six chunks written, renamed; no new chunk was written for no data


def test_a_grown_grid_must_keep_its_origin(tmp_path, grid):
    from pipeline.store.zarr_store import grow_store

    create_store(tmp_path / "s.zarr", grid, CRS_WKT, attrs={})
    moved = TileGrid(x0=grid.x0 - 16.0, y0=grid.y0, resolution=2.0, nx=28, ny=16, tile_cells=8)
    with pytest.raises(UsageError, match="does not extend"):
        grow_store(tmp_path / "s.zarr", grid, moved)


def test_a_store_on_object_storage_grows_by_renaming_its_objects(server):
    """The same growth on a real S3 server (in a process of its own: s3fs in
    this one would outlive the module's server)."""
    import subprocess
    import sys

    server.filesystem().mkdir("grow")
    code = "from tests.pipeline.test_store import _grow_and_check; _grow_and_check('s3://grow/dem.zarr', 3)"
    done = subprocess.run([sys.executable, "-c", code], env=server.env(), capture_output=True, text=True,
                          cwd=Path(__file__).parents[2])
    assert done.returncode == 0, done.stderr[-3000:]
