"""The options of :func:`meshcore.build_mesh` and of the surface, as string enums with clear errors."""

from __future__ import annotations

from enum import Enum
from typing import TypeVar

from .errors import InvalidInputError

__all__ = ["TriangleMeasure", "QuadMeasure", "MergeMethod", "Surface", "parse_option"]


class TriangleMeasure(str, Enum):
    """How triangles are improved: none (Delaunay), or flips driven by S1 or S3."""

    DELAUNAY = "delaunay"
    S1 = "s1"
    S3 = "s3"


class QuadMeasure(str, Enum):
    """The quadrangle measure that drives the elimination of diagonals."""

    S2 = "s2"
    S4 = "s4"


class MergeMethod(str, Enum):
    """Which diagonals are eliminated: the paper's greedy queue, or a maximum-weight matching."""

    GREEDY = "greedy"
    OPTIMAL = "optimal"


class Surface(str, Enum):
    """The surface over the faces: the paper's linear/bilinear one, or cubic patches through the same points."""

    LINEAR = "linear"
    SMOOTH = "smooth"


E = TypeVar("E", bound=Enum)


def parse_option(kind: type[E], value: object, name: str) -> E:
    """``kind(value)``, or an :class:`InvalidInputError` naming the valid values."""
    try:
        return kind(value.lower() if isinstance(value, str) else value)
    except ValueError:
        valid = ", ".join(repr(m.value) for m in kind)
        raise InvalidInputError(f"{name}={value!r} is not valid; expected one of {valid}") from None
