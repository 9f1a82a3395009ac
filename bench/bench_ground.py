"""Ground classification of unclassified clouds against the surveys' own, and
against two peers (run by hand; ``pip install -e ".[bench]"``).

    python bench/bench_ground.py [--samples NAME ...] [--peers csf whitebox] [--cache DIR] [--pipeline REPEAT [--forest N]]

Every shared sample with a ground class has its classes removed (the points
of every class but noise, 7 and 18, are classified) and is classified by
:func:`meshcore.ground.classify_ground`, by CSF (PyPI
``cloth-simulation-filter``: cloth resolution 0.5, rigidness 2, slope
smoothing on, the issue's settings) and by Whitebox Workflows'
``improved_ground_point_filter`` (its defaults, with the sizes in the file's
unit: its block size and largest building are given in metres and scaled).
Each is compared with the survey's class 2:

* through the DTM each makes: a TIN of its ground points (scipy's Delaunay,
  linear) sampled at the centres of 1-unit cells (1 m, or 1 ft for the
  samples in feet), over the cells inside both TINs; median, 95th percentile,
  RMS and largest absolute difference, in the file's unit;
* point by point: type I (survey ground called not ground, share of the
  survey's ground), type II (survey non-ground called ground, share of the
  survey's non-ground) and Cohen's kappa;
* and the time of the classification alone (the file read and the peers'
  file writing excluded; Whitebox's time includes its reading and writing,
  which it cannot skip).  Ours is timed after one call that compiles the
  kernels.

The peers are slow (CSF takes minutes on ign_semis): ``--cache DIR`` keeps
their flags per sample and reuses them.

``--pipeline REPEAT`` also times whole runs, the files' own classes against
``--classify-ground``; ``--forest N`` adds to that table a synthetic forest of
``N`` points (:func:`bench_products.forest`: trees over most of it, a few
buildings, ground a small share of the returns), a survey larger than the
samples, classified in one block.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from meshcore.ground import classify_ground  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
NOISE = (7, 18)


def _unit(las) -> tuple[float, str]:
    """Metres per coordinate unit and its name (metres when the file does not say)."""
    try:
        crs = las.header.parse_crs()
    except Exception:  # a broken CRS record: the bench assumes metres, as the table says
        crs = None
    if crs is None:
        return 1.0, "m?"
    crs = crs.sub_crs_list[0] if crs.is_compound else crs
    axis = crs.axis_info[0] if crs.axis_info else None
    if axis is None or crs.is_geographic:
        return 1.0, "m?"
    return axis.unit_conversion_factor, "m" if axis.unit_conversion_factor == 1.0 else "ft"


def samples(names: list[str] | None) -> list[Path]:
    found = []
    for path in sorted(SHARED.glob("*.la[sz]")):
        if names and path.stem not in names and path.name not in names:
            continue
        with laspy.open(path) as f:
            if f.header.point_count < 100:
                continue
            las = f.read()
        if (np.asarray(las.classification) == 2).any():
            found.append(path)
    return found


def dtm_difference(x, y, z, mine, theirs) -> tuple[float, float, float, float]:
    """Absolute difference of the two TIN DTMs on 1-unit cells both cover."""
    from scipy.interpolate import LinearNDInterpolator

    x0, y0 = math.floor(x.min()), math.floor(y.min())
    gx = np.arange(x0, math.ceil(x.max())) + 0.5
    gy = np.arange(y0, math.ceil(y.max())) + 0.5
    cx, cy = np.meshgrid(gx, gy)
    grids = []
    for flags in (mine, theirs):
        if flags.sum() < 3:
            return (math.nan,) * 4
        f = LinearNDInterpolator(np.column_stack([x[flags] - x0, y[flags] - y0]), z[flags])
        grids.append(f(cx - x0, cy - y0))
    d = np.abs(grids[0] - grids[1])
    d = d[np.isfinite(d)]
    if d.size == 0:
        return (math.nan,) * 4
    return float(np.median(d)), float(np.percentile(d, 95)), float(np.sqrt(np.mean(d * d))), float(d.max())


def agreement(ref, got) -> tuple[float, float, float]:
    """Type I, type II and Cohen's kappa of ``got`` against ``ref``."""
    n = ref.size
    tp = float((ref & got).sum())
    fn = float((ref & ~got).sum())
    fp = float((~ref & got).sum())
    tn = float((~ref & ~got).sum())
    type1 = fn / max(tp + fn, 1.0)
    type2 = fp / max(fp + tn, 1.0)
    po = (tp + tn) / n
    pe = ((tp + fn) * (tp + fp) + (fp + tn) * (fn + tn)) / (n * n)
    kappa = (po - pe) / (1.0 - pe) if pe < 1.0 else 1.0
    return type1, type2, kappa


