"""Products (dsm, chm, intensity, density, ground_density) on scenes with known
answers, the return filters, tiled against untiled runs, export and STAC per
layer, the Python API, odd but valid inputs, and the shared samples."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
import xarray as xr
from pyproj import CRS

from pipeline.api import open_store
from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.products import PRODUCTS, ProductSettings, Returns, Selection, product
from pipeline.products.dsm import dsm_faces
from pipeline.runs.runner import run

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
NEW = ("dsm", "chm", "intensity", "density", "ground_density")
X0, Y0 = 651000.0, 6861000.0
GROUND, ROOF, TREE_HEIGHT = 100.0, 112.0, 17.5
ROOF_BOX = (10.0, 10.0, 25.0, 25.0)
TREE = (40.0, 40.0, 6.0)  # centre x, y, crown radius
I_GROUND, I_ROOF, I_CROWN, I_UNDER = 300, 1000, 500, 50


def _lattice(rng, size: float = 60.0):
    """Points at (0.25, 0.75) + k / 2 jittered by at most 0.2: four in every 1 m cell."""
    g = np.arange(0.25, size, 0.5)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    return x + rng.uniform(-0.2, 0.2, x.size), y + rng.uniform(-0.2, 0.2, y.size)


def _scene(rng) -> dict[str, np.ndarray]:
    """Flat ground at 100 m; a flat roof at 112 m over a box (no ground under
    it); a tree of 17.5 m whose flat crown is each pulse's first return and
    the ground its second; noise and withheld points far above all of it."""
    x, y = _lattice(rng)
    roof = (x >= ROOF_BOX[0]) & (x <= ROOF_BOX[2]) & (y >= ROOF_BOX[1]) & (y <= ROOF_BOX[3])
    crown = (x - TREE[0]) ** 2 + (y - TREE[1]) ** 2 <= TREE[2] ** 2
    open_ground = ~roof & ~crown
    parts = [
        # x, y, z, class, return number, number of returns, intensity, withheld
        (x[open_ground], y[open_ground], GROUND, 2, 1, 1, I_GROUND, False),
        (x[roof], y[roof], ROOF, 6, 1, 1, I_ROOF, False),
        (x[crown], y[crown], GROUND + TREE_HEIGHT, 5, 1, 2, I_CROWN, False),
        (x[crown], y[crown], GROUND, 2, 2, 2, I_UNDER, False),
    ]
    high = rng.uniform(5, 55, (40, 2))
    parts.append((high[:20, 0], high[:20, 1], 300.0, 7, 1, 1, 9999, False))  # noise: no product sees it
    parts.append((high[20:, 0], high[20:, 1], 250.0, 1, 1, 1, 9999, True))  # withheld
    out: dict[str, list] = {k: [] for k in ("x", "y", "z", "cls", "rn", "nr", "intensity", "withheld")}
    for px, py, z, c, rn, nr, i, w in parts:
        n = px.size
        for key, value in zip(out, (px, py, np.full(n, z), np.full(n, c), np.full(n, rn), np.full(n, nr),
                                    np.full(n, i), np.full(n, w))):
            out[key].append(value)
    return {k: np.concatenate(v) for k, v in out.items()}


def _write(path: Path, pts: dict[str, np.ndarray], point_format: int = 6) -> Path:
    header = laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([X0, Y0, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts["x"] + X0, pts["y"] + Y0, pts["z"]
    las.classification = pts["cls"].astype(np.uint8)
    las.return_number = pts["rn"].astype(np.uint8)
    las.number_of_returns = pts["nr"].astype(np.uint8)
    las.intensity = pts["intensity"].astype(np.uint16)
    las.withheld = pts["withheld"].astype(bool)
    las.write(path)
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene")
    pts = _scene(np.random.default_rng(41))
    return _write(folder / "scene.las", pts), pts


def _run(inputs, out: Path, **kw):
    config = RunConfig(inputs=tuple(str(i) for i in inputs), output=str(out), workers=2,
                       **({"layers": NEW, "resolution": 1.0} | kw))
    return run(config, progress=False)


@pytest.fixture(scope="module")
def stores(scene, tmp_path_factory):
    """The scene tiled (16 m tiles) and in one tile."""
    folder = tmp_path_factory.mktemp("stores")
    path, _ = scene
    reports = {}
    for name, tile in (("tiled", 16.0), ("whole", 64.0)):
        reports[name] = _run([path], folder / f"{name}.zarr", tile_size=tile)
    return folder / "tiled.zarr", folder / "whole.zarr", reports


def _cells(store: Path):
    with xr.open_zarr(store) as ds:
        return ds.load()


def _interior(ds, box, inset: float) -> np.ndarray:
    """Cells whose centre lies at least ``inset`` inside ``box`` (scene coordinates)."""
    x = ds["x"].values[None, :] - X0
    y = ds["y"].values[:, None] - Y0
    return (x >= box[0] + inset) & (x <= box[2] - inset) & (y >= box[1] + inset) & (y <= box[3] - inset)


def _in_crown(ds, inset: float) -> np.ndarray:
    x = ds["x"].values[None, :] - X0
    y = ds["y"].values[:, None] - Y0
    return (x - TREE[0]) ** 2 + (y - TREE[1]) ** 2 <= (TREE[2] - inset) ** 2


def _open_ground(ds) -> np.ndarray:
    return ~_interior(ds, ROOF_BOX, -2.0) & ~_in_crown(ds, -2.0) & _interior(ds, (0, 0, 60, 60), 2.0)


def test_a_flat_roof_gives_its_height_and_a_tree_its_height_above_ground(stores):
    ds = _cells(stores[0])
    roof = _interior(ds, ROOF_BOX, 1.0)
    crown = _in_crown(ds, 1.0)
    ground = _open_ground(ds)
    assert roof.sum() > 100 and crown.sum() > 50 and ground.sum() > 1000
    dsm, chm, dtm = ds["dsm"].values, ds["chm"].values, ds["elevation"].values
    assert np.all(dsm[roof] == np.float32(ROOF))  # noise and withheld points above it left out
    assert np.all(dsm[crown] == np.float32(GROUND + TREE_HEIGHT))
    assert np.allclose(dtm[roof | crown | ground], GROUND, atol=1e-4)  # the ground interpolated under the roof
    assert np.allclose(chm[crown], TREE_HEIGHT, atol=1e-4)
    assert np.allclose(chm[roof], ROOF - GROUND, atol=1e-4)
    assert np.allclose(chm[ground], 0.0, atol=1e-4)
    assert np.array_equal(chm, dsm - dtm, equal_nan=True)


def test_intensity_is_the_mean_of_the_first_returns(stores):
    ds = _cells(stores[0])
    intensity = ds["intensity"].values
    assert np.all(intensity[_interior(ds, ROOF_BOX, 1.0)] == I_ROOF)
    assert np.all(intensity[_in_crown(ds, 1.0)] == I_CROWN)  # the ground under it is a second return
    assert np.all(intensity[_open_ground(ds)] == I_GROUND)


def test_densities_count_the_points_of_each_cell(stores, scene):
    _, pts = scene
    ds = _cells(stores[0])
    x, y = ds["x"].values, ds["y"].values
    edges_x = np.append(x - 0.5, x[-1] + 0.5)
    edges_y = np.append(y[::-1] - 0.5, y[0] + 0.5)

    def histogram(keep):
        counts, _, _ = np.histogram2d(pts["y"][keep] + Y0, pts["x"][keep] + X0, bins=(edges_y, edges_x))
        return counts[::-1]  # north-up

    returns = (pts["cls"] != 7) & ~pts["withheld"]
    assert np.array_equal(ds["density"].values, histogram(returns).astype(np.float32))
    assert np.array_equal(ds["ground_density"].values, histogram(pts["cls"] == 2).astype(np.float32))
    # the lattice puts four points in every cell: eight under the crown (crown and ground)
    assert np.all(ds["density"].values[_open_ground(ds)] == 4.0)
    assert np.all(ds["density"].values[_in_crown(ds, 1.0)] == 8.0)
    assert np.all(ds["ground_density"].values[_interior(ds, ROOF_BOX, 1.0)] == 0.0)
    assert np.all(ds["ground_density"].values[_in_crown(ds, 1.0)] == 4.0)


def test_every_layer_is_the_same_tiled_and_untiled(stores):
    tiled, whole, _ = stores
    with xr.open_zarr(tiled) as a, xr.open_zarr(whole) as b:
        assert a.attrs["provenance"]["grid"]["tile_cells"] != b.attrs["provenance"]["grid"]["tile_cells"]
        for layer in ("elevation", *NEW):
            x, y = a[layer].values, b[layer].values
            assert np.array_equal(x, y, equal_nan=True), layer
            assert np.isfinite(x).any(), layer


def test_every_point_read_is_kept_or_counted_with_its_reason(stores, scene):
    _, pts = scene
    for report in stores[2].values():
        assert report.points_read == pts["x"].size
        assert report.filtered_withheld == int(pts["withheld"].sum())
        assert report.products_only == int(((pts["cls"] != 2) & (pts["cls"] != 7) & ~pts["withheld"]).sum())
        assert report.points_read == (report.points_kept + report.filtered_class + report.filtered_withheld
                                      + report.outside_bbox + report.filtered_returns + report.products_only)


@pytest.mark.parametrize("returns", ["first", "last", "single"])
def test_return_filters_choose_the_dtm_points(scene, tmp_path, returns):
    path, pts = scene
    ground = (pts["cls"] == 2) & ~pts["withheld"]
    keep = {"first": pts["rn"] <= 1, "last": pts["rn"] >= pts["nr"], "single": pts["nr"] <= 1}[returns]
    report = _run([path], tmp_path / "dtm.zarr", layers=("point_count",), returns=returns)
    assert report.points_kept == int((ground & keep).sum())
    assert report.filtered_returns == int((ground & ~keep).sum())
    with xr.open_zarr(tmp_path / "dtm.zarr") as ds:
        assert int(ds["point_count"].values.sum()) == report.points_kept
        assert ds.attrs["provenance"]["parameters"]["returns"] == returns
    # with products the DTM's filter holds, and the points it leaves out still reach the products
    both = _run([path], tmp_path / "both.zarr", layers=("point_count", "density"), returns=returns)
    assert both.points_kept == report.points_kept
    assert both.filtered_returns == 0
    with xr.open_zarr(tmp_path / "both.zarr") as ds:
        assert int(ds["point_count"].values.sum()) == report.points_kept
        assert ds["density"].values.sum() == ((pts["cls"] != 7) & ~pts["withheld"]).sum()


def test_the_intensity_of_a_laz_file_of_point_format_6_is_each_points_own(scene, tmp_path):
    """LAS 1.4 LAZ keeps intensity in a layer of its own: a reader that leaves
    it compressed gets every point of a chunk the first one's intensity."""
    _, pts = scene
    varied = dict(pts, intensity=np.random.default_rng(7).integers(0, 65536, pts["x"].size))
    path = _write(tmp_path / "varied.laz", varied)
    _run([path], tmp_path / "varied.zarr", layers=("intensity",), tile_size=32.0)
    ds = _cells(tmp_path / "varied.zarr")
    first = (varied["rn"] <= 1) & (varied["cls"] != 7) & ~varied["withheld"]
    # a point's cell: the lattice keeps its points 0.05 m from every cell edge
    col, row = np.floor(varied["x"][first]).astype(int), np.floor(varied["y"][first]).astype(int)
    counts, sums = np.zeros((60, 60), np.int64), np.zeros((60, 60), np.int64)
    np.add.at(counts, (row, col), 1)
    np.add.at(sums, (row, col), varied["intensity"][first])
    with np.errstate(invalid="ignore"):
        expected = (sums / counts).astype(np.float32)
    cols = np.floor(ds["x"].values - X0).astype(int)
    rows = np.floor(ds["y"].values - Y0).astype(int)
    assert cols.min() >= 0 and rows.min() >= 0 and cols.max() < 60 and rows.max() < 60
    assert np.array_equal(ds["intensity"].values, expected[rows[:, None], cols[None, :]], equal_nan=True)
    assert np.count_nonzero(counts) > 3000


