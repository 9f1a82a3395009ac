"""Tests of pipeline.inputs.crs: resolving source/target CRSs and reprojecting points."""

from __future__ import annotations

import pickle
import threading
from pathlib import Path

import numpy as np
import pyproj
import pytest
from numpy.testing import assert_allclose

from pipeline.inputs import crs as crs_module
from pipeline.inputs.crs import CrsPlan, Reprojector, resolve_crs
from pipeline.errors import CrsError, UsageError
from pipeline.inputs.header import SourceInfo
from pipeline.inputs.sources import read_info

from .test_sources import LAMBERT93_ORIGIN, sample, write_las

LAMBERT93 = "EPSG:2154"


def info_for(tmp_path: Path, name: str, crs: str | None, **kwargs: object) -> SourceInfo:
    """Header info of a small synthetic file in ``crs``, by default at
    Lambert-93's origin (central France; 50 km east of UTM 31N's band), so
    that its coordinates agree with a record of either."""
    kwargs.setdefault("origin", LAMBERT93_ORIGIN)
    return read_info(write_las(tmp_path / name, crs=crs, n=20, **kwargs).path)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- resolve_crs


def test_single_crs_needs_no_reprojection(tmp_path: Path) -> None:
    a = info_for(tmp_path, "a.las", LAMBERT93, origin=(700_000.0, 6_600_000.0))
    b = info_for(tmp_path, "b.laz", LAMBERT93, point_format=6, version="1.4", origin=(700_000.0, 6_600_000.0))
    plan = resolve_crs([a, b], None, None)
    assert plan.paths == (a.path, b.path)
    assert pyproj.CRS.from_wkt(plan.target_wkt).to_epsg() == 2154
    assert plan.horizontal_unit == "metre"
    assert plan.vertical_unit is None
    assert all(plan.reprojector(p).is_identity for p in plan.paths)
    assert any("no reprojection" in note for note in plan.notes)
    assert CrsPlan.from_dict(plan.to_dict()) == plan


def test_missing_crs_without_in_crs_lists_the_files(tmp_path: Path) -> None:
    a = info_for(tmp_path, "a.las", LAMBERT93)
    b = info_for(tmp_path, "nocrs1.las", None)
    c = info_for(tmp_path, "nocrs2.las", None)
    with pytest.raises(CrsError) as exc:
        resolve_crs([a, b, c], None, None)
    message = str(exc.value)
    assert str(b.path) in message and str(c.path) in message and str(a.path) not in message
    assert "in_crs" in message and "\n" not in message


def _lambert93_without(parameter: str) -> str:
    """Lambert-93 as WKT with one of its projection's parameters cut out (a
    damaged record that pyproj still parses)."""
    wkt = pyproj.CRS.from_epsg(2154).to_wkt()
    start = wkt.index(f'PARAMETER["{parameter}"')
    return wkt[:start] + wkt[wkt.index("]]", start) + 3:]


@pytest.mark.parametrize("parameter", ["Easting at false origin", "Latitude of 1st standard parallel"])
def test_a_file_crs_short_of_a_parameter_is_unusable_and_named(tmp_path: Path, parameter) -> None:
    """pyproj parses such a record but fails with a KeyError when it is
    described for the store: the file's CRS is unusable (exit 2, named), not
    a crash part way through a run."""
    import dataclasses

    damaged = _lambert93_without(parameter)
    pyproj.CRS.from_wkt(damaged)  # parses
    good = info_for(tmp_path, "a.las", LAMBERT93)
    bad = dataclasses.replace(info_for(tmp_path, "b.las", LAMBERT93), crs_wkt=damaged)
    with pytest.raises(CrsError, match="incomplete") as exc:
        resolve_crs([good, bad], None, None)
    assert str(bad.path) in str(exc.value) and str(good.path) not in str(exc.value)
    plan = resolve_crs([good, bad], LAMBERT93, None)  # --in-crs stands in for it, with a note
    assert any(str(bad.path) in note and "incomplete" in note for note in plan.notes)
    with pytest.raises(CrsError, match="out_crs"):
        resolve_crs([good], None, damaged)