def spacing_metres(x, y, unit: float) -> float:
    """The points' spacing as a run measures it: the square root of their convex hull's area over their number."""
    from meshcore import convex_hull
    from pipeline.meshing.surface import signed_area

    if x.size < 3:
        return math.nan
    local = np.column_stack([x - x.min(), y - y.min()])
    area = abs(signed_area(local[convex_hull(local[:, 0], local[:, 1])]))
    return math.sqrt(area / x.size) * unit


def run_ours(las, keep, unit):
    from meshcore import GroundParameters

    x, y, z = (np.asarray(v)[keep] for v in (las.x, las.y, las.z))
    rn = np.asarray(las.return_number)[keep]
    nr = np.asarray(las.number_of_returns)[keep]
    t0 = time.perf_counter()
    parameters = GroundParameters().for_spacing(spacing_metres(x, y, unit))
    result = classify_ground(x, y, z, unit=unit, parameters=parameters, return_number=rn, number_of_returns=nr)
    return result.ground, time.perf_counter() - t0, result.low_outliers


#: CSF's cloth above this many particles is not run (its memory grows past this machine's)
CSF_MAX_CLOTH = 20_000_000


def run_csf(las, keep, unit):
    import CSF

    xyz = np.column_stack([np.asarray(v)[keep] for v in (las.x, las.y, las.z)])
    span = xyz[:, :2].max(axis=0) - xyz[:, :2].min(axis=0)
    cloth = float(np.prod(span / (0.5 / unit) + 1))
    if cloth > CSF_MAX_CLOTH:
        raise PeerCannot(f"a cloth of {cloth:,.0f} particles at 0.5 m (above {CSF_MAX_CLOTH:,}: more memory than "
                         "this machine has)")
    csf = CSF.CSF()
    csf.params.bSloopSmooth = True
    csf.params.cloth_resolution = 0.5 / unit
    csf.params.rigidness = 2
    csf.params.class_threshold = 0.5 / unit
    t0 = time.perf_counter()
    csf.setPointCloud(xyz)
    ground, off = CSF.VecInt(), CSF.VecInt()
    csf.do_filtering(ground, off, False)
    elapsed = time.perf_counter() - t0
    flags = np.zeros(xyz.shape[0], dtype=bool)
    flags[np.asarray(ground, dtype=np.int64)] = True
    return flags, elapsed


def run_whitebox(las, keep, unit):
    from whitebox_workflows import WbEnvironment

    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in.las"
        out = Path(tmp) / "out.las"
        points = las.points[keep].copy()
        clean = laspy.LasData(las.header.copy(), points)
        clean.classification = np.zeros(len(points), dtype=np.uint8)
        clean.write(src)
        wbe = WbEnvironment()
        wbe.verbose = False
        t0 = time.perf_counter()
        wbe.lidar.improved_ground_point_filter(input=str(src), classify=True, output=str(out))
        elapsed = time.perf_counter() - t0
        flags = np.asarray(laspy.read(out).classification) == 2
    return flags, elapsed


class PeerCannot(Exception):
    """A peer that cannot run on a sample (the reason is printed in its row)."""


PEERS = {"csf": run_csf, "whitebox": run_whitebox}


