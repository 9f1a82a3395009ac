"""Greedy against optimal elimination of diagonals; prints tables (run by hand).

    python bench/bench_merge.py [--points 500] [--trials 20] [--seed 0]

For the paper's setting (points uniform in the unit disc), compares the
paper's greedy queue with a maximum-weight matching of the positive gains:
total gain, number of quadrangles, time, and the experiment's L2 errors of
the combined rows S2(q) and S4(q).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import meshcore
from experiments.combined_mesh import run_experiment

PAIRED = {"s2": (meshcore.s1, meshcore.s2), "s4": (meshcore.s3, meshcore.s4)}


def total_gain(mesh: meshcore.Mesh, quad_measure: str) -> float:
    """Sum over quadrangles of S_q(q) - max{S(e13), S(e24)}."""
    tri_measure, quad = PAIRED[quad_measure]
    v = mesh.vertices
    q = mesh.faces[mesh.is_quad]
    p0, p1, p2, p3 = q.T
    d02 = np.minimum(tri_measure(v[np.stack([p0, p1, p2], 1)]), tri_measure(v[np.stack([p2, p3, p0], 1)]))
    d13 = np.minimum(tri_measure(v[np.stack([p1, p2, p3], 1)]), tri_measure(v[np.stack([p3, p0, p1], 1)]))
    return float((quad(v[q]) - np.maximum(d02, d13)).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=500)
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    sets = []
    for _ in range(args.trials):
        r = np.sqrt(rng.random(args.points))
        a = rng.random(args.points) * 2 * np.pi
        sets.append(np.c_[r * np.cos(a), r * np.sin(a)])
    print(f"{args.trials} point sets of {args.points} points uniform in the unit disc (mean per set)")
    print(f"{'row':6} {'merge':8} {'total gain':>11} {'quads':>7} {'seconds':>8}")
    for tm, qm in (("s1", "s2"), ("s3", "s4")):
        for merge in ("greedy", "optimal"):
            gains, quads, secs = [], [], []
            for xy in sets:
                t0 = time.perf_counter()
                mesh = meshcore.build_mesh(xy, tm, qm, merge)
                secs.append(time.perf_counter() - t0)
                gains.append(total_gain(mesh, qm))
                quads.append(mesh.n_quads)
            print(f"{qm.upper():6} {merge:8} {np.mean(gains):11.3f} {np.mean(quads):7.1f} {np.mean(secs):8.4f}")

    results = {m: run_experiment(args.points, args.trials, args.seed, merge=m) for m in ("greedy", "optimal")}
    print("\nL2 errors of the combined rows (experiment functions, same seed)")
    print(f"{'function':9} {'row':6} {'column':22} {'greedy':>9} {'optimal':>9} {'change':>8}")
    g = results["greedy"].mean_errors
    o = results["optimal"].mean_errors
    for k, fname in enumerate(results["greedy"].functions):
        for r, row in enumerate(results["greedy"].rows):
            if not row.endswith("(q)"):
                continue
            for c, col in enumerate(("||f-g||_2", "||grad f - grad g||_2")):
                change = (o[k, r, c] - g[k, r, c]) / g[k, r, c]
                print(f"{fname:9} {row:6} {col:22} {g[k, r, c]:9.5f} {o[k, r, c]:9.5f} {change:+8.2%}")


if __name__ == "__main__":
    main()
