"""COPC files for the tests, written with copclib, and their plain LAZ twins.

The octree is built as a COPC writer builds one: a cube around the points,
each point placed at one level (a thinning sample at each level, the rest at
the deepest) in the node of that level that holds it.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
from pyproj import CRS


def write_copc(path: Path, x, y, z, classification, *, crs: str = "EPSG:2154", depth: int = 4,
               scale: float = 0.01, page_level: int = 2, intensity=None) -> Path:
    import copclib as cl

    x, y, z = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    n = x.size
    offsets = [float(np.floor(x.min())), float(np.floor(y.min())), 0.0]
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = [scale] * 3, offsets
    records = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    records.x, records.y, records.z = x, y, z
    records.classification = np.asarray(classification, dtype=np.uint8)
    records.return_number = np.ones(n, np.uint8)
    records.number_of_returns = np.ones(n, np.uint8)
    if intensity is not None:
        records.intensity = np.asarray(intensity, dtype=np.uint16)
    raw = records.array
    # the coordinates as stored: what the cube and the nodes must hold
    xs, ys, zs = (np.asarray(getattr(records, a)) for a in "xyz")
    mins = np.array([xs.min(), ys.min(), zs.min()])
    maxs = np.array([xs.max(), ys.max(), zs.max()])
    center = (mins + maxs) / 2
    half = float((maxs - mins).max() / 2 + scale)
    # levels by thinning, as COPC writers do: at each level the first point of
    # every 1/8 of a node's edge goes there, so every node with points below has points
    level = np.full(n, depth, dtype=np.int64)
    left = np.arange(n)
    corner = center - half
    for lv in range(depth):
        cell = 2 * half / 2**lv / 8
        keys = np.column_stack([((c[left] - corner[i]) / cell).astype(np.int64) for i, c in enumerate((xs, ys, zs))])
        _, first = np.unique(keys, axis=0, return_index=True)
        level[left[first]] = lv
        left = np.delete(left, first)
    nodes: dict[tuple[int, int, int, int], np.ndarray] = {}
    for lv in range(depth + 1):
        chosen = np.flatnonzero(level == lv)
        cell = 2 * half / 2**lv
        keys = np.column_stack([
            np.clip(((c[chosen] - (center[i] - half)) / cell).astype(np.int64), 0, 2**lv - 1)
            for i, c in enumerate((xs, ys, zs))
        ])
        order = np.lexsort(keys.T[::-1])
        keys, chosen = keys[order], chosen[order]
        if chosen.size:
            starts = np.flatnonzero(np.r_[True, (np.diff(keys, axis=0) != 0).any(axis=1)])
            for s, e in zip(starts, [*starts[1:], chosen.size]):
                nodes[(lv, *map(int, keys[s]))] = np.sort(chosen[s:e])
    config = cl.CopcConfigWriter(6, cl.Vector3(scale, scale, scale), cl.Vector3(*offsets), CRS.from_user_input(crs).to_wkt())
    info = config.copc_info
    info.center_x, info.center_y, info.center_z = (float(v) for v in center)
    info.halfsize = half
    info.spacing = 2 * half / 128
    config.las_header.min = cl.Vector3(*(float(v) for v in mins))
    config.las_header.max = cl.Vector3(*(float(v) for v in maxs))
    writer = cl.FileWriter(str(path), config)
    for key in sorted(nodes):
        lv, a, b, c = key
        up = max(0, lv - page_level)  # pages by subtree, as COPC writers page their hierarchy
        page = (page_level, a >> up, b >> up, c >> up) if lv >= page_level else (0, 0, 0, 0)
        writer.AddNode(cl.VoxelKey(*key), cl.VectorChar(np.frombuffer(raw[nodes[key]].tobytes(), dtype=np.int8)),
                       cl.VoxelKey(*page))
    writer.Close()
    return path


def plain_twin(copc: Path, path: Path, crs: str = "EPSG:2154") -> Path:
    """The same points in the same order (the nodes' order in the file), as plain LAZ."""
    with laspy.CopcReader.open(str(copc)) as reader:
        points = reader.query()
        header = reader.header
    twin = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    twin.header.scales, twin.header.offsets = header.scales, header.offsets
    twin.header.add_crs(CRS.from_user_input(crs))
    twin.points = laspy.ScaleAwarePointRecord(points.array.copy(), points.point_format, header.scales, header.offsets)
    twin.write(str(path))
    return path


def nodes_meeting(copc: Path, window) -> tuple[int, int]:
    """(bytes, points) of the octree nodes a window query needs."""
    from laspy.copc import Bounds, CopcReader, load_octree_for_query

    with open(copc, "rb") as fh:
        reader = CopcReader(fh, close_fd=False)
        box = Bounds(mins=np.array([window[0], window[1], -np.inf]), maxs=np.array([window[2], window[3], np.inf]))
        nodes = load_octree_for_query(reader.source, reader.copc_info, reader.root_page, query_bounds=box)
    nodes = [n for n in nodes if n.point_count > 0]
    return sum(int(n.byte_size) for n in nodes), sum(int(n.point_count) for n in nodes)
