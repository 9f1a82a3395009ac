"""Evaluate the surface of a mesh: linear on triangles, bilinear on quadrangles, or smooth.

The surface
-----------
On a triangle ``a, b, c`` the surface is the linear interpolant of the three
vertex values.  On a quadrangle ``P0, P1, P2, P3`` it is the isoparametric
bilinear patch

    p(u, v) = (1-u)(1-v) P0 + u(1-v) P1 + uv P2 + (1-u)v P3,  (u, v) in [0, 1]^2

with the same weights on z.  Along an edge both reduce to linear interpolation
between the edge's end vertices, so the surface is continuous across every
shared edge of a conforming mesh; the gradient is not.  The gradient of a
patch is ``J^-T [dz/du, dz/dv]`` with ``J = d(x, y) / d(u, v)``.

With ``surface="smooth"`` each face carries a cubic patch through the same
corners instead (:mod:`meshcore.patches`), whose other nodes are kriged from
the points around (:mod:`meshcore.smooth`); it is continuous too.

The inverse map
---------------
``(x, y) -> (u, v)`` on a quadrangle (:func:`_bilinear_inverse`) eliminates
one coordinate and solves the quadratic in the other with the stable root
formula (no cancellation between ``-b`` and the square root).  Of the two
quadratics (in ``u`` and in ``v``) it solves the one whose leading coefficient
is smaller, so a parallelogram (both vanish) and a trapezoid (one vanishes)
are solved as the linear equations they are.  Two Newton steps on the forward
map polish the root, and the result is clamped to the unit square.

Point location
--------------
Faces are registered in a uniform bucket grid over the mesh (about one face
per bucket, each face in every bucket its bounding box overlaps, CSR arrays).
A point is tested against the faces of its bucket: inside the face's bounding
box, then the edge orientation tests (barycentric coordinates for triangles,
four edge tests for quadrangles) with a relative tolerance of
``_INSIDE_TOL``, so points on edges and vertices are always found.  A point on
an edge shared by two faces takes the one whose corners come first by
coordinates (:func:`face_after`), so the answer, value and gradient, does
not depend on the order of the faces: a tile that holds its neighbours'
faces in another order reads the same bits.  Points outside the mesh (its
convex hull) give NaN.
:mod:`meshcore.rasterize` uses the same bounding boxes and inside tests, so
both cover exactly the same points.

All coordinates are taken relative to a vertex of the face before they are
multiplied, so survey coordinates (``x ~ 5e5``) lose no precision.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import larger, njit, njit_helper, smaller
from .errors import InvalidInputError
from .mesh import Mesh, mesh_arrays, vertex_values
from .options import Surface, parse_option
from .patches import NODES_PER_FACE, bilinear_gradient, quad_patch, triangle_patch
from .smooth import SmoothSurface, smooth_surface
from .variogram import Variogram

__all__ = ["interpolate", "gradient"]

_INSIDE_TOL = 1e-10
"""Relative tolerance of the inside tests (a fraction of a barycentric coordinate)."""

_BBOX_MARGIN = 4.0 * _INSIDE_TOL
"""Face bounding boxes grow by this fraction of their width plus height."""


# --------------------------------------------------------------------------
# Scalar kernels on one face
# --------------------------------------------------------------------------


@njit
def _quadratic_roots(a: float, b: float, c: float) -> tuple[float, float]:
    """Both roots of ``a t^2 + b t + c = 0`` by the stable formula, NaN where missing.

    ``q = -(b + sign(b) sqrt(b^2 - 4ac)) / 2``; the roots are ``c / q`` and
    ``q / a``.  When ``a -> 0`` the first tends to the root ``-c / b`` of the
    linear equation and the second is NaN.  A slightly negative discriminant
    (a tangent, or rounding) is taken as zero.
    """
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        disc = 0.0
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    if q == 0.0:
        # b == 0 and a c >= 0: the double root 0, or no root (a c > 0) -> nearest 0.
        return 0.0, math.nan
    r2 = q / a if a != 0.0 else math.nan
    return c / q, r2


@njit_helper
def _other_coordinate(
    hx: float, hy: float, ax: float, ay: float, bx: float, by: float,
    gx: float, gy: float, t: float,
) -> float:
    """Solve ``h = t a + s (b + t g)`` for ``s`` in the least-squares sense."""
    wx = bx + t * gx
    wy = by + t * gy
    ww = wx * wx + wy * wy
    if ww == 0.0:
        return math.nan
    return ((hx - t * ax) * wx + (hy - t * ay) * wy) / ww


@njit_helper
def _out_of_unit(t: float) -> float:
    """Distance of ``t`` from ``[0, 1]``; infinite for NaN."""
    if t >= 0.0:
        if t <= 1.0:
            return 0.0
        return t - 1.0
    if t < 0.0:
        return -t
    return math.inf


@njit
def _bilinear_inverse(
    x0: float, y0: float, x1: float, y1: float,
    x2: float, y2: float, x3: float, y3: float,
    px: float, py: float,
) -> tuple[float, float]:
    """The parameters ``(u, v)`` of the point ``p`` in the quadrangle ``P0 P1 P2 P3``.

    Inverts ``p = (1-u)(1-v) P0 + u(1-v) P1 + uv P2 + (1-u)v P3`` for a
    strictly convex quadrangle (either orientation) and a point inside it.
    With ``e = P1 - P0``, ``f = P3 - P0``, ``g = P0 - P1 + P2 - P3`` and
    ``h = p - P0`` the map is ``h = u e + v f + uv g``; crossing with
    ``e + v g`` (or ``f + u g``) leaves a quadratic in ``v`` (or ``u``):

        cross(g, f) v^2 + (cross(e, f) + cross(h, g)) v + cross(h, e) = 0
        cross(g, e) u^2 + (cross(h, g) - cross(e, f)) u + cross(h, f) = 0

    The one with the smaller leading coefficient is solved (exactly linear for
    a parallelogram or a trapezoid), the other coordinate follows by least
    squares, the root pair nearest the unit square is kept, polished with two
    Newton steps and clamped to ``[0, 1]^2``.  For a point outside the
    quadrangle the result is therefore a point of its boundary, not an
    extrapolation.

    Examples
    --------
    >>> _bilinear_inverse(0.0, 0.0, 2.0, 0.0, 2.0, 1.0, 0.0, 1.0, 1.5, 0.25)
    (0.75, 0.25)
    """
    ex = x1 - x0
    ey = y1 - y0
    fx = x3 - x0
    fy = y3 - y0
    gx = (x2 - x3) - ex
    gy = (y2 - y3) - ey
    hx = px - x0
    hy = py - y0
    cross_ef = ex * fy - ey * fx
    cross_hg = hx * gy - hy * gx
    k2 = gx * fy - gy * fx
    l2 = gx * ey - gy * ex
    if abs(k2) <= abs(l2):
        v1, v2 = _quadratic_roots(k2, cross_ef + cross_hg, hx * ey - hy * ex)
        u1 = _other_coordinate(hx, hy, fx, fy, ex, ey, gx, gy, v1)
        u2 = _other_coordinate(hx, hy, fx, fy, ex, ey, gx, gy, v2)
    else:
        u1, u2 = _quadratic_roots(l2, cross_hg - cross_ef, hx * fy - hy * fx)
        v1 = _other_coordinate(hx, hy, ex, ey, fx, fy, gx, gy, u1)
        v2 = _other_coordinate(hx, hy, ex, ey, fx, fy, gx, gy, u2)
    d1 = _out_of_unit(u1) + _out_of_unit(v1)
    d2 = _out_of_unit(u2) + _out_of_unit(v2)
    if d2 < d1:
        u = u2
        v = v2
    elif d1 < math.inf:
        u = u1
        v = v1
    else:  # degenerate quadrangle: let Newton start from the centre
        u = 0.5
        v = 0.5
    for _ in range(2):
        jux = ex + v * gx
        juy = ey + v * gy
        jvx = fx + u * gx
        jvy = fy + u * gy
        det = jux * jvy - juy * jvx
        if det == 0.0:
            break
        rx = u * ex + v * fx + u * v * gx - hx
        ry = u * ey + v * fy + u * v * gy - hy
        if rx == 0.0 and ry == 0.0:
            break
        u -= (jvy * rx - jvx * ry) / det
        v -= (jux * ry - juy * rx) / det
    u = smaller(larger(u, 0.0), 1.0)
    v = smaller(larger(v, 0.0), 1.0)
    return u, v


@njit_helper
def _triangle_value_and_gradient(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float,
    za: float, zb: float, zc: float, px: float, py: float,
) -> tuple[float, float, float]:
    """Value and ``(dz/dx, dz/dy)`` of the linear interpolant on triangle ``a b c`` at ``p``."""
    bax = bx - ax
    bay = by - ay
    cax = cx - ax
    cay = cy - ay
    d = bax * cay - bay * cax
    qx = px - ax
    qy = py - ay
    lb = (qx * cay - qy * cax) / d
    lc = (bax * qy - bay * qx) / d
    value = (1.0 - lb - lc) * za + lb * zb + lc * zc
    dzb = zb - za
    dzc = zc - za
    return value, (dzb * cay - dzc * bay) / d, (dzc * bax - dzb * cax) / d


@njit_helper
def _quad_value_and_gradient(
    x0: float, y0: float, x1: float, y1: float,
    x2: float, y2: float, x3: float, y3: float,
    z0: float, z1: float, z2: float, z3: float, px: float, py: float,
) -> tuple[float, float, float]:
    """Value and ``(dz/dx, dz/dy)`` of the bilinear patch on quadrangle ``P0..P3`` at ``p``."""
    u, v = _bilinear_inverse(x0, y0, x1, y1, x2, y2, x3, y3, px, py)
    value = (1.0 - u) * (1.0 - v) * z0 + u * (1.0 - v) * z1 + u * v * z2 + (1.0 - u) * v * z3
    zu = (1.0 - v) * (z1 - z0) + v * (z2 - z3)
    zv = (1.0 - u) * (z3 - z0) + u * (z2 - z1)
    gx, gy = bilinear_gradient(x0, y0, x1, y1, x2, y2, x3, y3, u, v, zu, zv)
    return value, gx, gy


@njit
def _surface_at(
    vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, nodes: np.ndarray | None, f: int, px: float, py: float
) -> tuple[float, float, float]:
    """Value and ``(dz/dx, dz/dy)`` of face ``f``'s formula at ``p`` (no inside test):
    linear/bilinear when ``nodes`` is None (compiled without the patches), else the face's cubic patch."""
    a = faces[f, 0]
    b = faces[f, 1]
    c = faces[f, 2]
    d = faces[f, 3]
    ax, ay, bx, by, cx, cy = vertices[a, 0], vertices[a, 1], vertices[b, 0], vertices[b, 1], vertices[c, 0], vertices[c, 1]
    if d < 0:
        if nodes is not None:
            return triangle_patch(ax, ay, bx, by, cx, cy, z[a], z[b], z[c], nodes[f], px, py)
        return _triangle_value_and_gradient(ax, ay, bx, by, cx, cy, z[a], z[b], z[c], px, py)
    dx, dy = vertices[d, 0], vertices[d, 1]
    if nodes is not None:
        u, v = _bilinear_inverse(ax, ay, bx, by, cx, cy, dx, dy, px, py)
        return quad_patch(ax, ay, bx, by, cx, cy, dx, dy, z[a], z[b], z[c], z[d], nodes[f], u, v)
    return _quad_value_and_gradient(ax, ay, bx, by, cx, cy, dx, dy, z[a], z[b], z[c], z[d], px, py)


