"""Every tile's seams certify on surveys shaped like real ones.

Real archives are cut on straight lines (kilometre tiles, slanted project
boundaries), store coordinates as integers of a scale (cm, 0.25 mm) at
survey-sized offsets, and their ground is sparse, with voids under canopy and
water.  The slivers along a cut edge have circumcircles of thousands of
kilometres whose lens inside the survey runs the length of the edge: a tile
must find every point such a circle reaches, however far, and its piece must
then be the global mesh's piece.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import meshcore
from pipeline.store import zarr_store as store
from pipeline.config import RunConfig
from pipeline.runs.runner import run

from .store_checks import face_set


def _survey(path: Path, seed: int, width: float, height: float) -> tuple[np.ndarray, dict]:
    """A ground-only LAS file; returns its points' x, y as stored and the draw."""
    import laspy

    rng = np.random.default_rng(seed)
    draw = {
        "scale": float(rng.choice([0.01, 0.00025])),
        "offset": (float(rng.choice([6.0e5, 2.9e5])), float(rng.choice([5.0e6, 6.8e6]))),
        "density": float(rng.uniform(0.1, 1.0)),
        "slanted": bool(rng.integers(2)),
    }
    x0, y0 = draw["offset"][0] + 1000.0 * rng.integers(0, 9), draw["offset"][1] + 1000.0 * rng.integers(0, 9)
    n = int(draw["density"] * width * height)
    x = x0 + rng.uniform(0.0, width, n)
    y = y0 + rng.uniform(0.0, height, n)
    keep = np.ones(n, dtype=bool)
    for _ in range(int(rng.integers(1, 4))):  # voids: water, a building, canopy
        cx, cy = x0 + rng.uniform(0, width), y0 + rng.uniform(0, height)
        keep &= np.hypot(x - cx, y - cy) > rng.uniform(0.05, 0.25) * min(width, height)
    scale = draw["scale"]
    # stored as integers of the scale; cut as a tiler cuts, on the stored values
    ix = np.round((x - draw["offset"][0]) / scale)
    iy = np.round((y - draw["offset"][1]) / scale)
    sx = ix * scale + draw["offset"][0]
    sy = iy * scale + draw["offset"][1]
    keep &= (sx >= x0) & (sx < x0 + width) & (sy >= y0) & (sy < y0 + height)
    if draw["slanted"]:  # a project boundary across a corner, at an angle no grid has
        angle = rng.uniform(0.2, 1.3)
        u = (sx - x0) * np.cos(angle) + (sy - y0) * np.sin(angle)
        keep &= u >= rng.uniform(0.1, 0.3) * width * np.cos(angle)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([scale, scale, 0.01])
    header.offsets = np.array([draw["offset"][0], draw["offset"][1], 0.0])
    las = laspy.LasData(header)
    las.X, las.Y = ix[keep].astype(np.int32), iy[keep].astype(np.int32)
    las.z = 100.0 + 0.02 * (sx[keep] - x0) + 5.0 * np.sin((sy[keep] - y0) / 30.0)
    las.classification = np.full(int(keep.sum()), 2, dtype=np.uint8)
    las.write(path)
    back = laspy.read(path)
    return np.column_stack([np.asarray(back.x), np.asarray(back.y)]), draw


def _run(path: Path, out: Path, **kw):
    config = RunConfig(inputs=(str(path),), output=str(out), in_crs="EPSG:2154", workers=2, **kw)
    return run(config, progress=False)


# (seed, width, height, tile size as a share of the width, buffer as a share of the tile)
CASES = [
    (1, 500.0, 20.0, 0.02, 0.0),
    (2, 400.0, 60.0, 0.04, 1.0),
    (3, 250.0, 200.0, 0.1, 0.3),
    (4, 300.0, 120.0, 0.25, 0.05),
    (5, 200.0, 150.0, 0.5, 0.6),
    (6, 180.0, 160.0, 1.0, 0.15),
]


@pytest.mark.parametrize("seed,width,height,share,buffer_share", CASES)
def test_every_tile_certifies_and_the_delaunay_pieces_are_the_whole_triangulation(
    tmp_path, seed, width, height, share, buffer_share
):
    xy, draw = _survey(tmp_path / "ground.las", seed, width, height)
    tile = share * width
    sizes = dict(resolution=tile / 8.0, tile_size=tile, buffer=buffer_share * tile)
    out = tmp_path / "delaunay.zarr"
    report = _run(tmp_path / "ground.las", out, triangle_measure="delaunay", quad_measure=None, **sizes)
    assert report.tiles_uncertified == 0
    node_xy, _, faces = store.read_mesh(out)
    node_xy, faces = np.asarray(node_xy), np.asarray(faces)
    meshcore.validate(meshcore.Mesh(node_xy, faces, np.arange(len(node_xy))))
    # every distinct point is a vertex (the pipeline decodes a coordinate to the
    # float nearest its decimal value, which may be an ulp from laspy's)
    assert len(node_xy) == len(np.unique(xy, axis=0))
    whole = meshcore.build_mesh(node_xy, "delaunay", None)
    want = face_set(whole.vertices, whole.faces)
    got = face_set(node_xy, faces)
    assert got == want, (draw, len(got - want), len(want - got))

    combined = _run(tmp_path / "ground.las", tmp_path / "combined.zarr", **sizes)
    assert combined.tiles_uncertified == 0
    node_xy, _, faces = store.read_mesh(tmp_path / "combined.zarr")
    meshcore.validate(meshcore.Mesh(np.asarray(node_xy), np.asarray(faces), np.arange(len(node_xy))))
    assert len(node_xy) == combined.vertices == whole.vertices.shape[0]
