"""Comparing stores: the same arrays, byte for byte."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import zarr

METADATA = {"zarr.json", ".zarray", ".zattrs", ".zgroup", ".zmetadata"}


def chunk_files(path: Path) -> dict[str, bytes]:
    """Every array chunk of the store, by relative path (metadata left out)."""
    out = {}
    for root, _, files in os.walk(path):
        for name in files:
            if name not in METADATA:
                full = Path(root) / name
                out[str(full.relative_to(path))] = full.read_bytes()
    return out


def assert_same_store(path: Path, reference: Path, changed: tuple[str, ...] = ()) -> None:
    """Every array of ``reference`` and its chunk files are in ``path``, the same byte for byte,
    but the arrays named in ``changed`` (changed on purpose: left out)."""
    got, want = zarr.open_group(str(path), mode="r"), zarr.open_group(str(reference), mode="r")
    names = sorted(name for name, _ in want.arrays()) + sorted(f"mesh/{n}" for n, _ in want["mesh"].arrays())
    for name in names:
        if name in changed:
            continue
        a, b = got[name][...], want[name][...]
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), name
    got_files, want_files = ({k: v for k, v in chunk_files(p).items()
                              if not any(Path(k).as_posix().startswith(f"{n}/") for n in changed)}
                             for p in (path, reference))
    differ = sorted(k for k in set(got_files) & set(want_files) if got_files[k] != want_files[k])
    assert got_files == want_files, (  # byte for byte
        f"chunk files: only in {path.name}: {sorted(set(got_files) - set(want_files))}, "
        f"only in the reference: {sorted(set(want_files) - set(got_files))}, different bytes: {differ}"
    )
    assert got.attrs["complete"] is True


def face_set(node_xy, faces) -> set:
    """A mesh's faces, each as the bytes of its corners' coordinates (x0, y0,
    x1, y1, ...) from its smallest corner (by x, then y): the same set for the
    same mesh whatever its vertex numbering.  Built with numpy, face lengths
    one at a time (a tuple per corner in Python took 6 s for 1.15M faces)."""
    xy = np.asarray(node_xy, dtype=np.float64)[:, :2] + 0.0  # -0.0 as 0.0: the same bytes for equal values
    faces = np.asarray(faces).reshape(len(faces), -1)
    sizes = (faces >= 0).sum(axis=1)
    # the corners of each face in their order, the -1 of padding after them
    corners = np.take_along_axis(faces, np.argsort(faces < 0, axis=1, kind="stable"), axis=1)
    out: set = set()
    for k in np.unique(sizes).tolist():
        points = xy[corners[sizes == k, :k]]  # (n, k, 2)
        x, y = points[..., 0], points[..., 1]
        # the first smallest corner: least x, of those least y
        first = np.argmin(np.where(x == x.min(axis=1, keepdims=True), y, np.inf), axis=1)
        turn = (first[:, None] + np.arange(k)) % k
        rows = np.ascontiguousarray(np.take_along_axis(points, turn[..., None], axis=1).reshape(-1, 2 * k))
        out.update(rows.view(np.dtype((np.void, rows.itemsize * 2 * k))).ravel().tolist())  # a face: its bytes
    return out
