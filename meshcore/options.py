"""The options of :func:`meshcore.build_mesh` and of the surface, as string enums with clear errors."""

from __future__ import annotations

from enum import Enum, StrEnum
from collections.abc import Callable
from typing import TypeVar

from .errors import InvalidInputError

__all__ = ["TriangleMeasure", "QuadMeasure", "MergeMethod", "Surface", "parse_option"]


class TriangleMeasure(StrEnum):
    """How triangles are improved: none (Delaunay), or flips driven by S1 or S3."""

    DELAUNAY = "delaunay"
    S1 = "s1"
    S3 = "s3"


class QuadMeasure(StrEnum):
    """The quadrangle measure that drives the elimination of diagonals."""

    S2 = "s2"
    S4 = "s4"


class MergeMethod(StrEnum):
    """Which diagonals are eliminated: the paper's greedy queue, or a maximum-weight matching."""

    GREEDY = "greedy"
    OPTIMAL = "optimal"


class Surface(StrEnum):
    """The surface over the faces: the paper's linear/bilinear one, or cubic patches through the same points."""

    LINEAR = "linear"
    SMOOTH = "smooth"


E = TypeVar("E", bound=Enum)


def parse_option(
    kind: type[E],
    value: object,
    name: str,
    *,
    error: Callable[[str], Exception] = InvalidInputError,
    fold_case: bool = True,
    message: str = "{name}={value!r} is not valid; expected one of {valid}",
) -> E:
    """``kind(value)``, or ``error(message)`` naming the valid values: the
    one parser of string options, here and in the packages that use meshcore.

    Parameters
    ----------
    kind : Enum subclass
        The option's values.
    value : object
        A member of ``kind`` or its value.
    name : str
        The parameter's name, for the message.
    error : callable, default InvalidInputError
        Makes the exception from the message (a caller's own error type).
    fold_case : bool, default True
        Match text whatever its case.
    message : str
        Format of the message, with ``name``, ``value``, ``valid`` (the valid
        values quoted, comma-separated) and ``names`` (the same, unquoted).

    Examples
    --------
    >>> parse_option(MergeMethod, "Greedy", "merge")
    <MergeMethod.GREEDY: 'greedy'>
    >>> parse_option(MergeMethod, "best", "merge")
    Traceback (most recent call last):
    ...
    meshcore.errors.InvalidInputError: merge='best' is not valid; expected one of 'greedy', 'optimal'
    """
    try:
        return kind(value.lower() if fold_case and isinstance(value, str) else value)
    except ValueError:
        values = [str(m.value) for m in kind]
        text = message.format(
            name=name, value=value, valid=", ".join(repr(v) for v in values), names=", ".join(values)
        )
        raise error(text) from None
