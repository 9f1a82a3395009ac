import json
import math

import numpy as np
import pytest

from pipeline.config import RunConfig
from pipeline.errors import UsageError
from pipeline.tiling.scratch import Scratch
from pipeline.tiling.grid import TileGrid, check_cells
from pipeline.tiling.routing import RouteResult, TileSpiller, load_tile_points


def test_grid_is_snapped_and_covers_the_bounds():
    g = TileGrid.covering((651000.37, 6861000.9, 651600.2, 6861400.0), 0.5, 100)
    assert g.x0 == 651000.0 and g.y0 == 6861000.5
    assert g.x0 + g.nx * g.resolution > 651600.2
    assert g.y0 + g.ny * g.resolution > 6861400.0
    assert (g.n_cols, g.n_rows) == (math.ceil(g.nx / 100), math.ceil(g.ny / 100))


def test_every_point_has_one_owner_consistent_with_windows(rng):
    g = TileGrid.covering((0.0, 0.0, 99.0, 77.0), 1.0, 16)
    x = np.concatenate([rng.random(2000) * 120 - 10, g.x0 + np.arange(1, g.n_cols) * g.tile_size])
    y = np.concatenate([rng.random(2000) * 100 - 10, np.full(g.n_cols - 1, 5.0)])
    rows, cols = g.owner(x, y)
    for xi, yi, r, c in zip(x, y, rows, cols):
        x_lo, y_lo, x_hi, y_hi = g.window(int(r), int(c))
        assert x_lo <= xi < x_hi and y_lo <= yi < y_hi


@pytest.mark.parametrize(
    "bounds, resolution, cells",
    [
        ((0.0, 0.0, 99.0, 77.0), 1.0, 16),
        ((651000.37, 6861000.9, 655600.2, 6864400.0), 0.5, 100),
        ((-1234.5, -98765.4, 2345.6, -95000.0), 1 / 3, 7),  # edges that are not exact sums
        ((5e6, 5e6, 5.0001e6, 5.0001e6), 0.1, 1),
    ],
)
def test_bins_count_the_edges_at_or_below_each_value_exactly(bounds, resolution, cells, rng):
    g = TileGrid.covering(bounds, resolution, cells)
    for axis, (lo, hi) in enumerate(((g.extent[0], g.extent[2]), (g.extent[1], g.extent[3]))):
        edges = g._inner_edges(axis)
        values = np.concatenate([
            rng.uniform(lo - 50, hi + 50, 5000), edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf),
            [lo - 1e12, hi + 1e12],
        ])
        assert np.array_equal(g.bins(values, axis), np.searchsorted(edges, values, side="right"))


def test_spilled_points_reach_every_tile_within_the_buffer(tmp_path, rng):
    g = TileGrid.covering((0.0, 0.0, 100.0, 100.0), 1.0, 25)
    pts = rng.random((5000, 3)) * 100
    spill = TileSpiller(Scratch(tmp_path), g, buffer=3.0, source=0, budget=500)
    for chunk in np.array_split(pts, 7):
        spill.add(chunk[:, 0], chunk[:, 1], chunk[:, 2])
    spill.flush()
    total_owned = 0
    for r, c in g.tiles():
        got = load_tile_points(Scratch(tmp_path), r, c)
        x0, y0, x1, y1 = g.box(r, c)
        expect = (pts[:, 0] >= x0 - 3) & (pts[:, 0] < x1 + 3) & (pts[:, 1] >= y0 - 3) & (pts[:, 1] < y1 + 3)
        # every point of core + buffer is there, once, and no other
        assert got.shape[0] == expect.sum()
        assert {tuple(p) for p in pts[expect]} == {tuple(p) for p in got}
        # in reading order within each group: the points whose reach starts at
        # this tile, those whose reach starts one column to the west, ...
        group = (r - g.bins(got[:, 1] - 3, 1)) * 2 + c - g.bins(got[:, 0] - 3, 0)
        group_of = (r - g.bins(pts[:, 1] - 3, 1)) * 2 + c - g.bins(pts[:, 0] - 3, 0)
        for k in range(4):
            assert np.array_equal(got[group == k], pts[expect & (group_of == k)])
        orow, ocol = g.owner(got[:, 0], got[:, 1])
        total_owned += int(np.count_nonzero((orow == r) & (ocol == c)))
    assert total_owned == len(pts)  # every point reached the tile that owns it