def pipeline_table(paths: list[Path], repeat: int, cache: Path | None) -> None:
    """``terrain run`` on the files' own classes against ``--classify-ground``
    on the same file (every class but noise), interleaved, medians of
    ``repeat``; and the ratio to CSF's time on the same points."""
    from pipeline.config import RunConfig
    from pipeline.runs.runner import run

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in paths:
            times: dict[str, list[float]] = {"own": [], "classify": [], "own command": [], "classify command": []}
            for k in range(repeat + 1):  # the first round warms the kernels and the file cache
                for mode in ("own", "classify"):
                    # a sample without a usable CRS record is taken as metres of Lambert-93
                    config = RunConfig(inputs=(str(path),), output=f"{tmp}/{mode}.zarr", resolution=1.0,
                                       classify_ground=mode == "classify", overwrite=True, in_crs="EPSG:2154")
                    t0 = time.perf_counter()
                    run(config, progress=False)
                    if k:
                        times[mode].append(time.perf_counter() - t0)
                    command = [str(Path(sys.executable).with_name("terrain")), "run", str(path), "-o", f"{tmp}/{mode}.zarr",
                               "--resolution", "1", "--overwrite", "-q", "--in-crs", "EPSG:2154"]
                    t0 = time.perf_counter()
                    subprocess.run(command + (["--classify-ground"] if mode == "classify" else []), check=True)
                    if k:
                        times[f"{mode} command"].append(time.perf_counter() - t0)
            own, mine = (float(np.median(times[m])) for m in ("own", "classify"))
            own_cmd, mine_cmd = (float(np.median(times[m])) for m in ("own command", "classify command"))
            csf = ""
            cached = cache / f"{path.stem}.csf.npz" if cache else None
            if cached is not None and cached.exists():
                csf = f"{float(np.load(cached)['seconds']) / mine:.1f}x"
            rows.append([path.stem, f"{own_cmd:.2f}", f"{mine_cmd:.2f}", f"{mine_cmd / own_cmd:.2f}x",
                         f"{own:.2f}", f"{mine:.2f}", f"{mine / own:.2f}x", csf])
    header = ["sample", "own classes s", "--classify-ground s", "ratio", "run() own s", "run() classify s",
              "run() ratio", "CSF time / ours"]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    print(f"\nterrain run, 1-unit cells: the files' classes against --classify-ground (medians of {repeat}, interleaved;"
          " the whole command, and run() in this process)")
    print("  ".join(h.rjust(w) for h, w in zip(header, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", nargs="*")
    parser.add_argument("--peers", nargs="*", default=list(PEERS), choices=list(PEERS))
    parser.add_argument("--cache", type=Path, help="folder keeping the peers' flags between runs")
    parser.add_argument("--pipeline", type=int, metavar="REPEAT", default=0,
                        help="also time whole runs, own classes against --classify-ground (medians of REPEAT)")
    parser.add_argument("--forest", type=int, metavar="N", default=0,
                        help="with --pipeline: also a synthetic forest of N points")
    args = parser.parse_args(argv)

    classify_ground(*np.random.default_rng(0).uniform(0, 50, (3, 500)))  # compile outside the timings
    rows = []
    skipped: list[str] = []
    for path in samples(args.samples):
        las = laspy.read(path)
        unit, unit_name = _unit(las)
        keep = ~np.isin(np.asarray(las.classification), NOISE)
        x, y, z = (np.asarray(v)[keep] for v in (las.x, las.y, las.z))
        ref = np.asarray(las.classification)[keep] == 2
        results = {"ours": run_ours(las, keep, unit)}
        for peer in args.peers:
            cached = args.cache / f"{path.stem}.{peer}.npz" if args.cache else None
            if cached is not None and cached.exists():
                data = np.load(cached)
                results[peer] = (data["flags"], float(data["seconds"]), None)
                continue
            try:
                flags, seconds = PEERS[peer](las, keep, unit)
            except PeerCannot as reason:
                skipped.append(f"{path.stem}: {peer} not run: {reason}")
                continue
            results[peer] = (flags, seconds, None)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.savez_compressed(cached, flags=flags, seconds=seconds)
        for name, (flags, seconds, outliers) in results.items():
            med, p95, rms, mx = dtm_difference(x, y, z, flags, ref)
            t1, t2, kappa = agreement(ref, flags)
            rows.append([
                path.stem if name == "ours" else "", name, f"{ref.size:,}", unit_name,
                f"{med:.2f}", f"{p95:.2f}", f"{rms:.2f}", f"{mx:.1f}",
                f"{100 * t1:.1f}", f"{100 * t2:.1f}", f"{kappa:.3f}", f"{seconds:.2f}",
                "" if outliers is None else str(outliers),
            ])
            print(json.dumps({"sample": path.stem, "method": name, "rms": rms, "kappa": kappa, "seconds": seconds}), file=sys.stderr)
    header = ["sample", "method", "points", "unit", "median", "p95", "RMS", "max", "type I %", "type II %", "kappa", "time s", "low outliers"]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    print("\nGround against the survey's class 2 (DTM difference in the file's unit, 1-unit cells)")
    print("  ".join(h.rjust(w) for h, w in zip(header, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))
    for line in skipped:
        print(line)
    if args.pipeline:
        with tempfile.TemporaryDirectory() as tmp:
            from bench_products import forest

            extra = []
            if args.forest:
                written = forest(Path(tmp), args.forest)
                extra = [written.rename(written.with_name(f"synthetic_forest_{args.forest}.laz"))]
            pipeline_table(samples(args.samples) + extra, args.pipeline, args.cache)


if __name__ == "__main__":
    main()
