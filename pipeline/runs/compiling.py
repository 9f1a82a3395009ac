"""The first run on a machine: the mesh kernels compiled in other processes.

numba compiles a kernel in the thread that first calls it, holding the GIL,
so a run on this process's threads compiles its kernels one after another:
about 20 s of kernels for the demo's first run (its later runs take 7 s).
When the kernel cache holds no mesh kernels compiled from these sources
(:func:`meshcore.tiles.kernels_compiled`: the first run after an install or an
upgrade), :func:`compile_aside` starts a process for each part of them
(:data:`~pipeline.meshing.kernels.MESH_KERNEL_PARTS`: the Delaunay sweep's,
the kernels after it, the smooth surface's; 6-8 s each on one core)
while this one creates the store, reads and routes the points and compiles
the DEM's kernels; the tiles wait for them (:meth:`KernelCompile.wait`) and
load their kernels from the cache.  Nothing depends on them: had one failed,
the tiles compile its kernels themselves.
"""

from __future__ import annotations

import json
import subprocess
import sys

import meshcore

from ..config import MeshOptions
from ..meshing.kernels import MESH_KERNEL_PARTS

__all__ = ["KernelCompile", "compile_aside"]

_CHILD = (
    "import json, sys; from pipeline.meshing.kernels import load_mesh_kernels; "
    "load_mesh_kernels(**json.loads(sys.argv[1]), parts=(sys.argv[2],))"
)

WAIT_SECONDS = 600.0
"""How long the tiles wait for the other processes at most (they compile in 6-8 s)."""


class KernelCompile:
    """The processes compiling the mesh kernels, if any were started."""

    def __init__(self, processes: list[subprocess.Popen] | None = None) -> None:
        self.processes = list(processes or [])

    def wait(self) -> None:
        """Until the kernels are compiled (or the processes ended otherwise)."""
        for process in self.processes:
            try:
                process.wait(timeout=WAIT_SECONDS)
            except subprocess.TimeoutExpired:
                break
        self.stop()

    def stop(self) -> None:
        """End the processes now (the run stopped before its tiles)."""
        for process in self.processes:
            if process.poll() is None:
                process.kill()
                process.wait()
        self.processes = []


_STARTED: dict[str, list[subprocess.Popen]] = {}
"""The processes this one started, by the measures they compile: a run takes
over those still compiling (``terrain demo`` starts them before it writes its survey)."""


def compile_aside(options: MeshOptions) -> KernelCompile:
    """Start compiling the mesh kernels of the measures ``options`` names in
    other processes, one per part, unless the kernel cache holds them already
    or such processes are still at it (then those are returned)."""
    if meshcore.tiles.kernels_compiled():
        return KernelCompile()
    measures = {"triangle_measure": options.triangle_measure, "quad_measure": options.quad_measure,
                "merge": options.merge, "surface": options.surface}
    key = json.dumps(measures, sort_keys=True)
    running = [p for p in _STARTED.get(key, []) if p.poll() is None]
    if running:
        return KernelCompile(running)
    parts = [part for part in MESH_KERNEL_PARTS if part != "smooth" or options.surface == "smooth"]
    processes = []
    for part in parts:
        try:
            processes.append(subprocess.Popen([sys.executable, "-c", _CHILD, key, part], stdin=subprocess.DEVNULL,
                                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        except OSError:  # no process to spare: the tiles compile the rest
            break
    _STARTED[key] = processes
    return KernelCompile(processes)