def test_too_many_cells_need_an_explicit_limit():
    g = TileGrid.covering((0.0, 0.0, 1e6, 1e6), 0.01, 1000)
    with pytest.raises(UsageError, match="above max_cells"):
        check_cells(g, 4_000_000_000)


def test_one_tile_never_outgrows_the_grid():
    g = TileGrid.covering((0.0, 0.0, 499.0, 299.0), 1.0, 65536)
    assert g.n_tiles == 1
    assert g.tile_cells == 500 and (g.nx, g.ny) == (500, 300)  # the data's rows: no padding to a whole tile


def test_the_tiles_among_some_that_boxes_meet_are_those_of_all_the_tiles_they_meet(rng):
    g = TileGrid(x0=651_000.0, y0=6_861_000.0, resolution=0.5, tile_cells=40, nx=400, ny=300)
    tiles = [(r, c) for r in range(g.n_rows) for c in range(g.n_cols)]
    for _ in range(50):
        lo = rng.uniform([650_980.0, 6_860_980.0], [651_210.0, 6_861_160.0], (int(rng.integers(1, 30)), 2))
        boxes = np.c_[lo, lo + rng.exponential(15.0, lo.shape) * (rng.random((lo.shape[0], 1)) < 0.7)]
        boxes[rng.random(lo.shape[0]) < 0.1, 2] = math.inf
        among = [tiles[i] for i in rng.choice(len(tiles), int(rng.integers(0, 40)), replace=False)]
        every = g.tiles_meeting(boxes)
        assert g.tiles_meeting(boxes, among=among) == sorted(set(every) & set(among))
        assert g.tiles_meeting(boxes, among=tiles) == every


@pytest.mark.parametrize("cells", [1, 7, 16, 25, 1000])
def test_the_grid_is_the_datas_whatever_the_tile_size(cells):
    bounds = (651000.37, 6861000.9, 651049.2, 6861030.1)
    g = TileGrid.covering(bounds, 0.5, cells)
    assert (g.x0, g.y0, g.nx, g.ny) == (651000.0, 6861000.5, 99, 60)
    assert g.extent[2] - 0.5 <= bounds[2] < g.extent[2] and g.extent[3] - 0.5 <= bounds[3] < g.extent[3]
    assert (g.n_rows, g.n_cols) == (math.ceil(60 / g.tile_cells), math.ceil(99 / g.tile_cells))
    top = g.cell_slice(g.n_rows - 1, 0)
    assert top[1] == 60 and 0 < top[1] - top[0] <= g.tile_cells  # the northern row holds the last rows, no more
    assert g.rows_share_chunks == (60 % g.tile_cells != 0 and g.n_rows > 1)


def test_a_grid_grown_north_moves_its_northern_row_even_within_a_tile_row():
    before = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=10, nx=25, ny=23)
    taller = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=10, nx=25, ny=27)  # still 3 tile rows
    assert taller.extends(before) and taller.n_rows == before.n_rows
    assert taller.edge_tiles_moved_by(before) == {(2, 0), (2, 1), (2, 2)}  # its box grew
    wider = TileGrid(x0=0.0, y0=0.0, resolution=1.0, tile_cells=10, nx=41, ny=23)
    assert wider.edge_tiles_moved_by(before) == {(0, 2), (1, 2), (2, 2)}
    assert before.edge_tiles_moved_by(before) == set()