def test_in_crs_fills_missing_and_keeps_a_files_valid_crs(tmp_path: Path) -> None:
    a = info_for(tmp_path, "utm.las", "EPSG:32631")
    b = info_for(tmp_path, "nocrs.las", None)
    c = info_for(tmp_path, "l93.las", LAMBERT93)
    plan = resolve_crs([a, b, c], LAMBERT93, LAMBERT93)
    assert [pyproj.CRS.from_wkt(w).to_epsg() for w in plan.source_wkts] == [32631, 2154, 2154]
    assert [plan.reprojector(p).is_identity for p in plan.paths] == [False, True, True]
    kept = [n for n in plan.notes if "is kept" in n]
    assert len(kept) == 1 and str(a.path) in kept[0] and "UTM zone 31N" in kept[0]
    assert any(str(b.path) in n and "without a CRS" in n for n in plan.notes)
    with pytest.raises(CrsError, match="2 different CRSs"):  # the UTM file still needs --out-crs
        resolve_crs([a, b, c], LAMBERT93, None)


def test_mixed_crs_without_out_crs_groups_the_files(tmp_path: Path) -> None:
    a = info_for(tmp_path, "a.las", LAMBERT93)
    b = info_for(tmp_path, "b.las", "EPSG:32631")
    c = info_for(tmp_path, "c.las", LAMBERT93)
    with pytest.raises(CrsError) as exc:
        resolve_crs([a, b, c], None, None)
    message = str(exc.value)
    assert "2 different CRSs" in message and "out_crs" in message
    assert f"Lambert-93 (EPSG:2154): {a.path}, {c.path}" in message
    assert f"UTM zone 31N (EPSG:32631): {b.path}" in message


def test_mixed_crs_with_out_crs_reprojects_and_explains_z(tmp_path: Path) -> None:
    a = info_for(tmp_path, "a.las", LAMBERT93, origin=(700_000.0, 6_600_000.0))
    b = info_for(tmp_path, "b.las", "EPSG:32631", origin=(500_000.0, 5_000_000.0))
    plan = resolve_crs([a, b], None, "EPSG:32631")
    assert plan.reprojector(b.path).is_identity
    assert not plan.reprojector(a.path).is_identity
    z_notes = [n for n in plan.notes if "z is not transformed" in n]
    assert len(z_notes) == 1 and str(a.path) in z_notes[0] and "compound/3D" in z_notes[0]


def test_geographic_target_suggests_the_utm_zone(tmp_path: Path) -> None:
    info = info_for(tmp_path, "geo.las", "EPSG:4326", origin=(3.0, 45.0), spread=0.5)
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], None, None)
    message = str(exc.value)
    assert "geographic" in message and "out_crs='EPSG:32631' (WGS 84 / UTM zone 31N)" in message
    with pytest.raises(CrsError, match="out_crs='WGS 84 .*EPSG:32631'"):
        resolve_crs([info], None, "EPSG:4326")
    plan = resolve_crs([info], None, "EPSG:32631")
    assert plan.horizontal_unit == "metre"


def test_work_in_degrees_is_done_in_the_utm_zone(tmp_path: Path) -> None:
    """``terrain classify`` writes no grid: files in degrees are worked on in their UTM zone, not refused."""
    from pipeline.inputs.crs import working_crs

    geo = info_for(tmp_path, "geo.las", "EPSG:4326", origin=(3.0, 45.0), spread=0.5)
    assert working_crs([geo]) == ("EPSG:32631", "WGS 84 / UTM zone 31N")
    projected = info_for(tmp_path, "a.las", LAMBERT93, origin=(700_000.0, 6_600_000.0))
    assert working_crs([projected]) is None
    # what the override says, not the record
    wrong = info_for(tmp_path, "wrong.las", LAMBERT93, origin=(3.0, 45.0), spread=0.5)
    assert working_crs([wrong], override_crs="EPSG:4326") == ("EPSG:32631", "WGS 84 / UTM zone 31N")
    assert working_crs([geo], override_crs=LAMBERT93) is None


@pytest.mark.parametrize("target", ["EPSG:4978", "EPSG:5703", "EPSG:4979"])
def test_non_projected_targets_are_refused(tmp_path: Path, target: str) -> None:
    info = info_for(tmp_path, "a.las", LAMBERT93, origin=(700_000.0, 6_600_000.0))
    with pytest.raises(CrsError, match="projected CRS"):
        resolve_crs([info], None, target)