def test_a_file_of_first_returns_without_intensity_is_valid_input(scene, tmp_path):
    _, pts = scene
    plain = {k: v.copy() for k, v in pts.items()}
    plain["rn"][:] = 0  # some writers leave return numbers at 0: first returns
    plain["nr"][:] = 0
    plain["intensity"][:] = 0
    path = _write(tmp_path / "plain.las", plain, point_format=0)  # LAS 1.2, format 0
    assert main(["run", str(path), "-o", str(tmp_path / "plain.zarr"), "--resolution", "1", "--layers",
                 ",".join(NEW), "-q", "--no-progress"]) == 0
    ds = _cells(tmp_path / "plain.zarr")
    seen = ds["density"].values > 0
    assert np.all(ds["intensity"].values[seen] == 0.0)
    # every return is a first return now: the crown and the ground under it share x and y, the highest kept
    assert np.all(ds["dsm"].values[_in_crown(ds, 1.0)] == np.float32(GROUND + TREE_HEIGHT))


def test_export_and_stac_for_every_layer(stores, tmp_path):
    rasterio = pytest.importorskip("rasterio")
    store = stores[0]
    assert main(["export", str(store), "-o", str(tmp_path / "dem.tif")]) == 0
    ds = _cells(store)
    item = json.loads(store.with_name("tiled.stac.json").read_text())
    for layer in ("elevation", *NEW):
        spec = product(layer)
        path = tmp_path / ("dem.tif" if layer == "elevation" else f"dem_{layer}.tif")
        with rasterio.open(path) as src:
            assert src.descriptions[0] == layer and src.dtypes[0] == spec.export_dtype
            values = src.read(1)
            if spec.nodata is None:
                assert src.nodata is None
            else:
                assert np.isnan(src.nodata) and np.isnan(spec.nodata)
        assert np.array_equal(values, ds[layer].values, equal_nan=True), layer
        asset = item["assets"][layer]
        band = asset["raster:bands"][0]
        assert band["data_type"] == spec.export_dtype
        assert asset["description"] == spec.description
        assert ("nodata" in band) == (spec.nodata is not None)
    bands = item["assets"]["zarr"]["terrain:layers"]
    assert set(bands) == {"elevation", *NEW}
    assert bands["dsm"].get("unit") == bands["elevation"].get("unit") and bands["density"]["unit"] == "metre-2"


