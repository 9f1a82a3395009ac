"""The first run on a machine compiles its mesh kernels in other processes, one per part."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from meshcore import Surface
from pipeline.config import MeshOptions, RunConfig
from pipeline.runs import compiling
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey

_MEASURES = MeshOptions()
_SMOOTH = MeshOptions(surface=Surface.SMOOTH)


@pytest.fixture
def started(monkeypatch):
    """The processes started, with the kernels taken as not compiled yet."""
    processes = []
    popen = subprocess.Popen

    def recording(args, **kwargs):
        processes.append(popen(args, **kwargs))
        processes[-1].args_given = args
        return processes[-1]

    monkeypatch.setattr(compiling.meshcore.tiles, "kernels_compiled", lambda: False)
    monkeypatch.setattr(compiling.subprocess, "Popen", recording)
    return processes


def test_kernels_not_compiled_are_compiled_by_other_processes(started):
    aside = compiling.compile_aside(_MEASURES)
    assert [p.args_given[-1] for p in started] == ["triangulation", "faces"]  # no smooth part for a linear run
    assert all(json.loads(p.args_given[-2])["quad_measure"] == "s4" for p in started)
    aside.wait()
    assert [p.returncode for p in started] == [0, 0] and aside.processes == []  # the children's code ran to its end


def test_a_smooth_run_compiles_the_smooth_kernels_in_a_third(started):
    aside = compiling.compile_aside(_SMOOTH)
    assert [p.args_given[-1] for p in started] == ["triangulation", "faces", "smooth"]
    aside.stop()
    assert all(p.poll() is not None for p in started)


def test_compiled_kernels_start_no_process(monkeypatch):
    monkeypatch.setattr(compiling.meshcore.tiles, "kernels_compiled", lambda: True)
    assert compiling.compile_aside(_MEASURES).processes == []


def test_a_run_waits_for_the_kernels_and_ends_the_process(tmp_path, started):
    write_survey(tmp_path / "survey", SurveySpec(points=6_000, files=1, width=60.0, height=40.0, seed=2))
    report = run(RunConfig(inputs=(str(tmp_path / "survey"),), output=str(tmp_path / "o.zarr"), resolution=2.0),
                 progress=False)
    assert report.tiles_uncertified == 0 and report.points_kept > 0
    assert len(started) == 2 and all(p.poll() is not None for p in started)


def test_a_run_takes_over_the_process_its_caller_started(tmp_path, started):
    """terrain demo starts compiling before it writes its survey; its run waits for that process, starts none."""
    survey = tmp_path / "survey"
    config = RunConfig(inputs=(str(survey),), output=str(tmp_path / "o.zarr"), resolution=2.0)
    early = compiling.compile_aside(config.mesh_options())
    assert compiling.compile_aside(config.mesh_options()).processes == early.processes  # still at it: the same processes
    write_survey(survey, SurveySpec(points=6_000, files=1, width=60.0, height=40.0, seed=2))
    report = run(config, progress=False)
    assert report.points_kept > 0
    assert len(started) == 2 and all(p.poll() is not None for p in started)
    early.stop()  # finished: nothing to stop
    assert [p.returncode for p in started] == [0, 0]


_TILE_MESH = """
import numpy as np
from numba.core import event
import meshcore
compiled = []
class Listener(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Listener())
rng = np.random.default_rng(4)
xy = np.round(rng.random((3000, 2)) * 100.0 + [651000.0, 6862000.0], 2)
mesh = meshcore.build_mesh(xy, "s3", "s4", "greedy", window=(651020.0, 6862020.0, 651080.0, 6862080.0),
                           known=(651000.0, 6862000.0, 651100.0, 6862100.0))
meshcore.tiles.lexicographic_order(np.take(mesh.vertices, np.arange(10), axis=0))
print(sorted(set(compiled)))
"""


def test_the_parts_compiled_apart_are_every_kernel_a_tile_mesh_runs(tmp_path):
    """The parts compile the kernels for the argument types a tile passes
    them: a tile's mesh afterwards compiles nothing (a part that ran its
    kernels on other types would leave them to the tiles, on one core)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("NUMBA_DISABLE_JIT", None)
    key = json.dumps({"triangle_measure": "s3", "quad_measure": "s4", "merge": "greedy", "surface": "linear"})
    parts = [subprocess.Popen([sys.executable, "-c", compiling._CHILD, key, part], env=env)
             for part in ("triangulation", "faces")]
    assert [p.wait(timeout=300) for p in parts] == [0, 0]
    after = subprocess.run([sys.executable, "-c", _TILE_MESH], env=env, capture_output=True, text=True, timeout=300)
    assert after.returncode == 0, after.stderr
    assert after.stdout.strip() == "[]"
