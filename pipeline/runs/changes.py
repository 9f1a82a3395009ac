"""What changed since a store's last run, and which tiles that touches.

An incremental run (``pipeline.runs.workflow``) compares the inputs with those the
store was made from: the spilled points of files that changed or went away are
dropped, the others renumbered to their place in the new input list, and every
tile whose piece held points in a changed region (its recorded held boxes), or
near a part of the convex hull that moved, is meshed again, with the DEM of
its neighbours and the whole mesh.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..tiling.checkpoint import Ledger, WorkDir, source_key
from ..meshing.tiles import held_box, hull_near, reached_tiles
from ..tiling.grid import TileGrid, intersect_boxes, tile_key
from ..tiling.routing import drop_source_spill, source_spill

__all__ = [
    "changed_inputs", "forget_changed_inputs", "same_input", "tiles_depending_on", "tiles_whose_hull_moved", "forget_tiles",
    "reroute_near_growth",
]


def same_input(old: dict[str, Any], item: dict[str, Any], routed: dict[str, Any] | None) -> bool:
    """Whether input ``item`` (path, size, mtime) is the file ``old`` of the
    last run: the same size and time stamp, or a file only touched (the same
    size and SHA-256 as its routing record ``routed``, when there is one)."""
    from ..inputs.sources import file_digest

    if (old["size"], old["mtime"], old.get("etag")) == (item["size"], item["mtime"], item.get("etag")):
        return True
    return routed is not None and old["size"] == item["size"] and routed.get("sha256") == file_digest(item["path"])


def changed_inputs(work: WorkDir, before: list[dict[str, Any]], now: list[dict[str, Any]]) -> tuple[dict[int, int], list[tuple]]:
    """Which inputs of the last run stay (their old index -> their new one),
    and the regions (boxes) whose points changed: those of new or changed
    inputs, and those of the inputs that changed or went away (their kept
    points' bounds, else their header's).  Reads the work folder only."""
    old_index = {i["path"]: k for k, i in enumerate(before)}
    regions: list[tuple] = []
    keep: dict[int, int] = {}  # old index -> new index
    for k, item in enumerate(now):
        j = old_index.get(item["path"])
        routed = None if j is None else work.recorded(Ledger.ROUTE, source_key(j))
        if j is not None and routed is not None and same_input(before[j], item, routed):
            keep[j] = k
            continue
        if item.get("bounds"):
            regions.append(tuple(item["bounds"]))
    for j, old in enumerate(before):
        if j in keep:
            continue
        rec = work.recorded(Ledger.ROUTE, source_key(j))
        box = (rec or {}).get("bounds") or old.get("bounds")
        if box:
            regions.append(tuple(box))
    return keep, regions


def forget_changed_inputs(work: WorkDir, n_before: int, keep: dict[int, int]) -> None:
    """Drop the spilled points and records of the last run's ``n_before``
    inputs that are not kept, and renumber the spill files of those kept
    (``keep``: old index -> new index, of :func:`changed_inputs`)."""
    # a run stopped between the two renaming steps below left "tmp" names:
    # their records are gone with them, so those files are routed again
    work.scratch.remove([*work.scratch.glob("tiles/*/tmp*.npy"), *work.scratch.glob("records/route/tmp*")])
    for j in range(n_before):
        if j not in keep:
            drop_source(work, j)
    # renumber in two steps, so no new name meets an old one still in use
    for j in keep:
        rename_source(work, j, f"tmp{j:06d}")
    for j, k in keep.items():
        rename_source(work, f"tmp{j:06d}", f"{k:06d}")


def drop_source(work: WorkDir, index: int) -> None:
    drop_source_spill(work.scratch, index)
    work.forget_record(Ledger.ROUTE, source_key(index))


def rename_source(work: WorkDir, old: int | str, new: str) -> None:
    old = f"{old:06d}" if isinstance(old, int) else old
    for key in source_spill(work.scratch, old):
        folder, name = key.rsplit("/", 1)
        work.scratch.rename(key, f"{folder}/{new}{name[len(old):]}")
    work.rename_record(Ledger.ROUTE, old, new)


def tiles_depending_on(work: WorkDir, grid: TileGrid, regions: list[tuple]) -> set[tuple[int, int]]:
    """Tiles whose recorded piece held points in any of ``regions`` (all tiles
    without a record count too: they are computed anyway)."""
    out = set()
    for r, c in grid.tiles():
        rec = work.recorded(Ledger.MESH, tile_key(r, c))
        if rec is None:
            out.add((r, c))
            continue
        if any(intersect_boxes(held, b) is not None for held in rec.get("held", ()) for b in regions):
            out.add((r, c))
    return out


def tiles_whose_hull_moved(work: WorkDir, grid: TileGrid, buffer: float, hull: np.ndarray) -> set[tuple[int, int]]:
    """Tiles with a recorded piece whose nearby part of the global hull changed."""
    before = work.load("hull.npy")
    if before is None:
        return set()
    if before.shape == hull.shape and np.array_equal(before, hull):
        return set()
    out = set()
    for r, c in grid.tiles():
        if work.recorded(Ledger.MESH, tile_key(r, c)) is None:
            continue
        box = held_box(grid, r, c, buffer)  # where the tile took hull points from
        a, b = hull_near(before, box), hull_near(hull, box)
        if a.shape != b.shape or not np.array_equal(a, b):
            out.add((r, c))
    return out


def forget_tiles(work: WorkDir, output: str, grid: TileGrid, tiles: set[tuple[int, int]]) -> None:
    """Mesh these tiles again, and write the DEM of them and of the tiles their
    faces reached (whose DEM reads those faces) and the whole mesh again."""
    from ..store import zarr_store as store

    dem = set()
    for r, c in tiles:
        rec = work.recorded(Ledger.MESH, tile_key(r, c))
        reach = None if rec is None or rec.get("reach") is None else tuple(rec["reach"])
        work.forget_record(Ledger.MESH, tile_key(r, c))
        dem.update(reached_tiles(grid, None, r, c))
        dem.update(reached_tiles(grid, reach, r, c))  # where its old faces reached
    store.reset_tiles_done(output, sorted(dem))
    work.forget(Ledger.WRITE)


def reroute_near_growth(work: WorkDir, before: TileGrid, inputs: list[dict[str, Any]], buffer: float) -> None:
    """Drop the routing of the files whose points reach the new tiles of a
    grid grown from ``before`` (within ``buffer`` of them): routed again,
    they give those tiles their points; the tiles they held keep the same."""
    north = before.y0 + before.n_rows * before.tile_size - buffer
    east = before.x0 + before.n_cols * before.tile_size - buffer
    for k, item in enumerate(inputs):
        box = item.get("bounds")
        if box and (box[3] >= north or box[2] >= east) and work.recorded(Ledger.ROUTE, source_key(k)) is not None:
            drop_source(work, k)