def test_the_python_api_sees_the_layers(stores):
    tiles = open_store(stores[0])
    assert tiles.layers() == ["elevation", *NEW]
    window = tiles.dem_window(X0 + 12, Y0 + 12, X0 + 20, Y0 + 20, layers=["chm"])
    assert list(window.data_vars) == ["chm"] and np.allclose(window["chm"].values, ROOF - GROUND, atol=1e-4)
    tallest = tiles.map_tiles(lambda tile, mesh, z, dem: float(dem["chm"].max()), layers=["chm"])
    assert len(tallest) == len(tiles.tiles()) and max(tallest) == pytest.approx(TREE_HEIGHT, abs=1e-4)
    from pipeline.errors import UsageError

    with pytest.raises(UsageError, match="holds no layer 'slope'"):
        tiles.dem_window(X0, Y0, X0 + 5, Y0 + 5, layers=["slope"])


def test_the_preview_draws_the_chm_beside_the_hillshade(stores, tmp_path):
    from matplotlib.image import imread

    assert main(["preview", str(stores[0]), "-o", str(tmp_path / "p.png")]) == 0
    picture = imread(tmp_path / "p.png")
    assert picture.shape[1] > 1.6 * picture.shape[0]  # two panels side by side


def test_a_buffer_smaller_than_the_dsms_margin_gives_the_same_layers(scene, tmp_path):
    # tiles of 16 m with a 2 m buffer, a DSM of edges up to 3 m: its points are spilled with their own margin
    path, _ = scene
    report = _run([path], tmp_path / "small.zarr", tile_size=16.0, buffer=2.0, dsm_max_edge=3.0)
    reference = _run([path], tmp_path / "big.zarr", tile_size=64.0, buffer=8.0, dsm_max_edge=3.0)
    assert report.tiles > reference.tiles == 1
    with xr.open_zarr(tmp_path / "small.zarr") as a, xr.open_zarr(tmp_path / "big.zarr") as b:
        for layer in ("elevation", *NEW):
            assert np.array_equal(a[layer].values, b[layer].values, equal_nan=True), layer
        assert np.isfinite(a["dsm"].values).any()


