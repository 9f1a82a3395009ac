"""Synthetic LiDAR surveys with analytic terrain, for tests, benchmarks and the demo.

The terrain is a smooth analytic function (hills and a valley), so the error of
a DEM built from the points is known.  Points are written with laspy as real
LAS/LAZ files in a projected CRS, with ground (class 2) and non-ground classes,
a few withheld points and a few exact duplicates.  Like a real survey's files,
each strip holds its points in flight order (scan line after scan line) with
the attributes of a pulse: GPS time, intensity, returns, scan angle and
direction, flight line; so a file compresses and decodes as a real one does.  A scene can add a lake (no
returns at all, as over water), buildings (class 6 roofs, no ground beneath)
and trees (class 5 canopy over some ground returns).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["terrain_height", "SurveySpec", "demo_spec", "write_survey"]


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
    lake: tuple[float, float, float] | None = None
    """(x, y, radius) from the origin: a lake, with no returns."""
    buildings: int = 0
    """Flat-roofed buildings (class 6) of 10-30 m, placed at random."""
    trees: int = 0
    """Tree crowns (class 5) of 3-9 m radius, placed at random."""


def demo_spec(points: int = 400_000) -> SurveySpec:
    """The demo's survey: 800 m x 600 m of hills and a valley in Lambert-93, four
    overlapping strips, a lake in the valley, a village and scattered trees."""
    return SurveySpec(
        points=points, files=4, width=800.0, height=600.0, overlap=25.0, ground_share=0.93,
        lake=(500.0, 330.0, 70.0), buildings=40, trees=400, seed=2026,
    )


def _scene(spec: SurveySpec, rng: np.random.Generator):
    """Buildings (x0, y0, x1, y1, roof z) and trees (x, y, r, height), off the lake."""
    x0, y0 = spec.origin

    def off_lake(x, y, margin):
        if spec.lake is None:
            return True
        lx, ly, r = spec.lake
        return (x - lx) ** 2 + (y - ly) ** 2 > (r + margin) ** 2

    buildings = []
    while len(buildings) < spec.buildings:
        # a village on the hillside: buildings clustered around one place
        cx = spec.width * 0.25 + rng.normal(0, spec.width * 0.08)
        cy = spec.height * 0.6 + rng.normal(0, spec.height * 0.08)
        w, h = rng.uniform(10, 30, 2)
        if not (w < cx < spec.width - w and h < cy < spec.height - h) or not off_lake(cx, cy, 40):
            continue
        box = (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
        if any(box[0] < b[2] + 4 and b[0] < box[2] + 4 and box[1] < b[3] + 4 and b[1] < box[3] + 4 for b in buildings):
            continue
        ground = terrain_height(np.array([x0 + cx]), np.array([y0 + cy]), spec.origin)[0]
        buildings.append((*box, float(ground + rng.uniform(5, 14))))
    trees = []
    while len(trees) < spec.trees:
        x, y = rng.uniform(0, spec.width), rng.uniform(0, spec.height)
        if off_lake(x, y, 10) and not any(b[0] - 5 < x < b[2] + 5 and b[1] - 5 < y < b[3] + 5 for b in buildings):
            trees.append((x, y, rng.uniform(3, 9), rng.uniform(8, 25)))
    return buildings, trees


def write_survey(folder: str | Path, spec: SurveySpec = SurveySpec()) -> list[Path]:
    """Write the survey's files into ``folder``; returns their paths."""
    import laspy
    from pyproj import CRS

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(spec.seed)
    buildings, trees = _scene(spec, rng)
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
        cls = np.where(ground, 2, rng.choice([1, 3, 4], per_file)).astype(np.uint8)
        for bx0, by0, bx1, by1, roof in buildings:
            on = (x >= x0 + bx0) & (x <= x0 + bx1) & (y >= y0 + by0) & (y <= y0 + by1)
            ground[on] = False
            cls[on] = 6
            z[on] = roof + rng.normal(0.0, 0.03, int(on.sum()))
        for tx, ty, r, height in trees:
            d2 = (x - x0 - tx) ** 2 + (y - y0 - ty) ** 2
            crown = (d2 <= r * r) & (rng.random(per_file) < 0.7)  # some pulses reach the ground
            ground[crown] = False
            cls[crown] = 5
            z[crown] = terrain_height(x[crown], y[crown], spec.origin) + height * (1.0 - 0.5 * d2[crown] / (r * r)) * rng.uniform(0.85, 1.0, int(crown.sum()))
        if spec.lake is not None:
            lx, ly, r = spec.lake
            dry = (x - x0 - lx) ** 2 + (y - y0 - ly) ** 2 > r * r  # water returns nothing
            x, y, z, ground, cls = x[dry], y[dry], z[dry], ground[dry], cls[dry]
        n = x.size
        n_dup = int(spec.duplicate_share * n)
        if n_dup:
            src = rng.integers(0, n, n_dup)
            dst = rng.integers(0, n, n_dup)
            x[dst], y[dst], ground[dst], cls[dst] = x[src], y[src], ground[src], cls[src]
            z[dst] = z[src] + np.where(ground[src], rng.random(n_dup) * 0.05, 1.0)
        header = laspy.LasHeader(point_format=spec.point_format, version=spec.version)
        header.scales = np.array([0.01, 0.01, 0.01])
        header.offsets = np.array([x0, y0, 0.0])
        header.add_crs(CRS.from_user_input(spec.crs))
        las = laspy.LasData(header)
        las.x = x
        las.y = y
        las.z = z
        las.classification = cls
        las.withheld = rng.random(n) < spec.withheld_share
        _as_flown(las, k, lo, hi, spec)
        path = folder / f"strip_{k:02d}.{'laz' if spec.laz else 'las'}"
        las.write(path)
        paths.append(path)
    return paths


