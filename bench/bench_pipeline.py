"""Pipeline benchmarks; prints tables (run by hand).

    python bench/bench_pipeline.py throughput [--points 20000000] [--files 10] [--repeat 3]
    python bench/bench_pipeline.py memory [--small 5000000] [--large 50000000]
    python bench/bench_pipeline.py seams [--points 4000000] [--tile-size 256]
    python bench/bench_pipeline.py certify [--tile-sizes 10,20,50]
    python bench/bench_pipeline.py surface [--repeat 3] [--points 2000000 (0: none)] [--samples a.laz,b.las]

throughput: three synthetic LAZ archives to DEM + mesh, side by side (runs
    interleaved, medians): "flown" (all ground, strips, points in flight
    order, default tiles), "tiles" (all ground, adjacent 1 km tiles, points in
    random order, --tile-size 500) and "town" (the flown extent with buildings,
    tree crowns and a lake cut out of its ground, default tiles).  Each run's wall time against decoding the same archive
    on one core (measured here before and after the runs), CPU/wall, peak RSS
    and time per stage.  The real samples in ../shared/data, when present, are
    decoded too, to show that the archives decode as real files do.
memory: peak RSS of a whole run (a fresh process each) on two archive sizes.
seams: the same archive tiled and untiled: share of identical faces and DEM cells.
surface: --surface smooth against linear, whole runs side by side (interleaved,
    in turns first and second, medians) on the real samples with ground and a
    2M-point flown archive.
certify: the real samples with ground (../shared/data) at several tile sizes:
    every tile certifies, and what that costs: the points each tile reads
    beyond its buffer against the points it holds (median and worst tile).
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

from pipeline.tools.synthetic import SurveySpec, write_survey


def archive(cache: Path, points: int, files: int) -> Path:
    # "flown": points in flight order with a pulse's attributes (older caches
    # held points in random order with constant attributes: not comparable)
    folder = cache / f"flown_{points}_{files}"
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
    tile = float(sys.argv[3]) if len(sys.argv) > 3 and sys.argv[3] != "auto" else None
    surface = sys.argv[4] if len(sys.argv) > 4 else "linear"
    resolution = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
    cfg = RunConfig(inputs=(sys.argv[1],), output=sys.argv[2], resolution=resolution, tile_size=tile, overwrite=True,
                    surface=surface)
    import pipeline.runs.runner
    stage_cpu = {}  # CPU and wall seconds of each stage's tasks, by their progress label
    mapped = pipeline.runs.runner.map_tasks

    def timed(client, fn, items, progress, *args, **kwargs):
        c0, w0 = time.process_time(), time.perf_counter()
        try:
            return mapped(client, fn, items, progress, *args, **kwargs)
        finally:
            seen = stage_cpu.setdefault(progress.label, [0.0, 0.0])
            seen[0] += time.process_time() - c0
            seen[1] += time.perf_counter() - w0

    pipeline.runs.runner.map_tasks = timed
    t0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_SELF)
    report = run(cfg, progress=False)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = c1.ru_utime - c0.ru_utime + c1.ru_stime - c0.ru_stime
    peak = c1.ru_maxrss * 1024
    print(json.dumps({"wall": wall, "cpu": cpu, "peak": peak, "report": report.to_dict(), "stage_cpu": stage_cpu}))
    """
)


