"""The smooth surface's node values: local kriging at every patch node.

The smooth surface (``surface="smooth"``) puts a cubic patch on every face
(:mod:`meshcore.patches`).  Its corners take the points' z; each of its other
nodes takes the value of universal kriging with a linear drift from the
node's ``neighbours`` nearest vertices:

- nearest is exact, with ties broken by coordinates, so a node's value
  depends only on the points inside the disk of radius ``R`` (its distance to
  its last neighbour), never on the order of the points or on which points a
  tile happens to hold beyond that disk (:func:`neighbourhood_radii`);
- an edge's nodes are placed from its end first in coordinate order, and the
  kriging system is built relative to the node, so the two faces of an edge,
  in one tile or in two, get bit-identical values: the surface is continuous
  (C0 across every edge) and seamless across tiles;
- the kriged value is clamped to the range of the neighbours' values and of
  its edge's (an inner node: its face's) corners.  Kriging with a linear
  drift reproduces linear functions, and a linear function stays inside that
  range, so the surface reproduces linear functions exactly; the clamp only
  stops overshoot where the neighbours lie to one side (the hull, voids);
- a node whose neighbours are collinear (no plane fits) takes the linear
  surface's value.

The covariance is the exponential model of a :class:`Variogram`;
:func:`fit_variogram` chooses its nugget and range by leave-one-out
cross-validation of this same kriging on a sample.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import njit
from .errors import InvalidInputError
from .mesh import Mesh, mesh_arrays, vertex_values
from .patches import NODES_PER_FACE

__all__ = ["Variogram", "fit_variogram", "smooth_nodes", "neighbourhood_radii", "DEFAULT_NEIGHBOURS"]

DEFAULT_NEIGHBOURS = 16
"""Points per kriging neighbourhood (the vertex and its 15 nearest)."""

_PIVOT_TOL = 1e-10
"""A kriging system whose pivot falls below this (relative) is singular."""

@dataclass(frozen=True)
class Variogram:
    """An exponential variogram ``nugget + sill (1 - exp(-h / range))`` (h > 0).

    Attributes
    ----------
    nugget : float
        The semivariance at zero lag: noise the smoother does not follow (z unit squared).
    sill : float
        The partial sill, ``> 0`` (z unit squared).
    range : float
        The distance scale of the exponential, ``> 0`` (horizontal unit).

    Only ``nugget / sill`` and ``range`` change the kriging weights.
    """

    nugget: float
    sill: float
    range: float

    def __post_init__(self) -> None:
        for name in ("nugget", "sill", "range"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InvalidInputError(f"variogram {name} must be a finite number, got {value!r}")
        if self.nugget < 0.0 or not self.sill > 0.0 or not self.range > 0.0:
            raise InvalidInputError(
                f"variogram needs nugget >= 0, sill > 0 and range > 0, got {self.nugget!r}, {self.sill!r}, {self.range!r}"
            )

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Variogram":
        try:
            return cls(float(data["nugget"]), float(data["sill"]), float(data["range"]))
        except (KeyError, TypeError, ValueError):
            raise InvalidInputError(f"a variogram needs numbers nugget, sill and range, got {data!r}") from None


# --------------------------------------------------------------------------
# Nearest neighbours: a bucket grid, rings searched outwards
# --------------------------------------------------------------------------


@njit
def _before(d2a: float, xa: float, ya: float, d2b: float, xb: float, yb: float) -> bool:
    """The order of neighbours: by squared distance, then x, then y."""
    if d2a != d2b:
        return d2a < d2b
    if xa != xb:
        return xa < xb
    return ya < yb


@njit
def _knn_kernel(
    xy: np.ndarray, x0: float, y0: float, cell: float, nbx: int, nby: int,
    start: np.ndarray, items: np.ndarray, queries: np.ndarray, k: int,
    out_index: np.ndarray, out_d2: np.ndarray,
) -> None:
    """The ``k`` nearest points of every query, in :func:`_before` order (``-1`` pads)."""
    for q in range(queries.shape[0]):
        qx = queries[q, 0]
        qy = queries[q, 1]
        count = 0
        for s in range(k):
            out_index[q, s] = -1
            out_d2[q, s] = math.inf
        ci = min(max(int((qx - x0) / cell), 0), nbx - 1)
        cj = min(max(int((qy - y0) / cell), 0), nby - 1)
        ring = 0
        while True:
            for j in range(cj - ring, cj + ring + 1):
                if j < 0 or j >= nby:
                    continue
                edge_row = j == cj - ring or j == cj + ring
                step = 1 if edge_row else 2 * ring
                i = ci - ring
                while i <= ci + ring:
                    if i >= 0 and i < nbx:
                        b = j * nbx + i
                        for s in range(start[b], start[b + 1]):
                            p = items[s]
                            px = xy[p, 0]
                            py = xy[p, 1]
                            d2 = (px - qx) * (px - qx) + (py - qy) * (py - qy)
                            if count == k:
                                last = out_index[q, k - 1]
                                if not _before(d2, px, py, out_d2[q, k - 1], xy[last, 0], xy[last, 1]):
                                    continue
                                pos = k - 1
                            else:
                                pos = count
                                count += 1
                            while pos > 0:
                                prev = out_index[q, pos - 1]
                                if _before(d2, px, py, out_d2[q, pos - 1], xy[prev, 0], xy[prev, 1]):
                                    out_index[q, pos] = prev
                                    out_d2[q, pos] = out_d2[q, pos - 1]
                                    pos -= 1
                                else:
                                    break
                            out_index[q, pos] = p
                            out_d2[q, pos] = d2
                    i += step if step > 0 else 1
            covers = ci - ring <= 0 and cj - ring <= 0 and ci + ring >= nbx - 1 and cj + ring >= nby - 1
            if covers:
                break
            if count == k:
                # every point not yet seen is at least this far away
                gap = min(
                    min(qx - (x0 + (ci - ring) * cell), (x0 + (ci + ring + 1) * cell) - qx),
                    min(qy - (y0 + (cj - ring) * cell), (y0 + (cj + ring + 1) * cell) - qy),
                )
                gap *= 1.0 - 1e-12
                if gap > 0.0 and gap * gap > out_d2[q, k - 1]:
                    break
            ring += 1


def _nearest(
    xy: NDArray[np.float64], queries: NDArray[np.float64], k: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Indices ``(m, k)`` and squared distances of the ``k`` nearest points of each query."""
    n = xy.shape[0]
    k = min(k, n)
    out_index = np.full((queries.shape[0], k), -1, dtype=np.int64)
    out_d2 = np.full((queries.shape[0], k), np.inf)
    if n == 0 or queries.shape[0] == 0 or k == 0:
        return out_index, out_d2
    lo = xy.min(axis=0)
    hi = xy.max(axis=0)
    span = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    area = float(max(hi[0] - lo[0], span * 1e-9) * max(hi[1] - lo[1], span * 1e-9))
    cell = math.sqrt(2.0 * area / n) if span > 0.0 else 1.0
    cell = max(cell, span * 1e-6, 1e-300)
    nbx = max(int((hi[0] - lo[0]) / cell) + 1, 1)
    nby = max(int((hi[1] - lo[1]) / cell) + 1, 1)
    ci = np.minimum(((xy[:, 0] - lo[0]) / cell).astype(np.int64), nbx - 1)
    cj = np.minimum(((xy[:, 1] - lo[1]) / cell).astype(np.int64), nby - 1)
    key = cj * nbx + ci
    items = np.argsort(key, kind="stable").astype(np.int64)
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    np.cumsum(np.bincount(key, minlength=nbx * nby), out=start[1:])
    _knn_kernel(
        xy, float(lo[0]), float(lo[1]), cell, nbx, nby, start, items,
        np.ascontiguousarray(queries, dtype=np.float64), k, out_index, out_d2,
    )
    return out_index, out_d2


