"""Accuracy of the surfaces: predicting withheld ground points (run by hand).

    python bench/bench_accuracy.py [--samples ../shared/data] [--lidr-sets 20] [--repeats 3]

The test: take a survey's ground points (class 2), merge exact x, y
duplicates (the lowest z stays), withhold a random 10%
(``numpy.random.default_rng(11)``, ``--repeats`` draws), fit every method on
the rest and take the root mean square error at the withheld points that lie
inside the fitted points' convex hull (the same points for every method).

Methods:

- ``TIN``: meshcore's Delaunay triangulation, linear (what PDAL, LAStools,
  lidR and Whitebox grid from);
- ``S1/S2``, ``S3/S4``: the combined mesh's linear/bilinear surface;
- ``smooth TIN``, ``smooth S1/S2``, ``smooth S3/S4``: ``surface="smooth"``
  (cubic patches, kriged nodes, the variogram fitted on the fitted points);
- ``NNI``: startinpy's natural-neighbour interpolation (``pip install -e .[bench]``; skipped when missing);
- ``kriging``: a reference written here with numpy alone, ordinary kriging
  at each withheld point from its 32 nearest fitted points with the same
  fitted variogram (its model too) (no patches, not through a mesh).

The lidR test re-enacted (``tests/testthat/test-rasterize_terrain.R``): 5,000
uniform points on 100 x 100 m of ``0.1 x + 0.1 y + sin(0.01 x) - sin(0.1 y)
+ sin(0.003 x y)``, z rounded to the mm, one set per seed, withheld as above
(one draw per set).

Prints RMSE and the change against the TIN per survey, the medians over the
lidR sets, and the fitted variogram (its nugget is the noise floor).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import meshcore
from bench_mesh import table  # the sibling script (bench/ is on sys.path when run as a script)

SAMPLES = ("ign_semis_lambert93.laz", "extra_byte_blocks_lambert93.laz", "autzen_trim.las",
           "startinpy_small_extrabytes.laz", "4_6_crop_us_feet.las")

MESHES = {"TIN": ("delaunay", None), "S1/S2": ("s1", "s2"), "S3/S4": ("s3", "s4")}


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
    plan = meshcore.smooth_plan(mesh, variogram)
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


def one_split(fit: np.ndarray, test: np.ndarray) -> tuple[dict[str, float], meshcore.Variogram, dict[str, float]]:
    """RMSE of every method on one split, the variogram, and seconds per method."""
    variogram = meshcore.fit_variogram(fit[:, :2], fit[:, 2])
    predictions: dict[str, np.ndarray] = {}
    seconds: dict[str, float] = {}
    for name, (tm, qm) in MESHES.items():
        t0 = time.perf_counter()
        mesh = meshcore.build_mesh(fit[:, :2], tm, qm)
        z = np.full(mesh.vertices.shape[0], np.nan)
        z[mesh.input_to_vertex] = fit[:, 2]
        predictions[name] = meshcore.interpolate(mesh, z, test[:, 0], test[:, 1])
        seconds[name] = time.perf_counter() - t0
        t0 = time.perf_counter()
        surface = meshcore.smooth_surface(mesh, z, variogram)
        predictions[f"smooth {name}"] = meshcore.interpolate(mesh, z, test[:, 0], test[:, 1], surface=surface)
        seconds[f"smooth {name}"] = seconds[name] + time.perf_counter() - t0
    nn = nni(fit, test)
    if nn is not None:
        predictions["NNI"] = nn
    inside = np.isfinite(predictions["TIN"])
    predictions["kriging"] = np.full(test.shape[0], np.nan)
    predictions["kriging"][inside] = kriging_reference(fit, test[inside], variogram)
    rmse = {}
    for name, pred in predictions.items():
        err = pred[inside] - test[inside, 2]
        rmse[name] = float(np.sqrt(np.nanmean(err**2))) if np.isfinite(err).any() else float("nan")
    return rmse, variogram, seconds


def splits(points: np.ndarray, repeats: int, rng: np.random.Generator):
    n = points.shape[0]
    n_test = n // 10
    for _ in range(repeats):
        perm = rng.permutation(n)
        yield points[perm[n_test:]], points[perm[:n_test]]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--samples", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--lidr-sets", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    results: list[tuple[str, int, dict[str, float], meshcore.Variogram]] = []
    for name in SAMPLES:
        path = args.samples / name
        if not path.is_file():
            print(f"skipped {name}: not found in {args.samples}")
            continue
        pts = ground_points(path)
        rng = np.random.default_rng(11)
        runs = [one_split(fit, test) for fit, test in splits(pts, args.repeats, rng)]
        mean = {m: statistics.fmean(r[0][m] for r in runs) for m in runs[0][0]}
        results.append((name.split(".")[0], pts.shape[0], mean, runs[0][1]))
    lidr = []
    exact = []
    for seed in range(args.lidr_sets):
        pts = lidr_set(seed)
        fit, test = next(splits(pts, 1, np.random.default_rng(11)))
        lidr.append(one_split(fit, test))
        exact.append(exact_nodes_error(fit, test) / lidr[-1][0]["TIN"] - 1.0)
    if lidr:
        mean = {m: statistics.median(r[0][m] for r in lidr) for m in lidr[0][0]}
        results.append((f"lidR test ({len(lidr)} sets, median)", 5000, mean, lidr[0][1]))

    methods = list(results[0][2])
    header = ["survey", "ground pts"] + methods
    rows = []
    for label, n, rmse, _ in results:
        tin = rmse["TIN"]
        rows.append([label, f"{n:,}"] + [
            f"{rmse[m]:.4f}" if m == "TIN" else f"{100.0 * (rmse[m] / tin - 1.0):+.1f}%" for m in methods
        ])
    table("RMSE at withheld ground points: the TIN's, and every method's change against it", header, rows)
    if exact:
        print(f"lidR test, smooth S3/S4 with the surface's exact values at its nodes: {100.0 * statistics.median(exact):+.1f}% "
              "(median): the patches' own error on the mesh's long faces, the bound of any smoother of the nodes")
    rows = [[label, v.model, f"{v.nugget:.3g}", f"{v.sill:.3g}", f"{v.range:.3g}", f"{v.spacing:.3g}", f"{np.sqrt(v.nugget):.3g}",
             f"{100.0 * (r['kriging'] / r['TIN'] - 1.0):+.1f}%", f"{100.0 * (r['smooth S3/S4'] / r['TIN'] - 1.0):+.1f}%"]
            for label, _, r, v in results]
    table("Fitted variograms (first draw): the nugget's root is the noise floor in z units",
          ["survey", "model", "nugget", "sill", "range", "spacing", "sqrt(nugget)", "kriging", "smooth S3/S4"], rows)


if __name__ == "__main__":
    main()
