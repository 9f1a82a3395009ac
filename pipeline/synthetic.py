"""Synthetic LiDAR surveys with analytic terrain, for tests, benchmarks and the demo.

The terrain is a smooth analytic function (hills and a valley), so the error of
a DEM built from the points is known.  Points are written with laspy as real
LAS/LAZ files in a projected CRS, with ground (class 2) and non-ground classes,
a few withheld points and a few exact duplicates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["terrain_height", "SurveySpec", "write_survey"]


def terrain_height(x: NDArray[np.float64], y: NDArray[np.float64], origin=(0.0, 0.0)) -> NDArray[np.float64]:
    """Hills and a valley (metres), a smooth function of the position (metres)."""
    u = (np.asarray(x) - origin[0]) / 250.0
    v = (np.asarray(y) - origin[1]) / 250.0
    return 120.0 + 15.0 * np.sin(u) * np.cos(0.7 * v) + 6.0 * np.cos(1.9 * u + 0.4 * v) - 8.0 * np.exp(-((u - 2.0) ** 2))


@dataclass(frozen=True)
class SurveySpec:
    """A rectangular survey cut into ``files`` strips."""

    origin: tuple[float, float] = (651000.0, 6861000.0)
    width: float = 600.0
    height: float = 400.0
    points: int = 200_000
    files: int = 2
    overlap: float = 10.0
    ground_share: float = 0.8
    withheld_share: float = 0.01
    duplicate_share: float = 0.005
    crs: str = "EPSG:2154"
    laz: bool = True
    point_format: int = 6
    version: str = "1.4"
    seed: int = 0


def write_survey(folder: str | Path, spec: SurveySpec = SurveySpec()) -> list[Path]:
    """Write the survey's files into ``folder``; returns their paths."""
    import laspy
    from pyproj import CRS

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(spec.seed)
    x0, y0 = spec.origin
    strip = spec.width / spec.files
    per_file = spec.points // spec.files
    paths = []
    for k in range(spec.files):
        lo = max(0.0, k * strip - spec.overlap)
        hi = min(spec.width, (k + 1) * strip + spec.overlap)
        x = x0 + lo + rng.random(per_file) * (hi - lo)
        y = y0 + rng.random(per_file) * spec.height
        x = np.round(x, 2)
        y = np.round(y, 2)
        ground = rng.random(per_file) < spec.ground_share
        z = terrain_height(x, y, spec.origin)
        z = np.where(ground, z, z + rng.random(per_file) * 20.0 + 1.0)
        n_dup = int(spec.duplicate_share * per_file)
        if n_dup:
            src = rng.integers(0, per_file, n_dup)
            dst = rng.integers(0, per_file, n_dup)
            x[dst], y[dst], ground[dst] = x[src], y[src], ground[src]
            z[dst] = z[src] + np.where(ground[src], rng.random(n_dup) * 0.05, 1.0)
        header = laspy.LasHeader(point_format=spec.point_format, version=spec.version)
        header.scales = np.array([0.01, 0.01, 0.01])
        header.offsets = np.array([x0, y0, 0.0])
        header.add_crs(CRS.from_user_input(spec.crs))
        las = laspy.LasData(header)
        las.x = x
        las.y = y
        las.z = z
        las.classification = np.where(ground, 2, rng.choice([1, 3, 5, 6], per_file)).astype(np.uint8)
        las.withheld = rng.random(per_file) < spec.withheld_share
        path = folder / f"strip_{k:02d}.{'laz' if spec.laz else 'las'}"
        las.write(path)
        paths.append(path)
    return paths