@njit_helper
def _grow_bbox(
    xmin: float, ymin: float, xmax: float, ymax: float
) -> tuple[float, float, float, float]:
    """The box grown on every side by ``_BBOX_MARGIN`` of its width plus height."""
    margin = _BBOX_MARGIN * ((xmax - xmin) + (ymax - ymin))
    return xmin - margin, ymin - margin, xmax + margin, ymax + margin


@njit_helper
def _face_bbox(
    vertices: np.ndarray, faces: np.ndarray, f: int
) -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` of face ``f``, grown by :func:`_grow_bbox`."""
    n = 4 if faces[f, 3] >= 0 else 3
    v = faces[f, 0]
    xmin = vertices[v, 0]
    xmax = xmin
    ymin = vertices[v, 1]
    ymax = ymin
    for k in range(1, n):
        v = faces[f, k]
        xmin = smaller(xmin, vertices[v, 0])
        xmax = larger(xmax, vertices[v, 0])
        ymin = smaller(ymin, vertices[v, 1])
        ymax = larger(ymax, vertices[v, 1])
    return _grow_bbox(xmin, ymin, xmax, ymax)


@njit_helper
def _edge_turn(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    """``cross(b - a, p - a)``: positive when ``p`` is left of ``a -> b``."""
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@njit_helper
def _triangle_contains(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, px: float, py: float
) -> bool:
    """True when ``p`` is in the counter-clockwise triangle ``a b c`` or on its boundary.

    Every barycentric coordinate must be ``>= -_INSIDE_TOL``; a degenerate or
    clockwise triangle contains nothing.
    """
    area2 = _edge_turn(ax, ay, bx, by, cx, cy)
    if not area2 > 0.0:
        return False
    tol = -_INSIDE_TOL * area2
    return (
        _edge_turn(ax, ay, bx, by, px, py) >= tol
        and _edge_turn(bx, by, cx, cy, px, py) >= tol
        and _edge_turn(cx, cy, ax, ay, px, py) >= tol
    )


@njit_helper
def _quad_area2(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, dx: float, dy: float) -> float:
    """Twice the area of the quadrangle ``a b c d``: the cross product of its diagonals."""
    return (cx - ax) * (dy - by) - (cy - ay) * (dx - bx)


@njit_helper
def _quad_contains(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float,
    dx: float, dy: float, px: float, py: float,
) -> bool:
    """True when ``p`` is in the counter-clockwise convex quadrangle ``a b c d`` or on its boundary.

    Every edge turn ``cross(edge, p - start)`` must be ``>= -_INSIDE_TOL``
    times twice the area (:func:`_quad_area2`).
    """
    area2 = _quad_area2(ax, ay, bx, by, cx, cy, dx, dy)
    if not area2 > 0.0:
        return False
    tol = -_INSIDE_TOL * area2
    return (
        _edge_turn(ax, ay, bx, by, px, py) >= tol
        and _edge_turn(bx, by, cx, cy, px, py) >= tol
        and _edge_turn(cx, cy, dx, dy, px, py) >= tol
        and _edge_turn(dx, dy, ax, ay, px, py) >= tol
    )


@njit_helper
def _face_contains(vertices: np.ndarray, faces: np.ndarray, f: int, px: float, py: float) -> bool:
    """True when ``p`` is inside face ``f`` or on its boundary (the bounding box is not tested)."""
    a = faces[f, 0]
    b = faces[f, 1]
    c = faces[f, 2]
    d = faces[f, 3]
    if d < 0:
        return _triangle_contains(
            vertices[a, 0], vertices[a, 1], vertices[b, 0], vertices[b, 1],
            vertices[c, 0], vertices[c, 1], px, py,
        )
    return _quad_contains(
        vertices[a, 0], vertices[a, 1], vertices[b, 0], vertices[b, 1],
        vertices[c, 0], vertices[c, 1], vertices[d, 0], vertices[d, 1], px, py,
    )


@njit_helper
def face_after(vertices: np.ndarray, faces: np.ndarray, f: int, g: int) -> bool:
    """Whether face ``f`` comes after face ``g`` by its first two corners'
    coordinates (x, then y, of the first corner, then of the second; the
    index when both are the same point pairs, which a conforming mesh's
    counter-clockwise faces never share).  Where faces overlap only within
    the inside tests' tolerance, this rule of the geometry picks the face
    that answers, whatever the faces' order."""
    for k in range(2):
        a = faces[f, k]
        b = faces[g, k]
        for c in range(2):
            if vertices[a, c] != vertices[b, c]:
                return vertices[a, c] > vertices[b, c]
    return f > g


# --------------------------------------------------------------------------
# Array kernels: bucket grid, location, evaluation
# --------------------------------------------------------------------------


@njit
def _face_bboxes_kernel(vertices: np.ndarray, faces: np.ndarray, bbox: np.ndarray) -> None:
    for f in range(faces.shape[0]):
        bbox[f, 0], bbox[f, 1], bbox[f, 2], bbox[f, 3] = _face_bbox(vertices, faces, f)


@njit_helper
def _bucket_range(
    lo: float, hi: float, origin: float, inv_size: float, n: int
) -> tuple[int, int]:
    """Inclusive bucket index range covering ``[lo, hi]`` (clamped to ``0 .. n-1``)."""
    top = n - 1.0
    a = (lo - origin) * inv_size
    b = (hi - origin) * inv_size
    i = np.int64(smaller(a, top)) if a > 0.0 else 0
    j = np.int64(smaller(b, top)) if b > 0.0 else 0
    return i, j


@njit
def _bucket_count_kernel(
    bbox: np.ndarray, xmin: float, ymin: float, inv_dx: float, inv_dy: float,
    nbx: int, nby: int, counts: np.ndarray,
) -> None:
    for f in range(bbox.shape[0]):
        i0, i1 = _bucket_range(bbox[f, 0], bbox[f, 2], xmin, inv_dx, nbx)
        j0, j1 = _bucket_range(bbox[f, 1], bbox[f, 3], ymin, inv_dy, nby)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                counts[j * nbx + i] += 1


@njit
def _bucket_fill_kernel(
    bbox: np.ndarray, xmin: float, ymin: float, inv_dx: float, inv_dy: float,
    nbx: int, nby: int, start: np.ndarray, items: np.ndarray,
) -> None:
    fill = start[:-1].copy()
    for f in range(bbox.shape[0]):
        i0, i1 = _bucket_range(bbox[f, 0], bbox[f, 2], xmin, inv_dx, nbx)
        j0, j1 = _bucket_range(bbox[f, 1], bbox[f, 3], ymin, inv_dy, nby)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                b = j * nbx + i
                items[fill[b]] = f
                fill[b] += 1


@njit
def _locate_kernel(
    vertices: np.ndarray, faces: np.ndarray, bbox: np.ndarray,
    xmin: float, ymin: float, xmax: float, ymax: float, inv_dx: float, inv_dy: float,
    nbx: int, nby: int, start: np.ndarray, items: np.ndarray,
    px: np.ndarray, py: np.ndarray, out_face: np.ndarray,
) -> None:
    for k in range(px.shape[0]):
        x = px[k]
        y = py[k]
        out_face[k] = -1
        if not (x >= xmin and x <= xmax and y >= ymin and y <= ymax):
            continue  # also NaN
        i = smaller(np.int64((x - xmin) * inv_dx), nbx - 1)
        j = smaller(np.int64((y - ymin) * inv_dy), nby - 1)
        b = j * nbx + i
        for s in range(start[b], start[b + 1]):
            f = items[s]
            if (
                x >= bbox[f, 0] and x <= bbox[f, 2] and y >= bbox[f, 1] and y <= bbox[f, 3]
                and _face_contains(vertices, faces, f, x, y)
                and (out_face[k] < 0 or face_after(vertices, faces, out_face[k], f))
            ):
                out_face[k] = f  # on a shared edge: the first face by coordinates


@njit
def _evaluate_kernel(
    vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, nodes: np.ndarray | None,
    px: np.ndarray, py: np.ndarray, face: np.ndarray, out: np.ndarray,
) -> None:
    for k in range(px.shape[0]):
        f = face[k]
        if f < 0:
            out[k] = math.nan
        else:
            out[k] = _surface_at(vertices, faces, z, nodes, f, px[k], py[k])[0]


@njit
def _gradient_kernel(
    vertices: np.ndarray, faces: np.ndarray, z: np.ndarray, nodes: np.ndarray | None,
    px: np.ndarray, py: np.ndarray, face: np.ndarray, out_x: np.ndarray, out_y: np.ndarray,
) -> None:
    for k in range(px.shape[0]):
        f = face[k]
        if f < 0:
            out_x[k] = math.nan
            out_y[k] = math.nan
        else:
            _, out_x[k], out_y[k] = _surface_at(vertices, faces, z, nodes, f, px[k], py[k])


# --------------------------------------------------------------------------
# Drivers
# --------------------------------------------------------------------------


class _Locator(NamedTuple):
    """A uniform bucket grid: the faces of bucket ``b`` are ``items[start[b]:start[b + 1]]``."""

    bbox: NDArray[np.float64]
    xmin: float
    ymin: float
    xmax: float
    ymax: float
    inv_dx: float
    inv_dy: float
    nbx: int
    nby: int
    start: NDArray[np.int64]
    items: NDArray[np.int64]


def _query_points(
    x: ArrayLike, y: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[int, ...]]:
    """Flat contiguous float64 copies of ``x`` and ``y`` and their common shape."""
    xa = np.asarray(x)
    ya = np.asarray(y)
    for name, arr in (("x", xa), ("y", ya)):
        if arr.dtype.kind not in "biuf":
            raise InvalidInputError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if xa.shape != ya.shape:
        raise InvalidInputError(f"x and y must have the same shape, got {xa.shape} and {ya.shape}")
    px = np.ascontiguousarray(xa, dtype=np.float64).reshape(-1)
    py = np.ascontiguousarray(ya, dtype=np.float64).reshape(-1)
    return px, py, xa.shape


def _build_locator(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> _Locator:
    """The bucket grid of a mesh with at least one face (about one face per bucket)."""
    n_f = faces.shape[0]
    bbox = np.empty((n_f, 4))
    _face_bboxes_kernel(vertices, faces, bbox)
    xmin = float(bbox[:, 0].min())
    ymin = float(bbox[:, 1].min())
    xmax = float(bbox[:, 2].max())
    ymax = float(bbox[:, 3].max())
    width = xmax - xmin
    height = ymax - ymin
    if width > 0.0 and height > 0.0:
        size = math.sqrt(width * height / n_f)
        nbx = min(max(math.ceil(width / size), 1), n_f)
        nby = min(max(math.ceil(height / size), 1), n_f)
    else:  # a degenerate mesh: one row or column of buckets
        nbx = n_f if width > 0.0 else 1
        nby = n_f if height > 0.0 else 1
    inv_dx = nbx / width if width > 0.0 else 0.0
    inv_dy = nby / height if height > 0.0 else 0.0
    counts = np.zeros(nbx * nby, dtype=np.int64)
    _bucket_count_kernel(bbox, xmin, ymin, inv_dx, inv_dy, nbx, nby, counts)
    start = np.zeros(nbx * nby + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    items = np.empty(int(start[-1]), dtype=np.int64)
    _bucket_fill_kernel(bbox, xmin, ymin, inv_dx, inv_dy, nbx, nby, start, items)
    return _Locator(bbox, xmin, ymin, xmax, ymax, inv_dx, inv_dy, nbx, nby, start, items)


def _locate(
    vertices: NDArray[np.float64], faces: NDArray[np.int64],
    px: NDArray[np.float64], py: NDArray[np.float64],
) -> NDArray[np.int64]:
    """The face containing each point, ``-1`` outside the mesh."""
    face = np.full(px.shape[0], -1, dtype=np.int64)
    if faces.shape[0] == 0 or px.shape[0] == 0:
        return face
    loc = _build_locator(vertices, faces)
    _locate_kernel(
        vertices, faces, loc.bbox, loc.xmin, loc.ymin, loc.xmax, loc.ymax,
        loc.inv_dx, loc.inv_dy, loc.nbx, loc.nby, loc.start, loc.items, px, py, face,
    )
    return face


class SurfaceArrays(NamedTuple):
    """What the evaluation kernels take for a surface: its faces, values and nodes."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    z: NDArray[np.float64]
    nodes: NDArray[np.float64] | None
    """None for the linear surface (its kernels are compiled without the patches)."""
    parent: NDArray[np.int64] | None
    """The mesh's face of each face (a refined smooth surface), or None: the mesh's own faces."""


def surface_arrays(
    mesh: Mesh,
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    z: NDArray[np.float64],
    surface: str | Surface | SmoothSurface,
    nodes: ArrayLike | None,
    variogram: Variogram | None,
) -> SurfaceArrays:
    """The arrays a kernel evaluates for ``surface`` over ``mesh``: its own faces
    (linear, or smooth with ``nodes`` given), or a smooth surface's refined ones
    (given, or computed by :func:`meshcore.smooth_surface`).

    ``vertices, faces, z`` are ``mesh``'s, already checked.
    """
    if isinstance(surface, SmoothSurface):
        if nodes is not None or variogram is not None:
            raise InvalidInputError("a computed smooth surface carries its nodes and variogram: give neither")
        n_v = vertices.shape[0]
        ok = (
            surface.parent.shape == (surface.mesh.faces.shape[0],)
            and surface.nodes.shape == (surface.mesh.faces.shape[0], NODES_PER_FACE)
            and surface.z.shape == (surface.mesh.vertices.shape[0],)
            and surface.z.shape[0] >= n_v
            and (surface.parent.size == 0 or 0 <= surface.parent.min() <= surface.parent.max() < faces.shape[0])
        )
        if not ok or not np.array_equal(surface.z[:n_v], z, equal_nan=True):
            raise InvalidInputError("surface was computed for another mesh or other values")
        return SurfaceArrays(*mesh_arrays(surface.mesh), surface.z, np.ascontiguousarray(surface.nodes, dtype=np.float64),
                             surface.parent)
    kind = parse_option(Surface, surface, "surface")
    n_f = faces.shape[0]
    if kind is Surface.LINEAR:
        if nodes is not None:
            raise InvalidInputError("nodes are the smooth surface's: give them with surface='smooth'")
        return SurfaceArrays(vertices, faces, z, None, None)
    if nodes is None:
        smooth = smooth_surface(mesh, z, variogram)
        return SurfaceArrays(*mesh_arrays(smooth.mesh), smooth.z, smooth.nodes, smooth.parent)
    arr = np.asarray(nodes)
    if arr.dtype.kind not in "fiu" or arr.shape != (n_f, NODES_PER_FACE):
        raise InvalidInputError(
            f"nodes must be a real array of shape (n_faces, {NODES_PER_FACE}) = ({n_f}, {NODES_PER_FACE}), "
            f"got {arr.dtype} {arr.shape}"
        )
    return SurfaceArrays(vertices, faces, z, np.ascontiguousarray(arr, dtype=np.float64), None)


def interpolate(
    mesh: Mesh,
    z: ArrayLike,
    x: ArrayLike,
    y: ArrayLike,
    surface: str | Surface | SmoothSurface = "linear",
    nodes: ArrayLike | None = None,
    variogram: Variogram | None = None,
) -> NDArray[np.float64]:
    """Evaluate the mesh surface at points ``(x, y)``.

    Linear on triangles, isoparametric bilinear on quadrangles (see the module
    docstring); continuous across shared edges.

    Parameters
    ----------
    mesh : Mesh
        A conforming counter-clockwise mesh of triangles and convex quadrangles.
    z : (n_v,) array
        One value per vertex, finite or NaN (NaN spreads to the faces using it).
    x, y : arrays of one shape, or scalars
        The query points.
    surface : {"linear", "smooth"} or SmoothSurface
        The paper's linear/bilinear faces, or cubic patches through the same
        vertices (:mod:`meshcore.patches`, :mod:`meshcore.smooth`): computed
        by :func:`meshcore.smooth_surface` (its long faces cut first), or as
        computed already for this mesh and ``z``.
    nodes : (n_f, 12) array, optional
        With ``surface="smooth"``: node values of patches on the mesh's own
        faces (:func:`meshcore.smooth_nodes`, none cut).
    variogram : Variogram, optional
        For a computed smooth surface: the kriging model (fitted to the vertices when omitted).

    Returns
    -------
    ndarray of float64, the shape of ``x``
        The surface value; NaN outside the mesh and at NaN coordinates.

    Raises
    ------
    InvalidInputError
        When ``z`` is not ``(n_v,)``, contains inf, or ``x`` and ``y`` differ in shape.

    Examples
    --------
    >>> import numpy as np
    >>> from meshcore.mesh import Mesh
    >>> square = Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]),
    ...               np.array([[0, 1, 2, 3]]), np.arange(4))
    >>> interpolate(square, [0.0, 1.0, 3.0, 1.0], [0.5, 2.0], [0.5, 0.5]).tolist()
    [1.25, nan]
    """
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    px, py, shape = _query_points(x, y)
    arrays = surface_arrays(mesh, vertices, faces, zv, surface, nodes, variogram)
    face = _locate(arrays.vertices, arrays.faces, px, py)
    out = np.empty(px.shape[0])
    _evaluate_kernel(arrays.vertices, arrays.faces, arrays.z, arrays.nodes, px, py, face, out)
    return out.reshape(shape)


def gradient(
    mesh: Mesh,
    z: ArrayLike,
    x: ArrayLike,
    y: ArrayLike,
    surface: str | Surface | SmoothSurface = "linear",
    nodes: ArrayLike | None = None,
    variogram: Variogram | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The gradient ``(dz/dx, dz/dy)`` of the mesh surface at points ``(x, y)``.

    Linear surface: constant on a triangle, ``J^-T [dz/du, dz/dv]`` on a
    quadrangle.  Smooth surface: the cubic patch's.  The gradient jumps
    across edges: a point on a shared edge takes the gradient of either face.
    Arguments as for :func:`interpolate`.

    Returns
    -------
    (dzdx, dzdy) : two float64 arrays, the shape of ``x``
        NaN outside the mesh.

    Examples
    --------
    >>> import numpy as np
    >>> from meshcore.mesh import Mesh
    >>> tri = Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
    ...            np.array([[0, 1, 2, -1]]), np.arange(3))
    >>> gx, gy = gradient(tri, [1.0, 3.0, 6.0], 0.2, 0.2)
    >>> float(gx), float(gy)
    (2.0, 5.0)
    """
    vertices, faces = mesh_arrays(mesh)
    zv = vertex_values(z, vertices.shape[0])
    px, py, shape = _query_points(x, y)
    arrays = surface_arrays(mesh, vertices, faces, zv, surface, nodes, variogram)
    face = _locate(arrays.vertices, arrays.faces, px, py)
    gx = np.empty(px.shape[0])
    gy = np.empty(px.shape[0])
    _gradient_kernel(arrays.vertices, arrays.faces, arrays.z, arrays.nodes, px, py, face, gx, gy)
    return gx.reshape(shape), gy.reshape(shape)
