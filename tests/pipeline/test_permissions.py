"""File permissions, for real: an unreadable input and a read-only store.

Root ignores permission bits, so when the suite runs as root the job runs in a
child process whose capabilities to override them are dropped (``setpriv``);
it then meets the permission bits as any user would.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from pipeline.store import zarr_store as store
from pipeline.tools.synthetic import SurveySpec, write_survey

from .store_checks import assert_same_store

_DROP = ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"]


def _unprivileged() -> list[str]:
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: permission bits cannot be enforced")
    probe = subprocess.run([*_DROP, "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot drop capabilities here: {probe.stderr.decode().strip()}")
    return _DROP


def _terrain(*args: str, unprivileged: bool = False) -> subprocess.CompletedProcess[str]:
    prefix = _unprivileged() if unprivileged else []
    command = [*prefix, sys.executable, "-m", "pipeline.cli", *args, "--no-progress"]
    return subprocess.run(command, capture_output=True, text=True, timeout=600)


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line.lower()]


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    folder = tmp_path_factory.mktemp("survey")
    write_survey(folder, SurveySpec(points=200_000, files=2, width=500.0, height=400.0, seed=9))
    return folder


@pytest.fixture
def workspace():
    # not under pytest's own temporary folder, whose permission bits would stop the child first
    path = Path(tempfile.mkdtemp(prefix="terrain-perm-"))
    yield path
    for p in [path, *path.rglob("*")]:
        if not p.is_symlink():
            p.chmod(0o700 if p.is_dir() else 0o600)
    shutil.rmtree(path)


def test_an_unreadable_input_is_one_line_or_skipped(survey, workspace):
    folder = workspace / "survey"
    shutil.copytree(survey, folder)
    locked = sorted(folder.glob("*.la[sz]"))[0]
    locked.chmod(0)
    done = _terrain("run", str(folder), "-o", str(workspace / "a.zarr"), "--resolution", "2", unprivileged=True)
    assert done.returncode == 2, done.stderr
    assert _error_lines(done.stderr) == [f"terrain: error: {locked}: permission denied (cannot read the file)"]
    assert store.read_attrs(workspace / "a.zarr") is None
    done = _terrain("run", str(folder), "-o", str(workspace / "b.zarr"), "--resolution", "2", "--skip-bad-files",
                    unprivileged=True)
    assert done.returncode == 0, done.stderr
    assert "permission denied" in done.stdout and str(locked) in done.stdout


def test_a_read_only_store_is_one_line_exit_1_and_resumes_once_writable(survey, workspace, tmp_path):
    reference = tmp_path / "reference.zarr"
    args = ["run", str(survey), "--resolution", "1", "--tile-size", "50"]
    assert _terrain(*args, "-o", str(reference)).returncode == 0
    out = workspace / "c.zarr"
    command = [sys.executable, "-m", "pipeline.cli", *args, "-o", str(out), "--no-progress"]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    meshed = workspace / ".c.zarr.work" / "records" / "mesh"
    deadline = time.monotonic() + 300
    while not (meshed.is_dir() and any(meshed.glob("*.json"))) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)  # a store part-written, then its folder made read-only
    proc.wait()
    for p in [workspace, *workspace.rglob("*")]:
        p.chmod(0o555 if p.is_dir() else 0o444)

    done = _terrain(*args, "-o", str(out), unprivileged=True)
    assert done.returncode == 1, done.stderr
    (line,) = _error_lines(done.stderr)
    assert line.startswith(f"terrain: error: {out}: cannot write ") and "Permission denied" in line, line
    assert "Traceback" not in done.stderr
    assert store.read_attrs(out)["complete"] is False

    for p in [workspace, *workspace.rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    done = _terrain(*args, "-o", str(out), unprivileged=True)
    assert done.returncode == 0, done.stderr
    assert "resumed" in done.stdout
    assert_same_store(out, reference)