# --------------------------------------------------------------------------
# Kriging: one system per vertex, solved in its dual form
# --------------------------------------------------------------------------


@njit
def _solve_in_place(a: np.ndarray, b: np.ndarray, m: int) -> bool:
    """Solve ``a[:m, :m] x = b[:m]`` into ``b`` (partial pivoting); False when singular."""
    scale = 0.0
    for i in range(m):
        for j in range(m):
            scale = max(scale, abs(a[i, j]))
    if scale == 0.0:
        return False
    for col in range(m):
        piv = col
        best = abs(a[col, col])
        for r in range(col + 1, m):
            if abs(a[r, col]) > best:
                best = abs(a[r, col])
                piv = r
        if best <= _PIVOT_TOL * scale:
            return False
        if piv != col:
            for c in range(m):
                tmp = a[col, c]
                a[col, c] = a[piv, c]
                a[piv, c] = tmp
            tmp = b[col]
            b[col] = b[piv]
            b[piv] = tmp
        inv = 1.0 / a[col, col]
        for r in range(col + 1, m):
            f = a[r, col] * inv
            if f != 0.0:
                for c in range(col + 1, m):
                    a[r, c] -= f * a[col, c]
                b[r] -= f * b[col]
    for r in range(m - 1, -1, -1):
        s = b[r]
        for c in range(r + 1, m):
            s -= a[r, c] * b[c]
        b[r] = s / a[r, r]
    return True


