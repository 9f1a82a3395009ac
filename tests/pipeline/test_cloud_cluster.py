"""A cluster that shares no disk: a real ``dask scheduler`` and ``dask worker``
processes on loopback, each worker in its own empty folder with its own
temporary directory, and inputs, work files and store on a real S3 server
(moto's ``moto_server``).  The workers have no credentials of their own: the
job file's ``storage_options`` reach them through the scheduler."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("s3fs")
pytest.importorskip("moto")

from pipeline.config import RunConfig  # noqa: E402
from pipeline.runs.runner import run  # noqa: E402
from pipeline.tools.synthetic import SurveySpec, write_survey  # noqa: E402

from .processes import stop_all  # noqa: E402
from .store_checks import assert_same_store  # noqa: E402

BIN = Path(sys.executable).parent
JOB = dict(resolution=1.0, tile_size=64.0)


def _bare_env(**more: str) -> dict[str, str]:
    """An environment with no AWS credentials, profile or endpoint at all."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    env.update(AWS_SHARED_CREDENTIALS_FILE="/nonexistent", AWS_CONFIG_FILE="/nonexistent", **more)
    return env


class Machines:
    """A scheduler and workers, each worker alone in its own folder."""

    def __init__(self, root: Path):
        self.root = root
        self.address = ""
        self.procs: list[subprocess.Popen] = []
        self.workers: list[subprocess.Popen] = []
        self.homes: list[Path] = []

    def start_scheduler(self) -> None:
        info = self.root / "scheduler.json"
        self.procs.append(subprocess.Popen(
            [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", ":0",
             "--scheduler-file", str(info)],
            cwd=self.root, env=_bare_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        ))
        deadline = time.time() + 60
        while not info.exists() and time.time() < deadline:
            time.sleep(0.2)
        self.address = json.loads(info.read_text())["address"]

    def add_worker(self) -> subprocess.Popen:
        home = self.root / f"machine-{len(self.homes)}"
        (home / "tmp").mkdir(parents=True)
        worker = subprocess.Popen(
            [str(BIN / "dask"), "worker", self.address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard",
             "--no-nanny"],
            cwd=home, env=_bare_env(TMPDIR=str(home / "tmp"), HOME=str(home)),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        self.homes.append(home)
        self.workers.append(worker)
        self.procs.append(worker)
        return worker

    def wait_for_workers(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s", set_as_default=False) as client:
            client.wait_for_workers(n, timeout=60)

    def stop(self) -> None:
        stop_all(self.procs)


@pytest.fixture(scope="module")
def machines(tmp_path_factory):
    m = Machines(tmp_path_factory.mktemp("machines"))
    m.start_scheduler()
    m.add_worker()
    m.add_worker()
    m.wait_for_workers(2)
    yield m
    m.stop()


def _wait_for(fs, prefix: str, timeout: float, process: subprocess.Popen) -> bool:
    """Wait until an object appears below ``prefix``; False if ``process`` ended first."""
    deadline = time.time() + timeout
    while time.time() < deadline and process.poll() is None:
        fs.invalidate_cache()
        if fs.exists(prefix) and fs.find(prefix):
            return True
        time.sleep(0.05)
    return False


def _survey_on_s3(s3, tmp_path: Path, bucket: str, spec: SurveySpec):
    """A synthetic survey written to ``tmp_path / "survey"`` and copied to
    ``s3://BUCKET/survey/``; the local folder and the S3 filesystem."""
    folder = tmp_path / "survey"
    fs = s3.filesystem()
    fs.mkdir(bucket)
    for p in write_survey(folder, spec):
        fs.put_file(str(p), f"{bucket}/survey/{p.name}")
    return folder, fs


def test_a_cluster_with_no_shared_disk_runs_on_s3_survives_a_killed_worker_and_a_killed_client(
    server, machines, tmp_path
):
    s3 = server
    folder, fs = _survey_on_s3(s3, tmp_path, "lidar", SurveySpec(points=24_000, files=3, width=240.0, height=160.0, seed=43))
    reference = tmp_path / "local.zarr"
    run(RunConfig(inputs=(str(folder),), output=str(reference), workers=2, **JOB), progress=False)

    job_file = tmp_path / "job.toml"
    job_file.write_text(
        '[run]\ninputs = ["s3://lidar/survey/"]\noutput = "s3://lidar/dem/survey.zarr"\n'
        f"resolution = {JOB['resolution']}\ntile_size = {JOB['tile_size']}\n"
        f'scheduler = "{machines.address}"\n'
        f'[run.storage_options]\nkey = "{s3.key}"\nsecret = "{s3.secret}"\nendpoint_url = "{s3.endpoint}"\n'
    )
    command = [str(BIN / "terrain"), "run", "--config", str(job_file), "--no-progress"]
    work = "lidar/dem/.survey.zarr.work"  # beside the store: the workers' disks are their own
    client = subprocess.Popen(command, cwd=tmp_path, env=_bare_env(), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(fs, f"{work}/records/route", 120, client), client.communicate()
        machines.workers[0].send_signal(signal.SIGKILL)  # a machine lost mid-run: its tasks go to the other
        assert _wait_for(fs, f"{work}/records/mesh", 120, client), client.communicate()
        client.send_signal(signal.SIGKILL)  # and then the machine that ran the job
        client.wait(timeout=30)
    finally:
        if client.poll() is None:
            client.kill()
    assert machines.workers[0].wait(timeout=30) == -signal.SIGKILL
    assert fs.find(f"{work}/records/mesh"), "the work folder on s3 keeps what was done"
    # a new machine joins, in its own empty folder, and the same command resumes the job
    machines.add_worker()
    machines.wait_for_workers(2)
    again = subprocess.run(command, cwd=tmp_path, env=_bare_env(), capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert "resumed an unfinished run" in again.stdout
    fs.invalidate_cache()
    assert not fs.exists(work), "the work folder is removed once the store is complete"
    fs.get("lidar/dem/survey.zarr", str(tmp_path / "fetched.zarr"), recursive=True)
    assert_same_store(tmp_path / "fetched.zarr", reference)
    # no machine kept a work file of its own
    for home in machines.homes:
        left = [p for p in home.rglob("*") if p.suffix in (".npy", ".json") or p.name.endswith(".work")]
        assert not left, left


def test_a_smooth_run_on_the_cluster_and_s3_gives_the_local_store(server, machines, tmp_path):
    """The smooth surface's variogram, and its pieces (the nodes of the faces the
    grid samples, and their rows), travel to the workers and through object
    storage: the store and its slope are the local run's, byte for byte."""
    s3 = server
    folder, fs = _survey_on_s3(s3, tmp_path, "smooth", SurveySpec(points=12_000, files=2, width=160.0, height=120.0, seed=47))
    reference = tmp_path / "local.zarr"
    report = run(RunConfig(inputs=(str(folder),), output=str(reference), workers=2, surface="smooth",
                           layers=("elevation", "slope"), **JOB), progress=False)
    assert report.tiles > 4
    job_file = tmp_path / "job.toml"
    job_file.write_text(
        '[run]\ninputs = ["s3://smooth/survey/"]\noutput = "s3://smooth/dem/survey.zarr"\n'
        f"resolution = {JOB['resolution']}\ntile_size = {JOB['tile_size']}\n"
        'surface = "smooth"\nlayers = ["elevation", "slope"]\n'
        f'scheduler = "{machines.address}"\n'
        f'[run.storage_options]\nkey = "{s3.key}"\nsecret = "{s3.secret}"\nendpoint_url = "{s3.endpoint}"\n'
    )
    done = subprocess.run([str(BIN / "terrain"), "run", "--config", str(job_file), "--no-progress"], cwd=tmp_path,
                          env=_bare_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    fs.invalidate_cache()
    fs.get("smooth/dem/survey.zarr", str(tmp_path / "fetched.zarr"), recursive=True)
    assert_same_store(tmp_path / "fetched.zarr", reference)


def test_a_finished_task_is_not_run_again_when_the_worker_that_ran_it_is_lost(tmp_path):
    """A task's result lives on the worker that made it.  Held on to, its future
    made a lost worker's finished tasks run again, rewriting their files (a
    route's spills) while the run read them on; each is let go once taken."""
    from distributed import Client

    from pipeline.runs.cluster import Progress, map_tasks

    def logged_task(item: tuple[str, str]) -> int:
        """Note one run of the task in the log, take a while if it is the slow one, and say which worker
        ran it (nested: shipped by value, as the workers cannot import the tests)."""
        name, log = item
        with open(log, "a") as f:
            f.write(name + "\n")
        if name == "slow":
            time.sleep(3.0)
        return os.getpid()

    m = Machines(tmp_path)
    try:
        m.start_scheduler()
        for _ in range(3):  # one for each task, and one idle that would run a lost one again at once
            m.add_worker()
        m.wait_for_workers(3)
        log = str(tmp_path / "runs.log")

        def finished(item, pid):
            if item[0] == "fast":  # the slow one still runs: lose the machine that ran this one
                os.kill(pid, signal.SIGKILL)

        with Client(m.address, timeout="30s", set_as_default=False) as client:
            pids = map_tasks(client, logged_task, [("fast", log), ("slow", log)], Progress("tasks", 2, False),
                             lambda result: 1, finished)
            assert pids[0] != pids[1]
            time.sleep(1.0)  # a task run again would have logged by now
        runs = Path(log).read_text().split()
        assert runs.count("fast") == 1, runs
        assert runs.count("slow") == 1, runs
    finally:
        m.stop()
