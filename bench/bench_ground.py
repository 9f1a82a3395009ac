"""Ground classification of unclassified clouds against the surveys' own, and
against two peers (run by hand; ``pip install -e ".[bench]"``).

    python bench/bench_ground.py [--samples NAME ...] [--peers csf whitebox] [--cache DIR] [--pipeline REPEAT [--forest N]]
    python bench/bench_ground.py --steep SEED
    python bench/bench_ground.py --low-roofs SEED

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

``--steep SEED`` prints only a table of synthetic steep terrain with a known
surface: sharp ridges, a dike and cones bare, and a mountain village
(:func:`steep_table`).  ``--low-roofs SEED`` prints only a table of low wide
flat roofs beside a terrace and a raised field, with the wall test and
without it (:func:`low_roofs_table`).
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

from bench_mesh import table  # noqa: E402
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
    table(f"terrain run, 1-unit cells: the files' classes against --classify-ground (medians of {repeat}, interleaved;"
          " the whole command, and run() in this process)",
          ["sample", "own classes s", "--classify-ground s", "ratio", "run() own s", "run() classify s", "run() ratio",
           "CSF time / ours"], rows)


def _tin_errors(x, y, z, ground, gx, gy, truth):
    """The finite differences, at the cells ``gx, gy``, between a TIN of the
    ``ground`` points (scipy, local coordinates) and the true heights ``truth``."""
    from scipy.interpolate import LinearNDInterpolator

    err = LinearNDInterpolator(np.column_stack([x[ground], y[ground]]), z[ground])(gx, gy) - truth
    return err[np.isfinite(err)]


def _ridges(slope: float, spacing: float):
    return lambda x, y: slope * (spacing / 2 - np.abs(((x + 0.3 * y) % spacing) - spacing / 2))


def _dike(x, y):
    return np.clip(6.0 - np.maximum(np.abs(x - 300.0) - 2.0, 0.0) * 0.6, 0.0, None)


def _cone_hills(x, y):
    z = np.zeros_like(x)
    for cx, cy, r, h in ((150, 150, 40, 25), (420, 200, 25, 15), (300, 450, 60, 40), (120, 470, 15, 12)):
        z = np.maximum(z, h * np.clip(1 - np.hypot(x - cx, y - cy) / r, 0.0, None))
    return z


STEEP = {
    "ridges of V section every 120 m, slope 0.3": _ridges(0.3, 120.0),
    "the same, slope 0.5": _ridges(0.5, 120.0),
    "the same, slope 0.84": _ridges(0.84, 120.0),
    "a dike 6 m high, crest 4 m wide, sides of 0.6": _dike,
    "cones 12-40 m high, slopes 0.6-0.8": _cone_hills,
}


def steep_table(seed: int) -> None:
    """Ground found on synthetic steep terrain: bare (360,000 points over
    600 x 600 m, 5 cm of noise, survey coordinates at 1 cm), and a mountain
    village (ridges every 100 m with houses, conifers letting 40% of the
    returns through and shrubs, on sides of 0.3 and 0.6); the DTM a TIN of
    the ground found (scipy, local coordinates) on 1 m cells against the
    true surface."""
    rng = np.random.default_rng(seed)
    rows = []
    size = 600.0
    for name, terrain in STEEP.items():
        n = 360_000
        lx, ly = rng.uniform(0.0, size, n), rng.uniform(0.0, size, n)
        x, y = np.round(lx + 651_000.0, 2), np.round(ly + 6_861_000.0, 2)
        z = np.round(terrain(lx, ly) + 120.0 + rng.normal(0.0, 0.05, n), 2)
        ground = classify_ground(x, y, z).ground
        gx, gy = np.meshgrid(np.arange(20.5, size - 20.0), np.arange(20.5, size - 20.0))
        err = _tin_errors(lx, ly, z, ground, gx, gy, terrain(gx, gy) + 120.0)
        rows.append([name, f"{100 * ground.mean():.1f}", "", f"{np.sqrt(np.mean(err ** 2)):.3f}", f"{np.abs(err).max():.2f}"])
    for slope in (0.3, 0.6):
        x, y, z, rn, nr, objects, terrain = _village(rng, slope)
        ground = classify_ground(x + 340_000.0, y + 5_100_000.0, z, return_number=rn, number_of_returns=nr).ground
        gx, gy = np.meshgrid(np.arange(10.5, 490.0), np.arange(10.5, 490.0))
        err = _tin_errors(x, y, z, ground, gx, gy, terrain(gx, gy))
        rows.append([f"mountain village, sides of {slope}", f"{100 * ground[~objects].mean():.1f}",
                     f"{100 * ground[objects].mean():.2f}", f"{np.sqrt(np.mean(err ** 2)):.3f}", f"{np.abs(err).max():.2f}"])
    table("Steep synthetic terrain (DTM of the ground found against the true surface, 1 m cells)",
          ["terrain", "ground kept %", "objects taken %", "DTM RMS m", "max m"], rows)


#: x, y, width, depth and height of the flat roofs of :func:`low_roofs_table`
LOW_ROOFS = [(200, 60, 60, 48, 2.5), (300, 60, 60, 48, 3.0), (400, 60, 60, 48, 3.5), (520, 60, 48, 36, 2.5),
             (600, 60, 48, 36, 3.5), (200, 200, 30, 24, 2.5), (280, 200, 30, 24, 3.0), (360, 200, 90, 70, 3.0),
             (520, 200, 40, 30, 4.5)]


def _rising(x, y):
    """Ground rising 0.04 to the east, with hills."""
    return 40.0 + 0.04 * x + 3.0 * np.sin(y / 90.0) + 2.0 * np.cos(x / 130.0)


def _banks(x, y):
    """The raised ground of :func:`low_roofs_table`: the north-east quarter
    3 m up behind a bank 2 m wide, and a field 80 x 110 m 2.8 m up behind banks 3 m wide."""
    terrace = np.clip((y - 380.0) / 2.0, 0.0, 1.0) * (x > 420.0) * 3.0
    field = 2.8 * np.clip(np.minimum(x - 40.0, 120.0 - x) / 3.0, 0.0, 1.0) * np.clip(np.minimum(y - 30.0, 140.0 - y) / 3.0, 0.0, 1.0)
    return terrace, field


def low_roofs_table(seed: int) -> None:
    """Flat roofs 2.5-4.5 m high and 24-90 m across on ground rising 0.04
    (700 x 500 m, 2 points a square metre, 120 trees), beside a terrace and
    a raised field: the share of each roof's points taken for ground with the
    wall test (``wall_height``) and without it (``wall_radius=0``: Pingel's
    threshold alone), the raised ground kept, and the DTM's RMS."""
    from meshcore import GroundParameters

    rng = np.random.default_rng(seed)
    width, depth = 700.0, 500.0
    n = int(width * depth * 2.0)
    lx, ly = rng.uniform(0.0, width, n), rng.uniform(0.0, depth, n)
    terrace, field = _banks(lx, ly)
    bare = _rising(lx, ly) + terrace + field
    z = bare + rng.normal(0.0, 0.04, n)
    roofs = []
    for bx, by, w, h, height in LOW_ROOFS:
        inside = (lx >= bx) & (lx < bx + w) & (ly >= by) & (ly < by + h)
        z[inside] = _rising(bx + w / 2, by + h / 2) + height + rng.normal(0.0, 0.03, inside.sum())
        roofs.append(inside)
    objects = np.any(roofs, axis=0)
    for cx, cy in zip(rng.uniform(0.0, width, 120), rng.uniform(300.0, depth, 120)):
        radius, height = rng.uniform(2.0, 5.0), rng.uniform(6.0, 18.0)
        d = np.hypot(lx - cx, ly - cy)
        crown = (d < radius) & ~objects & (rng.random(n) < 0.6)
        z[crown] = bare[crown] + height * (1.0 - 0.3 * d[crown] / radius)
        objects |= crown
    x, y, z = np.round(lx + 651_000.0, 2), np.round(ly + 6_861_000.0, 2), np.round(z, 2)
    gx, gy = np.meshgrid(np.arange(2.5, width - 2.0), np.arange(2.5, depth - 2.0))
    truth = _rising(gx, gy) + sum(_banks(gx, gy))
    raised = (terrace > 0.5) | (field > 0.5)
    rows = []
    for name, parameters in (("Pingel's threshold alone (wall_radius 0)", GroundParameters(wall_radius=0.0)),
                             ("with the wall test (defaults)", GroundParameters())):
        ground = classify_ground(x, y, z, parameters=parameters).ground
        err = _tin_errors(lx, ly, z, ground, gx, gy, truth)
        rows.append([name, *(f"{100 * ground[r].mean():.0f}" for r in roofs),
                     f"{100 * ground[raised & ~objects].mean():.1f}", f"{np.sqrt(np.mean(err ** 2)):.3f}"])
    table("Low wide flat roofs: the share of each roof's points taken for ground, %",
          ["test", *(f"{w}x{h}, {height} m" for _, _, w, h, height in LOW_ROOFS), "raised ground kept %", "DTM RMS m"],
          rows)


