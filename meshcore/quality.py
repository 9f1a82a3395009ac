"""Shape quality measures S1-S4 of the paper (eq. 2 and 3), scalar and vectorised.

All four are *fair* measures: 0 for a degenerate domain, at most 1, equal to 1
for the optimal shape (the equilateral triangle for S1 and S3, the square for
S2 and S4), and invariant to translation, rotation, reflection and scale.

S1(t) = 2/sqrt(3) * min over the angles of  sin(theta)     if theta <= 90 deg
                                            1 + cos(theta) otherwise
S2(q) = the same minimum over the four angles of a quadrangle, without 2/sqrt(3)
S3(t) = (4 / (3 sqrt 3) * A / R^2) ** (1/3)      (A area, R circumradius)
S4(q) = (A / (2 R_max^2)) ** (1/3)                (R_max: largest circumradius
                                                   of the four vertex triples)

A quadrangle that is not strictly convex scores 0 under S2 and S4.

The scalar kernels (``s1_kernel`` ...) take plain coordinates and are used by
the flip and merge kernels; the public functions take ``(..., 3, 2)`` or
``(..., 4, 2)`` arrays of vertex coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._jit import larger, njit, njit_helper, smaller
from .errors import InvalidInputError

__all__ = [
    "s1",
    "s2",
    "s3",
    "s4",
    "MeasureSummary",
    "QualitySummary",
    "quality_summary",
]

_TWO_OVER_SQRT3 = 2.0 / math.sqrt(3.0)
_S3_CUBE_FACTOR = _TWO_OVER_SQRT3**3


@njit_helper
def _angle_score(ux: float, uy: float, vx: float, vy: float) -> float:
    """sin(theta) for theta <= 90 deg, 1 + cos(theta) above; theta = angle(u, v)."""
    lu = math.sqrt(ux * ux + uy * uy)
    lv = math.sqrt(vx * vx + vy * vy)
    if lu == 0.0 or lv == 0.0:
        return 0.0
    luv = lu * lv
    dot = ux * vx + uy * vy
    cross = ux * vy - uy * vx
    if dot >= 0.0:
        return abs(cross) / luv
    # 1 + cos = sin^2 / (1 - cos): no cancellation as theta nears 180 deg
    return cross * cross / (luv * (luv - dot))


@njit_helper
def _normalised(ax, ay, bx, by, cx, cy):
    """b - a and c - a divided by their largest component (zeros when all vanish).

    Measures are scale-invariant; normalising keeps squares and products of
    lengths clear of underflow and overflow for any coordinate magnitude.
    """
    ux = bx - ax
    uy = by - ay
    vx = cx - ax
    vy = cy - ay
    s = larger(larger(abs(ux), abs(uy)), larger(abs(vx), abs(vy)))
    if s == 0.0 or not math.isfinite(s):
        return 0.0, 0.0, 0.0, 0.0
    if s > 1e-290:  # multiply by the inverse: cheaper, and exact enough
        inv = 1.0 / s
        return ux * inv, uy * inv, vx * inv, vy * inv
    return ux / s, uy / s, vx / s, vy / s  # 1 / s would overflow


@njit
def s1_kernel(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """S1 of the triangle ``a, b, c`` (either orientation)."""
    ux, uy, vx, vy = _normalised(ax, ay, bx, by, cx, cy)
    if ux * vy - uy * vx == 0.0:
        return 0.0
    sa = _angle_score(ux, uy, vx, vy)
    sb = _angle_score(vx - ux, vy - uy, -ux, -uy)
    sc = _angle_score(-vx, -vy, ux - vx, uy - vy)
    return smaller(_TWO_OVER_SQRT3 * smaller(sa, smaller(sb, sc)), 1.0)


@njit
def s3_cubed_kernel(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """S3 ** 3 of the triangle ``a, b, c``: the same order as S3 without a cube root."""
    cross, denom = _cross_and_sides(*_normalised(ax, ay, bx, by, cx, cy))
    if cross == 0.0 or denom == 0.0:  # an edge shorter than 1e-154 of the longest: degenerate
        return 0.0
    return smaller(_S3_CUBE_FACTOR * cross * cross * cross / denom, 1.0)


@njit_helper
def _cross_and_sides(ux: float, uy: float, vx: float, vy: float) -> tuple[float, float]:
    """|u x v| and the product of the squared sides of the triangle with edge
    vectors u and v from one corner: S3 cubed is their ratio, scaled."""
    cross = abs(ux * vy - uy * vx)
    return cross, ((vx - ux) ** 2 + (vy - uy) ** 2) * (vx * vx + vy * vy) * (ux * ux + uy * uy)


@njit
def s3_cubed_below(ax: float, ay: float, bx: float, by: float, cx: float, cy: float, limit: float) -> bool:
    """True when :func:`s3_cubed_kernel` of the triangle is surely below ``limit``
    (``limit >= 1e-3``), decided on raw coordinates without its normalisation
    and divisions; False means "compute it".

    A triangle whose score is near such a limit has no angle near 0 or 180
    degrees, so this estimate and the kernel's value agree to about 1e-12
    relative; the estimate must be below the limit by 1e-9 relative to count.
    Out-of-range magnitudes (products outside 1e-250..1e250) say False.
    """
    if limit < 1e-3:
        return False
    cross, denom = _cross_and_sides(bx - ax, by - ay, cx - ax, cy - ay)
    if not 1e-250 < denom < 1e250:
        return False
    return _S3_CUBE_FACTOR * cross * cross * cross < limit * denom * (1.0 - 1e-9)


@njit_helper
def s3_kernel(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """S3 of the triangle ``a, b, c`` = 4/sqrt(3) A / (l1 l2 l3)^(2/3)."""
    return np.cbrt(s3_cubed_kernel(ax, ay, bx, by, cx, cy))


@njit_helper
def _quad_turns_ok(ax, ay, bx, by, cx, cy, dx, dy) -> bool:
    """True when the quadrangle a, b, c, d is strictly convex (either orientation)."""
    t0 = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
    t1 = (cx - bx) * (dy - cy) - (cy - by) * (dx - cx)
    t2 = (dx - cx) * (ay - dy) - (dy - cy) * (ax - dx)
    t3 = (ax - dx) * (by - ay) - (ay - dy) * (bx - ax)
    if t0 > 0.0 and t1 > 0.0 and t2 > 0.0 and t3 > 0.0:
        return True
    return t0 < 0.0 and t1 < 0.0 and t2 < 0.0 and t3 < 0.0


@njit_helper
def _quad_frame(ax, ay, bx, by, cx, cy, dx, dy):
    """The quadrangle translated to a = 0 and scaled to unit largest coordinate."""
    s = larger(
        larger(larger(abs(bx - ax), abs(by - ay)), larger(abs(cx - ax), abs(cy - ay))),
        larger(abs(dx - ax), abs(dy - ay)),
    )
    if s == 0.0 or not math.isfinite(s):
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False
    if s > 1e-290:
        inv = 1.0 / s
        return (bx - ax) * inv, (by - ay) * inv, (cx - ax) * inv, (cy - ay) * inv, (dx - ax) * inv, (dy - ay) * inv, True
    return (bx - ax) / s, (by - ay) / s, (cx - ax) / s, (cy - ay) / s, (dx - ax) / s, (dy - ay) / s, True


@njit_helper
def s2_kernel(ax, ay, bx, by, cx, cy, dx, dy) -> float:
    """S2 of the quadrangle ``a, b, c, d`` (vertices in boundary order)."""
    bx, by, cx, cy, dx, dy, ok = _quad_frame(ax, ay, bx, by, cx, cy, dx, dy)
    if not ok or not _quad_turns_ok(0.0, 0.0, bx, by, cx, cy, dx, dy):
        return 0.0
    sa = _angle_score(bx, by, dx, dy)
    sb = _angle_score(cx - bx, cy - by, -bx, -by)
    sc = _angle_score(dx - cx, dy - cy, bx - cx, by - cy)
    sd = _angle_score(-dx, -dy, cx - dx, cy - dy)
    return smaller(smaller(sa, sb), smaller(sc, sd))


@njit_helper
def _cross_over_lengths(ax, ay, bx, by, cx, cy) -> float:
    """cross^2 / (la lb lc) = 1 / (4 R^2) of the triangle a, b, c."""
    cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    la = (bx - cx) ** 2 + (by - cy) ** 2
    lb = (cx - ax) ** 2 + (cy - ay) ** 2
    lc = (ax - bx) ** 2 + (ay - by) ** 2
    denom = la * lb * lc
    if denom == 0.0:
        return 0.0
    return cross * cross / denom


@njit_helper
def s4_cubed_kernel(ax, ay, bx, by, cx, cy, dx, dy) -> float:
    """S4 ** 3 of the quadrangle ``a, b, c, d``: the same order as S4 without a cube root."""
    bx, by, cx, cy, dx, dy, ok = _quad_frame(ax, ay, bx, by, cx, cy, dx, dy)
    if not ok or not _quad_turns_ok(0.0, 0.0, bx, by, cx, cy, dx, dy):
        return 0.0
    inv4r2 = smaller(
        smaller(
            _cross_over_lengths(0.0, 0.0, bx, by, cx, cy),
            _cross_over_lengths(bx, by, cx, cy, dx, dy),
        ),
        smaller(
            _cross_over_lengths(cx, cy, dx, dy, 0.0, 0.0),
            _cross_over_lengths(dx, dy, 0.0, 0.0, bx, by),
        ),
    )
    area = 0.5 * abs(cx * (dy - by) - cy * (dx - bx))
    # A / (2 R^2) = A * 2 * (1 / (4 R^2))
    return smaller(2.0 * area * inv4r2, 1.0)


@njit_helper
def s4_kernel(ax, ay, bx, by, cx, cy, dx, dy) -> float:
    """S4 of the quadrangle ``a, b, c, d`` (vertices in boundary order)."""
    return np.cbrt(s4_cubed_kernel(ax, ay, bx, by, cx, cy, dx, dy))


@njit
def _triangles_kernel(p: np.ndarray, measure: int, out: np.ndarray) -> None:
    for i in range(p.shape[0]):
        if measure == 1:
            out[i] = s1_kernel(p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1], p[i, 2, 0], p[i, 2, 1])
        else:
            out[i] = s3_kernel(p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1], p[i, 2, 0], p[i, 2, 1])


@njit
def _quads_kernel(p: np.ndarray, measure: int, out: np.ndarray) -> None:
    for i in range(p.shape[0]):
        if measure == 2:
            out[i] = s2_kernel(
                p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1],
                p[i, 2, 0], p[i, 2, 1], p[i, 3, 0], p[i, 3, 1],
            )
        else:
            out[i] = s4_kernel(
                p[i, 0, 0], p[i, 0, 1], p[i, 1, 0], p[i, 1, 1],
                p[i, 2, 0], p[i, 2, 1], p[i, 3, 0], p[i, 3, 1],
            )


def _evaluate(points: ArrayLike, corners: int, measure: int) -> NDArray[np.float64]:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-2:] != (corners, 2):
        raise InvalidInputError(
            f"expected an array of shape (..., {corners}, 2) of vertex coordinates, got {arr.shape}"
        )
    flat = np.ascontiguousarray(arr.reshape(-1, corners, 2))
    out = np.empty(flat.shape[0])
    if corners == 3:
        _triangles_kernel(flat, measure, out)
    else:
        _quads_kernel(flat, measure, out)
    return out.reshape(arr.shape[:-2])


def s1(triangles: ArrayLike) -> NDArray[np.float64]:
    """S1 (angle measure, eq. 2) of triangles given as ``(..., 3, 2)`` coordinates.

    Examples
    --------
    >>> import numpy as np
    >>> float(s1([[0, 0], [1, 0], [0.5, np.sqrt(3) / 2]]))
    1.0
    """
    return _evaluate(triangles, 3, 1)


def s2(quads: ArrayLike) -> NDArray[np.float64]:
    """S2 (angle measure, eq. 2) of quadrangles given as ``(..., 4, 2)`` coordinates.

    Examples
    --------
    >>> float(s2([[0, 0], [1, 0], [1, 1], [0, 1]]))
    1.0
    """
    return _evaluate(quads, 4, 2)


def s3(triangles: ArrayLike) -> NDArray[np.float64]:
    """S3 (area over squared circumradius, eq. 3) of ``(..., 3, 2)`` triangles."""
    return _evaluate(triangles, 3, 3)


def s4(quads: ArrayLike) -> NDArray[np.float64]:
    """S4 (area over largest squared circumradius, eq. 3) of ``(..., 4, 2)`` quadrangles."""
    return _evaluate(quads, 4, 4)


@dataclass(frozen=True)
class MeasureSummary:
    """Distribution of one measure over the faces it applies to."""

    measure: str
    count: int
    minimum: float
    mean: float
    histogram: tuple[int, ...]
    bin_edges: tuple[float, ...]


@dataclass(frozen=True)
class QualitySummary:
    """Counts of faces and the distribution of S1/S3 on triangles and S2/S4 on quads."""

    n_triangles: int
    n_quads: int
    measures: tuple[MeasureSummary, ...]

    def __str__(self) -> str:
        lines = [f"{self.n_triangles} triangles, {self.n_quads} quadrangles"]
        for m in self.measures:
            lines.append(f"  {m.measure}: n={m.count} min={m.minimum:.4f} mean={m.mean:.4f}")
        return "\n".join(lines)


def quality_summary(vertices: ArrayLike, faces: ArrayLike, bins: int = 10) -> QualitySummary:
    """Summarise the shape quality of a combined mesh.

    Parameters
    ----------
    vertices : (n, 2) float array
    faces : (m, 4) int array, ``-1`` in column 3 for triangles
    bins : number of equal histogram bins on [0, 1]
    """
    v = np.asarray(vertices, dtype=np.float64)[:, :2]
    f = np.asarray(faces, dtype=np.int64)
    is_quad = f[:, 3] >= 0
    tri = v[f[~is_quad, :3]]
    quad = v[f[is_quad]]
    edges = np.linspace(0.0, 1.0, bins + 1)
    out = []
    for name, values in (("s1", s1(tri)), ("s3", s3(tri)), ("s2", s2(quad)), ("s4", s4(quad))):
        hist = np.histogram(values, bins=edges)[0]
        out.append(
            MeasureSummary(
                measure=name,
                count=int(values.size),
                minimum=float(values.min()) if values.size else math.nan,
                mean=float(values.mean()) if values.size else math.nan,
                histogram=tuple(int(h) for h in hist),
                bin_edges=tuple(float(e) for e in edges),
            )
        )
    return QualitySummary(int((~is_quad).sum()), int(is_quad.sum()), tuple(out))