@njit
def _covariance(h: float, inv_range: float) -> float:
    """The exponential covariance less its sill, per unit sill: ``exp(-h / range) - 1``."""
    return math.expm1(-h * inv_range)


@njit
def _krige_at(
    xy: np.ndarray, z: np.ndarray, px: float, py: float, neighbours: np.ndarray, k: int,
    nugget_ratio: float, inv_range: float, a: np.ndarray, b: np.ndarray,
) -> float:
    """Universal kriging (linear drift) at ``p`` from its first ``k`` neighbours; NaN when singular.

    The system is built in coordinates relative to ``p`` (the drift scaled by
    the neighbourhood's radius), so it depends on nothing but ``p`` and the
    neighbours, and survey coordinates lose no precision.
    """
    radius = 0.0
    for i in range(k):
        q = neighbours[i]
        dx = xy[q, 0] - px
        dy = xy[q, 1] - py
        radius = max(radius, math.sqrt(dx * dx + dy * dy))
    if k < 3 or not radius > 0.0:
        return math.nan
    inv_r = 1.0 / radius
    m = k + 3
    for i in range(k):
        q = neighbours[i]
        xi = xy[q, 0] - px
        yi = xy[q, 1] - py
        a[i, i] = nugget_ratio
        for j in range(i + 1, k):
            o = neighbours[j]
            dx = xy[o, 0] - px - xi
            dy = xy[o, 1] - py - yi
            c = _covariance(math.sqrt(dx * dx + dy * dy), inv_range)
            a[i, j] = c
            a[j, i] = c
        a[i, k] = 1.0
        a[i, k + 1] = xi * inv_r
        a[i, k + 2] = yi * inv_r
        a[k, i] = 1.0
        a[k + 1, i] = xi * inv_r
        a[k + 2, i] = yi * inv_r
        b[i] = _covariance(math.sqrt(xi * xi + yi * yi), inv_range)
    for i in range(k, m):
        for j in range(k, m):
            a[i, j] = 0.0
    b[k] = 1.0
    b[k + 1] = 0.0
    b[k + 2] = 0.0
    if not _solve_in_place(a, b, m):
        return math.nan
    base = z[neighbours[0]]
    value = base
    for i in range(k):
        value += b[i] * (z[neighbours[i]] - base)
    return value


@njit
def _count(neighbours: np.ndarray) -> int:
    """The neighbours present in a padded row (``-1`` pads the end)."""
    k = 0
    while k < neighbours.shape[0] and neighbours[k] >= 0:
        k += 1
    return k


@njit
def _nodes_kriged_kernel(
    xy: np.ndarray, z: np.ndarray, positions: np.ndarray, neighbours: np.ndarray,
    low: np.ndarray, high: np.ndarray, linear: np.ndarray,
    nugget_ratio: float, inv_range: float, out: np.ndarray,
) -> None:
    """Krig every node; clamp it to ``[low, high]`` widened by its neighbours' range.

    A node whose system is singular (collinear neighbours) or meets an unknown
    z takes ``linear``, the linear surface's value there.
    """
    k = neighbours.shape[1]
    a = np.empty((k + 3, k + 3))
    b = np.empty(k + 3)
    for s in range(positions.shape[0]):
        count = _count(neighbours[s])
        lo = low[s]
        hi = high[s]
        finite = True
        for i in range(count):
            zi = z[neighbours[s, i]]
            if not math.isfinite(zi):
                finite = False
            lo = min(lo, zi)
            hi = max(hi, zi)
        value = math.nan
        if finite:
            value = _krige_at(xy, z, positions[s, 0], positions[s, 1], neighbours[s], count, nugget_ratio, inv_range, a, b)
        if math.isfinite(value):
            out[s] = min(max(value, lo), hi)
        else:
            out[s] = linear[s]