def _village(rng, slope: float):
    """500 x 500 m, 300,000 returns: ridges every 100 m, 45 houses (8-30 m,
    3-9 m over their highest corner, every other one gabled), 400 conifers
    and 300 shrubs; coordinates local, heights absolute."""
    size, n = 500.0, 300_000

    def terrain(x, y):
        return 800.0 + slope * (50.0 - np.abs(((x + 0.4 * y) % 100.0) - 50.0)) + 0.02 * y

    x, y = rng.uniform(0.0, size, n), rng.uniform(0.0, size, n)
    bare = terrain(x, y)
    z = bare + rng.normal(0.0, 0.04, n)
    rn, nr = np.ones(n, dtype=np.int64), np.ones(n, dtype=np.int64)
    objects = np.zeros(n, dtype=bool)
    for k in range(45):
        bx, by = rng.uniform(30.0, size - 60.0, 2)
        w, h = rng.uniform(8.0, 30.0, 2)
        height = rng.uniform(3.0, 9.0)
        inside = (x > bx) & (x < bx + w) & (y > by) & (y < by + h)
        if inside.any():
            gable = rng.uniform(0.0, 0.8) * (w / 2 - np.abs(x[inside] - (bx + w / 2))) if k % 2 else 0.0
            z[inside] = bare[inside].max() + height + gable
            objects |= inside
    for _ in range(400):
        tx, ty = rng.uniform(0.0, size, 2)
        radius, height = rng.uniform(1.5, 4.0), rng.uniform(6.0, 20.0)
        d = np.hypot(x - tx, y - ty)
        inside = (d < radius) & ~objects
        canopy = inside & (rng.random(n) > 0.4)
        z[canopy] = bare[canopy] + height * (1 - d[canopy] / radius) * rng.uniform(0.7, 1.0, canopy.sum()) + 0.5
        objects |= canopy
        nr[inside], rn[canopy], rn[inside & ~canopy] = 2, 1, 2
    for _ in range(300):
        tx, ty = rng.uniform(0.0, size, 2)
        inside = (np.hypot(x - tx, y - ty) < rng.uniform(1.0, 2.5)) & ~objects
        z[inside] = bare[inside] + rng.uniform(0.5, 1.5)
        objects |= inside
    return np.round(x, 2), np.round(y, 2), np.round(z, 2), rn, nr, objects, terrain


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", nargs="*")
    parser.add_argument("--peers", nargs="*", default=list(PEERS), choices=list(PEERS))
    parser.add_argument("--cache", type=Path, help="folder keeping the peers' flags between runs")
    parser.add_argument("--pipeline", type=int, metavar="REPEAT", default=0,
                        help="also time whole runs, own classes against --classify-ground (medians of REPEAT)")
    parser.add_argument("--forest", type=int, metavar="N", default=0,
                        help="with --pipeline: also a synthetic forest of N points")
    parser.add_argument("--steep", type=int, metavar="SEED",
                        help="only the table of synthetic steep terrain, drawn with SEED")
    parser.add_argument("--low-roofs", type=int, metavar="SEED",
                        help="only the table of low wide flat roofs beside raised ground, drawn with SEED")
    args = parser.parse_args(argv)

    classify_ground(*np.random.default_rng(0).uniform(0, 50, (3, 500)))  # compile outside the timings
    if args.steep is not None:
        steep_table(args.steep)
        return
    if args.low_roofs is not None:
        low_roofs_table(args.low_roofs)
        return
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
    table("Ground against the survey's class 2 (DTM difference in the file's unit, 1-unit cells)",
          ["sample", "method", "points", "unit", "median", "p95", "RMS", "max", "type I %", "type II %", "kappa",
           "time s", "low outliers"], rows)
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