def test_uncovered_parts_are_exactly_the_box_minus_the_held_boxes(rng):
    from pipeline.meshing.tiles import _uncovered

    def inside(p, b, strict=False):
        if strict:
            return (p[:, 0] > b[0]) & (p[:, 0] < b[2]) & (p[:, 1] > b[1]) & (p[:, 1] < b[3])
        return (p[:, 0] >= b[0]) & (p[:, 0] <= b[2]) & (p[:, 1] >= b[1]) & (p[:, 1] <= b[3])

    for _ in range(50):
        x, y = rng.random(2) * 10
        box = (x, y, x + 1 + rng.random() * 5, y + 1 + rng.random() * 5)
        held = []
        for _ in range(int(rng.integers(0, 5))):
            x, y = rng.random(2) * 12 - 1
            held.append((x, y, x + rng.random() * 4, y + rng.random() * 4))
        parts = _uncovered(box, held)
        if not held:
            assert parts == [box]
        pts = np.c_[rng.uniform(box[0], box[2], 4000), rng.uniform(box[1], box[3], 4000)]
        held_in = np.zeros(len(pts), dtype=bool)
        held_strict = np.zeros(len(pts), dtype=bool)
        for h in held:
            held_in |= inside(pts, h)
            held_strict |= inside(pts, h, strict=True)
        part_in = np.zeros(len(pts), dtype=bool)
        part_strict = np.zeros(len(pts), dtype=bool)
        for p in parts:
            assert box[0] <= p[0] <= p[2] <= box[2] and box[1] <= p[1] <= p[3] <= box[3]
            part_in |= inside(pts, p)
            part_strict |= inside(pts, p, strict=True)
        assert np.all(held_in | part_in)  # nothing of the box is forgotten
        assert not np.any(held_strict & part_strict)  # and nothing held is asked for again


def test_an_escaping_circle_needs_only_its_part_inside_the_hull(rng):
    """The box of points to load for a circle: it holds every point of (disk ∩
    hull ∩ extent), and for the sliver circles along a slanted survey edge it is
    a thin strip, not the disk's whole span over the extent."""
    from pipeline.meshing.tiles import _disk_box_in, _disk_boxes_in_hull

    a = math.radians(20.0)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    hull = np.array([[0.0, 0.0], [500.0, 0.0], [500.0, 500.0], [0.0, 500.0]]) @ rot.T + 1000.0  # counter-clockwise
    extent = (*hull.min(axis=0), *hull.max(axis=0))
    edges = np.roll(hull, -1, axis=0) - hull
    samples = rng.uniform(extent[:2], extent[2:], size=(200_000, 2))
    cross = edges[:, 0] * (samples[:, 1, None] - hull[:, 1]) - edges[:, 1] * (samples[:, 0, None] - hull[:, 0])
    samples = samples[(cross >= 0).all(axis=1)]  # the hull's inside
    for _ in range(200):
        cx, cy = rng.uniform(500.0, 2000.0, 2)
        r = rng.uniform(1.0, 800.0)
        box = _disk_boxes_in_hull(np.array([[cx, cy, r]]), hull, extent)[0]
        hit = samples[(samples[:, 0] - cx) ** 2 + (samples[:, 1] - cy) ** 2 <= r * r]
        if box is None:
            assert hit.shape[0] == 0
            continue
        assert ((hit >= box[:2]) & (hit <= box[2:])).all()
    # a sliver's circle along the south-east edge: centre far outside, the lens inside thin
    mid, normal = (hull[0] + hull[1]) / 2, np.array([edges[0, 1], -edges[0, 0]]) / 500.0
    cx, cy = mid + normal * 20_000.0
    r = 20_000.0 + 0.5
    full = _disk_box_in(cx, cy, r, extent)
    lens = _disk_boxes_in_hull(np.array([[cx, cy, r]]), hull, extent)[0]
    area = lambda b: (b[2] - b[0]) * (b[3] - b[1])  # noqa: E731
    assert area(lens) < 0.5 * area(full)