def test_the_dsms_highest_returns_in_cells_wider_than_its_maximum_edge_are_joined_the_same_in_every_tile(tmp_path):
    # a rough canopy of first returns over ground, in cells of 3 m with a DSM edge of 2 m: the returns kept are
    # those of cells of 0.5 m, close enough to be joined, and a tile holds the whole cell of each
    rng = np.random.default_rng(7)
    x, y = _lattice(rng, 48.0)
    n = x.size
    canopy = np.round(GROUND + 8.0 + 3.0 * np.sin(x / 3.0) * np.cos(y / 4.0) + rng.uniform(0, 2.0, n), 2)
    first = rng.random(n) < 0.6
    pts = {"x": x, "y": y, "z": np.where(first, canopy, GROUND), "cls": np.where(first, 5, 2),
           "rn": np.where(first, 1, 2), "nr": np.full(n, 2), "intensity": np.full(n, 100), "withheld": np.zeros(n, bool)}
    path = _write(tmp_path / "canopy.las", pts)
    common = dict(layers=("dsm",), resolution=3.0, dsm_max_edge=2.0, buffer=0.5)
    tiled = _run([path], tmp_path / "tiled.zarr", tile_size=9.0, **common)
    _run([path], tmp_path / "whole.zarr", tile_size=60.0, **common)
    assert tiled.tiles > 1
    with xr.open_zarr(tmp_path / "tiled.zarr") as a, xr.open_zarr(tmp_path / "whole.zarr") as b:
        dsm = b["dsm"].values
        assert np.array_equal(a["dsm"].values, dsm, equal_nan=True)
        # the canopy's top, drawn between its highest returns, not the ground of voids
        inner = dsm[1:-1, 1:-1]
        assert inner.min() > GROUND + 5.0 and inner.max() <= canopy.max() + 1e-3


