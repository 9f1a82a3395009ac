"""Object storage against local disk: the same run, side by side; prints tables (run by hand).

    python bench/bench_object_storage.py [--points 2000000] [--files 4] [--repeat 3]

A real S3 protocol server (moto's ``moto_server``) on 127.0.0.1 holds a copy of
a synthetic survey.  ``terrain run`` reads it and writes its store

* local: from the local files into a local store;
* s3: from ``s3://`` into an ``s3://`` store (the work folder stays local);

interleaved, ``--repeat`` times each, in fresh processes; the table gives
median wall times and the bytes that crossed the loopback interface during
the s3 runs (requests and answers, both ways) against the survey's size.
Then a COPC copy of the survey: for each tile of a 4 x 4 grid over it, the
bytes a window read fetches from s3 (headers, hierarchy and nodes) against
the bytes of the octree nodes the tile needs.
Last, one s3 run whose server is stopped part way: its exit code, message, and
whether anything was marked complete.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1]))

from bench_mesh import table  # noqa: E402
from tests.pipeline.s3server import start_s3_server  # noqa: E402

from pipeline.synthetic import SurveySpec, write_survey  # noqa: E402

TERRAIN = str(Path(sys.executable).parent / "terrain")


def loopback_bytes() -> int:
    """Bytes received on the loopback interface so far (each byte sent there is received once)."""
    for line in Path("/proc/net/dev").read_text().splitlines():
        name, _, rest = line.partition(":")
        if name.strip() == "lo":
            return int(rest.split()[0])
    return 0


def copc_table(server, folder: Path, cache: Path) -> None:
    """Bytes fetched per tile window of a COPC on s3 against the bytes of the nodes it needs."""
    import laspy
    import numpy as np

    from pipeline import layout, sources, urls
    from tests.pipeline.copc_files import nodes_meeting, write_copc

    copc = cache / f"{folder.name}.copc.laz"
    if not copc.exists():
        parts = [laspy.read(p) for p in sorted(folder.glob("*.laz"))]
        x, y, z, c = (np.concatenate([np.asarray(getattr(p, a)) for p in parts]) for a in ("x", "y", "z", "classification"))
        partial = copc.with_name(f".{copc.name}")
        write_copc(partial, x, y, z, c, depth=6)
        partial.rename(copc)
    fs = server.filesystem()
    fs.put_file(str(copc), "bench/survey.copc.laz")
    urls.use_storage_options({"key": server.key, "secret": server.secret, "endpoint_url": server.endpoint})
    header = laspy.open(str(copc)).header
    (x0, y0, _), (x1, y1, _) = header.mins, header.maxs
    caches = []
    real_open = urls.open_input

    def counted(where, block_size=urls.HEADER_BLOCK):
        handle = real_open(where, block_size)
        caches.append(handle.cache)
        return handle

    sources.open_input = layout.open_input = counted  # every open of the inputs layer, headers included
    rows = []
    try:
        ratios = []
        for r in range(4):
            for c in range(4):
                window = (x0 + (x1 - x0) * c / 4, y0 + (y1 - y0) * r / 4, x0 + (x1 - x0) * (c + 1) / 4,
                          y0 + (y1 - y0) * (r + 1) / 4)
                caches.clear()
                for _ in sources.iter_points("s3://bench/survey.copc.laz", sources.PointFilter(classes=None),
                                             window=window):
                    pass
                fetched = sum(cache.total_requested_bytes for cache in caches)
                needed, _ = nodes_meeting(copc, window)
                ratios.append(fetched / needed)
        rows.append([f"{copc.stat().st_size / 2**20:.1f}", "16", f"{statistics.median(ratios):.2f}x",
                     f"{max(ratios):.2f}x"])
    finally:
        sources.open_input = layout.open_input = real_open
        urls.use_storage_options(None)
    table("COPC on s3, a window read per tile of a 4 x 4 grid: bytes fetched / bytes of the nodes needed",
          ["COPC MiB", "tiles", "median", "worst"], rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--files", type=int, default=4)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/terrain-bench"))
    args = parser.parse_args()

    folder = args.cache / f"s3_{args.points}_{args.files}"
    if not (folder / ".complete").exists():
        side = (args.points / 8.0) ** 0.5
        write_survey(folder, SurveySpec(points=args.points, files=args.files, width=side, height=side, seed=3))
        (folder / ".complete").write_text("ok")
    files = sorted(folder.glob("*.laz"))
    size = sum(p.stat().st_size for p in files)
    server = start_s3_server()
    try:
        fs = server.filesystem()
        fs.mkdir("bench")
        for p in files:
            fs.put_file(str(p), f"bench/survey/{p.name}")
        env = server.env()
        common = ["--resolution", "1", "--no-progress", "-q", "--overwrite"]
        runs = {
            "local": [TERRAIN, "run", str(folder), "-o", str(args.cache / "s3bench-local.zarr"), *common],
            "s3": [TERRAIN, "run", "s3://bench/survey/", "-o", "s3://bench/out.zarr", *common],
        }
        times: dict[str, list[float]] = {k: [] for k in runs}
        traffic: list[int] = []
        for _ in range(args.repeat):
            for name, command in runs.items():
                before = loopback_bytes()
                t0 = time.perf_counter()
                done = subprocess.run(command, env=env, capture_output=True, text=True)
                times[name].append(time.perf_counter() - t0)
                if done.returncode:
                    raise SystemExit(f"{name}: exit {done.returncode}: {done.stderr}")
                if name == "s3":
                    traffic.append(loopback_bytes() - before)
        local, remote = statistics.median(times["local"]), statistics.median(times["s3"])
        stored = fs.du("bench/out.zarr")
        moved = statistics.median(traffic)
        table(
            f"{args.points:,} points in {args.files} LAZ files ({size / 2**20:.1f} MiB), median of {args.repeat}",
            ["run", "wall s", "vs local", "loopback MiB", "store MiB", "rest / survey"],
            [
                ["local -> local", f"{local:.2f}", "1.00x", "-", "-", "-"],
                ["s3 -> s3", f"{remote:.2f}", f"{remote / local:.2f}x", f"{moved / 2**20:.1f}",
                 f"{stored / 2**20:.1f}", f"{(moved - stored) / size:.2f}x"],
            ],
        )
        print("rest: what crossed loopback beyond the store's bytes (the inputs read, requests, listings)")

        copc_table(server, folder, args.cache)

        # the server stopped part way through a run
        job = subprocess.Popen([*runs["s3"]], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(max(1.0, remote * 0.4))
        server.stop()
        t0 = time.perf_counter()
        out, err = job.communicate(timeout=600)
        print(f"\nserver stopped {max(1.0, remote * 0.4):.1f} s into an s3 run: exit {job.returncode} "
              f"{time.perf_counter() - t0:.1f} s later; stderr:\n{err.strip()}")
    finally:
        server.stop()


if __name__ == "__main__":
    main()
