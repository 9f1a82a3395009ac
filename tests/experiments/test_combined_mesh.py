"""Tests of experiments.combined_mesh: a small run, the table layout, the figures and the CLI."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from pipeline.cli import main
from experiments import ExperimentError, ExperimentParameterError
from experiments.combined_mesh import (
    ROWS,
    _convex,
    _GaussianBumps,
    _saddle,
    bump_count,
    format_table,
    run_experiment,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def small_result():
    return run_experiment(points=60, trials=2, seed=3, order=3)


def test_small_run_gives_finite_positive_errors_for_every_row(small_result):
    errors = small_result.errors
    assert errors.shape == (2, 3, len(ROWS), 2)
    assert np.all(np.isfinite(errors)) and np.all(errors > 0.0)
    assert small_result.mean_errors.shape == (3, len(ROWS), 2)
    assert_allclose(small_result.mean_errors, errors.mean(axis=0))


def test_only_the_combined_rows_have_quadrangles(small_result):
    share = small_result.quad_share
    assert np.all(share[:, [0, 2]] == 0.0)
    assert np.all(share[:, [1, 3]] > 0.0) and np.all(share < 1.0)
    assert np.all(small_result.quad_area_share[:, [1, 3]] > share[:, [1, 3]])  # a quad is two triangles


def test_tables_have_the_row_labels_and_marks(small_result):
    for k, name in enumerate(("convex", "saddle", "random")):
        text = small_result.table(k)
        assert text.startswith(f"Table {k + 1}: Summary error values for {name} test function")
        for label in ("S1(t)", "S2(q)", "S3(t)", "S4(q)"):
            assert label in text
        assert text.count("(+)") >= 2 and text.count("(-)") >= 2
        assert text == small_result.table(name)


def test_format_table_marks_column_minimum_and_maximum():
    values = np.array([[0.3, 2.0], [0.1, 4.0], [0.2, 1.0], [0.4, 3.0]])
    lines = format_table("T", ("a", "b", "c", "d"), values).splitlines()
    assert lines[0] == "T"
    rows = {line.split()[0]: line for line in lines[2:]}
    assert rows["a"].split()[1:] == ["0.30000", "2.00000"]
    assert rows["b"].split()[1:] == ["0.10000", "(+)", "4.00000", "(-)"]
    assert rows["c"].split()[1:] == ["0.20000", "1.00000", "(+)"]
    assert rows["d"].split()[1:] == ["0.40000", "(-)", "3.00000"]


def test_run_is_deterministic_and_depends_on_the_seed(small_result):
    again = run_experiment(points=60, trials=2, seed=3, order=3)
    assert np.array_equal(again.errors, small_result.errors)
    other = run_experiment(points=60, trials=2, seed=4, order=3)
    assert not np.array_equal(other.errors, small_result.errors)


@pytest.mark.parametrize(
    "kwargs", [{"points": 2}, {"trials": 0}, {"order": 0}, {"merge": "best"}, {"points": 10.5}]
)
def test_invalid_parameters_are_usage_errors(kwargs):
    with pytest.raises(ExperimentParameterError):
        run_experiment(**{"points": 60, "trials": 1, **kwargs})
    assert issubclass(ExperimentParameterError, ExperimentError) and issubclass(ExperimentParameterError, ValueError)


def test_bump_count_stays_well_below_the_vertex_count():
    assert bump_count(500) == 20
    assert bump_count(60) == 6
    assert bump_count(3) == 1


def test_analytic_gradients_match_finite_differences():
    rng = np.random.default_rng(7)
    x, y = rng.uniform(-0.9, 0.9, size=(2, 50))
    h = 1e-6
    for func in (_convex, _saddle, _GaussianBumps.draw(rng, 5)):
        _, fx, fy = func(x, y)
        assert_allclose(fx, (func(x + h, y)[0] - func(x - h, y)[0]) / (2 * h), rtol=1e-6, atol=1e-7)
        assert_allclose(fy, (func(x, y + h)[0] - func(x, y - h)[0]) / (2 * h), rtol=1e-6, atol=1e-7)


def test_cli_runs_the_experiment_and_writes_both_figures(tmp_path, capsys):
    out = tmp_path / "figures"
    assert main(["experiment", "--points", "60", "--trials", "2", "--out", str(out)]) == 0
    for name in ("figure2_measures.png", "combined_mesh.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE) and len(data) > 10_000
    text = capsys.readouterr().out
    for needle in ("Table 1", "Table 2", "Table 3", "Quadrature: tensor Gauss-Legendre", "Doubling check",
                   "Share of quadrangles", "f = 4 (x^2 + y^2)", "f = 4 x y"):
        assert needle in text


def test_cli_reports_an_unusable_output_folder(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["experiment", "--points", "60", "--trials", "1", "--out", str(blocker / "sub")]) == 2
    assert "cannot create the output folder" in capsys.readouterr().err
