"""Accuracy of the surfaces: predicting withheld ground points, one at a time and in voids (run by hand).

    python bench/bench_accuracy.py [--samples ../shared/data] [--lidr-sets 20] [--repeats 3]
                                   [--tests point,5,10,20,40] [--only ign_semis,autzen_trim] [--seed 0]

Two tests on each survey's ground points (class 2, exact x, y duplicates
merged, the lowest z kept), ``--repeats`` draws each:

- point cross-validation (``point``): withhold a random 10%
  (``numpy.random.default_rng(11)``): each withheld point has measured
  neighbours on every side;
- block cross-validation (``5``, ``10``, ``20``, ``40``: the radius, in the
  survey's CRS units): withhold every point inside random disks of that
  radius (simulated voids: buildings, water, scan shadows), centred on
  points at least a radius from the edges of the survey's box, 15 of them
  or as many as cover 30% of the box (draw ``d`` takes
  ``numpy.random.default_rng(100 + d)``); a radius no disk of which fits in
  the box is not tested (n/a).

Every method is fitted on the rest, in local coordinates (the fitted points'
lowest x and y subtracted), and scored by the root mean square error at the
withheld points inside the fitted points' convex hull (the same points for
every method).  The table gives the TIN's RMSE (the median of the draws) and
each method's change against it (the median of the draws' changes), and for
block rows the largest error of the smooth surface and of the TIN, and its
ripples: the share of the cells inside the disks (a grid of a point spacing,
at least r / 40) where the smooth S3/S4 surface lies outside the range of the
void's rim, the corners of the Delaunay triangles that hold those cells (a
TIN's share is zero by construction; the largest share of the draws).

Methods:

- ``TIN``: a Delaunay triangulation, linear (what PDAL, LAStools, lidR and
  Whitebox grid from);
- ``linear S3/S4``: the combined mesh's linear/bilinear surface;
- ``smooth TIN``, ``smooth S3/S4``: ``surface="smooth"`` (cubic patches,
  kriged nodes, the variogram fitted on the fitted points);
- ``NNI``: startinpy's natural-neighbour interpolation (``pip install -e .[bench]``; skipped when missing);
- ``kriging``: a reference written here with numpy alone, ordinary kriging
  at each withheld point from its 32 nearest fitted points with the same
  fitted variogram (its model too) (no patches, not through a mesh).

The lidR test re-enacted (``tests/testthat/test-rasterize_terrain.R``): 5,000
uniform points on 100 x 100 m of ``0.1 x + 0.1 y + sin(0.01 x) - sin(0.1 y)
+ sin(0.003 x y)``, z rounded to the mm, one set per seed, point
cross-validation (one draw per set; the change of each method's median RMSE
over the sets against the TIN's).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's meshcore, not an installed one
import meshcore  # noqa: E402
from bench_mesh import table  # noqa: E402  (the sibling script: bench/ is on sys.path when run as a script)

SAMPLES = ("ign_semis_lambert93.laz", "extra_byte_blocks_lambert93.laz", "autzen_trim.las",
           "startinpy_small_extrabytes.laz", "4_6_crop_us_feet.las", "warsaw_small_broken_crs.las", "no_crs_color.las")
"""The samples with ground points (class 2) in ../shared/data."""

MESHES = {"TIN": ("delaunay", None), "S3/S4": ("s3", "s4")}
"""The meshes whose linear and smooth surfaces are scored (the TIN's smooth surface too)."""

METHODS = ("linear S3/S4", "NNI", "smooth TIN", "smooth S3/S4", "kriging")
"""The columns, each against the TIN."""


def ground_points(path: Path) -> np.ndarray:
    """The class-2 points ``(x, y, z)``, exact x, y duplicates merged to their lowest z."""
    import laspy

    las = laspy.read(path)
    keep = np.asarray(las.classification) == 2
    pts = np.column_stack([np.asarray(las.x)[keep], np.asarray(las.y)[keep], np.asarray(las.z)[keep]])
    order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0]))
    pts = pts[order]
    first = np.ones(pts.shape[0], dtype=bool)
    first[1:] = (pts[1:, 0] != pts[:-1, 0]) | (pts[1:, 1] != pts[:-1, 1])
    return pts[first]