@pytest.mark.parametrize("option", ["in_crs", "out_crs"])
def test_bad_crs_strings_are_named(tmp_path: Path, option: str) -> None:
    info = info_for(tmp_path, "a.las", LAMBERT93)
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], **{option: "EPSG:99999999"})
    message = str(exc.value)
    assert message.startswith(f"{option}='EPSG:99999999'") and "\n" not in message


def test_user_crs_accepts_proj_strings_and_wkt(tmp_path: Path) -> None:
    info = info_for(tmp_path, "a.las", None)
    plan = resolve_crs([info], "+proj=utm +zone=31 +datum=WGS84 +units=m +no_defs", pyproj.CRS(LAMBERT93).to_wkt())
    assert pyproj.CRS.from_wkt(plan.target_wkt).to_epsg() == 2154
    assert not plan.reprojector(info.path).is_identity


def test_no_infos() -> None:
    with pytest.raises(UsageError):
        resolve_crs([], None, None)


def test_us_feet_target_and_compound_z_conversion(tmp_path: Path) -> None:
    info = info_for(tmp_path, "ft.las", None)
    plan = resolve_crs([info], "EPSG:2903+6360", "EPSG:32613+5703")  # NAVD88 height in ftUS -> metres
    assert plan.horizontal_unit == "metre" and plan.vertical_unit == "metre"
    assert any("z is transformed too" in n for n in plan.notes)
    _, _, z = plan.reprojector(info.path).transform(np.array([1_639_600.0]), np.array([1_454_500.0]), [7000.0])
    assert_allclose(z, [7000.0 * 1200 / 3937], rtol=1e-9)


# --------------------------------------------------------------------------- records the coordinates contradict

YELLOWSTONE = (515_368.0, 4_918_340.0)
"""UTM zone 12N metres (the lone-star survey): what PDAL's test files hold under wrong records."""


def _lonlat_in(crs: str, lon: float, lat: float) -> tuple[float, float]:
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    return float(x), float(y)


def _one_line_naming(message: str, info: SourceInfo, *words: str) -> None:
    assert "\n" not in message and message.startswith(f"{info.path}: ")
    for word in words:
        assert word in message, (word, message)


@pytest.mark.parametrize("out_crs", [None, "EPSG:32612"])
@pytest.mark.parametrize(
    ("record", "words"),
    [
        ("EPSG:4978", ("(EPSG:4978) is geocentric", "y 4,918,3", "km or more from the surface")),
        ("EPSG:4326", ("WGS 84 (EPSG:4326) is in degrees", "longitudes -180 to 180")),
    ],
)
def test_a_geocentric_or_degrees_record_on_metres_is_refused_before_any_transform(
    tmp_path: Path, record, words, out_crs
) -> None:
    info = info_for(tmp_path, "wrong.las", record, origin=YELLOWSTONE)
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], None, out_crs)
    message = str(exc.value)
    _one_line_naming(message, info, *words, "x 515,368", "give override_crs")
    assert "bbox" not in message
    assert "WGS 84 / UTM zone" not in message  # no zone guessed from coordinates that are not what the record says


@pytest.mark.parametrize(
    ("record", "place", "label"),
    [
        ("EPSG:2154", YELLOWSTONE, "Lambert-93"),  # lands 1,075 km south of France
        ("EPSG:2994", LAMBERT93_ORIGIN, "Oregon"),  # Lambert-93 metres read as Oregon feet: northern British Columbia
        ("EPSG:32612", _lonlat_in("EPSG:2154", 9.2, 42.0), "UTM zone 12N"),  # Corsica read as UTM 12N: Manitoba
    ],
)
def test_a_projected_record_of_another_continent_is_refused(tmp_path: Path, record, place, label) -> None:
    info = info_for(tmp_path, "elsewhere.las", record, origin=place)
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], None, None)
    _one_line_naming(str(exc.value), info, label, "km outside that area", "override_crs")
    plan = resolve_crs([info], override_crs="EPSG:32612" if record != "EPSG:32612" else "EPSG:2154")
    assert any(note.startswith(f"{info.path}: its CRS record ") and "is replaced by override_crs=" in note
               for note in plan.notes)


