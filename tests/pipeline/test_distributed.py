"""The distributed path: a real `dask scheduler` and two `dask worker` processes on loopback."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from pipeline.store import zarr_store as store
from pipeline.config import RunConfig
from pipeline.runs.runner import run
from pipeline.tools.synthetic import SurveySpec, write_survey

from .processes import stop_all


DASK = Path(sys.executable).with_name("dask")


def _dask_command() -> list[str]:
    return [str(DASK)]


@dataclass
class Cluster:
    address: str
    workers: list[subprocess.Popen]


@pytest.fixture
def cluster(tmp_path):
    assert DASK.exists(), "the dask command line comes with dask[distributed]"
    scheduler_file = tmp_path / "scheduler.json"
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
    procs = [
        subprocess.Popen(
            [*_dask_command(), "scheduler", "--host", "127.0.0.1", "--port", "0",
             "--dashboard-address", ":0", "--scheduler-file", str(scheduler_file)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
        )
    ]
    deadline = time.time() + 60
    while not scheduler_file.exists() and time.time() < deadline:
        time.sleep(0.2)
    for _ in range(2):
        procs.append(
            subprocess.Popen(
                [*_dask_command(), "worker", "--scheduler-file", str(scheduler_file), "--nthreads", "1",
                 "--host", "127.0.0.1", "--no-dashboard"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
            )
        )
    import json

    from distributed import Client

    address = json.loads(scheduler_file.read_text())["address"]
    with Client(address, timeout="30s", set_as_default=False) as client:
        client.wait_for_workers(2, timeout=60)
    try:
        yield Cluster(address, procs[1:])
    finally:
        stop_all(procs)


def test_distributed_run_equals_local_run(cluster, tmp_path):
    folder = tmp_path / "survey"
    write_survey(folder, SurveySpec(points=30_000, files=2, width=200.0, height=150.0, seed=7))
    common = dict(inputs=(str(folder),), resolution=2.0, tile_size=64.0, scratch_dir=str(tmp_path))
    local = run(RunConfig(output=str(tmp_path / "local.zarr"), workers=2, **common), progress=False)
    remote = run(RunConfig(output=str(tmp_path / "remote.zarr"), scheduler=cluster.address, **common), progress=False)
    assert remote.tiles == local.tiles > 4
    assert remote.faces == local.faces and remote.vertices == local.vertices
    a = xr.open_zarr(tmp_path / "local.zarr")["elevation"].values
    b = xr.open_zarr(tmp_path / "remote.zarr")["elevation"].values
    np.testing.assert_array_equal(a, b)
    for x, y in zip(store.read_mesh(tmp_path / "local.zarr"), store.read_mesh(tmp_path / "remote.zarr")):
        np.testing.assert_array_equal(x, y)


def test_a_distributed_run_of_every_stage_and_product_equals_a_local_run(cluster, tmp_path):
    """The ground stage (its blocks on the workers), the smooth surface (its
    variogram's sample merged from the workers' tiles) and every product
    (their spill files, the DSM's margin) on the cluster, against this
    process's threads: every layer and the mesh, bit for bit."""
    folder = tmp_path / "survey"
    write_survey(folder, SurveySpec(points=30_000, files=2, width=200.0, height=150.0, seed=11))
    common = dict(inputs=(str(folder),), resolution=2.0, tile_size=64.0, scratch_dir=str(tmp_path),
                  classify_ground=True, surface="smooth",
                  layers=("elevation", "dsm", "chm", "intensity", "density", "ground_density", "slope"))
    local = run(RunConfig(output=str(tmp_path / "local.zarr"), workers=2, **common), progress=False)
    remote = run(RunConfig(output=str(tmp_path / "remote.zarr"), scheduler=cluster.address, **common), progress=False)
    assert remote.tiles == local.tiles > 4 and remote.points_kept == local.points_kept
    a, b = xr.open_zarr(tmp_path / "local.zarr"), xr.open_zarr(tmp_path / "remote.zarr")
    for name in common["layers"]:
        assert np.isfinite(a[name].values).any(), name
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
    for x, y in zip(store.read_mesh(tmp_path / "local.zarr"), store.read_mesh(tmp_path / "remote.zarr")):
        np.testing.assert_array_equal(x, y)


def test_a_task_mapped_after_others_on_the_cluster_starts_only_when_they_have_ended(cluster, tmp_path):
    from distributed import Client

    from pipeline.runs.cluster import Progress, map_tasks

    def timed_task(item: tuple[str, float, str]) -> str:
        """Log when the task starts and ends (nested: shipped by value, as the workers cannot import the tests)."""
        name, seconds, log = item
        with open(log, "a") as f:
            f.write(f"{name} start {time.perf_counter():.6f}\n")
        time.sleep(seconds)
        with open(log, "a") as f:
            f.write(f"{name} end {time.perf_counter():.6f}\n")
        return name

    log = tmp_path / "log"
    items = [("A", 0.3, str(log)), ("B", 0.5, str(log)), ("C", 0.0, str(log)), ("D", 0.1, str(log))]
    with Client(cluster.address, timeout="30s", set_as_default=False) as client:
        names = map_tasks(client, timed_task, items, Progress("t", 4, False), lambda _: 0, after={2: [0, 1], 3: [2]})
    assert names == ["A", "B", "C", "D"]
    t = {(name, what): float(at) for name, what, at in (line.split() for line in log.read_text().splitlines())}
    assert t["C", "start"] >= max(t["A", "end"], t["B", "end"]) and t["D", "start"] >= t["C", "end"]


def test_a_worker_killed_mid_job_changes_nothing(cluster, tmp_path):
    folder = tmp_path / "survey"
    write_survey(folder, SurveySpec(points=120_000, files=4, width=300.0, height=200.0, seed=17))
    common = dict(inputs=(str(folder),), resolution=1.0, tile_size=40.0, scratch_dir=str(tmp_path))
    started = time.perf_counter()
    local = run(RunConfig(output=str(tmp_path / "local.zarr"), workers=2, **common), progress=False)
    whole = time.perf_counter() - started
    victim = cluster.workers[0]
    killer = threading.Timer(0.5 * whole, victim.kill)  # SIGKILL, half way through
    killer.start()
    try:
        remote = run(RunConfig(output=str(tmp_path / "remote.zarr"), scheduler=cluster.address, **common), progress=False)
    finally:
        killer.cancel()
    assert victim.poll() is not None, "the worker was not killed before the job ended"
    assert remote.faces == local.faces and remote.vertices == local.vertices
    from .store_checks import assert_same_store

    assert_same_store(tmp_path / "remote.zarr", tmp_path / "local.zarr")