def _node_layout(vertices: NDArray[np.float64], faces: NDArray[np.int64], z: NDArray[np.float64]):
    """Where the nodes are, and how the face rows take them.

    Returns ``positions (m, 2)``, the range ``low, high`` of the corner values
    each node's clamp starts from, the linear surface's value ``linear`` there,
    and ``take (n_f, 12)``: for each slot of a face's row the node it holds
    (``-1``: unused).  An edge's two nodes are listed once, from its end first
    in coordinate order, so that every face (in any tile) computes them from
    the same numbers.
    """
    n_f = faces.shape[0]
    is_quad = faces[:, 3] >= 0
    take = np.full((n_f, 12), -1, dtype=np.int64)
    # every face edge k: from corner k to the next (a triangle's closes at corner 2)
    starts = faces.copy()
    ends = np.roll(faces, -1, axis=1)
    ends[~is_quad, 2] = faces[~is_quad, 0]
    valid = np.ones((n_f, 4), dtype=bool)
    valid[~is_quad, 3] = False
    s = starts[valid]
    e = ends[valid]
    sx, sy = vertices[s, 0], vertices[s, 1]
    ex, ey = vertices[e, 0], vertices[e, 1]
    forward = (sx < ex) | ((sx == ex) & (sy < ey))
    lo_v = np.where(forward, s, e)
    hi_v = np.where(forward, e, s)
    pairs = np.unique(np.column_stack([lo_v, hi_v]), axis=0, return_inverse=True)
    edges, which = pairs[0], pairs[1].reshape(-1)
    a, b = edges[:, 0], edges[:, 1]
    ax, ay, bx, by = vertices[a, 0], vertices[a, 1], vertices[b, 0], vertices[b, 1]
    n_e = edges.shape[0]
    positions = [np.empty((0, 2))] * 3
    lows, highs, linears = [], [], []
    for t_index, t in enumerate((1.0 / 3.0, 2.0 / 3.0)):
        positions[t_index] = np.column_stack([ax + t * (bx - ax), ay + t * (by - ay)])
        lows.append(np.minimum(z[a], z[b]))
        highs.append(np.maximum(z[a], z[b]))
        linears.append((1.0 - t) * z[a] + t * z[b])
    # face slot 2k + j: the edge's node j from the face's corner k
    slot_face, slot_edge = np.nonzero(valid)
    fwd = forward
    take[slot_face, 2 * slot_edge] = np.where(fwd, which, n_e + which)
    take[slot_face, 2 * slot_edge + 1] = np.where(fwd, n_e + which, which)
    # inner nodes: a triangle's centroid, a quadrangle's four at (1/3 | 2/3)^2
    corner = np.maximum(faces, 0)
    cx, cy, cz = vertices[corner, 0], vertices[corner, 1], z[corner]
    tri = np.flatnonzero(~is_quad)
    third = 1.0 / 3.0
    inner_pos = [np.column_stack([(cx[tri, 0] + cx[tri, 1] + cx[tri, 2]) * third,
                                  (cy[tri, 0] + cy[tri, 1] + cy[tri, 2]) * third])]
    inner_lin = [(cz[tri, 0] + cz[tri, 1] + cz[tri, 2]) * third]
    inner_lo = [cz[tri, :3].min(axis=1)]
    inner_hi = [cz[tri, :3].max(axis=1)]
    base = 2 * n_e
    take[tri, 8] = base + np.arange(tri.size)
    base += tri.size
    quad = np.flatnonzero(is_quad)
    for m, (u, v) in enumerate(((third, third), (2 * third, third), (2 * third, 2 * third), (third, 2 * third))):
        w = np.array([(1.0 - u) * (1.0 - v), u * (1.0 - v), u * v, (1.0 - u) * v])
        inner_pos.append(np.column_stack([cx[quad] @ w, cy[quad] @ w]))
        inner_lin.append(cz[quad] @ w)
        inner_lo.append(cz[quad].min(axis=1))
        inner_hi.append(cz[quad].max(axis=1))
        take[quad, 8 + m] = base + np.arange(quad.size)
        base += quad.size
    positions = np.concatenate([positions[0], positions[1], *inner_pos])
    low = np.concatenate([*lows, *inner_lo])
    high = np.concatenate([*highs, *inner_hi])
    linear = np.concatenate([*linears, *inner_lin])
    return np.ascontiguousarray(positions), low, high, linear, take


