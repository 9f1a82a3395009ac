"""meshcore under attack: random and adversarial point sets, every result valid.

``MESHCORE_ATTACK_CASES`` sets the number of point sets (a sample of a few
hundred by default; 10,000+ for the long run), ``MESHCORE_ATTACK_SEED`` the seed.
Each set is built with every option pair, as a whole mesh and as window pieces,
and must pass :func:`meshcore.validate` with every input point a vertex or
merged into one.
"""

from __future__ import annotations

import os

import numpy as np

from meshcore import build_mesh, validate

CASES = int(os.environ.get("MESHCORE_ATTACK_CASES", "1000"))
SEED = int(os.environ.get("MESHCORE_ATTACK_SEED", "1123"))
OPTIONS = [("s1", "s2"), ("s3", "s4"), ("delaunay", None), ("s3", None)]


def _grid(rng):
    n = int(rng.integers(2, 30))
    g = np.stack(np.meshgrid(np.arange(n), np.arange(int(rng.integers(2, 30)))), -1).reshape(-1, 2).astype(float)
    return g * rng.choice([1.0, 0.5, 0.25, 1e-3, 3.0])


def _rings(rng):
    k = int(rng.integers(1, 6))
    parts = []
    for r in rng.uniform(0.5, 10, k):
        m = int(rng.integers(3, 80))
        a = 2 * np.pi * np.arange(m) / m
        parts.append(np.c_[r * np.cos(a), r * np.sin(a)])
    parts.append(np.zeros((1, 2)))
    return np.round(np.vstack(parts), int(rng.integers(2, 12)))


def _strip(rng):
    n = int(rng.integers(3, 400))
    x = np.sort(rng.uniform(0, 100, n))
    return np.c_[x, x * rng.uniform(-2, 2) + rng.normal(0, 10.0 ** -rng.integers(3, 12), n)]


def _cluster(rng):
    centres = rng.uniform(0, 1000, (int(rng.integers(1, 5)), 2))
    pts = [c + rng.normal(0, 10.0 ** -rng.integers(1, 6), (int(rng.integers(1, 200)), 2)) for c in centres]
    return np.vstack(pts)


def _survey(rng):
    # survey-scale coordinates with millimetre spacing (the local origin must be exact)
    n = int(rng.integers(3, 800))
    base = np.array([rng.uniform(1e5, 9e5), rng.uniform(1e6, 7e6)])
    return base + np.round(rng.uniform(0, rng.choice([0.05, 1.0, 30.0]), (n, 2)), 3)


def _duplicates(rng):
    src = rng.uniform(0, 10, (int(rng.integers(1, 20)), 2))
    return src[rng.integers(0, len(src), int(rng.integers(1, 300)))]


def _random(rng):
    return rng.random((int(rng.integers(0, 600)), 2)) * 10.0 ** rng.integers(-3, 7)


def _collinear(rng):
    t = rng.uniform(0, 1, int(rng.integers(1, 100)))
    return np.c_[t, 2 * t + 1]


KINDS = [_grid, _rings, _strip, _cluster, _survey, _duplicates, _random, _collinear]


def _check(xy, tm, qm, window=None):
    mesh = build_mesh(xy, tm, qm, window=window)
    validate(mesh)
    if len(xy):
        # every input point is a vertex, or merged into the one with its coordinates
        assert np.array_equal(mesh.vertices[mesh.input_to_vertex], xy)
    return mesh


def test_adversarial_point_sets_give_valid_meshes():
    rng = np.random.default_rng(SEED)
    tried = {kind.__name__: 0 for kind in KINDS}
    for case in range(CASES):
        kind = KINDS[case % len(KINDS)]
        xy = kind(rng)
        if len(xy) and rng.random() < 0.3:
            xy = np.vstack([xy, xy[rng.integers(0, len(xy), max(1, len(xy) // 10))]])  # duplicates mixed in
        xy = xy[rng.permutation(len(xy))]
        tm, qm = OPTIONS[case % len(OPTIONS)]
        try:
            _check(xy, tm, qm)
            if len(xy) > 10:
                lo, hi = xy.min(axis=0), xy.max(axis=0)
                mid = lo + (hi - lo) * rng.uniform(0.2, 0.8, 2)
                _check(xy, tm, qm, window=(-np.inf, -np.inf, float(mid[0]), float(mid[1])))
        except Exception as exc:
            raise AssertionError(f"case {case} ({kind.__name__}, {tm}/{qm}, {len(xy)} points, seed {SEED}): {exc}") from exc
        tried[kind.__name__] += 1
    assert sum(tried.values()) == CASES
