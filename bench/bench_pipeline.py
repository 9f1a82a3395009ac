"""Pipeline benchmarks; prints tables (run by hand).

    python bench/bench_pipeline.py throughput [--points 20000000] [--files 10]
    python bench/bench_pipeline.py memory [--small 5000000] [--large 50000000]

throughput: an all-ground synthetic LAZ archive to DEM + mesh, time per stage.
memory: peak RSS of a whole run (a fresh process each) on two archive sizes.
Archives are generated once into --cache (default /tmp/terrain-bench).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from pipeline.synthetic import SurveySpec, write_survey


def archive(cache: Path, points: int, files: int) -> Path:
    folder = cache / f"ground_{points}_{files}"
    done = folder / ".complete"
    if not done.exists():
        side = (points / 8.0) ** 0.5  # 8 points per square metre
        spec = SurveySpec(
            points=points, files=files, width=side, height=side, ground_share=1.0,
            withheld_share=0.0, duplicate_share=0.0, seed=1, overlap=0.0,
        )
        t0 = time.perf_counter()
        write_survey(folder, spec)
        done.write_text("ok")
        print(f"wrote {points:,} points in {files} LAZ files in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return folder


_RUN = textwrap.dedent(
    """
    import json, resource, sys, time
    from pipeline import RunConfig, run
    cfg = RunConfig(inputs=(sys.argv[1],), output=sys.argv[2], resolution=1.0, overwrite=True)
    t0 = time.perf_counter()
    report = run(cfg, progress=False)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"wall": wall, "peak": peak, "report": report.to_dict()}))
    """
)


def run_once(folder: Path, out: Path) -> dict:
    res = subprocess.run([sys.executable, "-c", _RUN, str(folder), str(out)], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(res.stderr)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["throughput", "memory"])
    parser.add_argument("--points", type=int, default=20_000_000)
    parser.add_argument("--files", type=int, default=10)
    parser.add_argument("--small", type=int, default=5_000_000)
    parser.add_argument("--large", type=int, default=50_000_000)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/terrain-bench"))
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    if args.what == "throughput":
        folder = archive(args.cache, args.points, args.files)
        res = run_once(folder, args.cache / "out.zarr")
        rep = res["report"]
        print(f"\n{args.points:,} points, {args.files} LAZ files -> DEM + mesh")
        print(f"{'stage':12} {'seconds':>8}")
        for stage, sec in rep["stages"].items():
            print(f"{stage:12} {sec:8.2f}")
        print(f"{'wall':12} {res['wall']:8.2f}   ({args.points / res['wall'] / 1e6:.2f} M points/s)")
        print(f"tiles {rep['tiles']}, faces {rep['faces']:,}, quads {100 * rep['quad_share']:.1f} %, peak RSS {res['peak'] / 2**30:.2f} GiB")
    else:
        rows = []
        for n in (args.small, args.large):
            folder = archive(args.cache, n, max(1, n // 2_000_000))
            res = run_once(folder, args.cache / f"mem_{n}.zarr")
            rows.append((n, res["peak"], res["wall"]))
        print(f"\n{'points':>12} {'peak RSS GiB':>13} {'wall s':>8}")
        for n, peak, wall in rows:
            print(f"{n:12,} {peak / 2**30:13.2f} {wall:8.1f}")
        print(f"ratio large/small: {rows[1][1] / rows[0][1]:.2f}")


if __name__ == "__main__":
    main()
