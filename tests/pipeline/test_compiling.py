"""The first run on a machine compiles its mesh kernels in a second process."""

from __future__ import annotations

import json
import subprocess
from types import SimpleNamespace

import pytest

from pipeline.config import RunConfig
from pipeline.runs import compiling
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey

_MEASURES = SimpleNamespace(triangle_measure="s3", quad_measure="s4", merge="greedy", duplicates="lowest", surface="linear")


@pytest.fixture
def started(monkeypatch):
    """The processes started, with the kernels taken as not compiled yet."""
    processes = []
    popen = subprocess.Popen

    def recording(args, **kwargs):
        processes.append(popen(args, **kwargs))
        processes[-1].args_given = args
        return processes[-1]

    monkeypatch.setattr(compiling.meshcore, "kernels_compiled", lambda: False)
    monkeypatch.setattr(compiling.subprocess, "Popen", recording)
    return processes


def test_kernels_not_compiled_are_compiled_by_another_process(started):
    aside = compiling.compile_aside(_MEASURES)
    assert len(started) == 1 and json.loads(started[0].args_given[-1])["quad_measure"] == "s4"
    aside.wait()
    assert started[0].returncode == 0 and aside.process is None  # the child's code ran to its end


def test_compiled_kernels_start_no_process(monkeypatch):
    monkeypatch.setattr(compiling.meshcore, "kernels_compiled", lambda: True)
    assert compiling.compile_aside(_MEASURES).process is None


def test_a_run_waits_for_the_kernels_and_ends_the_process(tmp_path, started):
    write_survey(tmp_path / "survey", SurveySpec(points=6_000, files=1, width=60.0, height=40.0, seed=2))
    report = run(RunConfig(inputs=(str(tmp_path / "survey"),), output=str(tmp_path / "o.zarr"), resolution=2.0),
                 progress=False)
    assert report.tiles_uncertified == 0 and report.points_kept > 0
    assert len(started) == 1 and started[0].poll() is not None


def test_a_run_takes_over_the_process_its_caller_started(tmp_path, started):
    """terrain demo starts compiling before it writes its survey; its run waits for that process, starts none."""
    survey = tmp_path / "survey"
    config = RunConfig(inputs=(str(survey),), output=str(tmp_path / "o.zarr"), resolution=2.0)
    early = compiling.compile_aside(config)
    assert compiling.compile_aside(config).process is early.process  # still at it: the same process
    write_survey(survey, SurveySpec(points=6_000, files=1, width=60.0, height=40.0, seed=2))
    report = run(config, progress=False)
    assert report.points_kept > 0
    assert len(started) == 1 and started[0].poll() is not None
    early.stop()  # finished: nothing to stop
    assert started[0].returncode == 0