def lidr_surface(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.1 * x + 0.1 * y + np.sin(0.01 * x) - np.sin(0.1 * y) + np.sin(0.003 * x * y)


def lidr_set(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 100.0, 5000)
    y = rng.uniform(0.0, 100.0, 5000)
    return np.column_stack([x, y, np.round(lidr_surface(x, y), 3)])


def exact_nodes_error(fit: np.ndarray, test: np.ndarray) -> float:
    """RMSE of the smooth S3/S4 surface with the lidR surface's exact values at
    its nodes and added points: the patches' own error, which no smoother of the nodes beats."""
    mesh = meshcore.build_mesh(fit[:, :2], "s3", "s4")
    z = np.full(mesh.vertices.shape[0], np.nan)
    z[mesh.input_to_vertex] = fit[:, 2]
    variogram = meshcore.fit_variogram(fit[:, :2], fit[:, 2])
    plan = meshcore.tiles.smooth_plan(mesh, variogram)
    refined = plan.refinement.mesh
    added = refined.vertices[z.size:]
    z_all = np.concatenate([z, lidr_surface(added[:, 0], added[:, 1])])
    hoods = plan.nodes
    exact = lidr_surface(hoods.positions[:, 0], hoods.positions[:, 1])
    nodes = np.full(hoods.take.shape, np.nan)
    used = hoods.take >= 0
    nodes[used] = exact[hoods.take[used]]
    surface = meshcore.SmoothSurface(refined, z_all, nodes, plan.refinement.parent)
    pred = meshcore.interpolate(mesh, z, test[:, 0], test[:, 1], surface=surface)
    ok = np.isfinite(pred)
    return float(np.sqrt(np.mean((pred[ok] - test[ok, 2]) ** 2)))


def kriging_reference(fit: np.ndarray, query: np.ndarray, variogram: meshcore.Variogram, k: int = 32) -> np.ndarray:
    """Ordinary kriging at ``query`` from the ``k`` nearest fitted points (numpy, batched)."""
    from scipy.spatial import cKDTree

    origin = fit[:, :2].min(axis=0)
    xy = fit[:, :2] - origin
    q = query[:, :2] - origin
    _, idx = cKDTree(xy).query(q, k=k)
    nb = xy[idx]  # (m, k, 2)
    h = np.linalg.norm(nb[:, :, None, :] - nb[:, None, :, :], axis=3)

    m = q.shape[0]
    a = np.ones((m, k + 1, k + 1))
    a[:, :k, :k] = variogram.semivariance(h)
    a[:, k, k] = 0.0
    b = np.ones((m, k + 1))
    b[:, :k] = variogram.semivariance(np.linalg.norm(nb - q[:, None, :], axis=2))
    w = np.linalg.solve(a, b[:, :, None])[:, :k, 0]
    return np.sum(w * fit[idx, 2], axis=1)


def nni(fit: np.ndarray, query: np.ndarray) -> np.ndarray | None:
    try:
        import startinpy
    except ImportError:
        return None
    origin = fit[:, :2].min(axis=0)
    dt = startinpy.DT()
    dt.insert(np.column_stack([fit[:, :2] - origin, fit[:, 2]]))
    return np.asarray(dt.interpolate({"method": "NNI"}, query[:, :2] - origin, strict=False), dtype=float)


def void_cells(fit: np.ndarray, centres: np.ndarray, radius: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The centres of a grid's cells inside the disks (side: a point spacing, at least
    ``radius / 40``) and inside the hull, and per cell the range ``(low, high)`` of
    its void's rim: the corners of the Delaunay triangles that hold the void's cells."""
    from scipy.spatial import Delaunay

    side = max(spacing, radius / 40.0)
    steps = np.arange(-radius + side / 2, radius, side)
    gx, gy = np.meshgrid(steps, steps)
    offsets = np.column_stack([gx.ravel(), gy.ravel()])
    offsets = offsets[np.hypot(offsets[:, 0], offsets[:, 1]) < radius]
    dt = Delaunay(fit[:, :2])
    cells, ranges = [], []
    for c in centres:
        q = c + offsets
        t = dt.find_simplex(q)
        q, t = q[t >= 0], t[t >= 0]
        if not q.size:
            continue
        rim = fit[np.unique(dt.simplices[t]), 2]
        cells.append(q)
        ranges.append(np.repeat([[rim.min(), rim.max()]], q.shape[0], axis=0))
    if not cells:
        return np.empty((0, 2)), np.empty((0, 2))
    return np.concatenate(cells), np.concatenate(ranges)


def outside_rim(values: np.ndarray, ranges: np.ndarray) -> float:
    """The share of cells whose value lies outside their rim's range (beyond rounding)."""
    if not values.size:
        return float("nan")
    slack = 1e-9 * np.maximum(1.0, np.abs(ranges).max(axis=1))
    return float(np.mean((values < ranges[:, 0] - slack) | (values > ranges[:, 1] + slack)))


def one_split(fit: np.ndarray, test: np.ndarray, voids: tuple[np.ndarray, float] | None = None,
              ) -> tuple[dict[str, float], dict[str, float], meshcore.Variogram]:
    """RMSE and largest error of every method on one split, and the variogram; with
    ``voids`` (the disks' centres and radius), the share of void cells outside the
    rim's range too (``worst["ripples smooth"]``, ``worst["ripples TIN"]``)."""
    origin = fit[:, :2].min(axis=0)
    fit = np.column_stack([fit[:, :2] - origin, fit[:, 2]])
    test = np.column_stack([test[:, :2] - origin, test[:, 2]])
    variogram = meshcore.fit_variogram(fit[:, :2], fit[:, 2])
    cells = ranges = None
    if voids is not None:
        cells, ranges = void_cells(fit, voids[0] - origin, voids[1], float(variogram.spacing))
    predictions: dict[str, np.ndarray] = {}
    ripples: dict[str, float] = {}
    for name, (tm, qm) in MESHES.items():
        mesh = meshcore.build_mesh(fit[:, :2], tm, qm)
        z = np.full(mesh.vertices.shape[0], np.nan)
        z[mesh.input_to_vertex] = fit[:, 2]
        predictions["TIN" if name == "TIN" else f"linear {name}"] = meshcore.interpolate(mesh, z, test[:, 0], test[:, 1])
        surface = meshcore.smooth_surface(mesh, z, variogram)
        predictions[f"smooth {name}"] = meshcore.interpolate(mesh, z, test[:, 0], test[:, 1], surface=surface)
        if cells is not None:
            if name == "TIN":
                ripples["ripples TIN"] = outside_rim(meshcore.interpolate(mesh, z, cells[:, 0], cells[:, 1]), ranges)
            else:
                ripples["ripples smooth"] = outside_rim(
                    meshcore.interpolate(mesh, z, cells[:, 0], cells[:, 1], surface=surface), ranges)
    nn = nni(fit, test)
    if nn is not None:
        predictions["NNI"] = nn
    inside = np.isfinite(predictions["TIN"])
    predictions["kriging"] = np.full(test.shape[0], np.nan)
    predictions["kriging"][inside] = kriging_reference(fit, test[inside], variogram)
    rmse, worst = {}, {}
    for name, pred in predictions.items():
        err = pred[inside] - test[inside, 2]
        ok = np.isfinite(err)
        rmse[name] = float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else float("nan")
        worst[name] = float(np.max(np.abs(err[ok]))) if ok.any() else float("nan")
    worst.update(ripples)
    return rmse, worst, variogram


def point_splits(points: np.ndarray, repeats: int, seed: int = 11):
    """Point cross-validation: a random 10% withheld, ``repeats`` draws."""
    rng = np.random.default_rng(seed)
    n = points.shape[0]
    n_test = n // 10
    for _ in range(repeats):
        perm = rng.permutation(n)
        yield points[perm[n_test:]], points[perm[:n_test]]


def void_centres(points: np.ndarray, radius: float, rng: np.random.Generator, most: int = 15) -> np.ndarray | None:
    """Centres of the disks of one block draw: points at least ``radius`` from the
    edges of the survey's box, as many as cover 30% of it (at most ``most``); None when none fits."""
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    fits = np.all((points[:, :2] >= lo + radius) & (points[:, :2] <= hi - radius), axis=1)
    count = min(most, int(0.3 * float(np.prod(hi - lo)) / (np.pi * radius * radius)))
    if count < 1 or not fits.any():
        return None
    return points[rng.choice(np.flatnonzero(fits), min(count, int(fits.sum())), replace=False), :2]


def block_splits(points: np.ndarray, radius: float, repeats: int, seed: int = 100):
    """Block cross-validation: every point inside the disks of :func:`void_centres` withheld, ``repeats`` draws."""
    from scipy.spatial import cKDTree

    for draw in range(repeats):
        centres = void_centres(points, radius, np.random.default_rng(seed + draw))
        if centres is None:
            return
        out = cKDTree(centres).query(points[:, :2])[0] <= radius
        yield points[~out], points[out], centres


def scores(runs: list) -> tuple[dict[str, float], dict[str, float], dict[str, float], meshcore.Variogram]:
    """The TIN's RMSE (median over the draws), every method's change against it
    (median of the draws' changes), the largest errors, and the first draw's variogram."""
    methods = runs[0][0]
    tin = statistics.median(r[0]["TIN"] for r in runs)
    change = {m: statistics.median(r[0][m] / r[0]["TIN"] - 1.0 for r in runs) for m in methods if m != "TIN"}
    worst = {m: max(r[1][m] for r in runs) for m in runs[0][1]}
    return {"TIN": tin}, change, worst, runs[0][2]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--lidr-sets", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tests", default="point,5,10,20,40", help="point and/or void radii (CRS units), comma-separated")
    ap.add_argument("--only", default="", help="sample names (without extension) to run, comma-separated")
    ap.add_argument("--seed", type=int, default=0, help="added to the draws' seeds (11 and 100 + d): other draws")
    args = ap.parse_args(argv)
    tests = [t.strip() for t in args.tests.split(",") if t.strip()]
    only = {o.strip() for o in args.only.split(",") if o.strip()}

    rows = []
    for name in SAMPLES:
        label = name.split(".")[0]
        if only and label not in only and label.split("_lambert93")[0] not in only:
            continue
        path = args.samples / name
        if not path.is_file():
            print(f"skipped {name}: not found in {args.samples}")
            continue
        pts = ground_points(path)
        for test in tests:
            if test == "point":
                runs = [one_split(fit, withheld) for fit, withheld in point_splits(pts, args.repeats, 11 + args.seed)]
            else:
                runs = [one_split(fit, withheld, (centres, float(test)))
                        for fit, withheld, centres in block_splits(pts, float(test), args.repeats, 100 + args.seed)]
            rows.append((label, f"{pts.shape[0]:,}", "point" if test == "point" else f"r={float(test):g}",
                         scores(runs) if runs else None))
    lidr = []
    exact = []
    if "point" in tests:
        for seed in range(args.lidr_sets):
            fit, withheld = next(point_splits(lidr_set(seed), 1))
            lidr.append(one_split(fit, withheld))
            exact.append(exact_nodes_error(fit, withheld) / lidr[-1][0]["TIN"] - 1.0)
    if lidr:
        methods = lidr[0][0]
        # the change of the median RMSE over the sets (a set's own ratio swings with its hull's slivers)
        tin = {"TIN": statistics.median(r[0]["TIN"] for r in lidr)}
        change = {m: statistics.median(r[0][m] for r in lidr) / tin["TIN"] - 1.0 for m in methods if m != "TIN"}
        rows.append((f"lidR test ({len(lidr)} sets, median)", "5,000", "point", (tin, change, None, lidr[0][2])))

    header = ["survey", "ground pts", "test", "TIN RMSE", *METHODS, "max error smooth/TIN", "ripples smooth/TIN",
              "model"]
    out = []
    for label, n, test, found in rows:
        if found is None:
            out.append([label, n, test, "n/a", *([""] * len(METHODS)), "", "", ""])
            continue
        tin, change, worst, variogram = found
        cells = [f"{100.0 * change[m]:+.1f}%" if m in change else "" for m in METHODS]
        extreme = ripples = ""
        if worst is not None and test != "point":
            extreme = f"{worst['smooth S3/S4']:.2f}/{worst['TIN']:.2f}"
            ripples = f"{100.0 * worst['ripples smooth']:.2f}%/{100.0 * worst['ripples TIN']:.2f}%"
        model = variogram.model if test == "point" else ""
        out.append([label, n, test, f"{tin['TIN']:.4f}", *cells, extreme, ripples, model])
    table("Predicting withheld ground points, one at a time (point) and in voids of radius r (CRS units): "
          "the TIN's RMSE and every method's change against it (medians of the draws)", header, out)
    if exact:
        print(f"lidR test, smooth S3/S4 with the surface's exact values at its nodes: {100.0 * statistics.median(exact):+.1f}% "
              "(median): the patches' own error on the mesh's long faces, the bound of any smoother of the nodes")


if __name__ == "__main__":
    main()
