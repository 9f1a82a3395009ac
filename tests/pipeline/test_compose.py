"""docker-compose.yml: parsed, and its commands run natively on loopback.

Docker may not run where the tests run, so the compose file is checked by
parsing it, and the very commands its services run (scheduler, two workers,
the runner's workflow) are started as local processes on 127.0.0.1.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import xarray as xr
import yaml

from pipeline.synthetic import SurveySpec, write_survey

from .processes import stop_all

REPO = Path(__file__).parents[2]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_compose_defines_a_scalable_cluster_and_a_runner(compose):
    services = compose["services"]
    assert set(services) == {"scheduler", "worker", "runner"}
    for name, service in services.items():
        assert service["image"] == "terrain:latest" and service["build"] == ".", name
        assert "./data:/data" in service["volumes"], name  # one shared folder for inputs, store, work files
        assert service["environment"]["DASK_SCHEDULER_ADDRESS"] == "tcp://scheduler:8786"
    assert "8787:8787" in services["scheduler"]["ports"]  # the dashboard
    assert "--dashboard-address" in services["scheduler"]["command"]
    worker = services["worker"]
    assert "container_name" not in worker and "ports" not in worker  # so --scale worker=N works
    assert "tcp://scheduler:8786" in worker["command"]
    runner = services["runner"]["command"]
    assert runner[:3] == ["terrain", "workflow", "run"]
    assert (REPO / Path(runner[3]).relative_to("/opt/terrain")).exists()
    dockerfile = (REPO / "Dockerfile").read_text()
    assert "pip install \".[cluster]\"" in dockerfile and "COPY workflows" in dockerfile  # bokeh: the dashboard
    assert "terrain demo" in dockerfile  # every kernel of a run compiled into the image


def _native(command: list[str], port: int) -> list[str]:
    """A service's command as a local process: loopback instead of the service
    names, a free port, the venv's executables, the repository for /opt/terrain."""
    out = []
    for arg in command:
        arg = arg.replace("tcp://scheduler:8786", f"tcp://127.0.0.1:{port}").replace("/opt/terrain", str(REPO))
        out.append({"0.0.0.0": "127.0.0.1", "8786": str(port), ":8787": ":0"}.get(arg, arg))
    out[0] = str(BIN / out[0])
    return out


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_compose_commands_run_natively_on_loopback(compose, tmp_path):
    data = tmp_path / "data"
    write_survey(data / "archive", SurveySpec(points=80_000, files=2, width=600.0, height=300.0, seed=5))
    port = _free_port()
    services = compose["services"]
    env = dict(os.environ, TERRAIN_DATA=str(data), DASK_SCHEDULER_ADDRESS=f"tcp://127.0.0.1:{port}",
               DASK_DISTRIBUTED__WORKER__DAEMON="False")
    procs = [subprocess.Popen(_native(services["scheduler"]["command"], port), env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        from distributed import Client

        deadline = time.time() + 60
        while True:
            try:
                client = Client(f"tcp://127.0.0.1:{port}", timeout="2s")
                break
            except OSError:
                if time.time() > deadline:
                    raise
                time.sleep(0.5)
        for _ in range(2):
            procs.append(subprocess.Popen(_native(services["worker"]["command"], port), env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        client.wait_for_workers(2, timeout=60)
        result = subprocess.run(_native(services["runner"]["command"], port), env=env,
                                capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stderr
        ran = client.run_on_scheduler(lambda dask_scheduler: sorted(dask_scheduler.task_prefixes))
        assert "mesh_tile" in ran and "route_source" in ran  # the work ran on the cluster
        client.close()
        ds = xr.open_zarr(data / "dem" / "archive.zarr")
        assert ds.attrs["complete"] is True
        assert int(ds["elevation"].notnull().sum()) > 0.95 * 600 * 300  # the survey's cells (1 m)
    finally:
        stop_all(procs)