@pytest.mark.parametrize(
    ("record", "lon", "lat"),
    [
        ("EPSG:32612", -115.6, 45.0),  # UTM 12N, 1.6 degrees (126 km) west of its band
        ("EPSG:32612", -105.5, 40.0),  # 2.5 degrees (213 km) east of it
        ("EPSG:25832", 15.1, 55.1),  # Bornholm in Denmark's UTM 32N
        ("EPSG:25833", 30.5, 70.2),  # Finnmark in Norway's UTM 33N, 470 km east of its band
        ("EPSG:2154", 8.6, 41.4),  # the south of Corsica, inside
    ],
)
def test_a_right_record_a_little_outside_its_area_is_kept(tmp_path: Path, record, lon, lat) -> None:
    info = info_for(tmp_path, "edge.las", record, origin=_lonlat_in(record, lon, lat))
    plan = resolve_crs([info], None, None)
    assert plan.reprojector(info.path).is_identity
    assert not any("outside" in note for note in plan.notes)


def test_a_survey_past_its_zone_edge_runs(tmp_path: Path) -> None:
    """UTM zone 12N's record on a survey 1.6 degrees west of the zone's band:
    the record is right (zones are used past their edges), and the run gives
    its DEM in that zone, with no note."""
    import xarray as xr

    from pipeline.config import RunConfig
    from pipeline.runs.runner import run

    path = write_las(tmp_path / "edge.las", crs="EPSG:32612", n=2000, classes=(2,),
                     origin=_lonlat_in("EPSG:32612", -115.6, 45.0)).path
    out = tmp_path / "edge.zarr"
    report = run(RunConfig(inputs=(str(path),), output=str(out), resolution=5.0), progress=False)
    assert report.points_kept == 2000 and not any("area" in note for note in report.notes)
    ds = xr.open_zarr(out)
    assert pyproj.CRS.from_wkt(ds["spatial_ref"].attrs["crs_wkt"]).to_epsg() == 32612
    assert np.isfinite(ds["elevation"].values).any()


def test_the_area_tolerance(tmp_path: Path) -> None:
    """Lambert-93 is for France (south to 41.15 N): 3 degrees (334 km) south
    of it still holds, 6 degrees (668 km) no longer does."""
    lambert93 = pyproj.CRS("EPSG:2154")
    assert crs_module.AREA_TOLERANCE_KM == 500.0
    for lat, refused in ((38.15, False), (35.15, True)):
        x, y = _lonlat_in("EPSG:2154", 3.0, lat)
        found = crs_module.contradiction(lambert93, (x, y, 0.0, x + 100.0, y + 100.0, 10.0))
        assert (found is not None) == refused, found
        if found:
            assert found[1] is False and "lat 35.15, 668 km outside that area" in found[0]


def test_a_geocentric_record_on_geocentric_coordinates_is_kept_and_gets_its_zone(tmp_path: Path) -> None:
    import dataclasses

    x, y, z = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(-110.8, -44.4, 2300.0)
    bounds = (x, y, z, x + 40.0, y + 40.0, z + 15.0)
    assert crs_module.contradiction(pyproj.CRS("EPSG:4978"), bounds) is None
    info = dataclasses.replace(info_for(tmp_path, "ecef.las", "EPSG:4978", origin=(x, y)), bounds=bounds)
    with pytest.raises(CrsError, match=r"geocentric .* use out_crs='EPSG:32712' \(WGS 84 / UTM zone 12S\)"):
        resolve_crs([info], None, None)  # south of the equator: z says so


def test_a_stray_point_beyond_the_pole_does_not_condemn_a_degrees_record() -> None:
    """Only bounds that hold no coordinate of the CRS at all contradict it:
    the points that cannot be transformed are named when they are."""
    assert crs_module.contradiction(pyproj.CRS("EPSG:4326"), (2.0, 46.0, 0.0, 2.01, 95.0, 1.0)) is None


