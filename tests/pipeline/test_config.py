import json

import pytest

from pipeline.config import RunConfig
from pipeline.errors import UsageError


def base(**kw):
    values = {"inputs": ("a.laz",), "output": "out.zarr", "resolution": 1.0}
    values.update(kw)
    return RunConfig(**values)


def test_defaults_and_round_trip(tmp_path):
    cfg = base(classes=(9, 2, 2), layers=("slope",), bbox=[0, 0, 10, 10])
    assert cfg.classes == (2, 9)
    assert cfg.layers == ("elevation", "slope")
    assert cfg.bbox == (0.0, 0.0, 10.0, 10.0)
    assert RunConfig.from_dict(cfg.to_dict()) == cfg
    job = tmp_path / "job.toml"
    job.write_text('[run]\ninputs = ["a.laz"]\noutput = "out.zarr"\nresolution = 1.0\nclasses = "all"\n')
    loaded = RunConfig.from_toml(job)
    assert loaded.classes is None
    assert loaded.differences(base()) == ["classes"]


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"resolution": 0}, "resolution must be a positive number"),
        ({"duplicates": "median"}, "duplicates='median' is not valid; expected one of 'lowest', 'highest', 'mean', 'first'"),
        ({"triangle_measure": "s4"}, "triangle_measure='s4' is not valid"),
        ({"merge": "GREEDY"}, "merge='GREEDY' is not valid; expected one of 'greedy', 'optimal'"),  # exact text
        ({"classes": (300,)}, "classes must be integers 0-255"),
        ({"bbox": (1, 1, 0, 0)}, "min < max"),
        ({"layers": ("aspect",)}, "unknown layer"),
        ({"zarr_format": 4}, "zarr_format must be 2 or 3"),
        ({"zarr_format": 3.0}, "zarr_format must be 2 or 3"),
        ({"inputs": ()}, "at least one"),
        ({"classes": "2,x"}, "classes must be integers 0-255"),
        ({"overwrite": "false"}, "overwrite must be true or false, got 'false'"),
        ({"keep_withheld": 1}, "keep_withheld must be true or false"),
        ({"skip_bad_files": "yes"}, "skip_bad_files must be true or false"),
        ({"workers": "abc"}, "workers must be a positive integer, got 'abc'"),
        ({"workers": 2.5}, "workers must be a positive integer"),
        ({"workers": 0}, "workers must be a positive integer"),
        ({"max_cells": "lots"}, "max_cells must be a positive integer"),
        ({"max_cells": 1.5}, "max_cells must be a positive integer"),
        ({"max_cells": float("inf")}, "max_cells must be a positive integer"),
        ({"scheduler": 5}, "scheduler must be a string"),
        ({"override_crs": 32612}, "override_crs must be a string"),
        ({"in_crs": "EPSG:2154", "override_crs": "EPSG:32612"}, "give in_crs or override_crs, not both"),
    ],
)
def test_invalid_values_are_named(kw, match):
    with pytest.raises(UsageError, match=match):
        base(**kw)


@pytest.mark.parametrize("kw", [{"classes": None}, {"quad_measure": None}, {"classes": None, "quad_measure": None}])
def test_none_that_is_not_the_default_survives_a_round_trip(tmp_path, kw):
    # "all classes" and "no quads" must not come back as the defaults (ground, s4)
    cfg = base(**kw)
    data = cfg.to_dict()
    assert RunConfig.from_dict(data) == cfg
    job = tmp_path / "job.toml"
    job.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in data.items()))  # JSON scalars and lists are TOML
    assert RunConfig.from_toml(job) == cfg
    assert RunConfig.from_dict(data).differences(cfg) == []


def test_counts_written_as_whole_floats_are_counts():
    # TOML and the command line take 4e9 for max_cells, as its help writes it
    assert base(max_cells=4e9).max_cells == 4_000_000_000 and base(workers=2.0).workers == 2
    import numpy as np

    assert base(workers=np.int64(3)).workers == 3


def test_classes_as_text_and_neutral_differences():
    assert base(classes="9, 2").classes == (2, 9)
    assert base(classes="ALL").classes is None
    # the order of the layers asked and the cell limit do not change the store
    a = base(layers=("point_count", "slope"), max_cells=10**6, workers=1)
    b = base(layers=("slope", "point_count"))
    assert a.layers == b.layers == ("elevation", "slope", "point_count")
    assert a.differences(b) == []
    assert base(layers=("slope",)).differences(b) == ["layers"]


def test_unknown_keys_and_bad_toml(tmp_path):
    with pytest.raises(UsageError, match=r"unknown parameter\(s\) \['resolutoin'\]"):
        RunConfig.from_dict({"inputs": ["a"], "output": "o", "resolutoin": 1})
    bad = tmp_path / "bad.toml"
    bad.write_text("inputs = [")
    with pytest.raises(UsageError, match="bad.toml: not valid TOML"):
        RunConfig.from_toml(bad)


def test_override_crs_in_a_job_file_changes_the_result(tmp_path):
    job = tmp_path / "job.toml"
    job.write_text('[run]\ninputs = ["a.laz"]\noutput = "out.zarr"\nresolution = 1.0\noverride_crs = "EPSG:32612"\n')
    loaded = RunConfig.from_toml(job)
    assert loaded.override_crs == "EPSG:32612" and loaded.in_crs is None
    assert loaded.to_dict()["override_crs"] == "EPSG:32612"  # so the provenance records it
    assert RunConfig.from_dict(loaded.to_dict()) == loaded
    assert loaded.differences(base()) == ["override_crs"]  # a store made without it is not resumed
