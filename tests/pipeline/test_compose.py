"""docker-compose.yml: parsed, and its commands run natively on loopback.

Docker may not run where the tests run, so the compose file is checked by
parsing it, and the very commands its services run (scheduler, two workers,
the runner's workflow) are started as local processes on 127.0.0.1.
"""

from __future__ import annotations

import os
import shutil
import re
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
    # nothing reachable from outside the host: the dashboard on loopback, the scheduler unpublished
    assert services["scheduler"]["ports"] == ["127.0.0.1:8787:8787"]
    assert "--dashboard-address" in services["scheduler"]["command"]
    worker = services["worker"]
    assert "container_name" not in worker and "ports" not in worker  # so --scale worker=N works
    assert "tcp://scheduler:8786" in worker["command"]
    limit = worker["command"][worker["command"].index("--memory-limit") + 1]
    assert _interpolated(limit) not in ("0", "", "none", "auto")  # a worker that outgrows it is restarted
    runner = services["runner"]["command"]
    assert runner[:3] == ["terrain", "workflow", "run"]
    assert (REPO / Path(runner[3]).relative_to("/opt/terrain")).exists()
    dockerfile = (REPO / "Dockerfile").read_text()
    assert "pip install \".[cluster,cloud]\"" in dockerfile and "COPY workflows" in dockerfile  # bokeh, s3fs
    assert "terrain demo" in dockerfile  # every kernel of a run compiled into the image


def _interpolated(arg: str) -> str:
    """Compose's ``${NAME:-default}``, with NAME unset."""
    return re.sub(r"\$\{[A-Z_]+:-([^}]*)\}", r"\1", arg)


def _native(command: list[str], port: int, certs: Path | None = None) -> list[str]:
    """A service's command as a local process: loopback instead of the service
    names, a free port, the venv's executables, the repository for /opt/terrain."""
    out = []
    for arg in command:
        arg = _interpolated(arg)
        for scheme in ("tcp", "tls"):
            arg = arg.replace(f"{scheme}://scheduler:8786", f"{scheme}://127.0.0.1:{port}")
        arg = arg.replace("/opt/terrain", str(REPO))
        if certs is not None:
            arg = arg.replace("/certs", str(certs))
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


@pytest.fixture(scope="module")
def tls_override() -> dict:
    return yaml.safe_load((REPO / "docker-compose.tls.yml").read_text())


def test_the_tls_override_opens_only_a_tls_scheduler(tls_override):
    services = tls_override["services"]
    scheduler = services["scheduler"]["command"]
    assert scheduler[scheduler.index("--protocol") + 1] == "tls"
    for flag in ("--tls-ca-file", "--tls-cert", "--tls-key"):
        assert flag in scheduler and flag in services["worker"]["command"]
    # the one port open to other hosts is the TLS scheduler's; the dashboard stays on loopback
    assert [p for p in services["scheduler"]["ports"] if not p.startswith("127.0.0.1:")] == ["8786:8786"]
    assert "--memory-limit" in services["worker"]["command"]
    for name, service in services.items():
        env = service["environment"]
        assert env["DASK_SCHEDULER_ADDRESS"] == "tls://scheduler:8786", name
        assert env["DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION"] == "True", name
        assert "./certs:/certs:ro" in service["volumes"], name


def _security(certs: Path):
    from distributed.security import Security

    return Security(tls_ca_file=str(certs / "ca.pem"), tls_client_cert=str(certs / "node.pem"),
                    tls_client_key=str(certs / "node-key.pem"), require_encryption=True)


def test_a_tls_cluster_runs_a_job_with_the_certificate_and_refuses_clients_without_it(tls_override, tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed: make-certs.sh needs it")
    from distributed import Client

    certs, rogue = tmp_path / "certs", tmp_path / "rogue"
    for folder in (certs, rogue):  # the cluster's CA, and another one nobody trusts
        subprocess.run(["sh", str(REPO / "make-certs.sh"), str(folder), "2"], check=True, capture_output=True)
    survey = tmp_path / "survey"
    write_survey(survey, SurveySpec(points=30_000, files=2, width=200.0, height=150.0, seed=6))
    port = _free_port()
    services = tls_override["services"]
    env = dict(os.environ, DASK_DISTRIBUTED__WORKER__DAEMON="False")
    env.update({k: v.replace("/certs", str(certs)) for k, v in services["scheduler"]["environment"].items()
                if k.startswith("DASK_DISTRIBUTED__COMM")})
    procs = [subprocess.Popen(_native(services["scheduler"]["command"], port, certs), env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        address = f"tls://127.0.0.1:{port}"
        deadline = time.time() + 60
        while True:
            try:
                client = Client(address, security=_security(certs), timeout="2s")
                break
            except OSError:
                if time.time() > deadline:
                    raise
                time.sleep(0.5)
        procs.append(subprocess.Popen(_native(services["worker"]["command"], port, certs), env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        client.wait_for_workers(1, timeout=60)
        store = tmp_path / "dem.zarr"
        job = subprocess.run([str(BIN / "terrain"), "run", str(survey), "-o", str(store), "--resolution", "1",
                              "--scheduler", address, "--no-progress"], env=env, capture_output=True, text=True,
                             timeout=300)
        assert job.returncode == 0, job.stderr
        assert "mesh_tile" in client.run_on_scheduler(lambda dask_scheduler: sorted(dask_scheduler.task_prefixes))
        client.close()
        assert xr.open_zarr(store).attrs["complete"] is True
        # refused: plain TCP, TLS without a certificate, and a certificate of another CA
        with pytest.raises((OSError, TimeoutError)):
            Client(f"tcp://127.0.0.1:{port}", timeout="2s")
        from distributed.security import Security

        with pytest.raises((OSError, TimeoutError, TypeError, ValueError)):
            Client(address, security=Security(), timeout="2s")
        with pytest.raises((OSError, TimeoutError)):
            Client(address, security=_security(rogue), timeout="2s")
    finally:
        stop_all(procs)
