"""The smooth surface through the pipeline: seamless tiles, one variogram per run, provenance."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
import zarr

import meshcore

from pipeline import run
from pipeline.config import RunConfig
from pipeline.errors import UsageError

from .test_seams import _run, _survey


def _elevation(path) -> xr.DataArray:
    return xr.open_zarr(path)["elevation"]


@pytest.mark.parametrize("seed,share,buffer_share", [(3, 0.1, 0.3), (5, 0.25, 0.0)])
def test_tiled_smooth_dem_is_the_untiled_one_bit_for_bit(tmp_path, seed, share, buffer_share):
    """Delaunay pieces are the whole triangulation; the kriged nodes then match too, cell for cell."""
    survey = tmp_path / "ground.las"
    xy, _ = _survey(survey, seed, 250.0, 200.0)
    tile = share * 250.0
    plain = dict(triangle_measure="delaunay", quad_measure=None, resolution=tile / 10.0, surface="smooth")
    tiled = _run(survey, tmp_path / "tiled.zarr", tile_size=tile, buffer=buffer_share * tile, **plain)
    whole = _run(survey, tmp_path / "whole.zarr", tile_size=tile * 20, **plain)
    assert tiled.tiles > 4 and whole.tiles == 1
    a, b = _elevation(tmp_path / "tiled.zarr"), _elevation(tmp_path / "whole.zarr")
    assert a.shape == b.shape and a.size > 1000  # one grid, the data's, at any tile size
    np.testing.assert_array_equal(a.x.values, b.x.values)
    np.testing.assert_array_equal(a.y.values, b.y.values)
    np.testing.assert_array_equal(a.values, b.values)
    prov = [zarr.open_group(str(tmp_path / name), mode="r").attrs["provenance"] for name in ("tiled.zarr", "whole.zarr")]
    assert prov[0]["smooth_surface"]["variogram"] == prov[1]["smooth_surface"]["variogram"]
    assert prov[0]["parameters"]["surface"] == "smooth"
    # the survey's voids and hull give faces long enough to be cut: their added points are seamless too
    variogram = meshcore.Variogram.from_dict(prov[0]["smooth_surface"]["variogram"])
    plan = meshcore.tiles.smooth_plan(meshcore.build_mesh(xy - xy.min(axis=0)), variogram)
    assert plan.refinement.ends.shape[0] > 10
    # and nodes in the voids take natural neighbours, read across the tiles' seams alike
    assert np.count_nonzero(np.diff(plan.nodes.fill.coordinates.first)) > 10


def test_a_sampled_variogram_is_the_same_at_any_tile_size_and_buffer(tmp_path, monkeypatch):
    """A survey above the all-points threshold (lowered here) fits its
    variogram from whole cells of a fixed lattice: two tilings draw the same
    sample, every point of the cells and no other, and fit the same
    variogram, bit for bit."""
    from pipeline.meshing import surface

    monkeypatch.setattr(surface, "SAMPLE_POINTS", 3000)
    survey = tmp_path / "ground.las"
    _survey(survey, 3, 250.0, 200.0)
    plain = dict(triangle_measure="delaunay", quad_measure=None, resolution=2.5, surface="smooth")
    runs = [_run(survey, tmp_path / "small.zarr", tile_size=25.0, buffer=7.5, **plain),
            _run(survey, tmp_path / "large.zarr", tile_size=100.0, buffer=0.0, **plain)]
    assert runs[0].tiles > runs[1].tiles > 1 and runs[0].points_kept > 3 * 3000
    fitted = [zarr.open_group(str(tmp_path / name), mode="r").attrs["provenance"]["smooth_surface"]
              for name in ("small.zarr", "large.zarr")]
    assert fitted[0] == fitted[1]
    drawn = fitted[0]["sample"]
    assert drawn["points"] == "whole cells" and drawn["cell_side"] % 2.5 == 0.0
    assert 3000 <= fitted[0]["sample_points"] < runs[0].vertices / 2 or len(drawn["cells"]) == surface.MAX_SAMPLE_CELLS
    # the sample is every distinct point in its cells (the mesh's nodes are the distinct points kept)
    x, y = (xr.open_zarr(tmp_path / "small.zarr", group="mesh")[name].values for name in ("node_x", "node_y"))
    side = drawn["cell_side"]
    in_cells = np.isin(np.floor(x / side) * 1e6 + np.floor(y / side), [i * 1e6 + j for i, j in drawn["cells"]])
    assert fitted[0]["sample_points"] == int(np.count_nonzero(in_cells))


def _assert_tiles_krig_from_the_whole_surveys_nearest_points(monkeypatch, run_it) -> None:
    """Every kriging system of every tile of ``run_it()`` (its nodes' and its
    added points') has the neighbours it has in the whole survey."""
    from meshcore._buckets import _nearest

    plans = []
    surface = meshcore.smooth_surface

    def spy(mesh, z, variogram=None, neighbours=meshcore.tiles.DEFAULT_NEIGHBOURS, plan=None):
        if plan is not None:
            plans.append(plan)
        return surface(mesh, z, variogram, neighbours, plan=plan)

    monkeypatch.setattr(meshcore, "smooth_surface", spy)
    report = run_it()
    assert len(plans) == report.tiles + report.tiles_meshed_again and report.tiles > 4  # a tile may mesh twice
    assert report.tile_expansions > 0  # tiles loaded points beyond their buffers
    # the survey as the tiles read it: every point is some tile's own
    pieces = [p.refinement.mesh.vertices[: p.refinement.mesh.vertices.shape[0] - p.refinement.t.shape[0]] for p in plans]
    survey_xy = np.unique(np.concatenate(pieces), axis=0)
    checked = 0
    for plan in plans:
        data = plan.refinement.mesh.vertices
        for centres, index in ((plan.nodes.centres, plan.nodes.index), (plan.added.centres, plan.added.index)):
            if centres.shape[0] == 0:
                continue
            want, _ = _nearest(survey_xy, centres, index.shape[1])
            np.testing.assert_array_equal(data[index], survey_xy[want])
            checked += centres.shape[0]
    assert checked > 1000


@pytest.mark.parametrize("seed,share,buffer_share", [(3, 0.1, 0.3), (4, 0.2, 0.05), (6, 0.08, 0.0)])
def test_every_tile_krigs_from_the_whole_surveys_nearest_points(tmp_path, monkeypatch, seed, share, buffer_share):
    """The certificate holds the kriging disks, however a tile came by their
    points (its buffer, points loaded for its faces' circles, for its disks)."""
    survey = tmp_path / "ground.las"
    _survey(survey, seed, 250.0, 200.0)
    tile = share * 250.0
    _assert_tiles_krig_from_the_whole_surveys_nearest_points(monkeypatch, lambda: _run(
        survey, tmp_path / "out.zarr", tile_size=tile, buffer=buffer_share * tile, resolution=tile / 8.0, surface="smooth"))


def test_every_tile_of_a_real_survey_krigs_from_its_nearest_points(tmp_path, monkeypatch):
    """Sparse ground under canopy: points a tile loads for its faces' circles
    that no circle holds may lie in its kriging disks (they did in three of
    these hundred tiles, which then missed them)."""
    from .test_real_data import sample

    path = sample("ign_semis_lambert93.laz")
    _assert_tiles_krig_from_the_whole_surveys_nearest_points(monkeypatch, lambda: run(RunConfig(
        inputs=(str(path),), output=str(tmp_path / "out.zarr"), resolution=1.0, tile_size=100.0, surface="smooth"),
        progress=False))


def test_smooth_run_differs_from_linear_and_its_slope_is_its_own(tmp_path):
    survey = tmp_path / "ground.las"
    _survey(survey, 4, 300.0, 120.0)
    kw = dict(resolution=2.0, tile_size=60.0, buffer=10.0, layers=("slope",))
    linear = _run(survey, tmp_path / "linear.zarr", **kw)
    smooth = _run(survey, tmp_path / "smooth.zarr", surface="smooth", **kw)
    assert smooth.tiles_uncertified == 0 and smooth.vertices == linear.vertices
    lin, smo = xr.open_zarr(tmp_path / "linear.zarr"), xr.open_zarr(tmp_path / "smooth.zarr")
    np.testing.assert_array_equal(np.isnan(lin["elevation"].values), np.isnan(smo["elevation"].values))
    diff = np.abs(lin["elevation"].values - smo["elevation"].values)
    assert np.nanmax(diff) > 0.01 and np.nanmedian(diff) < 0.5
    assert np.nanmax(np.abs(lin["slope"].values - smo["slope"].values)) > 0.1
    attrs = zarr.open_group(str(tmp_path / "smooth.zarr"), mode="r").attrs
    fitted = attrs["provenance"]["smooth_surface"]
    assert fitted["variogram"]["sill"] > 0 and fitted["sample_points"] == smooth.vertices
    # the model and the node cells' spacing are the run's, recorded for every tile
    assert fitted["model"] == fitted["variogram"]["model"] in ("exponential", "matern32", "matern52")
    assert 0.0 < fitted["variogram"]["spacing"] < 60.0
    assert "smooth_surface" not in zarr.open_group(str(tmp_path / "linear.zarr"), mode="r").attrs["provenance"]


def test_surface_is_validated():
    with pytest.raises(UsageError, match="surface='cubic' is not valid; expected one of 'linear', 'smooth'"):
        RunConfig(inputs=("a.las",), output="o.zarr", resolution=1.0, surface="cubic")
    assert RunConfig(inputs=("a.las",), output="o.zarr", resolution=1.0).surface == "linear"


def test_cli_takes_surface(tmp_path, capsys):
    from pipeline.cli import main

    survey = tmp_path / "ground.las"
    _survey(survey, 6, 180.0, 160.0)
    out = tmp_path / "s.zarr"
    args = ["run", str(survey), "-o", str(out), "--resolution", "4", "--in-crs", "EPSG:2154", "--no-progress"]
    assert main([*args, "--surface", "smooth"]) == 0
    assert zarr.open_group(str(out), mode="r").attrs["provenance"]["parameters"]["surface"] == "smooth"
    with pytest.raises(SystemExit) as exit_info:
        main([*args, "--surface", "cubic"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'cubic'" in capsys.readouterr().err


def test_smooth_store_does_not_depend_on_the_order_of_points_in_the_file(tmp_path):
    """Tiles sort their points in blocks for the smooth surface's kernels: the store is the same for any file order."""
    import laspy

    survey = tmp_path / "ground.las"
    _survey(survey, 7, 220.0, 160.0)
    las = laspy.read(survey)
    shuffled = laspy.LasData(las.header)
    perm = np.random.default_rng(1).permutation(len(las.points))
    shuffled.points = las.points[perm]
    shuffled.write(tmp_path / "shuffled.las")
    kw = dict(resolution=2.0, tile_size=60.0, buffer=8.0, surface="smooth", layers=("slope",))
    a = _run(survey, tmp_path / "a.zarr", **kw)
    b = _run(tmp_path / "shuffled.las", tmp_path / "b.zarr", **kw)
    assert a.tiles > 4 and a.vertices == b.vertices
    sa, sb = xr.open_zarr(tmp_path / "a.zarr"), xr.open_zarr(tmp_path / "b.zarr")
    for name in ("elevation", "slope"):
        np.testing.assert_array_equal(sa[name].values, sb[name].values)
    ma, mb = xr.open_zarr(tmp_path / "a.zarr", group="mesh"), xr.open_zarr(tmp_path / "b.zarr", group="mesh")
    for name in ("node_x", "node_y", "node_z", "face_nodes"):
        np.testing.assert_array_equal(ma[name].values, mb[name].values)