def test_the_dsm_keeps_the_crowns_top_where_a_first_return_went_through_a_gap_in_every_cell(tmp_path):
    # a closed canopy at 117.5 m over ground at 100 m, four first returns a cell: one of each cell's four went
    # through a gap to the ground.  The highest return of each cell is the crown's: no pit at any cell centre
    rng = np.random.default_rng(11)
    x, y = _lattice(rng, 30.0)
    n = x.size
    gap = (np.floor(2 * x) + 2 * np.floor(2 * y)) % 4 == 0  # one lattice point in each 1 m cell
    pts = {"x": x, "y": y, "z": np.where(gap, GROUND, GROUND + TREE_HEIGHT), "cls": np.where(gap, 2, 5),
           "rn": np.ones(n, int), "nr": np.ones(n, int), "intensity": np.full(n, 100), "withheld": np.zeros(n, bool)}
    path = _write(tmp_path / "canopy.las", pts)
    # an edge of 4 m: the returns kept are those of the grid's cells of 1 m (a quarter of the edge)
    _run([path], tmp_path / "canopy.zarr", layers=("dsm", "chm"), tile_size=12.0, dsm_max_edge=4.0)
    with xr.open_zarr(tmp_path / "canopy.zarr") as ds:
        dsm, chm = ds["dsm"].values[1:-1, 1:-1], ds["chm"].values[1:-1, 1:-1]
    assert np.all(dsm == np.float32(GROUND + TREE_HEIGHT))
    assert np.allclose(chm, TREE_HEIGHT)


def test_the_dsm_draws_no_triangle_beyond_its_maximum_edge_or_circumradius():
    # a sliver: every edge under 2, but its circumcircle about 25 across
    vertices = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 0.04], [1.0, 1.5]])
    triangles = np.array([[0, 1, 2], [0, 2, 3], [2, 1, 3]])
    kept = dsm_faces(vertices, triangles, 2.0)
    assert kept.shape == (2, 4) and (kept[:, 3] == -1).all()
    assert {tuple(sorted(f[:3])) for f in kept.tolist()} == {(0, 2, 3), (1, 2, 3)}
    # each kept triangle starts at its smallest corner, whatever corner it was given first
    rotated = dsm_faces(vertices, np.roll(triangles, 1, axis=1), 2.0)
    assert np.array_equal(rotated, kept)
    assert dsm_faces(vertices, triangles, 1.0).shape == (0, 4)


def test_points_carry_only_the_attributes_the_products_need():
    dtm_only = ProductSettings.for_run(("elevation", "slope"), (2,), "all")
    assert dtm_only.reads is None and dtm_only.reading() == (Selection(frozenset({2})), ())
    dsm = ProductSettings.for_run(("elevation", "dsm"), (2,), "all", 3.0)
    assert dsm.columns == () and dsm.reads.returns is Returns.FIRST
    # the reader decodes what tells the DTM's points (class 2, every return) from the DSM's (first returns)
    assert dsm.reading()[1] == ("classification", "return_number")
    full = ProductSettings.for_run(("elevation", *NEW), (2,), "all", 3.0)
    assert full.columns == ("classification", "return_number", "intensity")
    assert full.computed == ("elevation", "dsm", "chm", "intensity", "density", "ground_density")
    chm = ProductSettings.for_run(("elevation", "chm"), (2,), "all", 3.0)
    assert chm.computed == ("elevation", "dsm", "chm") and chm.layers == ("elevation", "chm")


