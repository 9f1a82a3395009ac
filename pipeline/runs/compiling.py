"""The first run on a machine: the mesh kernels compiled in a second process.

numba compiles a kernel in the thread that first calls it, holding the GIL,
so a run on this process's threads compiles its kernels one after another:
about 25 s of the demo's first run on two cores (its later runs take 6 s).
When the kernel cache holds no mesh kernels compiled from these sources
(:func:`meshcore.kernels_compiled`: the first run after an install or an
upgrade), :func:`compile_aside` starts a process that compiles them
(:func:`~pipeline.meshing.tiles.load_mesh_kernels`) while this one creates
the store, reads and routes the points and compiles the DEM's kernels; the
tiles wait for it (:meth:`KernelCompile.wait`) and load its kernels from the
cache.  Nothing depends on it: had it failed, the tiles compile their kernels
themselves.
"""

from __future__ import annotations

import json
import subprocess
import sys

import meshcore

from ..config import RunConfig
from ..meshing.tiles import TileJob

__all__ = ["KernelCompile", "compile_aside"]

_CHILD = "import json, sys; from pipeline.meshing.tiles import load_mesh_kernels; load_mesh_kernels(**json.loads(sys.argv[1]))"

WAIT_SECONDS = 600.0
"""How long the tiles wait for the other process at most (it compiles in about 20 s)."""


class KernelCompile:
    """The process compiling the mesh kernels, if one was started."""

    def __init__(self, process: subprocess.Popen | None) -> None:
        self.process = process

    def wait(self) -> None:
        """Until the kernels are compiled (or the process ended otherwise)."""
        if self.process is None:
            return
        try:
            self.process.wait(timeout=WAIT_SECONDS)
        except subprocess.TimeoutExpired:
            self.stop()
        self.process = None

    def stop(self) -> None:
        """End the process now (the run stopped before its tiles)."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.process = None


_STARTED: dict[str, subprocess.Popen] = {}
"""The processes this one started, by the measures they compile: a run takes
over one still compiling (``terrain demo`` starts it before it writes its survey)."""


def compile_aside(job: TileJob | RunConfig) -> KernelCompile:
    """Start compiling the mesh kernels of ``job``'s measures in another
    process, unless the kernel cache holds them already or such a process is
    still at it (then that one is returned)."""
    if meshcore.kernels_compiled():
        return KernelCompile(None)
    measures = {"triangle_measure": job.triangle_measure, "quad_measure": job.quad_measure, "merge": job.merge,
                "duplicates": job.duplicates, "surface": job.surface}
    key = json.dumps(measures, sort_keys=True)
    running = _STARTED.get(key)
    if running is not None and running.poll() is None:
        return KernelCompile(running)
    try:
        process = subprocess.Popen([sys.executable, "-c", _CHILD, key],
                                   stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:  # no process to spare: the tiles compile them
        return KernelCompile(None)
    _STARTED[key] = process
    return KernelCompile(process)
