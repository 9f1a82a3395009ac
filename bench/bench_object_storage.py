"""Object storage against local disk: the same run, side by side; prints tables (run by hand).

    python bench/bench_object_storage.py [--points 2000000] [--files 4] [--repeat 3]

A real S3 protocol server (moto's ``moto_server``) on 127.0.0.1 holds a copy of
a synthetic survey.  ``terrain run`` reads it and writes its store

* local: from the local files into a local store;
* s3: from ``s3://`` into an ``s3://`` store (the work folder stays local);
* cluster: the same on a scheduler and two worker processes that share no
  disk (the work folder on s3, beside the store);

interleaved, ``--repeat`` times each, in fresh processes; the table gives
median wall times and the bytes that crossed the loopback interface during
the s3 runs (requests and answers, both ways) against the survey's size.
Then a COPC copy of the survey on s3, run with tiles that read it by window:
the bytes each tile task fetches (headers, hierarchy and nodes) against the
bytes of the octree nodes its window plus buffer needs.
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
from tests.pipeline.processes import stop_all  # noqa: E402
from tests.pipeline.s3server import start_s3_server  # noqa: E402

from pipeline.tools.synthetic import SurveySpec, write_survey  # noqa: E402

TERRAIN = str(Path(sys.executable).parent / "terrain")


def loopback_bytes() -> int:
    """Bytes received on the loopback interface so far (each byte sent there is received once)."""
    for line in Path("/proc/net/dev").read_text().splitlines():
        name, _, rest = line.partition(":")
        if name.strip() == "lo":
            return int(rest.split()[0])
    return 0


def start_cluster(env: dict[str, str], root: Path) -> tuple[list[subprocess.Popen], str]:
    """A ``dask scheduler`` and two single-threaded ``dask worker`` processes on
    loopback, each worker in a folder of its own (no shared disk)."""
    import json
    import shutil

    from distributed import Client

    shutil.rmtree(root, ignore_errors=True)
    root.mkdir(parents=True)
    dask = str(Path(sys.executable).parent / "dask")
    info = root / "scheduler.json"
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", ":0",
                               "--scheduler-file", str(info)], env=env, cwd=root,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    while not info.exists():
        time.sleep(0.2)
    address = json.loads(info.read_text())["address"]
    for k in range(2):
        home = root / f"worker-{k}"
        (home / "tmp").mkdir(parents=True)
        procs.append(subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-dashboard"],
                                      env={**env, "TMPDIR": str(home / "tmp")}, cwd=home,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    with Client(address, timeout="30s") as client:
        client.wait_for_workers(2, timeout=60)
    return procs, address


def copc_table(server, folder: Path, cache: Path, tile_size: float) -> None:
    """A run over a COPC on s3, tiles reading it by window: the bytes each tile
    task fetches against the bytes of the octree nodes its window plus buffer
    needs, and what the hull pass and the whole run fetch against the file."""
    import threading

    import laspy
    import numpy as np
    import zarr

    from pipeline import urls
    from pipeline.inputs import layout
    from pipeline.inputs import sources
    from pipeline.meshing import tiles
    from pipeline.config import RunConfig
    from pipeline.runs.runner import run
    from pipeline.tiling.grid import TileGrid
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
    fetched: dict[int, int] = {}
    per_tile: dict[tuple[int, int], int] = {}
    real_open, real_points = urls.open_input, tiles.tile_points

    def counted(where, block_size=urls.HEADER_BLOCK):
        handle = real_open(where, block_size)
        me, close = threading.get_ident(), handle.close

        def closed():
            fetched[me] = fetched.get(me, 0) + handle.cache.total_requested_bytes
            close()
        handle.close = closed
        return handle

    def tile_points(scratch, windows, grid, buffer, row, col, box):
        me = threading.get_ident()
        before = fetched.get(me, 0)
        out = real_points(scratch, windows, grid, buffer, row, col, box)
        per_tile[(row, col)] = fetched.get(me, 0) - before
        return out

    sources.open_input = layout.open_input = counted  # every open of the inputs layer, headers included
    tiles.tile_points = tile_points
    out = cache / "copc-s3.zarr"
    try:
        config = RunConfig(inputs=("s3://bench/survey.copc.laz",), output=str(out), resolution=1.0,
                           tile_size=tile_size, overwrite=True,
                           storage_options={"key": server.key, "secret": server.secret, "endpoint_url": server.endpoint})
        report = run(config, progress=False)
    finally:
        sources.open_input = layout.open_input = real_open
        tiles.tile_points = real_points
        urls.use_storage_options(None)
    provenance = zarr.open_group(str(out), mode="r").attrs["provenance"]
    grid, buffer = TileGrid.from_dict(provenance["grid"]), float(provenance["buffer"])
    ratios = []
    for (r, c), got in per_tile.items():
        needed, _ = nodes_meeting(copc, tiles.held_box(grid, r, c, buffer))
        ratios.append(got / needed)
    total = sum(fetched.values())
    size = copc.stat().st_size
    table(f"COPC on s3 ({size / 2**20:.1f} MiB, {report.tiles} tiles of {tile_size:g} m): bytes a tile task fetches "
          "/ bytes of the octree nodes its window plus buffer needs",
          ["tiles", "median", "worst", "whole run (hull pass, tiles, certification) / file"],
          [[f"{len(ratios)}", f"{statistics.median(ratios):.2f}x", f"{max(ratios):.2f}x", f"{total / size:.2f}x"]])
    print("a process keeps the file's header and hierarchy pages: its later tiles fetch node bytes only")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--files", type=int, default=4)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/terrain-bench"))
    parser.add_argument("--copc-tile-size", type=float, default=128.0)
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
        cluster, address = start_cluster(env, args.cache / "machines")
        common = ["--resolution", "1", "--no-progress", "-q", "--overwrite"]
        runs = {
            "local": [TERRAIN, "run", str(folder), "-o", str(args.cache / "s3bench-local.zarr"), *common],
            "s3": [TERRAIN, "run", "s3://bench/survey/", "-o", "s3://bench/out.zarr", *common],
            "cluster": [TERRAIN, "run", "s3://bench/survey/", "-o", "s3://bench/out-cluster.zarr", *common,
                        "--scheduler", address],
        }
        times: dict[str, list[float]] = {k: [] for k in runs}
        traffic: list[int] = []
        traffic_cluster: list[int] = []
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
                if name == "cluster":
                    traffic_cluster.append(loopback_bytes() - before)
        local, remote = statistics.median(times["local"]), statistics.median(times["s3"])
        clustered = statistics.median(times["cluster"])
        stored = fs.du("bench/out.zarr")
        moved = statistics.median(traffic)
        table(
            f"{args.points:,} points in {args.files} LAZ files ({size / 2**20:.1f} MiB), median of {args.repeat}",
            ["run", "wall s", "vs local", "loopback MiB", "store MiB", "rest / survey"],
            [
                ["local -> local", f"{local:.2f}", "1.00x", "-", "-", "-"],
                ["s3 -> s3", f"{remote:.2f}", f"{remote / local:.2f}x", f"{moved / 2**20:.1f}",
                 f"{stored / 2**20:.1f}", f"{(moved - stored) / size:.2f}x"],
                ["s3 -> s3, 2 workers, work files on s3", f"{clustered:.2f}", f"{clustered / local:.2f}x",
                 f"{statistics.median(traffic_cluster) / 2**20:.1f}", f"{stored / 2**20:.1f}",
                 f"{(statistics.median(traffic_cluster) - stored) / size:.2f}x"],
            ],
        )
        stop_all(cluster)
        print("rest: what crossed loopback beyond the store's bytes (the inputs read, requests, listings)")

        copc_table(server, folder, args.cache, args.copc_tile_size)

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
