"""Helpers for tests that start real processes (Dask schedulers and workers)."""

from __future__ import annotations

import subprocess


def stop_all(procs: list[subprocess.Popen], timeout: float = 20.0) -> None:
    """Terminate the processes, last started first, and kill any that linger."""
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
