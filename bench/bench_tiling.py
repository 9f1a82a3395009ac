"""Tiling never changes the answer, on the real samples: each run tiled against one tile.

    python bench/bench_tiling.py [--data ../shared/data]

For each case of the tiling issue (sample, resolution, tile size, surface), the
share of DEM cells that differ from the untiled run and the largest difference,
the faces found in one store only, the rounds the survey flipped in, the tiles
meshed again because a neighbour flipped later than they assumed, and how far
beyond its buffer a tile's certificate had to hold every point (median and
largest over the tiles).  Every figure but the last three should read 0.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

# (sample, resolution, tile size, surface, layers)
CASES = [
    ("ign_semis_lambert93.laz", 1.0, 50.0, "linear", ("elevation",)),
    ("ign_semis_lambert93.laz", 1.0, 100.0, "linear", ("elevation",)),
    ("ign_semis_lambert93.laz", 1.0, 100.0, "smooth", ("elevation",)),
    ("autzen_trim.las", 1.0, 100.0, "linear", ("elevation",)),
    ("startinpy_small_extrabytes.laz", 0.25, 10.0, "linear", ("elevation",)),
    ("4_6_crop_us_feet.las", 1.0, 50.0, "linear", ("elevation", "slope")),
    ("extra_byte_blocks_lambert93.laz", 0.5, 25.0, "linear", ("elevation", "slope")),
]


def main() -> None:
    from pipeline import RunConfig, run
    from pipeline.store import zarr_store as store

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    args = parser.parse_args()

    def faces(path):
        xy, _, f = store.read_mesh(path)
        xy, f = np.asarray(xy), np.asarray(f)
        return {tuple(tuple(xy[v]) for v in row if v >= 0) for row in f.tolist()}

    header = (f"{'sample':34} {'res':>5} {'tile':>5} {'surface':7} {'cells differ':>12} {'max diff':>9} "
              f"{'faces differ':>12} {'rounds':>6} {'again':>5} {'reach median/max':>17}")
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        untiled_of = {}
        for name, res, tile, surface, layers in CASES:
            src = args.data / name
            key = (name, res, surface, layers)
            common = dict(inputs=(str(src),), resolution=res, surface=surface, layers=layers, overwrite=True)
            if key not in untiled_of:
                out = Path(tmp) / f"untiled_{len(untiled_of)}.zarr"
                run(RunConfig(output=str(out), tile_size=1e4 * res, **common), progress=False)
                untiled_of[key] = out
            out = Path(tmp) / "tiled.zarr"
            rep = run(RunConfig(output=str(out), tile_size=tile, **common), progress=False)
            a, b = xr.open_zarr(out), xr.open_zarr(untiled_of[key])
            worst, share = 0.0, 0.0
            for layer in layers:
                x, y = a[layer].values, b[layer].values
                if x.shape != y.shape:
                    share, worst = float("nan"), float("nan")
                    break
                differ = ~((x == y) | (np.isnan(x) & np.isnan(y)))
                share = max(share, differ.mean())
                if differ.any():
                    worst = max(worst, float(np.nanmax(np.abs(x - y))))
            fa, fb = faces(out), faces(untiled_of[key])
            reach = rep.certificate_reach or [0.0, 0.0]
            print(f"{name:34} {res:5g} {tile:5g} {surface:7} {100 * share:11.2f}% {worst:9.3g} "
                  f"{len(fa ^ fb):12d} {rep.flip_rounds:6d} {rep.tiles_meshed_again:5d} "
                  f"{reach[0]:8.1f}/{reach[1]:<8.1f}", flush=True)


if __name__ == "__main__":
    main()