@pytest.mark.parametrize("degrees", [20.0, 45.0, 71.0])
def test_a_slanted_survey_edge_is_held_as_a_thin_strip_along_it(rng, degrees):
    """The bands a tile holds along a hull edge cut at an angle: every point
    within ``depth`` inside the edge and near the tile is in one of them, the
    boxes hold little else, and the survey's straight sides get none (their
    bands are the extent's)."""
    from pipeline.meshing.tiles import _slanted_bands

    a = math.radians(degrees)
    # a 600 m square with its south-west corner cut on a line at ``degrees``
    cut = 300.0
    hull = np.array([[cut, 0.0], [600.0, 0.0], [600.0, 600.0], [0.0, 600.0],
                     [0.0, cut * math.tan(a)]]) + np.array([7.5e5, 6.6e6])
    extent = (*hull.min(axis=0), *hull.max(axis=0))
    depth, reach = 5.0, 100.0
    for box in [(7.5e5 + 100.0, 6.6e6 + 50.0, 7.5e5 + 228.0, 6.6e6 + 178.0),
                (7.5e5 + 150.0, 6.6e6 - 10.0, 7.5e5 + 260.0, 6.6e6 + 60.0)]:
        far = (max(extent[0], box[0] - reach), max(extent[1], box[1] - reach),
               min(extent[2], box[2] + reach), min(extent[3], box[3] + reach))
        bands = _slanted_bands(hull, box, depth, far, extent)
        p, q = hull[0], hull[4]  # the cut runs from the last vertex to the first
        d = (p - q) / np.hypot(*(p - q))
        inward = np.array([-d[1], d[0]])
        t = rng.uniform(0.0, np.hypot(*(p - q)), 50_000)
        s = rng.uniform(0.0, depth, t.size)
        strip = q + t[:, None] * d + s[:, None] * inward
        base = q + t[:, None] * d  # where on the edge each strip point is
        near = ((base >= np.array(far[:2])) & (base <= np.array(far[2:]))).all(axis=1)
        near_box = ((strip >= np.array(box[:2]) - depth) & (strip <= np.array(box[2:]) + depth)).all(axis=1)
        held = np.zeros(strip.shape[0], dtype=bool)
        for b in bands:
            held |= ((strip >= np.array(b[:2])) & (strip <= np.array(b[2:]))).all(axis=1)
        if not near_box.any():
            assert bands == []
            continue
        assert held[near].all()
        length = np.hypot(*(np.minimum(strip[near].max(axis=0), far[2:]) - strip[near].min(axis=0)))
        area = sum((b[2] - b[0]) * (b[3] - b[1]) for b in bands)
        assert area < 4.0 * length * depth  # a strip, not the box around the diagonal
        # nothing along the straight sides
        for b in bands:
            assert b[2] > extent[0] + depth and b[1] < extent[3] - depth


def test_circles_against_a_hull_of_many_vertices_are_boxed_a_chunk_at_a_time(rng, monkeypatch):
    """A survey cut on a curve has a hull of thousands of vertices; the boxes of
    thousands of circles are computed a bounded chunk at a time, each the same
    as computed alone."""
    import tracemalloc

    import pipeline.meshing.tiles as tiles

    angle = np.sort(rng.uniform(0.0, 2.0 * math.pi, 3000))
    hull = np.column_stack([5.0e5 + 300.0 * np.cos(angle), 6.8e6 + 300.0 * np.sin(angle)])  # counter-clockwise
    extent = (*hull.min(axis=0), *hull.max(axis=0))
    circles = np.column_stack([rng.uniform(extent[0] - 50, extent[2] + 50, 2500), rng.uniform(extent[1] - 50, extent[3] + 50, 2500),
                               rng.uniform(1.0, 60.0, 2500)])
    circles[::97, 2] = np.inf
    tracemalloc.start()
    try:
        whole = tiles._disk_boxes_in_hull(circles, hull, extent)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 256 * 2**20  # all at once: 1.4 GiB
    assert sum(b is None for b in whole) > 100 and sum(b is not None for b in whole) > 1000
    one_by_one = [tiles._disk_boxes_in_hull(circles[i:i + 1], hull, extent)[0] for i in range(0, 2500, 50)]
    assert one_by_one == whole[::50]
    monkeypatch.setattr(tiles, "_HULL_CHUNK", 7 * hull.shape[0] + 1)
    assert tiles._disk_boxes_in_hull(circles, hull, extent) == whole


