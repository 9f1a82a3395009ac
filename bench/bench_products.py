"""What the products cost: a DTM-only run, a run with every new layer, and
Whitebox Workflows' DTM plus DSM, on the same file (run by hand).

    python bench/bench_products.py [--file ../shared/data/extra_byte_blocks_lambert93.laz] [--forest N] [--repeat 5]

Jobs, each a fresh process as a user starts it, interleaved, medians, start-up
included:

- ``terrain run FILE --resolution 0.5`` (the DTM and the mesh);
- the same with ``--layers dsm,chm,intensity,density,ground_density``;
- Whitebox Workflows' ``lidar_tin_gridding`` of the ground (its DTM) then
  ``lidar_digital_surface_model`` (its DSM) at 0.5 m, in one process
  (``pip install -e ".[bench]"``).

``--forest N`` also writes a synthetic forested survey of N points (trees,
buildings, about a third of the points ground) and measures it the same way.
The table gives the median, the peak resident memory of the job's process,
and the ratios the issue asks for: products against the DTM-only run and
against Whitebox's DTM + DSM.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from bench_mesh import compile_bytecode, table

HERE = Path(__file__).resolve().parents[1]
SHARED = HERE.parent / "shared" / "data"
LAYERS = "dsm,chm,intensity,density,ground_density"

_WHITEBOX = textwrap.dedent(
    """
    import sys
    from whitebox_workflows import WbEnvironment
    wbe = WbEnvironment()
    wbe.verbose = False
    res = float(sys.argv[3])
    dtm = wbe.lidar.interpolation_gridding.lidar_tin_gridding(input=sys.argv[1], resolution=res,
        interpolation_parameter="elevation", returns_included="all", excluded_classes=[c for c in range(256) if c != 2])
    wbe.write_raster(dtm, sys.argv[2] + "_dtm.tif")
    dsm = wbe.lidar.lidar_digital_surface_model(input=sys.argv[1], resolution=res)
    wbe.write_raster(dsm, sys.argv[2] + "_dsm.tif")
    """
)


def _timed(cmd: list[str]) -> tuple[float, float]:
    """Seconds and peak resident memory (MiB) of one fresh process."""
    t0 = time.perf_counter()
    # this checkout's pipeline, whatever the environment has installed
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=HERE, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode})")
    return seconds, usage.ru_maxrss / 1024.0


def measure(path: Path, repeat: int, resolution: float) -> list[list[str]]:
    compile_bytecode(HERE)
    with tempfile.TemporaryDirectory() as tmp:
        base = [sys.executable, "-m", "pipeline.cli", "run", str(path), "--resolution", str(resolution), "--overwrite", "-q"]
        jobs = {
            "terrain DTM": base + ["-o", f"{tmp}/dtm.zarr"],
            f"terrain DTM + {LAYERS}": base + ["-o", f"{tmp}/all.zarr", "--layers", LAYERS],
            "Whitebox DTM + DSM": [sys.executable, "-c", _WHITEBOX, str(path), f"{tmp}/wb", str(resolution)],
        }
        for cmd in jobs.values():
            _timed(cmd)  # kernels compiled, the file in the page cache
        runs: dict[str, list[tuple[float, float]]] = {name: [] for name in jobs}
        for _ in range(repeat):
            for name, cmd in jobs.items():
                runs[name].append(_timed(cmd))
    median = {name: statistics.median(t for t, _ in r) for name, r in runs.items()}
    dtm, products, whitebox = median.values()
    rows = []
    for name, r in runs.items():
        rows.append([f"{path.name}: {name}", f"{median[name]:.2f} s", f"{max(m for _, m in r):.0f} MiB",
                     f"{median[name] / dtm:.2f}x", f"{median[name] / whitebox:.2f}x"])
    rows.append([f"{path.name}: products / DTM-only, / Whitebox", "", "", f"{products / dtm:.2f}x",
                 f"{products / whitebox:.2f}x"])
    return rows


def forest(folder: Path, points: int) -> Path:
    """A forested survey: many trees, a few buildings, about a third ground."""
    from pipeline.tools.synthetic import SurveySpec, write_survey

    side = (points / 8.0) ** 0.5  # 8 points a square metre
    spec = SurveySpec(points=points, files=1, width=side, height=side, overlap=0.0, ground_share=0.3, lake=None,
                      buildings=30, trees=int(side * side / 60.0), seed=41)
    return write_survey(folder, spec)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--file", type=Path, default=SHARED / "extra_byte_blocks_lambert93.laz")
    parser.add_argument("--forest", type=int, default=0, help="also a synthetic forest of this many points")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--resolution", type=float, default=0.5)
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    rows = measure(args.file, args.repeat, args.resolution) if args.file.exists() else []
    if args.forest:
        with tempfile.TemporaryDirectory() as tmp:
            rows += measure(forest(Path(tmp), args.forest), args.repeat, args.resolution)
    table(f"{args.repeat} runs each, interleaved, medians, start-up included",
          ["job", "median", "peak RSS", "vs DTM-only", "vs Whitebox DTM+DSM"], rows)


if __name__ == "__main__":
    main()
