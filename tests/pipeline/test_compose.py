"""docker-compose.yml: parsed, and its commands run natively on loopback.

Docker may not run where the tests run, so the compose file is checked by
parsing it, and the very commands its services run (scheduler, two workers,
the runner's workflow) are started as local processes on 127.0.0.1.
"""

from __future__ import annotations

import json
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

from pipeline.tools.synthetic import SurveySpec, write_survey

from .processes import stop_all

REPO = Path(__file__).parents[2]
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_compose_defines_a_scalable_cluster_and_a_runner(compose):
    services = {k: v for k, v in compose["services"].items() if "profiles" not in v}
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
    # every package the install names is copied into the image (pip fails on a missing one)
    import tomllib

    packages = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    for top in {name.split(".")[0] for name in packages}:
        assert f"COPY {top} ./{top}" in dockerfile, top


def test_the_s3_profile_is_a_cluster_that_shares_no_disk(compose):
    services = compose["services"]
    s3 = {k: v for k, v in services.items() if "s3" in v.get("profiles", ())}
    assert set(s3) == {"s3", "s3-worker", "s3-runner"}
    assert "ports" not in services["s3"]  # the bucket is reached on the compose network only
    assert "volumes" not in services["s3-worker"]  # its own disk: everything it reads and writes is in the bucket
    assert services["s3-runner"]["volumes"] == ["./data/archive:/archive:ro"]  # only to upload the archive
    for name in ("s3-worker", "s3-runner"):
        env = services[name]["environment"]
        assert env["AWS_ENDPOINT_URL"] == "http://s3:5000" and env["DASK_SCHEDULER_ADDRESS"] == "tcp://scheduler:8786"
    worker = services["s3-worker"]["command"]
    assert "tcp://scheduler:8786" in worker and "--memory-limit" in worker


def _interpolated(arg: str) -> str:
    """Compose's ``${NAME:-default}`` with NAME unset, and ``$$`` for a ``$`` of the command's own."""
    return re.sub(r"\$\{[A-Z_]+:-([^}]*)\}", r"\1", arg).replace("$$", "$")


def _native(command: list[str], port: int, certs: Path | None = None, words: dict[str, str] | None = None) -> list[str]:
    """A service's command as a local process: loopback instead of the service
    names, a free port, the venv's executables, the repository for /opt/terrain
    (and any other ``words`` replaced)."""
    out = []
    for arg in command:
        arg = _interpolated(arg)
        for scheme in ("tcp", "tls"):
            arg = arg.replace(f"{scheme}://scheduler:8786", f"{scheme}://127.0.0.1:{port}")
        arg = arg.replace("/opt/terrain", str(REPO))
        if certs is not None:
            arg = arg.replace("/certs", str(certs))
        for word, value in (words or {}).items():
            arg = arg.replace(word, value)
        out.append({"0.0.0.0": "127.0.0.1", "8786": str(port), ":8787": ":0"}.get(arg, arg))
    out[0] = str(BIN / out[0]) if (BIN / out[0]).exists() else shutil.which(out[0]) or out[0]
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
        client = _scheduler_client(port)
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


def _scheduler_client(port: int):
    """A client of the scheduler on ``port``, once it answers."""
    from distributed import Client

    deadline = time.time() + 60
    while True:
        try:
            return Client(f"tcp://127.0.0.1:{port}", timeout="2s", set_as_default=False)
        except OSError:
            if time.time() > deadline:
                raise
            time.sleep(0.5)


_LOOK = """
import json, s3fs, xarray as xr
fs = s3fs.S3FileSystem()
with xr.open_zarr(fs.get_mapper("terrain/dem/archive.zarr")) as ds:
    out = {"complete": ds.attrs["complete"], "cells": int(ds["elevation"].notnull().sum())}
out["work_records"] = len(fs.find("terrain/dem/.archive.zarr.work/records/mesh"))
print(json.dumps(out))
"""


def test_the_s3_profile_runs_natively_with_no_shared_disk(compose, tmp_path):
    pytest.importorskip("s3fs")
    pytest.importorskip("moto")

    services = compose["services"]
    archive = tmp_path / "data" / "archive"
    write_survey(archive, SurveySpec(points=16_000, files=2, width=400.0, height=200.0, seed=9))
    port, s3_port = _free_port(), _free_port()
    endpoint = f"http://127.0.0.1:{s3_port}"

    def machine(name: str, service: str) -> tuple[Path, dict[str, str]]:
        """A folder of its own, and the service's environment on loopback."""
        home = tmp_path / name
        (home / "tmp").mkdir(parents=True)
        env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
        env.update({k: _interpolated(str(v)) for k, v in services[service].get("environment", {}).items()})
        env.update(AWS_ENDPOINT_URL=endpoint, DASK_SCHEDULER_ADDRESS=f"tcp://127.0.0.1:{port}", TMPDIR=str(home / "tmp"),
                   PATH=f"{BIN}{os.pathsep}{os.environ['PATH']}", DASK_DISTRIBUTED__WORKER__DAEMON="False")
        return home, env

    s3 = services["s3"]
    home, env = machine("s3", "s3")
    procs = [subprocess.Popen(_native([*s3["entrypoint"], *s3["command"]], port, words={"5000": str(s3_port)}),
                              cwd=home, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        home, env = machine("scheduler", "scheduler")
        procs.append(subprocess.Popen(_native(services["scheduler"]["command"], port), cwd=home, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        client = _scheduler_client(port)
        workers = [machine(f"worker-{k}", "s3-worker") for k in range(2)]
        for home, env in workers:
            procs.append(subprocess.Popen(_native(services["s3-worker"]["command"], port), cwd=home, env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        client.wait_for_workers(2, timeout=60)
        home, env = machine("runner", "s3-runner")
        command = _native(services["s3-runner"]["command"], port, words={" /archive ": f" {archive} "})
        result = subprocess.run(command, cwd=home, env=env, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, result.stderr
        assert "uploaded 2 file(s) to s3://terrain/archive/" in result.stdout
        ran = client.run_on_scheduler(lambda dask_scheduler: sorted(dask_scheduler.task_prefixes))
        assert "mesh_tile" in ran and "route_source" in ran  # the work ran on the workers
        client.close()
        # looked at from outside, as a user would (s3fs and xarray in a process of their own)
        look = subprocess.run([sys.executable, "-c", _LOOK], env=env, capture_output=True, text=True, timeout=120)
        assert look.returncode == 0, look.stderr
        seen = json.loads(look.stdout)
        assert seen["complete"] is True and seen["cells"] > 0.95 * 400 * 200
        # a workflow keeps its work folder for its next run: in the bucket, beside the store
        assert seen["work_records"] > 0
        for home, _ in workers:  # nothing was kept on a worker's own disk
            assert not [p for p in home.rglob("*.npy")]
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
                client = Client(address, security=_security(certs), timeout="2s", set_as_default=False)
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
            Client(f"tcp://127.0.0.1:{port}", timeout="2s", set_as_default=False)
        from distributed.security import Security

        with pytest.raises((OSError, TimeoutError, TypeError, ValueError)):
            Client(address, security=Security(), timeout="2s", set_as_default=False)
        with pytest.raises((OSError, TimeoutError)):
            Client(address, security=_security(rogue), timeout="2s", set_as_default=False)
    finally:
        stop_all(procs)