@pytest.mark.parametrize("seed", range(6))
def test_the_hull_grown_chunk_by_chunk_is_the_hull_of_all_points(seed):
    """Routing grows the survey's hull one chunk at a time from each chunk's
    own hull: the same points, in the same order (repeated and collinear
    points included), as the hull of everything at once."""
    from pipeline.tiling.routing import grow_hull, hull_candidates

    rng = np.random.default_rng(seed)
    chunks = []
    for _ in range(4):
        n = int(rng.integers(0, 300))
        x = rng.integers(0, 12, n).astype(float)  # a coarse lattice: many repeats and collinear runs
        y = 2.0 * x if seed % 2 else rng.integers(0, 12, n).astype(float)
        chunks.append(np.column_stack([x, y, rng.random(n)]))
    hull = np.empty((0, 3))
    for c in chunks:
        hull = grow_hull(hull, c[:, 0], c[:, 1], c[:, 2])
    everything = hull_candidates(np.concatenate(chunks))
    assert np.array_equal(hull, everything)
    assert len(hull) >= 2


@pytest.mark.parametrize(
    "measures", [("delaunay", None, "greedy", "linear"), ("s3", "s4", "optimal", "smooth"), ("s1", "s2", "greedy", "linear")]
)
def test_loading_the_kernels_reads_and_writes_nothing(tmp_path, measures):
    from pipeline.meshing.tiles import TileJob, load_kernels

    scratch = Scratch(str(tmp_path / "work"))
    grid = TileGrid.covering((0.0, 0.0, 99.0, 99.0), 1.0, 50)
    triangle, quad, merge, surface = measures
    options = RunConfig(inputs=("a.las",), output="o.zarr", resolution=1.0, triangle_measure=triangle,
                        quad_measure=quad, merge=merge, surface=surface, max_edge=3.0).mesh_options()
    load_kernels(TileJob(0, 0, scratch, grid, 5.0, (0.0, 0.0, 99.0, 99.0), options))
    assert not (tmp_path / "work").exists()


# --------------------------------------------------------------------------
# Route results and their records
# --------------------------------------------------------------------------

ROUTED = RouteResult("a.laz", 10, 2, 1, 3, 4, 1, bounds=(0.5, 1.0, 2.5, 3.0), parts=((0, 0, 0), (0, 1, 0)),
                     tile_points=((0, 0, 3), (0, 1, 1)), sha256="ab", seconds=0.25, hull=np.ones((3, 3)))
SKIPPED = RouteResult("b.laz", skipped="b.laz: truncated")
WINDOW = RouteResult("c.copc.laz", bounds=(0.0, 0.0, 1.0, 1.0), sha256="cd", window=True, hull=np.ones((4, 3)))


@pytest.mark.parametrize(
    ("result", "text"),
    [  # the records work folders have always held, to the byte: an earlier version's work folder resumes
        (ROUTED, '{"path": "a.laz", "read": 10, "filtered_class": 2, "filtered_withheld": 1, "outside_bbox": 3, '
                 '"kept": 4, "beyond_grid": 1, "bounds": [0.5, 1.0, 2.5, 3.0], "parts": [[0, 0, 0], [0, 1, 0]], '
                 '"tile_points": [[0, 0, 3], [0, 1, 1]], "sha256": "ab", "seconds": 0.25}'),
        (SKIPPED, '{"path": "b.laz", "skipped": "b.laz: truncated", "read": 0, "filtered_class": 0, '
                  '"filtered_withheld": 0, "outside_bbox": 0, "kept": 0}'),
        (WINDOW, '{"path": "c.copc.laz", "window": true, "parts": [], "sha256": "cd", "bounds": [0.0, 0.0, 1.0, 1.0]}'),
    ],
)
def test_route_records_keep_their_format_and_read_back(result, text):
    assert json.dumps(result.to_record()) == text
    again = RouteResult.from_record(json.loads(text) | {"hull": result.hull})
    assert again == result and again.hull is result.hull


