"""Checks of mesh properties used by several test modules (not collected as tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from meshcore.mesh import Mesh
from meshcore.quality import s1, s2, s3, s4

TRIANGLE = {"s1": s1, "s3": s3}
QUAD = {"s2": s2, "s4": s4}
PAIRED = {"s2": "s1", "s4": "s3"}


def hand_mesh(vertices, faces) -> Mesh:
    """A mesh from hand-written vertices and faces (fresh arrays; vertex i is input point i)."""
    v = np.asarray(vertices, dtype=np.float64)
    return Mesh(v, np.asarray(faces, dtype=np.int64), np.arange(v.shape[0]))


def cross(o, a, b):
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])


def triangle_pairs(mesh):
    """(a, b, c, d) for every pair of adjacent triangles: (a, b, c) and (b, a, d), both CCW."""
    faces = mesh.faces
    tri = faces[faces[:, 3] < 0, :3]
    directed = {}
    for t, (a, b, c) in enumerate(tri.tolist()):
        directed[(a, b)] = c
        directed[(b, c)] = a
        directed[(c, a)] = b
    out = []
    for (a, b), c in directed.items():
        if a < b and (b, a) in directed:
            out.append((a, b, c, directed[(b, a)]))
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def strictly_convex(v, a, b, c, d):
    """Quadrangle a, d, b, c (the union of (a, b, c) and (b, a, d)) strictly convex."""
    return (cross(v[c], v[d], v[a]) < 0) & (cross(v[c], v[d], v[b]) > 0)


def pair_scores(mesh, measure, pairs):
    """(current, alternative) pair measure: min over the two triangles, for each diagonal."""
    v = mesh.vertices - mesh.vertices.min(axis=0)
    f = TRIANGLE[measure]
    a, b, c, d = pairs.T
    current = np.minimum(f(v[np.stack([a, b, c], 1)]), f(v[np.stack([b, a, d], 1)]))
    alternative = np.minimum(f(v[np.stack([a, d, c], 1)]), f(v[np.stack([b, c, d], 1)]))
    return current, alternative


def quad_gains(mesh, quad_measure, quads):
    """Elimination gain of every quad a, d, b, c given as faces rows (both diagonals checked)."""
    v = mesh.vertices - mesh.vertices.min(axis=0)
    tm = TRIANGLE[PAIRED[quad_measure]]
    q = QUAD[quad_measure](v[quads])
    p0, p1, p2, p3 = quads.T
    d02 = np.minimum(tm(v[np.stack([p0, p1, p2], 1)]), tm(v[np.stack([p2, p3, p0], 1)]))
    d13 = np.minimum(tm(v[np.stack([p1, p2, p3], 1)]), tm(v[np.stack([p3, p0, p1], 1)]))
    return q - np.maximum(d02, d13)


def edge_faces(faces) -> dict[tuple[int, int], list[int]]:
    """The faces of every edge, keyed by its ends (lower index first)."""
    sides: dict[tuple[int, int], list[int]] = {}
    for f, face in enumerate(np.asarray(faces).tolist()):
        n = 4 if face[3] >= 0 else 3
        for k in range(n):
            a, b = face[k], face[(k + 1) % n]
            sides.setdefault((min(a, b), max(a, b)), []).append(f)
    return sides


def python_and_compiled(script: str) -> list[list[np.ndarray]]:
    """The arrays ``script`` prints as a JSON list (``None`` for NaN), run with
    ``NUMBA_DISABLE_JIT=1`` and then compiled: the kernels' Python form and theirs."""
    runs = []
    for disable in ("1", "0"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
        runs.append([np.array(a, dtype=np.float64) for a in json.loads(result.stdout)])
    return runs
