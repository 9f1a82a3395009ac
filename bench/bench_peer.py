"""A one-file job against a peer, and the command line's start-up (run by hand).

    python bench/bench_peer.py whitebox [--file ../shared/data/extra_byte_blocks_lambert93.laz] [--repeat 7]
    python bench/bench_peer.py startup [--repeat 10]

whitebox: ``terrain run FILE -o x.zarr --resolution 0.5`` (default layers: the
    DEM and the mesh written) against Whitebox Workflows' TIN gridding of the
    same file's ground at 0.5 m to a GeoTIFF (``pip install -e ".[bench]"``).
    Each is a fresh process, as a user starts it, interleaved, medians; both
    cores free.  The two DEMs are compared where both have a value, as a check
    that both did the same job.
startup: ``terrain --help`` and ``terrain info FILE``, medians of fresh
    processes.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from bench_mesh import compile_bytecode, table

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
TERRAIN = Path(sys.executable).with_name("terrain")

_WHITEBOX = textwrap.dedent(
    """
    import sys
    from whitebox_workflows import WbEnvironment
    wbe = WbEnvironment()
    wbe.verbose = False
    # the ground only, as terrain run keeps by default
    dem = wbe.lidar.interpolation_gridding.lidar_tin_gridding(input=sys.argv[1], resolution=float(sys.argv[3]), interpolation_parameter="elevation",
        returns_included="all", excluded_classes=[c for c in range(256) if c != 2])
    wbe.write_raster(dem, sys.argv[2])
    """
)


def _timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _agreement(zarr_path: Path, tif: Path) -> str:
    """RMS and largest difference of the two DEMs at the cells both have."""
    import numpy as np
    import rasterio
    import xarray as xr

    ds = xr.open_zarr(zarr_path)
    ours = ds.elevation
    with rasterio.open(tif) as src:
        theirs = src.read(1, masked=True)
        t = src.transform
    ys = t.f + t.e * (np.arange(theirs.shape[0]) + 0.5)
    xs = t.c + t.a * (np.arange(theirs.shape[1]) + 0.5)
    # the peer's cells may sit half a cell from ours: each of its cells takes our nearest
    ours = ours.reindex(y=ys, x=xs, method="nearest", tolerance=t.a * 0.51).values
    both = np.isfinite(ours) & ~np.ma.getmaskarray(theirs)
    diff = ours[both] - theirs.data[both]
    return f"{both.sum():,} cells, RMS {np.sqrt(np.mean(diff**2)):.3f}, largest {np.abs(diff).max():.2f}"


def whitebox(path: Path, repeat: int, resolution: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out, tif = Path(tmp) / "x.zarr", Path(tmp) / "wb.tif"
        ours = [str(TERRAIN), "run", str(path), "-o", str(out), "--resolution", str(resolution), "--overwrite", "-q"]
        peer = [sys.executable, "-c", _WHITEBOX, str(path), str(tif), str(resolution)]
        _timed(ours), _timed(peer)  # the kernels compiled, the files in the page cache
        times: dict[str, list[float]] = {"terrain run (DEM + mesh)": [], "Whitebox lidar_tin_gridding": []}
        for _ in range(repeat):
            times["terrain run (DEM + mesh)"].append(_timed(ours))
            times["Whitebox lidar_tin_gridding"].append(_timed(peer))
        check = _agreement(out, tif)
    base = statistics.median(times["Whitebox lidar_tin_gridding"])
    rows = [
        [name, f"{statistics.median(t):.2f} s", f"{min(t):.2f} s", f"{max(t):.2f} s", f"{statistics.median(t) / base:.2f}x"]
        for name, t in times.items()
    ]
    table(f"{path.name} at {resolution} m, {repeat} runs each, interleaved", ["job", "median", "min", "max", "vs Whitebox"], rows)
    print(f"\nthe two DEMs where both have a value: {check}")


def startup(repeat: int, path: Path) -> None:
    commands = {"terrain --help": [str(TERRAIN), "--help"], f"terrain info {path.name}": [str(TERRAIN), "info", str(path)]}
    for cmd in commands.values():
        _timed(cmd)
    times = {name: [] for name in commands}
    for _ in range(repeat):
        for name, cmd in commands.items():
            times[name].append(_timed(cmd))
    rows = [[name, f"{statistics.median(t):.3f} s", f"{max(t):.3f} s"] for name, t in times.items()]
    table(f"start-up, {repeat} fresh processes each", ["command", "median", "max"], rows)


def main() -> None:
    compile_bytecode(Path(__file__).resolve().parents[1])
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["whitebox", "startup"])
    parser.add_argument("--file", type=Path, default=SHARED / "extra_byte_blocks_lambert93.laz")
    parser.add_argument("--resolution", type=float, default=0.5)
    parser.add_argument("--repeat", type=int, default=None)
    args = parser.parse_args()
    if args.what == "whitebox":
        whitebox(args.file, args.repeat or 7, args.resolution)
    else:
        startup(args.repeat or 10, args.file)


if __name__ == "__main__":
    main()
