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
        ({"tile_size": 2.5}, "multiple of the resolution"),
        ({"duplicates": "median"}, "duplicates='median' is not valid; expected one of 'lowest', 'highest', 'mean', 'first'"),
        ({"triangle_measure": "s4"}, "triangle_measure='s4' is not valid"),
        ({"classes": (300,)}, "classes must be integers 0-255"),
        ({"bbox": (1, 1, 0, 0)}, "min < max"),
        ({"layers": ("aspect",)}, "unknown layer"),
        ({"zarr_format": 4}, "zarr_format must be 2 or 3"),
        ({"inputs": ()}, "at least one"),
    ],
)
def test_invalid_values_are_named(kw, match):
    with pytest.raises(UsageError, match=match):
        base(**kw)


def test_unknown_keys_and_bad_toml(tmp_path):
    with pytest.raises(UsageError, match=r"unknown parameter\(s\) \['resolutoin'\]"):
        RunConfig.from_dict({"inputs": ["a"], "output": "o", "resolutoin": 1})
    bad = tmp_path / "bad.toml"
    bad.write_text("inputs = [")
    with pytest.raises(UsageError, match="bad.toml: not valid TOML"):
        RunConfig.from_toml(bad)