def _check_neighbours(neighbours: object) -> int:
    if isinstance(neighbours, bool) or not isinstance(neighbours, (int, np.integer)) or not 4 <= neighbours <= 64:
        raise InvalidInputError(f"neighbours must be an integer from 4 to 64, got {neighbours!r}")
    return int(neighbours)


def neighbourhood_radii(mesh: Mesh, neighbours: int = DEFAULT_NEIGHBOURS) -> NDArray[np.float64]:
    """The disks the smooth surface's nodes read from: ``(m, 3)`` rows ``(x, y, r)``.

    One per node of :func:`smooth_nodes`: the node and the distance to its
    ``neighbours``-th nearest vertex.  The node values depend on the mesh's
    vertices inside these (closed) disks only, so a piece of a larger point
    set gets the values of the whole set once every point of the set inside
    each disk is among its vertices.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> mesh = meshcore.build_mesh(np.random.default_rng(1).random((50, 2)))
    >>> disks = neighbourhood_radii(mesh)
    >>> bool(np.all(disks[:, 2] > 0))
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    if faces.shape[0] == 0:
        return np.empty((0, 3))
    positions = _node_layout(vertices, faces, np.zeros(vertices.shape[0]))[0]
    _, d2 = _nearest(vertices, positions, k)
    return np.column_stack([positions, np.sqrt(d2[:, -1])])


def smooth_nodes(
    mesh: Mesh, z: ArrayLike, variogram: Variogram | None = None, neighbours: int = DEFAULT_NEIGHBOURS
) -> NDArray[np.float64]:
    """The node values of the smooth surface's patches, one row of twelve per face.

    Every node is kriged (universal kriging, linear drift) from its
    ``neighbours`` nearest vertices, then clamped to the range of their values
    and of its edge's (or face's) corners: a linear function is within that
    range, so the clamp keeps it exact while stopping overshoot where the
    neighbours lie to one side (the hull, voids).

    Parameters
    ----------
    mesh : Mesh
        A conforming mesh; its vertices are the points kriged (every vertex,
        also those no face uses).
    z : (n_v,) array
        The value at every vertex.
    variogram : Variogram, optional
        The covariance model; fitted from the mesh's vertices by
        :func:`fit_variogram` when omitted.
    neighbours : int
        Points per kriging neighbourhood, 4 to 64.

    Returns
    -------
    (n_f, 12) float64
        Node values in the layout of :mod:`meshcore.patches`; unused columns NaN.

    Examples
    --------
    >>> import numpy as np, meshcore
    >>> xy = np.random.default_rng(2).random((60, 2))
    >>> mesh = meshcore.build_mesh(xy, "s3", "s4")
    >>> z = 2.0 * mesh.vertices[:, 0] - mesh.vertices[:, 1]
    >>> nodes = smooth_nodes(mesh, z, Variogram(0.0, 1.0, 0.5))
    >>> nodes.shape == (mesh.faces.shape[0], 12)
    True
    """
    k = _check_neighbours(neighbours)
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    if variogram is None:
        variogram = fit_variogram(vertices, zv, neighbours=k)
    elif not isinstance(variogram, Variogram):
        raise InvalidInputError(f"variogram must be a Variogram, got {type(variogram).__name__}")
    out = np.full((faces.shape[0], NODES_PER_FACE), np.nan)
    if faces.shape[0] == 0:
        return out
    positions, low, high, linear, take = _node_layout(vertices, faces, zv)
    index, _ = _nearest(vertices, positions, k)
    values = np.empty(positions.shape[0])
    _nodes_kriged_kernel(
        vertices, zv, positions, index, low, high, linear,
        variogram.nugget / variogram.sill, 1.0 / variogram.range, values,
    )
    used = take >= 0
    out[used] = values[take[used]]
    return out


# --------------------------------------------------------------------------
# Fitting the variogram
# --------------------------------------------------------------------------


@njit
def _loo_errors_kernel(
    xy: np.ndarray, z: np.ndarray, sample: np.ndarray, neighbours: np.ndarray,
    nugget_ratio: float, inv_range: float, out: np.ndarray,
) -> None:
    """Leave-one-out errors: each sample point kriged from its neighbours (itself left out)."""
    k = neighbours.shape[1]
    a = np.empty((k + 3, k + 3))
    b = np.empty(k + 3)
    for s in range(sample.shape[0]):
        p = sample[s]
        count = _count(neighbours[s])
        out[s] = _krige_at(xy, z, xy[p, 0], xy[p, 1], neighbours[s], count, nugget_ratio, inv_range, a, b) - z[p]


def fit_variogram(
    xy: ArrayLike, z: ArrayLike, neighbours: int = DEFAULT_NEIGHBOURS, sample: int = 2000, seed: int = 0
) -> Variogram:
    """The exponential variogram that best predicts left-out points of ``(xy, z)``.

    ``sample`` points (drawn with ``seed``) are each kriged, left out, from
    their ``neighbours`` nearest others, for ranges from a tenth to a hundred times the median
    neighbour distance and nuggets from none to five times the sill; the pair
    with the smallest root mean square error wins (ties: the smoother one).
    The sill is then scaled to the empirical semivariance of the neighbour
    pairs, so that ``nugget`` reads as the noise variance in z units squared.

    Deterministic: the same points (in any order) give the same variogram.

    Raises
    ------
    InvalidInputError
        When fewer than ``neighbours + 2`` finite points are given.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(3)
    >>> xy = rng.random((800, 2)) * 100.0
    >>> z = np.sin(xy[:, 0] / 15.0) + 0.01 * rng.standard_normal(800)
    >>> v = fit_variogram(xy, z)
    >>> v.range > 0 and v.nugget < v.sill
    True
    """
    k = _check_neighbours(neighbours)
    pts = np.asarray(xy, dtype=np.float64)
    zz = np.asarray(z, dtype=np.float64).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] < 2 or pts.shape[0] != zz.shape[0]:
        raise InvalidInputError(f"xy must be (n, 2) and z (n,), got {pts.shape} and {zz.shape}")
    keep = np.isfinite(zz) & np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1])
    pts = np.ascontiguousarray(pts[keep, :2])
    zz = np.ascontiguousarray(zz[keep])
    if pts.shape[0] < k + 2:
        raise InvalidInputError(f"fitting a variogram needs at least {k + 2} finite points, got {pts.shape[0]}")
    # a canonical order, so that the sample does not depend on the input order
    order = np.lexsort((zz, pts[:, 1], pts[:, 0]))
    pts = pts[order]
    zz = zz[order]
    rng = np.random.default_rng(seed)
    m = min(sample, pts.shape[0])
    chosen = np.sort(rng.choice(pts.shape[0], size=m, replace=False))
    index, d2 = _nearest(pts, pts[chosen], k + 1)
    index = np.ascontiguousarray(index[:, 1:])  # leave the point itself out
    d2 = d2[:, 1:]
    spacing = float(np.median(np.sqrt(d2[:, 0])))
    if not spacing > 0.0:
        spacing = float(np.median(np.sqrt(d2[np.isfinite(d2)]))) or 1.0
    best: tuple[float, float, float] | None = None
    errors = np.empty(m)
    for factor in (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0):
        inv_range = 1.0 / (factor * spacing)
        for ratio in (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 5.0):
            _loo_errors_kernel(pts, zz, chosen, index, ratio, inv_range, errors)
            ok = np.isfinite(errors)
            if not ok.any():
                continue
            rmse = float(np.sqrt(np.mean(errors[ok] ** 2)))
            if best is None or rmse < best[0] * (1.0 - 1e-9):
                best = (rmse, factor * spacing, ratio)
    if best is None:
        best = (math.nan, 10.0 * spacing, 0.1)
    _, rng_best, ratio = best
    # the sill: semivariances of neighbour pairs against the model's shape
    first = index[:, :4]
    h = np.sqrt(d2[:, :4]).ravel()
    gamma = 0.5 * (zz[chosen][:, None] - zz[first]).ravel() ** 2
    shape = ratio + 1.0 - np.exp(-h / rng_best)
    good = np.isfinite(gamma) & (shape > 0)
    sill = float(np.sum(gamma[good] * shape[good]) / np.sum(shape[good] ** 2)) if good.any() else 1.0
    if not sill > 0.0:
        sill = float(np.finfo(float).tiny) * 1e10
    return Variogram(nugget=ratio * sill, sill=sill, range=rng_best)
