"""Benchmarks of the meshcore engine; prints tables (run by hand).

    python bench/bench_mesh.py [--sizes 100000 1000000 4000000] [--repeat 3] [--rounds 5]

1. build_mesh(xy, "s3", "s4") against Triangle (plain Delaunay, ``-Q``) and
   scipy's Qhull on the same uniform points, side by side in one run; medians.
2. rasterize of a 1M-point combined mesh to 1000 x 1000 cells against scipy's
   LinearNDInterpolator evaluating the same grid (its triangulation excluded):
   the first call of a fresh interpolator (which also computes the per-simplex
   transforms it then caches) and a warm repeated call.
3. Peak memory of build_mesh per input point (a fresh process per size; the
   kernel's peak resident set is reset right before the call).
4. Start-up: the first process compiles the kernels and fills the cache, the
   second loads them from it; and the whole first ``terrain demo`` against
   its second run, in ``--rounds`` rounds (each with an empty cache), medians.
5. Where the time goes: build_mesh of a tile-sized piece (0.5M points, a
   window over all but a 5 m border, as the pipeline builds its tiles), time
   per kernel from the profiler, in nanoseconds per point; median of the runs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

import meshcore


def median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def compile_bytecode(root: Path) -> None:
    """Write the bytecode of ``root``'s packages, as an install or a first
    import does: where ``PYTHONDONTWRITEBYTECODE`` is set (this machine's
    environment sets it), every run of the command would compile each module
    whose cached bytecode is stale from its source again, 0.1 s of the start
    of a run after a few modules were edited."""
    import compileall

    for package in ("pipeline", "meshcore"):
        compileall.compile_dir(str(root / package), quiet=1)


def table(title: str, header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    print(f"\n{title}")
    print("  ".join(h.rjust(w) for h, w in zip(header, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))


def bench_build(sizes: list[int], repeat: int) -> None:
    import triangle
    from scipy.spatial import Delaunay

    rows = []
    rng = np.random.default_rng(1)
    meshcore.build_mesh(rng.random((1000, 2)), "s3", "s4")  # compile outside the timings
    for n in sizes:
        xy = rng.random((n, 2))
        # interleaved, so that drift of the shared machine hits every code alike
        runs: dict[str, list[float]] = {"ours": [], "dt": [], "tri": []}
        for _ in range(repeat):
            runs["ours"].append(median_time(lambda: meshcore.build_mesh(xy, "s3", "s4"), 1))
            runs["tri"].append(median_time(lambda: triangle.triangulate({"vertices": xy}, "Q"), 1))
            runs["dt"].append(median_time(lambda: meshcore.build_mesh(xy, "delaunay", None), 1))
        ours, tri, ours_dt = (statistics.median(runs[k]) for k in ("ours", "tri", "dt"))
        qhull = median_time(lambda: Delaunay(xy), 1) if n <= 1_000_000 else float("nan")
        rows.append(
            [
                f"{n:,}",
                f"{ours:.3f}",
                f"{ours_dt:.3f}",
                f"{tri:.3f}",
                f"{qhull:.3f}",
                f"{ours / tri:.2f}",
            ]
        )
    table(
        f"build_mesh vs Triangle (median of {repeat}; seconds)",
        ["points", "s3+s4", "delaunay only", "Triangle", "Qhull", "s3+s4 / Triangle"],
        rows,
    )


def bench_rasterize(repeat: int) -> None:
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(2)
    n = 1_000_000
    xy = rng.random((n, 2)) * 1000.0
    z = np.sin(xy[:, 0] / 80.0) * np.cos(xy[:, 1] / 120.0) * 20.0
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zv = np.empty(len(mesh.vertices))
    zv[mesh.input_to_vertex] = z
    meshcore.rasterize(mesh, zv, 0.0, 0.0, 100.0, 10, 10)  # compile
    ours = median_time(lambda: meshcore.rasterize(mesh, zv, 0.0, 0.0, 1.0, 1000, 1000), repeat)
    centres = (np.arange(1000) + 0.5) * 1.0
    gx, gy = np.meshgrid(centres, centres)
    first_calls = []
    for _ in range(repeat):
        # a fresh triangulation each time, built outside the timer; the first
        # evaluation also computes scipy's per-simplex barycentric transforms
        interp = LinearNDInterpolator(Delaunay(xy), z)
        t0 = time.perf_counter()
        interp(gx, gy)
        first_calls.append(time.perf_counter() - t0)
    first = statistics.median(first_calls)
    warm = median_time(lambda: interp(gx, gy), repeat)
    table(
        f"rasterize 1000 x 1000 of a 1M-point mesh (median of {repeat}; seconds)",
        ["meshcore.rasterize", "scipy first call", "scipy warm call", "vs first", "vs warm"],
        [[f"{ours:.3f}", f"{first:.3f}", f"{warm:.3f}", f"{first / ours:.1f}x", f"{warm / ours:.1f}x"]],
    )


_MEMORY_PROBE = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import meshcore

    def rss(field):
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field):
                    return int(line.split()[1]) * 1024
    n = int(sys.argv[1])
    meshcore.build_mesh(np.random.default_rng(0).random((1000, 2)), "s3", "s4")
    xy = np.random.default_rng(3).random((n, 2))
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    base = rss("VmRSS:")
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    peak = rss("VmHWM:")
    print(json.dumps({"n": n, "peak_bytes": peak - base}))
    """
)