def tiled_archive(cache: Path, points: int, files: int) -> Path:
    """The second shape: all-ground points in adjacent 1 km tiles (two rows),
    in random order inside each file, as a tiled delivery of a survey is cut."""
    import laspy
    import numpy as np

    from pipeline.tools.synthetic import terrain_height

    folder = cache / f"tiles_{points}_{files}"
    done = folder / ".complete"
    if done.exists():
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2)
    per = points // files
    for k in range(files):
        x0, y0 = 650_000.0 + 1000.0 * (k // 2), 6_860_000.0 + 1000.0 * (k % 2)
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([x0, y0, 0.0])
        header.add_crs(__import__("pyproj").CRS.from_epsg(2154))
        las = laspy.LasData(header)
        x, y = x0 + rng.random(per) * 1000.0, y0 + rng.random(per) * 1000.0
        las.x, las.y, las.z = x, y, terrain_height(x, y, (650_000.0, 6_860_000.0))
        las.classification = np.full(per, 2, dtype=np.uint8)
        las.write(folder / f"tile_{k:02d}.laz")
    done.write_text("ok")
    return folder


def town_archive(cache: Path, points: int, files: int) -> Path:
    """The third shape: the flown archive's extent and density with a survey's
    voids in its ground: a village of 60 buildings (roofs, no ground beneath),
    300 tree crowns (some pulses reach the ground), a lake that returns
    nothing, and 20% of the other points off the ground; strips of points in
    random order.  A tile next to a void holds more before its faces are
    proved, and flips there last more rounds."""
    folder = cache / f"town_{points}_{files}"
    done = folder / ".complete"
    if not done.exists():
        side = (points / 8.0) ** 0.5
        spec = SurveySpec(
            points=points, files=files, width=side, height=side, ground_share=0.8, withheld_share=0.0,
            duplicate_share=0.0, seed=3, overlap=0.0, buildings=60, trees=300, lake=(0.7 * side, 0.3 * side, 0.04 * side),
        )
        t0 = time.perf_counter()
        write_survey(folder, spec)
        done.write_text("ok")
        print(f"wrote {points:,} points in {files} LAZ files in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return folder


def run_once(folder: Path, out: Path, tile_size: float | None = None, surface: str = "linear",
             resolution: float = 1.0) -> dict:
    tile = "auto" if tile_size is None else str(tile_size)
    res = subprocess.run([sys.executable, "-c", _RUN, str(folder), str(out), tile, surface, str(resolution)],
                         capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(res.stderr)
    return json.loads(res.stdout.strip().splitlines()[-1])


#: the issue's yardstick: LAZ decoding alone runs at about this many points per second on one core
ANCHOR_DECODE_RATE = 3.3e6


#: the real samples (see their README), decoded beside the archive
REAL_SAMPLES = Path(__file__).resolve().parents[2] / "shared" / "data"


def decode_rate(folder: Path, repeat: int = 1) -> float:
    """Points per second of decoding every LAZ file in ``folder`` on one core
    (lazrs without threads), the fields a run reads: x, y, z, classification
    and flags (LAS 1.4 layered points decode only those): how fast this
    machine is, right now."""
    import laspy

    selection = laspy.DecompressionSelection.base().decompress_z().decompress_classification().decompress_flags()
    points = 0
    t0 = time.perf_counter()
    for path in sorted(folder.glob("*.laz")) * repeat:
        with laspy.open(path, laz_backend=laspy.LazBackend.Lazrs, decompression_selection=selection) as reader:
            for chunk in reader.chunk_iterator(2_000_000):
                points += len(chunk)
    return points / (time.perf_counter() - t0)


def seams(folder: Path, cache: Path, tile_size: float) -> None:
    import numpy as np
    import xarray as xr

    from pipeline import RunConfig, run
    from pipeline.store import zarr_store as store

    stores = {}
    for name, size in (("tiled", tile_size), ("untiled", 65536.0)):
        out = cache / f"seams_{name}.zarr"
        rep = run(RunConfig(inputs=(str(folder),), output=str(out), resolution=1.0, tile_size=size, overwrite=True), progress=False)
        stores[name] = (out, rep)

    def face_keys(path):
        # faces start at their smallest corner (meshcore's canonical rotation),
        # so a face is the row of its corner coordinates
        xy, _, faces = store.read_mesh(path)
        corners = np.where(faces[..., None] >= 0, xy[np.maximum(faces, 0)], -np.inf).reshape(len(faces), 8)
        bits = np.ascontiguousarray(corners).view(np.uint64)
        mix = np.array([0x9E3779B97F4A7C15 * (k + 1) % 2**64 for k in range(8)], dtype=np.uint64)
        with np.errstate(over="ignore"):
            return np.bitwise_xor.reduce(bits * mix, axis=1)  # a 64-bit hash of the corner coordinates

    a, b = face_keys(stores["tiled"][0]), face_keys(stores["untiled"][0])
    ea = xr.open_zarr(stores["tiled"][0])["elevation"].values
    eb = xr.open_zarr(stores["untiled"][0])["elevation"].values
    rows = min(ea.shape[0], eb.shape[0])
    ea, eb = ea[-rows:], eb[-rows:]
    both = np.isfinite(ea) & np.isfinite(eb)
    print(f"\n{stores['tiled'][1].tiles} tiles of {tile_size:g} m vs one tile")
    print(f"faces identical      {np.isin(b, a).mean():.4%}  ({b.size:,} faces)")
    print(f"DEM cells identical  {(ea[both] == eb[both]).mean():.4%}  ({both.sum():,} cells)")

_CERTIFY = textwrap.dedent(
    """
    import json, sys, time
    import pipeline.runs.runner as runner
    from pipeline import RunConfig, run
    mesh_tile, log = runner.mesh_tile, sys.argv[4]

    def logged(job):
        s = mesh_tile(job)
        with open(log, "a") as f:
            f.write(json.dumps([s.points_held, s.points_loaded, s.expansions]) + "\\n")
        return s

    runner.mesh_tile = logged
    tile = float(sys.argv[3])
    cfg = RunConfig(inputs=(sys.argv[1],), output=sys.argv[2], resolution=tile / 4, tile_size=tile, overwrite=True)
    t0 = time.perf_counter()
    report = run(cfg, progress=False)
    print(json.dumps({"wall": time.perf_counter() - t0, "report": report.to_dict()}))
    """
)

GROUND_SAMPLES = (
    "ign_semis_lambert93.laz", "extra_byte_blocks_lambert93.laz", "autzen_trim.las",
    "startinpy_small_extrabytes.laz", "4_6_crop_us_feet.las",
)


def certify(cache: Path, tile_sizes: list[float], samples: tuple[str, ...] = GROUND_SAMPLES) -> None:
    """Whole real samples at each tile size: uncertified tiles (an error now,
    so a failed run), and the points read beyond the buffer per tile."""
    import numpy as np

    print(f"\n{'sample':34} {'tile':>5} {'tiles':>6} {'exit':>4} {'wall s':>7} {'rounds':>7} "
          f"{'median read/held':>17} {'worst read/held':>16} {'read/held, all':>15}")
    for name in samples:
        path = REAL_SAMPLES / name
        if not path.exists():
            continue
        for tile in tile_sizes:
            log = cache / "certify.jsonl"
            log.unlink(missing_ok=True)
            out = subprocess.run(
                [sys.executable, "-c", _CERTIFY, str(path), str(cache / "certify.zarr"), str(tile), str(log)],
                capture_output=True, text=True,
            )
            if not log.exists():
                print(f"{name:34} {tile:5g}  failed: " + (out.stderr.strip().splitlines() or ["?"])[-1])
                continue
            rows = np.array([json.loads(line) for line in log.read_text().splitlines()]).reshape(-1, 3)
            held, read, rounds = rows[:, 0], rows[:, 1], rows[:, 2]
            share = read / np.maximum(held, 1)
            wall = json.loads(out.stdout.splitlines()[-1])["wall"] if out.returncode == 0 else float("nan")
            print(f"{name:34} {tile:5g} {len(rows):6} {out.returncode:4} {wall:7.1f} {int(rounds.sum()):7} "
                  f"{np.median(share):17.1%} {share.max():16.1%} {read.sum() / max(held.sum(), 1):15.1%}")
            if out.returncode:
                print("   " + out.stderr.strip().splitlines()[-1])


def surfaces(cache: Path, repeat: int, points: int, samples: list[str]) -> None:
    """``--surface smooth`` against ``linear``: whole runs at the same resolution, interleaved, medians."""
    import statistics

    cases = [(name, REAL_SAMPLES / name, 0.5) for name in samples if (REAL_SAMPLES / name).is_file()]
    if points > 0:
        cases.append((f"flown {points:,}", archive(cache, points, max(1, points // 2_000_000)), 1.0))
    rows = []
    for label, path, resolution in cases:
        walls: dict[str, list[float]] = {"linear": [], "smooth": []}
        stages: dict[str, dict] = {}
        for k in range(repeat):
            # the order swapped every round: a run right after another is often
            # slower (by up to a tenth here), and always being second would count against it
            for surface in ("linear", "smooth")[:: 1 if k % 2 == 0 else -1]:
                res = run_once(path, cache / f"surface_{surface}.zarr", None, surface, resolution)
                walls[surface].append(res["wall"])
                stages[surface] = res["report"]["stages"]
        lin, smo = statistics.median(walls["linear"]), statistics.median(walls["smooth"])
        extra = ", ".join(f"{k} {stages['smooth'].get(k, 0.0) - stages['linear'].get(k, 0.0):+.1f}"
                          for k in ("variogram", "mesh", "dem"))
        rows.append((label, resolution, lin, smo, extra))
    print(f"\nwhole runs, DEM + mesh, median of {repeat} interleaved run(s) each")
    print(f"{'input':34} {'res':>5} {'linear s':>9} {'smooth s':>9} {'ratio':>6}  smooth - linear by stage (s)")
    for label, resolution, lin, smo, extra in rows:
        print(f"{label:34} {resolution:5g} {lin:9.2f} {smo:9.2f} {smo / lin:6.2f}  {extra}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["throughput", "memory", "seams", "certify", "surface"])
    parser.add_argument("--tile-sizes", default="10,20,50", help="certify: tile sizes in CRS units")
    parser.add_argument("--samples", default=",".join(GROUND_SAMPLES),
                        help="certify, surface: the samples (file names; empty for none)")
    parser.add_argument("--tile-size", type=float, default=256.0)
    parser.add_argument("--points", type=int, default=20_000_000)
    parser.add_argument("--files", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=1, help="throughput: runs (the median is shown)")
    parser.add_argument("--small", type=int, default=5_000_000)
    parser.add_argument("--large", type=int, default=50_000_000)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/terrain-bench"))
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    if args.what == "surface":
        surfaces(args.cache, args.repeat if "--repeat" in sys.argv else 3,
                 args.points if "--points" in sys.argv else 2_000_000, args.samples.split(",") if args.samples else [])
        return
    if args.what == "certify":
        certify(args.cache, [float(v) for v in args.tile_sizes.split(",")], tuple(args.samples.split(",")))
        return
    if args.what == "seams":
        n = args.points if "--points" in sys.argv else 4_000_000
        seams(archive(args.cache, n, max(1, n // 2_000_000)), args.cache, args.tile_size)
        return
    if args.what == "throughput":
        # both shapes side by side, runs interleaved: (name, folder, tile size)
        shapes = [("flown", archive(args.cache, args.points, args.files), None),
                  ("tiles", tiled_archive(args.cache, args.points, args.files), 500.0),
                  ("town", town_archive(args.cache, args.points, args.files), None)]
        decode = {name: [args.points / decode_rate(folder)] for name, folder, _ in shapes}
        real = decode_rate(REAL_SAMPLES, repeat=5) if any(REAL_SAMPLES.glob("*.laz")) else None
        runs: dict[str, list[dict]] = {name: [] for name, _, _ in shapes}
        for _ in range(args.repeat):
            for name, folder, tile in shapes:
                runs[name].append(run_once(folder, args.cache / f"out_{name}.zarr", tile))
        for name, folder, _ in shapes:
            decode[name].append(args.points / decode_rate(folder))  # the machine drifts: before and after
        print(f"\n{args.points:,} points, {args.files} LAZ files -> DEM + mesh; median of {args.repeat} run(s)")
        print(f"{'shape':6} {'decode s':>9} {'wall s':>7} {'x decode':>9} {'cpu/wall':>9} {'mesh cpu/wall':>14} "
              f"{'peak GiB':>9} {'tiles':>6} {'again':>6} {'expand':>6}  stages (s)")
        for name, _, _ in shapes:
            res = sorted(runs[name], key=lambda r: r["wall"])[len(runs[name]) // 2]
            dec = sum(decode[name]) / len(decode[name])
            stages = ", ".join(f"{k} {v:.1f}" for k, v in res["report"]["stages"].items() if k != "total")
            mesh_cpu, mesh_wall = res["stage_cpu"].get("mesh", [0.0, 1.0])
            rep = res["report"]
            print(f"{name:6} {dec:9.2f} {res['wall']:7.2f} {res['wall'] / dec:9.2f} {res['cpu'] / res['wall']:9.2f} "
                  f"{mesh_cpu / mesh_wall:14.2f} {res['peak'] / 2**30:9.2f} {rep['tiles']:6d} "
                  f"{rep['tiles_meshed_again']:6d} {rep['tile_expansions']:6d}  {stages}")
        if real is not None:
            print(f"the real LAZ samples decode here at {real / 1e6:.2f} M points/s ({real / ANCHOR_DECODE_RATE:.2f}x the yardstick)")
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