def test_override_crs_replaces_every_record_and_names_each_file(tmp_path: Path) -> None:
    wrong = info_for(tmp_path, "wrong.las", "EPSG:4326", origin=YELLOWSTONE)
    right = info_for(tmp_path, "right.las", "EPSG:32612", origin=YELLOWSTONE)
    none = info_for(tmp_path, "none.las", None, origin=YELLOWSTONE)
    plan = resolve_crs([wrong, right, none], override_crs="EPSG:32612")
    assert {pyproj.CRS.from_wkt(w).to_epsg() for w in plan.source_wkts} == {32612}
    assert all(plan.reprojector(p).is_identity for p in plan.paths)
    replaced = [n for n in plan.notes if "is replaced by override_crs=" in n]
    assert len(replaced) == 1 and replaced[0].startswith(f"{wrong.path}: its CRS record WGS 84 (EPSG:4326)")
    assert any(str(none.path) in n and "without a CRS" in n and "override_crs=" in n for n in plan.notes)
    with pytest.raises(UsageError, match="not both"):
        resolve_crs([wrong], "EPSG:32612", override_crs="EPSG:32612")
    with pytest.raises(CrsError, match="^override_crs='EPSG:99999999'"):
        resolve_crs([wrong], override_crs="EPSG:99999999")


def test_a_given_crs_that_cannot_hold_the_coordinates_is_refused_and_one_far_off_is_noted(tmp_path: Path) -> None:
    metres = info_for(tmp_path, "metres.las", None, origin=YELLOWSTONE)
    for option in ("in_crs", "override_crs"):
        with pytest.raises(CrsError) as exc:
            resolve_crs([metres], **{option: "EPSG:4326"})
        _one_line_naming(str(exc.value), metres, f"{option}='WGS 84 (EPSG:4326)' is in degrees", f"give {option} the CRS")
    plan = resolve_crs([metres], "EPSG:2154")  # the user's word stands, with a note
    (far,) = [n for n in plan.notes if "outside that area" in n]
    assert far.startswith(f"{metres.path}: in_crs='RGF93 v1 / Lambert-93 (EPSG:2154)' is for lon -9.86 to 10.38")
    # and no UTM zone is suggested from its coordinates
    with pytest.raises(CrsError) as exc:
        resolve_crs([metres], "EPSG:2154", "EPSG:4326")
    assert "WGS 84 / UTM zone" not in str(exc.value) and "give out_crs the EPSG code" in str(exc.value)


def test_every_file_whose_record_is_contradicted_is_counted(tmp_path: Path) -> None:
    good = info_for(tmp_path, "good.las", "EPSG:32612", origin=YELLOWSTONE)
    bad = [info_for(tmp_path, f"bad{k}.las", "EPSG:4326", origin=YELLOWSTONE) for k in range(3)]
    with pytest.raises(CrsError) as exc:
        resolve_crs([good, *bad], None, "EPSG:32612")
    message = str(exc.value)
    assert message.startswith(f"{bad[0].path}: ") and str(good.path) not in message
    assert message.endswith(f"(2 more file(s) likewise: {bad[1].path}, {bad[2].path})")


def test_a_file_with_no_points_is_not_judged(tmp_path: Path) -> None:
    import dataclasses

    empty = dataclasses.replace(info_for(tmp_path, "empty.las", "EPSG:4326", origin=YELLOWSTONE), point_count=0)
    with pytest.raises(CrsError, match="geographic"):  # the target is refused, but not the record
        resolve_crs([empty], None, None)


# --------------------------------------------------------------------------- Reprojector


def test_reprojector_matches_pyproj(rng: np.random.Generator) -> None:
    r = Reprojector(pyproj.CRS(LAMBERT93).to_wkt(), pyproj.CRS("EPSG:32631").to_wkt())
    x = rng.uniform(600_000, 800_000, 100)
    y = rng.uniform(6_500_000, 6_700_000, 100)
    z = rng.uniform(0, 100, 100)
    expected = pyproj.Transformer.from_crs(LAMBERT93, "EPSG:32631", always_xy=True).transform(x, y, z)
    got = r.transform(x, y, z)
    for g, e in zip(got, expected):
        assert_allclose(g, e, rtol=0, atol=1e-6)
    assert_allclose(got[2], z)