def test_route_results_report_their_file_as_before():
    assert list(ROUTED.to_report()) == ["path", "read", "filtered_class", "filtered_withheld", "outside_bbox", "kept",
                                        "beyond_grid", "bounds", "sha256", "seconds"]
    assert ROUTED.to_report()["bounds"] == [0.5, 1.0, 2.5, 3.0]
    counted = WINDOW.counted(9, 1, 0, 2, 6)
    assert counted.to_report() == {"path": "c.copc.laz", "sha256": "cd", "bounds": [0.0, 0.0, 1.0, 1.0], "read": 9,
                                   "filtered_class": 1, "filtered_withheld": 0, "outside_bbox": 2, "kept": 6}
    assert WINDOW.read == 0  # frozen: counting makes a new result


def test_work_files_read_back_as_written_with_or_without_numpys_header_parser(tmp_path):
    import io

    from pipeline.tiling.scratch import _saved_header

    arrays = {
        "plain": np.arange(7.0), "scalar": np.array(2.5), "empty": np.zeros((0, 3)), "none": np.zeros((3, 0, 2), np.int64),
        "ints": np.arange(12, dtype=np.int32).reshape(3, 4), "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)),
        "flags": np.array([True, False]), "big_endian": np.array([1, -2], dtype=">i4"), "large": np.arange(400_000.0),
        "structured": np.zeros(2, dtype=[("a", "<f8"), ("b", "<i4")]),  # numpy's parser
    }
    scratch = Scratch(tmp_path)
    scratch.save_many({f"a/{k}.npy": v for k, v in arrays.items()})
    for mmap in (False, True):
        for (name, want), got in zip(arrays.items(), scratch.load_many([f"a/{k}.npy" for k in arrays], mmap=mmap)):
            assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want), name
            assert got.flags.f_contiguous == want.flags.f_contiguous or want.ndim < 2, name
    for name, want in arrays.items():
        raw = (tmp_path / "a" / f"{name}.npy").read_bytes()
        header = _saved_header(io.BytesIO(raw))
        if name == "structured":
            assert header is None
        else:  # what numpy reads from the same bytes
            assert header == np.lib.format.read_array_header_1_0(io.BytesIO(raw[8:])), name
    # a version 2 header (numpy writes one when the header outgrows 64 KiB) goes to numpy's parser too
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, arrays["ints"], version=(2, 0))
    (tmp_path / "a" / "v2.npy").write_bytes(buffer.getvalue())
    assert _saved_header(io.BytesIO(buffer.getvalue())) is None
    assert np.array_equal(scratch.load("a/v2.npy"), arrays["ints"])


def test_boxes_outside_the_held_ones_are_those_with_parts_left():
    """The kernel that settles thousands of sliver lenses at once answers as
    the box subtraction does, on boxes that touch, straddle and nest."""
    from pipeline.meshing.tiles import _outside_boxes, _uncovered

    rng = np.random.default_rng(7)
    # a lattice makes shared edges and corners common
    held = [tuple(float(v) for v in (x, y, x + w, y + h))
            for x, y, w, h in rng.integers(0, 8, size=(5, 4)) + np.array([0, 0, 1, 1])]
    held.append((-np.inf, 2.0, 3.0, np.inf))
    corners = rng.integers(0, 12, size=(4000, 2)).astype(float)
    sizes = rng.integers(0, 4, size=(4000, 2)).astype(float)
    boxes = np.column_stack([corners, corners + sizes])
    got = _outside_boxes(boxes, np.array(held))
    want = np.array([bool(_uncovered(tuple(b), held)) for b in boxes.tolist()])
    assert got.tolist() == want.tolist()
    assert 0.1 < want.mean() < 0.9  # both answers are common
