"""terrain preview: the pictures, and its refusals."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread

from pipeline.cli import main
from pipeline.config import RunConfig
from pipeline.runner import run
from pipeline.synthetic import SurveySpec, write_survey


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SurveySpec(points=60_000, files=2, width=200.0, height=150.0, seed=8))
    out = folder.parent / "preview.zarr"
    run(RunConfig(inputs=(str(folder),), output=str(out), resolution=1.0, tile_size=64.0, workers=2), progress=False)
    return out


def _red(picture) -> int:
    rgb = picture[..., :3]
    return int(((rgb[..., 0] > 0.8) & (rgb[..., 1] < 0.2) & (rgb[..., 2] < 0.2)).sum())


def test_overview_and_mesh_window(store, tmp_path):
    assert main(["preview", str(store), "-o", str(tmp_path / "a.png")]) == 0
    overview = imread(tmp_path / "a.png")
    assert _red(overview) == 0
    window = "651050,6861050,651080,6861080"
    assert main(["preview", str(store), "-o", str(tmp_path / "b.png"), "--window", window]) == 0
    both = imread(tmp_path / "b.png")
    assert both.shape[1] > 1.6 * overview.shape[1]  # a second panel
    assert _red(both) > 50  # the zoom box drawn on the overview
    # the mesh panel holds both face colours
    right = both[:, both.shape[1] // 2 :, :3]
    blue = (np.abs(right - np.array([0x21, 0x66, 0xAC]) / 255) < 0.25).all(axis=2).sum()
    orange = (np.abs(right - np.array([0xF4, 0xA5, 0x16]) / 255) < 0.25).all(axis=2).sum()
    assert blue > 1000 and orange > 1000


def test_refusals_are_one_line_errors(store, tmp_path, capsys):
    assert main(["preview", str(store), "-o", str(tmp_path / "c.png"), "--window", "651000,6861000,651200,6861150"]) == 2
    assert "too many to draw" in capsys.readouterr().err
    assert main(["preview", str(store), "-o", str(tmp_path / "d.png"), "--window", "1,2,3"]) == 2
    assert main(["preview", str(store), "-o", str(tmp_path / "f.png"), "--window", "0,0,10,10"]) == 2
    assert "meets no face of the mesh" in capsys.readouterr().err
    assert not (tmp_path / "f.png").exists()
    assert main(["preview", str(tmp_path / "nothing.zarr"), "-o", str(tmp_path / "e.png")]) == 2
