"""Point attributes past x, y, z, and the return filters that read them.

The reader decodes an attribute only when a product or a filter of the run
needs it (:mod:`pipeline.products`); these are their names and the filters'.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from ..errors import UsageError

__all__ = ["Returns", "Attribute", "RETURN_ATTRIBUTES"]


class Returns(StrEnum):
    """Which returns of each pulse a selection keeps (PDAL's and LAStools' words).

    ``first``: return number 1 (or 0, which some writers leave); ``last``:
    return number at least the number of returns; ``single``: pulses of one
    return (number of returns 0 or 1); ``all``: every return.
    """

    ALL = "all"
    FIRST = "first"
    LAST = "last"
    SINGLE = "single"

    @classmethod
    def parse(cls, value: object) -> Returns:
        """The filter named ``value``; a :class:`UsageError` lists the valid names."""
        from meshcore import parse_option

        return parse_option(cls, value, "returns", error=UsageError, fold_case=False)  # type: ignore[no-any-return]

    def mask(self, return_number: NDArray, number_of_returns: NDArray) -> NDArray[np.bool_] | None:
        """Which points this filter keeps (None: every one)."""
        if self is Returns.ALL:
            return None
        if self is Returns.FIRST:
            return np.asarray(return_number) <= 1
        if self is Returns.LAST:
            return np.asarray(return_number) >= np.asarray(number_of_returns)
        return np.asarray(number_of_returns) <= 1


class Attribute(StrEnum):
    """A point attribute a product may need past the reader (laspy's dimension names)."""

    CLASSIFICATION = "classification"
    RETURN_NUMBER = "return_number"
    NUMBER_OF_RETURNS = "number_of_returns"
    INTENSITY = "intensity"
    POINT_INDEX = "point_index"
    """Not a dimension: the point's position in its file (what ``terrain classify`` writes back by)."""


#: the attributes a return filter reads
RETURN_ATTRIBUTES = (Attribute.RETURN_NUMBER, Attribute.NUMBER_OF_RETURNS)
