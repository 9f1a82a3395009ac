"""Nodes in voids: how the smooth surface fills where there are no points.

A node farther than :data:`VOID_NEAR` spacings from its cell's points is
blended, by its distance from them, into the void's fill: the linear surface,
then the Delaunay TIN of the points around the void, moved half the way to
their natural-neighbour interpolant (:mod:`meshcore.natural`) where the two
agree within the ground's variability at that distance
(:data:`VOID_AGREEMENT`).  There the cell's points lie on one side of the
rim, and kriging carries that side's tilt and noise across the void: beyond
a few spacings it was worse than the TIN; the fill reads the whole rim,
stays within its values and reproduces linear functions.  The
blend depends on the node's position and its cell's points alone, so edges
stay C0 and tiles seamless (:func:`_void_blend`, :class:`VoidFill`).
"""

from __future__ import annotations
import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ._jit import larger, njit, njit_helper, smaller
from .natural import NaturalCoordinates, natural_coordinates, natural_ranges, natural_values, take_places, tin_values
from .cells import CELL_PER_SPACING
from .variogram import Variogram

__all__ = ["VoidFill", "VOID_NEAR", "VOID_FAR", "VOID_NATURAL_SHARE", "VOID_AGREEMENT", "VOID_REACH"]


@njit_helper
def _void_blend(value: float, linear: float, fill: float, gap: float, near: float, far: float) -> float:
    """A node's value ``gap`` from its nearest point: its kriged ``value`` up to ``near``,
    the void's ``fill`` (:meth:`VoidFill.values`; NaN where a node has none: the
    linear surface then) from ``far`` on, in between a blend linear in the
    distance.  Kriging, the fill and the linear surface reproduce linear
    functions, and the fill stays within the values of the points around the
    void: so does the blend, and it goes from one to the other smoothly."""
    base = fill if math.isfinite(fill) else linear
    if gap >= far:
        return base
    w = (far - gap) / (far - near)
    return base + w * (value - base)


class VoidFill(NamedTuple):
    """The nodes (or added points) of a smooth surface in voids, and their
    natural-neighbour coordinates (:func:`meshcore.natural.natural_coordinates`).

    Attributes
    ----------
    rows : (q,) int64, the nodes, ascending
    coordinates : NaturalCoordinates, one row for each
    """

    rows: NDArray[np.int64]
    coordinates: NaturalCoordinates

    def values(self, z: NDArray[np.float64], n: int, variogram: Variogram,
               gap: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(n, 3)``: for each of ``n`` nodes the void's fill of the points' values ``z``
        and the lowest and highest value of its natural neighbours; NaN at the
        nodes not in voids (and where a node has no natural neighbours).

        The fill is the Delaunay TIN's value, moved :data:`VOID_NATURAL_SHARE` of the
        way to the natural-neighbour interpolant's where the two agree: where
        they differ by more than :data:`VOID_AGREEMENT` times the ground's
        standard deviation at the node's distance ``gap`` from the points (the
        ``variogram``'s), less, and not at all from twice that."""
        out = np.full((n, 3), np.nan)
        natural = natural_values(self.coordinates, z)
        tin = tin_values(self.coordinates, z)
        spread = VOID_AGREEMENT * np.sqrt(variogram.semivariance(gap[self.rows]))
        share = VOID_NATURAL_SHARE * np.clip(2.0 - np.abs(natural - tin) / spread, 0.0, 1.0)
        out[self.rows, 0] = tin + share * (natural - tin)
        out[self.rows, 1], out[self.rows, 2] = natural_ranges(self.coordinates, z)
        return out


_NO_ENDS = np.zeros((0, 2), dtype=np.int64)


_NO_FILL = VoidFill(np.zeros(0, dtype=np.int64), NaturalCoordinates(
    np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0), np.empty((0, 3)),
    np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3))))


VOID_NEAR = 1.25
"""A node (or added point) farther than this many point spacings from the nearest
of its cell's points lies in a void: from here to :data:`VOID_FAR` its kriged
value is blended into the void's fill (:func:`_void_blend`)."""


