"""The synthetic surveys look like real files: flight order and pulse attributes."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from pipeline.tools import synthetic
from pipeline.tools.synthetic import SurveySpec, terrain_height, write_survey


@pytest.mark.parametrize("point_format, version", [(1, "1.2"), (6, "1.4")])
def test_strips_are_flown_in_order_with_pulse_attributes(tmp_path, point_format, version):
    spec = SurveySpec(points=40_000, files=2, point_format=point_format, version=version, seed=3)
    paths = write_survey(tmp_path, spec)
    for k, path in enumerate(paths):
        las = laspy.read(path)
        x, y = np.asarray(las.x), np.asarray(las.y)
        # scan line after scan line: consecutive points are neighbours (in
        # random order they would be a strip's width apart)
        step = np.hypot(np.diff(x), np.diff(y))
        assert np.median(step) < 3.0
        assert np.all(np.diff(las.gps_time) > 0)
        returns = np.asarray(las.number_of_returns)
        assert np.all((np.asarray(las.return_number) >= 1) & (np.asarray(las.return_number) <= returns))
        assert np.asarray(las.intensity).std() > 100
        assert np.all(np.asarray(las.point_source_id) == k + 1)
        angle = np.asarray(las.scan_angle_rank if point_format < 6 else las.scan_angle * 0.006)
        assert angle.min() < -15 and angle.max() > 15
        # ground is still on the analytic terrain, and the last return of its pulse
        ground = np.asarray(las.classification) == 2
        assert np.allclose(np.asarray(las.z)[ground], terrain_height(x[ground], y[ground], spec.origin), atol=0.06)
        assert np.all(np.asarray(las.return_number)[ground] == returns[ground])


def test_flight_order_keeps_the_survey_geometry(tmp_path, monkeypatch):
    """The order and attributes do not change which points a survey holds."""
    spec = SurveySpec(points=20_000, files=2, seed=5)
    a = write_survey(tmp_path / "a", spec)
    monkeypatch.setattr(synthetic, "_as_flown", lambda *args: None)
    b = write_survey(tmp_path / "b", spec)

    def points(paths):
        las = [laspy.read(p) for p in paths]
        xyz = np.concatenate([np.column_stack([l.x, l.y, l.z]) for l in las])
        return xyz[np.lexsort(xyz.T[::-1])]

    assert np.array_equal(points(a), points(b))
    assert not np.array_equal(laspy.read(a[0]).x, laspy.read(b[0]).x)  # though their order differs
    assert sum(laspy.read(p).header.point_count for p in a) > 0.95 * spec.points
