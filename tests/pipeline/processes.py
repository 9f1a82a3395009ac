"""Helpers for tests that start real processes (Dask schedulers and workers)."""

from __future__ import annotations

import subprocess


def stop_all(procs: list[subprocess.Popen], timeout: float = 3.0) -> None:
    """Terminate the processes, last started first, and kill any still there
    ``timeout`` seconds later (a test's cluster has nothing to save)."""
    import time

    for p in reversed(procs):
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