def bench_memory(sizes: list[int]) -> None:
    rows = []
    for n in sizes:
        out = subprocess.run(
            [sys.executable, "-c", _MEMORY_PROBE, str(n)], capture_output=True, text=True, check=True
        )
        res = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append([f"{n:,}", f"{res['peak_bytes'] / 2**20:.1f}", f"{res['peak_bytes'] / n:.0f}"])
    table("peak memory of build_mesh(xy, 's3', 's4') above the input", ["points", "MiB", "bytes/point"], rows)


_STARTUP_PROBE = textwrap.dedent(
    """
    import time
    t0 = time.perf_counter()
    import numpy as np
    import meshcore
    xy = np.random.default_rng(0).random((1000, 2))
    mesh = meshcore.build_mesh(xy, "s3", "s4")
    zv = np.zeros(len(mesh.vertices))
    meshcore.rasterize(mesh, zv, 0.0, 0.0, 0.1, 10, 10)
    meshcore.interpolate(mesh, zv, [0.5], [0.5])
    meshcore.validate(mesh)
    print(time.perf_counter() - t0)
    """
)


def bench_startup(rounds: int) -> None:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        runs = []
        for _ in range(3):
            out = subprocess.run(
                [sys.executable, "-c", _STARTUP_PROBE], capture_output=True, text=True, check=True, env=env
            )
            runs.append(float(out.stdout.strip().splitlines()[-1]))
    table(
        "start-up: import + first build_mesh/rasterize/interpolate/validate (seconds)",
        ["first process (compile + cache)", "second process (cached)", "third process (cached)"],
        [[f"{runs[0]:.2f}", f"{runs[1]:.2f}", f"{runs[2]:.2f}"]],
    )
    # the whole first job: `terrain demo` with an empty kernel cache, then
    # again with the cache it filled; rounds interleaved, medians
    terrain = Path(sys.executable).with_name("terrain")
    rows = []
    for _ in range(rounds):
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            walls = []
            for _ in range(2):
                t0 = time.perf_counter()
                subprocess.run([str(terrain), "demo", "--out", out, "--quiet"], capture_output=True, check=True, env=env)
                walls.append(time.perf_counter() - t0)
        rows.append([walls[0], walls[1], walls[0] - walls[1]])
    medians = [statistics.median(column) for column in zip(*rows)]
    table(
        f"terrain demo, wall seconds (kernels compiled by the first run; {rounds} rounds, load {_load()})",
        ["round", "first run (empty cache)", "second run (cached)", "compiling (difference)"],
        [[str(k + 1), *(f"{v:.2f}" for v in row)] for k, row in enumerate(rows)]
        + [["median", *(f"{v:.2f}" for v in medians)]],
    )


def _load() -> str:
    """The machine's load average over the last minute, and its cores."""
    try:
        return f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"
    except OSError:
        return "unknown"


def bench_passes(repeat: int, n: int = 500_000) -> None:
    import cProfile
    import pstats

    rng = np.random.default_rng(2)
    side = (n / 8.0) ** 0.5  # 8 points per square metre, survey coordinates on a 1 cm lattice
    xy = np.round(rng.random((n, 2)) * side + [651000.0, 6861000.0], 2)
    window = (651005.0, 6861005.0, 651000.0 + side - 5.0, 6861000.0 + side - 5.0)

    def build() -> None:
        meshcore.build_mesh(xy, "s3", "s4", window=window, known=window)

    build()  # compile outside the timings
    per_run: list[dict[str, float]] = []
    for _ in range(repeat):
        profile = cProfile.Profile()
        profile.enable()
        build()
        profile.disable()
        stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
        times: dict[str, float] = {}
        for (path, _, name), (_, _, own, total, _) in stats.items():
            if name == "build_mesh":
                times["build_mesh (total)"] = total
            elif path.endswith(".py") and "meshcore" in path:
                times[name] = times.get(name, 0.0) + own
            elif name.startswith("<method 'argsort'"):
                times["argsort (numpy)"] = times.get("argsort (numpy)", 0.0) + own
        per_run.append(times)
    names = sorted({k for t in per_run for k in t}, key=lambda k: -statistics.median(t.get(k, 0.0) for t in per_run))
    total = statistics.median(t["build_mesh (total)"] for t in per_run)
    rows = []
    for name in names:
        sec = statistics.median(t.get(name, 0.0) for t in per_run)
        if sec * 1e9 / n >= 1.0:
            rows.append([name, f"{sec * 1e3:.1f}", f"{sec * 1e9 / n:.0f}", f"{100 * sec / total:.0f}%"])
    table(
        f"where build_mesh spends its time: {n:,} points, a tile's window (median of {repeat})",
        ["kernel", "ms", "ns/point", "share"],
        rows,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 1_000_000, 4_000_000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=5, help="rounds of the first and second demo runs (default 5)")
    parser.add_argument("--skip", nargs="*", default=[], choices=["build", "rasterize", "memory", "startup", "passes"])
    args = parser.parse_args()
    if "startup" not in args.skip:
        bench_startup(args.rounds)
    if "build" not in args.skip:
        bench_build(args.sizes, args.repeat)
    if "rasterize" not in args.skip:
        bench_rasterize(args.repeat)
    if "memory" not in args.skip:
        bench_memory(args.sizes)
    if "passes" not in args.skip:
        bench_passes(args.repeat)


if __name__ == "__main__":
    main()