#: pulses per second of the simulated scanner
_PULSE_RATE = 200_000.0


def _as_flown(las, strip: int, lo: float, hi: float, spec: SurveySpec) -> None:
    """Put a strip's points in flight order and give them a pulse's attributes.

    The aircraft flies north along the strip's middle, scanning across it
    (west-east, then back): points are sorted by scan line, and along each line
    in the direction of the scan.  Attributes come from their own random
    stream, so the geometry of a survey does not depend on them.
    """
    x = np.asarray(las.x) - spec.origin[0]
    y = np.asarray(las.y) - spec.origin[1]
    n = x.size
    if n == 0:
        return
    spacing = ((hi - lo) * spec.height / n) ** 0.5  # one scan line per point spacing
    line = np.floor(y / spacing).astype(np.int64)
    backward = (line % 2) == 1
    order = np.lexsort((np.where(backward, -x, x), line))
    las.points = las.points[order]
    x, y, line, backward = x[order], y[order], line[order], backward[order]
    ground = np.asarray(las.classification) == 2
    rng = np.random.default_rng([spec.seed, strip, 7])
    names = set(las.point_format.dimension_names)
    half = max((hi - lo) / 2.0, 1e-9)
    angle = 20.0 * (x - (lo + hi) / 2.0) / half  # degrees off nadir
    if "gps_time" in names:
        las.gps_time = 4.0e8 + 3600.0 * strip + np.arange(n) / _PULSE_RATE
    returns = np.where(ground, rng.choice([1, 1, 1, 2], n), rng.integers(1, 4, n)).astype(np.uint8)
    las.number_of_returns = returns
    # ground is the last return of its pulse; other returns are any of theirs
    las.return_number = np.where(ground, returns, rng.integers(1, 4, n) % returns + 1).astype(np.uint8)
    las.intensity = np.clip(rng.gamma(8.0, 1.0, n) * np.where(ground, 250.0, 110.0), 0, 65535).astype(np.uint16)
    las.scan_direction_flag = (~backward).astype(np.uint8)
    edge = np.zeros(n, dtype=bool)
    edge[:-1] |= line[1:] != line[:-1]
    las.edge_of_flight_line = edge.astype(np.uint8)
    if "scan_angle" in names:
        las.scan_angle = np.round(angle / 0.006).astype(np.int16)
    else:
        las.scan_angle_rank = np.round(angle).astype(np.int8)
    las.point_source_id = np.full(n, strip + 1, dtype=np.uint16)