VOID_FAR = 2.5
"""From this many spacings on a node is the void's fill alone.

Why (``bench/bench_accuracy.py``, block cross-validation): in a void every
cell's 16 nearest points lie on one side of the rim, and the kriged value
carries that side's tilt (its linear drift) and noise across; up to 1-2
spacings from the rim it still beats the TIN, farther it loses to it.
A blend over 2-3.5 spacings kept the surface below the TIN's errors in voids
of 5 to 40 units on every sample with the documented draws, but other draws
found small voids where it lost: 4_6_crop at 7 ft (+3.7%, median of three
draws; over ten, better in 6 and up to 14% worse), warsaw_small at 7 m
(+2.3%).  There a void is 2-3 spacings across, so most of its nodes were
kriged from one side.  Over 1.5-3 spacings: 4_6_crop at 7 ft -1.7% (over ten
draws -7.0%, better in 8, at worst +5.6%), warsaw_small +1.0%, every
documented void still better than the TIN (autzen_trim keeps a little less
of its gain: -20.8% against -23.9% at 10 ft), and point cross-validation
within 0.2 points.  Nearer blends (1-2, 1-3) did as well on 4_6_crop but
treat a few percent of the ordinary gaps between random points as voids
(a Poisson gap exceeds 1.5 spacings at 0.1% of places, 1 spacing at 4%).

Over 1.25-2.5 spacings (from 1.5-3): other draws (seeds 0, 1, 1000, 1001
and 3131, one draw each, 7 samples, radii of 4 to 60 units) found voids of
2-3 spacings on ign_semis (2.3 m) where 1.5-3 lost in the median: 5 m +0.5%
(worst draw +31.5%), 6 m +2.4% (+22.1%); with 1.25-2.5, -3.7% (+22.2%) and
-3.6% (+18.5%).  The worst draw improved on most pairs (4_6_crop at 7 ft
+2.0% -> -0.3%, warsaw_small at 5 m +2.1% -> +0.5%, autzen_trim at 10 ft
+6.2% -> +3.5%, ign_semis at 4 m +10.7% -> +9.2%), at the price of some of
the median gain on autzen_trim's small voids (10 ft -20.2% -> -16.3%) and
ign_semis at 4 m (-10.9% -> -7.9%).  Point cross-validation moved by under
a point (ign_semis -6.4% -> -6.6%, autzen_trim -11.4% -> -11.3%, lidR's 20
sets -96.7% -> -96.4%).  1-2.5 did a little better in ign_semis's small
voids (-5.1%, -6.8%) but treated enough of the ordinary gaps as voids to
cost lidR's smooth test 2.4 points (-94.3%: its error 1.7 times as large);
1-2 gave up more of the gain (autzen_trim at 10 ft -8.6%)."""


VOID_NATURAL_SHARE = 0.5
"""The void's fill: this share of the natural-neighbour (Sibson) interpolant of the
points around it, the rest of their Delaunay TIN, where the two agree
(:data:`VOID_AGREEMENT`; :meth:`VoidFill.values`).

Measured as :data:`VOID_FAR`: the natural-neighbour interpolant alone was
2-25% better than the TIN inside most voids, but worse in a void across
startinpy_small's noisy ground (+2 to +4%); a triangulation of the rim (the
TIN's, the combined mesh's) is as arbitrary as another, and was up to 17%
worse than the TIN in some voids (the combined mesh's, 4_6_crop at 10 ft).
The mean of the natural-neighbour interpolant and a triangulation's was the
steadiest: better than the TIN in every void tested, where either alone was
not.  The TIN's, not the combined mesh's, as its value at a node needs no
more than the natural neighbours do (the triangle holding the node is one of
the cavity's), and the combined mesh's, on the faces cut across a void,
showed their small triangles in a hillshade."""