def test_reprojector_pickles_as_a_recipe() -> None:
    r = Reprojector(LAMBERT93, "EPSG:32631")
    r.transform([700_000.0], [6_600_000.0], [0.0])  # builds this thread's transformer
    blob = pickle.dumps(r)
    assert b"Transformer" not in blob
    copy = pickle.loads(blob)
    assert copy == r and copy.source_wkt.startswith("PROJCRS") and not copy.is_identity
    assert Reprojector.from_dict(r.to_dict()) == r


def test_reprojector_builds_one_transformer_per_thread() -> None:
    r = Reprojector(LAMBERT93, "EPSG:32631")
    seen: list[pyproj.Transformer] = []  # keeps them alive, so identities stay distinct

    def work() -> None:
        first = crs_module._thread_transformer(r.source_wkt, r.target_wkt)
        r.transform([700_000.0], [6_600_000.0], [0.0])
        assert crs_module._thread_transformer(r.source_wkt, r.target_wkt) is first
        seen.append(first)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(seen) == 3 and len({id(t) for t in seen}) == 3


def test_identity_builds_no_transformer(monkeypatch: pytest.MonkeyPatch) -> None:
    r = Reprojector(pyproj.CRS(LAMBERT93).to_wkt(), LAMBERT93)  # same CRS spelled differently
    assert r.is_identity

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a Transformer was built for an identity reprojection")

    monkeypatch.setattr(pyproj.Transformer, "from_crs", refuse)
    x, y, z = r.transform([1.0, 2.0], [3.0, 4.0], [5.0, 6.0])
    assert x.dtype == np.float64 and list(y) == [3.0, 4.0]


def test_reprojector_reports_untransformable_points() -> None:
    r = Reprojector("EPSG:4326", "EPSG:32631")
    with pytest.raises(CrsError, match="1 of 2 points"):
        r.transform([3.0, 3.0], [45.0, 95.0], [0.0, 0.0])


def test_reprojector_bad_input() -> None:
    with pytest.raises(CrsError, match="not a CRS"):
        Reprojector("nonsense", LAMBERT93)
    with pytest.raises(UsageError):
        Reprojector(LAMBERT93, "EPSG:32631").transform([1.0], [1.0, 2.0], [1.0])


# --------------------------------------------------------------------------- real samples (../shared/data)


def test_real_records_the_coordinates_contradict() -> None:
    """PDAL's lone-star survey in UTM zone 12N metres, under a geocentric and
    a geographic record: each refused in one line naming the file, its
    record, its bounds and override_crs; each planned with the override."""
    for name, record in (("lone_star_wrong_crs_geocentric.copc.laz", "unnamed (EPSG:4978) is geocentric"),
                         ("lone_star_wrong_crs_degrees.laz", "WGS 84 (EPSG:4326) is in degrees")):
        info = read_info(sample(name))
        for out_crs in (None, "EPSG:32612"):
            with pytest.raises(CrsError) as exc:
                resolve_crs([info], None, out_crs)
            _one_line_naming(str(exc.value), info, f"its CRS record {record}", "x 515,368.6", "override_crs")
            assert "WGS 84 / UTM zone" not in str(exc.value)
        with pytest.raises(CrsError):  # in_crs is for files without a record
            resolve_crs([info], "EPSG:32612", None)
        plan = resolve_crs([info], override_crs="EPSG:32612")
        assert pyproj.CRS.from_wkt(plan.target_wkt).to_epsg() == 32612
        assert plan.reprojector(info.path).is_identity


@pytest.mark.parametrize(
    "name",
    ["ign_semis_lambert93.laz", "autzen_trim.las", "4_6_crop_us_feet.las", "extra_byte_blocks_lambert93.laz",
     "startinpy_small_extrabytes.laz", "geographic_epsg4326.las"],
)
def test_real_right_records_are_not_contradicted(name: str) -> None:
    info = read_info(sample(name))
    assert crs_module.contradiction(pyproj.CRS.from_wkt(info.crs_wkt or ""), info.bounds) is None


def test_real_geographic_needs_a_projected_target() -> None:
    info = read_info(sample("geographic_epsg4326.las"))
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], None, None)
    assert "geographic" in str(exc.value) and "out_crs='EPSG:32615'" in str(exc.value)


