"""Tests of meshcore.options: the one parser of string options."""

from __future__ import annotations

import pytest

from meshcore import InvalidInputError, MergeMethod, Surface, parse_option


class _Refused(ValueError):
    pass


def test_members_and_values_parse_and_text_folds_case_by_default():
    assert parse_option(MergeMethod, MergeMethod.OPTIMAL, "merge") is MergeMethod.OPTIMAL
    assert parse_option(Surface, "SMOOTH", "surface") is Surface.SMOOTH


def test_an_invalid_value_names_the_valid_ones_in_the_callers_error():
    with pytest.raises(InvalidInputError, match=r"^merge='best' is not valid; expected one of 'greedy', 'optimal'$"):
        parse_option(MergeMethod, "best", "merge")
    with pytest.raises(_Refused, match=r"^merge='GREEDY' is not valid"):
        parse_option(MergeMethod, "GREEDY", "merge", error=_Refused, fold_case=False)


def test_a_caller_words_the_message():
    with pytest.raises(_Refused, match=r"^unknown surface 'cubic'; valid: linear, smooth \('linear', 'smooth'\)$"):
        parse_option(Surface, "cubic", "surface", error=_Refused, message="unknown {name} {value!r}; valid: {names} ({valid})")
