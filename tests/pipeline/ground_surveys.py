"""Ground surveys written as LAS files for the tiling tests, and a recorder of
what each tile's mesh reports."""

from __future__ import annotations

import laspy
import numpy as np
from pyproj import CRS

import pipeline.runs.runner as runner

ORIGIN = (651_000.0, 6_861_000.0)
"""Where the surveys lie, in Lambert-93 (EPSG:2154)."""


def write_ground(path, x, y, z):
    """``x, y, z`` as ground points (class 2) of a LAS 1.4 file at centimetre
    scale, offset to :data:`ORIGIN`, in EPSG:2154."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = np.array([0.01, 0.01, 0.01]), np.array([*ORIGIN, 0.0])
    header.add_crs(CRS.from_epsg(2154))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.round(z, 2)
    las.classification = np.full(np.size(x), 2, dtype=np.uint8)
    las.write(path)
    return path


def ground_with_void(path, rng, n: int, side: float, void):
    """``n`` points over ``side`` x ``side`` m from :data:`ORIGIN`, cut at the LAS
    scale, gently sloping and swelling, without those where ``void(x, y)``
    (coordinates from the origin) holds."""
    x = np.round(ORIGIN[0] + rng.random(n) * side, 2)
    y = np.round(ORIGIN[1] + rng.random(n) * side, 2)
    keep = ~void(x - ORIGIN[0], y - ORIGIN[1])
    x, y = x[keep], y[keep]
    return write_ground(path, x, y, 50.0 + 0.01 * (x - ORIGIN[0]) + 0.3 * np.sin(y / 40.0))


def same_mesh(store_a, store_b) -> bool:
    """Whether two stores hold the same faces over the same nodes."""
    from pipeline.store import zarr_store as store

    from .store_checks import face_set

    a, b = store.read_mesh(store_a), store.read_mesh(store_b)
    return face_set(np.asarray(a[0]), a[2]) == face_set(np.asarray(b[0]), b[2])


def record_tiles(monkeypatch, change=None) -> list:
    """The (job, summary) of every tile meshed from now on, in order; ``change``
    (a job to a job) alters each job first."""
    meshed, out = runner.mesh_tile, []

    def mesh_tile(job):
        job = job if change is None else change(job)
        summary = meshed(job)
        out.append((job, summary))
        return summary

    monkeypatch.setattr(runner, "mesh_tile", mesh_tile)
    return out


def middle_tiles_of_a_delaunay_run(tmp_path, monkeypatch, path, tile_size: float, buffer: float) -> tuple[list, bool]:
    """The summaries of the four middle tiles of a 4 x 4 run of the Delaunay
    mesh of ``path`` (their corner in the survey's middle), and whether that
    run's mesh is the untiled one."""
    from pipeline import RunConfig, run

    meshed = record_tiles(monkeypatch)
    common = dict(inputs=(str(path),), resolution=1.0, triangle_measure="delaunay", quad_measure="none", workers=1)
    run(RunConfig(output=str(tmp_path / "tiled.zarr"), tile_size=tile_size, buffer=buffer, **common), progress=False)
    middle = [s for _, s in meshed if (s.row, s.col) in {(1, 1), (1, 2), (2, 1), (2, 2)}]
    run(RunConfig(output=str(tmp_path / "whole.zarr"), tile_size=4096.0, **common), progress=False)
    return middle, same_mesh(tmp_path / "tiled.zarr", tmp_path / "whole.zarr")