def test_real_us_survey_feet() -> None:
    info = read_info(sample("4_6_crop_us_feet.las"))
    plan = resolve_crs([info], None, None)
    assert plan.horizontal_unit == "US survey foot"
    assert pyproj.CRS.from_wkt(plan.target_wkt).to_epsg() == 2903
    assert info.z_unit == "US survey foot"
    plan = resolve_crs([info], None, "EPSG:32613")
    assert any("z stays in US survey foot" in n for n in plan.notes)


def test_real_compound_crs_parses() -> None:
    info = read_info(sample("startinpy_small_extrabytes.laz"))
    crs = pyproj.CRS.from_wkt(info.crs_wkt or "")
    assert crs.is_compound and crs.to_epsg() == 7415
    plan = resolve_crs([info], None, None)
    assert (plan.horizontal_unit, plan.vertical_unit) == ("metre", "metre")


def test_real_broken_crs() -> None:
    info = read_info(sample("warsaw_small_broken_crs.las"))
    with pytest.raises(CrsError) as exc:
        resolve_crs([info], None, None)
    assert str(info.path) in str(exc.value) and "WKT" in str(exc.value)
    plan = resolve_crs([info], "EPSG:2180", None)
    assert any("using in_crs=" in n for n in plan.notes)


def test_real_single_point() -> None:
    info = read_info(sample("single_point.laz"))
    plan = resolve_crs([info], LAMBERT93, None)
    assert plan.reprojector(info.path).is_identity


def test_real_mixed_crs_lists_both() -> None:
    autzen = read_info(sample("autzen_trim.las"))
    ign = read_info(sample("ign_semis_lambert93.laz"))
    with pytest.raises(CrsError) as exc:
        resolve_crs([autzen, ign], None, None)
    message = str(exc.value)
    assert str(autzen.path) in message and str(ign.path) in message
    assert "NAD_1983_HARN_Lambert_Conformal_Conic" in message and "EPSG:2154" in message


# --------------------------------------------------------------------------- heights in a run


def _feet_plane(path: Path, grade: float) -> Path:
    """A plane rising ``grade`` feet per foot eastwards, in New Mexico Central (US survey feet), z undeclared."""
    import laspy

    rng = np.random.default_rng(5)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.001])
    header.offsets = np.array([1_639_600.0, 1_454_500.0, 0.0])
    header.add_crs(pyproj.CRS("EPSG:2903"))
    las = laspy.LasData(header)
    x = 1_639_600.0 + rng.uniform(0, 400, 3000)
    y = 1_454_500.0 + rng.uniform(0, 400, 3000)
    las.x, las.y = x, y
    las.z = 7000.0 + grade * (x - 1_639_600.0)
    las.classification = np.full(3000, 2, dtype=np.uint8)
    las.write(path)
    return path


def test_slope_and_height_units_survive_a_change_of_units(tmp_path: Path) -> None:
    import xarray as xr

    from pipeline.config import RunConfig
    from pipeline.runs.runner import run

    path = _feet_plane(tmp_path / "plane_ft.las", grade=0.1)
    expected = np.degrees(np.arctan(0.1))

    def store(name: str, resolution: float, out_crs: str | None) -> xr.Dataset:
        out = tmp_path / name
        cfg = RunConfig(inputs=(str(path),), output=str(out), resolution=resolution, out_crs=out_crs, layers=("slope",))
        run(cfg, progress=False)
        return xr.open_zarr(out)

    native = store("native.zarr", 5.0, None)
    metres = store("utm.zarr", 1.5, "EPSG:26913")  # x, y become metres, z stays in feet
    heights = store("utm_navd88.zarr", 1.5, "EPSG:26913+5703")  # z is given the target's unit too
    for ds in (native, metres, heights):
        assert_allclose(np.nanmedian(ds.slope.values), expected, atol=0.05)
    # heights: in feet unless the target has a vertical axis, and then labelled as they are
    for ds in (native, metres):  # the plane tops out at 7040 ft on its east edge
        assert_allclose(np.nanmax(ds.elevation.values), 7040.0, atol=1.0)
    assert_allclose(np.nanmax(heights.elevation.values), np.nanmax(metres.elevation.values) * 1200 / 3937, rtol=1e-5)
    assert heights.elevation.attrs["units"] == "metre"
    assert "units" not in native.elevation.attrs  # undeclared: no label is invented