def test_a_product_row_keeps_every_attribute_at_the_widest_values_a_las_record_holds():
    from pipeline.products.points import as_product_rows, from_product_rows, product_row_width

    columns = ("classification", "return_number", "number_of_returns", "intensity")
    attributes = {
        "classification": np.array([0, 255, 2, 7], dtype=np.uint8),
        "return_number": np.array([0, 15, 1, 3], dtype=np.uint8),
        "number_of_returns": np.array([15, 0, 1, 5], dtype=np.uint8),
        "intensity": np.array([65535, 0, 1, 40000], dtype=np.uint16),
    }
    x, y, z = np.array([1.5, 2.5, 3.5, 4.5]), np.array([0.25, 0.5, 0.75, 1.0]), np.array([-3.0, 0.0, 1e4, 2.5])
    rows = as_product_rows(x, y, z, attributes, columns)
    assert rows.shape == (4, product_row_width(columns)) == (4, 4)
    back = from_product_rows(rows, columns)
    assert np.array_equal(back.x, x) and np.array_equal(back.y, y) and np.array_equal(back.z, z)
    for name in columns:
        assert np.array_equal(back.attributes[name], attributes[name]), name
    # a subset: only its own columns, in their own bits
    part = from_product_rows(as_product_rows(x, y, z, attributes, columns[3:]), columns[3:])
    assert list(part.attributes) == ["intensity"] and np.array_equal(part.attributes["intensity"], attributes["intensity"])
    assert product_row_width(()) == 3 and len(from_product_rows(np.column_stack([x, y, z]), ())) == 4
    with pytest.raises(ValueError, match="return_number holds 16"):
        as_product_rows(x, y, z, attributes | {"return_number": np.array([0, 16, 1, 1])}, columns)


def test_every_product_declares_what_the_store_and_export_need():
    for spec in PRODUCTS:
        assert spec.export_dtype in ("float32", "uint8", "int32")
        assert spec.resampling in ("AVERAGE", "MODE", "NEAREST")
        assert all(product(n) for n in spec.needs)
        assert spec.description and spec.long_name


@pytest.mark.skipif(not (DATA / "ign_semis_lambert93.laz").exists(), reason="shared samples absent")
def test_a_real_survey_gives_the_same_layers_at_any_tiling(tmp_path):
    path = DATA / "ign_semis_lambert93.laz"
    reports = {name: _run([path], tmp_path / f"{name}.zarr", tile_size=tile, buffer=30.0)
               for name, tile in (("tiled", 250.0), ("whole", 1200.0))}
    a, b = _cells(tmp_path / "tiled.zarr"), _cells(tmp_path / "whole.zarr")
    for layer in ("elevation", *NEW):
        assert np.array_equal(a[layer].values, b[layer].values, equal_nan=True), layer
    with laspy.open(path) as f:
        las = f.read()
    cls, withheld = np.asarray(las.classification), np.asarray(las.withheld).astype(bool)
    report = reports["tiled"]
    assert report.points_read == len(las)
    assert report.products_only == int(((cls != 2) & (cls != 7) & (cls != 18) & ~withheld).sum())
    # every return but noise counted once, in the cell that holds it
    assert int(round(float(a["density"].values.sum()))) == int(((cls != 7) & (cls != 18) & ~withheld).sum())
    chm = a["chm"].values
    assert np.nanpercentile(chm, 99) > 5.0  # trees and buildings stand out
    assert np.nanmedian(chm[a["ground_density"].values > 0]) == pytest.approx(0.0, abs=0.3)


def test_every_layer_is_the_same_at_any_tiling_with_cells_of_no_power_of_two(tmp_path):
    """At 0.7 m a tile's own corner (the grid's plus 43 cells) rounds once more
    than the grid's: centres counted from it would differ from one tiling's
    to the next by an ulp, enough to move a DSM value over a tree by one
    float32 step, or a centre across an edge of the mesh (another face's slope)."""
    from pipeline.tools.synthetic import SurveySpec, write_survey

    spec = SurveySpec(points=120_000, files=1, width=150.0, height=120.0, overlap=0.0, ground_share=0.3, lake=None,
                      buildings=3, trees=300, seed=8811)
    path = write_survey(tmp_path, spec)[0]
    layers = (*NEW, "slope", "face_kind")
    for name, tile in (("tiled", 30.1), ("whole", 200.0)):
        _run([path], tmp_path / f"{name}.zarr", tile_size=tile, resolution=0.7, layers=layers)
    with xr.open_zarr(tmp_path / "tiled.zarr") as a, xr.open_zarr(tmp_path / "whole.zarr") as b:
        assert a.attrs["provenance"]["grid"]["tile_cells"] == 43 and b.attrs["report"]["tiles"] == 1
        for layer in ("elevation", *layers):
            assert np.array_equal(a[layer].values, b[layer].values, equal_nan=True), layer