VOID_AGREEMENT = 1.0
"""The natural-neighbour interpolant takes its share of a node's fill where it
departs from the TIN by at most this many times the ground's standard
deviation at the node's distance from the points (the square root of the
fitted variogram there); none where it departs by twice that, and in between
a share linear in the departure (:meth:`VoidFill.values`).

Why (``bench/bench_accuracy.py``): the natural-neighbour interpolant weighs
the whole rim by the areas its points take, and where the rim holds two
grounds, a strip a metre lower along a step, or the far side of a bay of the
survey's outline that the void opens onto, it carries the other ground in:
on startinpy_small (a survey shaped as a U) a void of 12 m that joined the
bay was 1.3 to 3 times the TIN's error far from the points with the half
share everywhere.  The two fills differ there by several of the ground's
standard deviations, which smooth ground seldom does.  With the test the
fill stayed within 0-3% of the TIN's error there.  Over the withheld
points farther than 3 spacings from the rim, in 57 draws (19 pairs of a
sample and a radius of 5 to 40 units), the gain over the TIN went from 7.0% to 4.6%
(medians), and the worst draw from +115% to +11% (a void of 5 m on
warsaw_small, as with the half share).  With 1.25 or 1.5 standard
deviations instead, the gain was 5.2% and 5.5%, and that bay stayed 1-3%
worse than the TIN.  Scaled to the void rather than to the variogram, the
spread let more of the natural neighbours in across large voids, and too
much in that bay (72 draws, radii of 5 to 80 units, medians against the
TIN, and that bay's worst draw): the spread grown past the variogram's
range, by ``(gap / range) ** 0.25``, -5.1% against -2.9%, the bay +9.6%
against +2.7%; the survey's own semivariance at the node's distance (pairs
of points, not the fitted model), -4.6%, the bay +17.7%."""


VOID_REACH = 3.0
"""A node's natural neighbours are read as one disk around it while their circles
reach no farther than this many times the distance to its edge's (its face's,
its cut face's parent's) farthest corner; beyond (beside the hull, where the
circles run far out of it) circle by circle, which a piece of a survey holds
where they meet the hull.  It changes no value, only how the disks are told."""


@njit
def _nearest_points_kernel(vertices: np.ndarray, neighbours: np.ndarray, owner: np.ndarray, positions: np.ndarray,
                           rows: np.ndarray, out: np.ndarray) -> None:
    for t in range(rows.shape[0]):
        n = rows[t]
        s = owner[n]
        best = math.inf
        out[t] = -1
        for i in range(neighbours.shape[1]):
            v = neighbours[s, i]
            if v < 0:
                break
            dx = vertices[v, 0] - positions[n, 0]
            dy = vertices[v, 1] - positions[n, 1]
            if dx * dx + dy * dy < best:
                best = dx * dx + dy * dy
                out[t] = v


def _nearest_points(vertices: NDArray[np.float64], positions: NDArray[np.float64], neighbours: NDArray[np.int64],
                    first: NDArray[np.int64], rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """The nearest of its system's neighbours of each node ``rows`` (-1: none)."""
    owner = np.full(positions.shape[0], -1, dtype=np.int64)
    owner[rows] = np.searchsorted(first, rows, side="right") - 1
    out = np.empty(rows.size, dtype=np.int64)
    _nearest_points_kernel(vertices, neighbours, owner, np.ascontiguousarray(positions), rows, out)
    return out


@njit
def _gaps_kernel(vertices: np.ndarray, neighbours: np.ndarray, first: np.ndarray, positions: np.ndarray, near: float,
                 out: np.ndarray) -> None:
    """``out[n]``: the distance from node ``n`` to the nearest of its system's neighbours
    (system ``s`` holds the nodes ``first[s] .. first[s + 1] - 1``; infinite without
    one), or, once one is found within ``near``, that one's."""
    near2 = near * near
    for s in range(neighbours.shape[0]):
        for n in range(first[s], first[s + 1]):
            px = positions[n, 0]
            py = positions[n, 1]
            best = math.inf
            for i in range(neighbours.shape[1]):
                v = neighbours[s, i]
                if v < 0:
                    break
                dx = vertices[v, 0] - px
                dy = vertices[v, 1] - py
                best = smaller(best, dx * dx + dy * dy)
                if best <= near2:
                    break
            out[n] = math.sqrt(best)


def _gaps(vertices: NDArray[np.float64], neighbours: NDArray[np.int64], first: NDArray[np.int64],
          positions: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """How far each node lies from its system's points: :func:`_gaps_kernel` (the nodes in system
    order), exact beyond :data:`VOID_NEAR` (for cells of side ``cell``)."""
    out = np.empty(positions.shape[0])
    _gaps_kernel(vertices, neighbours, first, positions, _void_distances(cell)[0], out)
    return out


def _void_distances(cell: float) -> tuple[float, float]:
    """:data:`VOID_NEAR` and :data:`VOID_FAR` for nodes in cells of side ``cell``
    (from the cell, which every plan of a survey shares bit for bit)."""
    return cell * (VOID_NEAR / CELL_PER_SPACING), cell * (VOID_FAR / CELL_PER_SPACING)


@njit
def _spans_kernel(positions: np.ndarray, vertices: np.ndarray, corners: np.ndarray, data: int, ends: np.ndarray,
                  out: np.ndarray) -> None:
    for n in range(positions.shape[0]):
        best = 0.0
        for j in range(corners.shape[1]):
            c = corners[n, j]
            if c < 0:
                continue
            for e in range(2):
                v = c if c < data else ends[c - data, e]
                dx = vertices[v, 0] - positions[n, 0]
                dy = vertices[v, 1] - positions[n, 1]
                best = larger(best, dx * dx + dy * dy)
        out[n] = math.sqrt(best)


def _spans(positions: NDArray[np.float64], vertices: NDArray[np.float64], corners: NDArray[np.integer], data: int,
           ends: NDArray[np.int64]) -> NDArray[np.float64]:
    """The distance from each node to the farthest point of its ``corners`` (``-1``
    pads): a corner among the first ``data`` vertices, or else both ends of the
    edge it was added on (``ends[corner - data]``), so that a node of a face cut
    reaches as far as the face's own corners."""
    out = np.empty(positions.shape[0])
    _spans_kernel(np.ascontiguousarray(positions), vertices, np.ascontiguousarray(corners, dtype=np.int64), data,
                  np.ascontiguousarray(ends, dtype=np.int64), out)
    return out


def _void_fills(vertices: NDArray[np.float64], data: int, ends: NDArray[np.int64], cell: float,
                *groups: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64],
                               NDArray[np.integer]], rows: list[NDArray[np.int64]] | None = None) -> list[VoidFill]:
    """For each group ``(positions, gap, index, first, corners)`` of nodes (``index``
    and ``first``: their systems; ``corners``: their edges' or faces' corners, as
    :func:`_spans` takes them): those in voids (or ``rows``) and their natural
    neighbours among the first ``data`` of ``vertices``, each read within
    :data:`VOID_REACH` times the distance to its farthest corner; one
    triangulation for all."""
    near, _ = _void_distances(cell)
    if rows is None:
        rows = [np.flatnonzero(gap > near) for _, gap, *_ in groups]
    if not any(r.size for r in rows):
        return [VoidFill(r, _NO_FILL.coordinates._replace(first=np.zeros(r.size + 1, dtype=np.int64))) for r in rows]
    points = np.ascontiguousarray(vertices[:data])
    places = np.concatenate([positions[r] for (positions, *_), r in zip(groups, rows)])
    reach = np.concatenate([4.0 * gap[r] for (_, gap, *_), r in zip(groups, rows)])
    cap = np.concatenate([VOID_REACH * _spans(positions[r], vertices, corners[r], data, ends)
                          for (positions, _, _, _, corners), r in zip(groups, rows)])
    # each from its nearest point, where the search for its natural neighbours starts
    start = np.concatenate([_nearest_points(points, positions, index, first, r)
                            for (positions, _, index, first, _), r in zip(groups, rows)])
    found = natural_coordinates(points, places, reach, cap, start)
    out = []
    lo = 0
    for r in rows:
        out.append(VoidFill(r, take_places(found, np.arange(lo, lo + r.size))))
        lo += r.size
    return out
