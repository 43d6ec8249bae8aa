"""The shared integer check behind every count-like argument."""

import re

import numpy as np
import pytest

from sb3_ua2c.checks import check_int


@pytest.mark.parametrize("value", [1, 7, np.int64(3)])
def test_check_int_accepts_integers_at_or_above_the_bound(value):
    check_int("n", value)


def test_check_int_lower_bound_is_a_parameter():
    check_int("learning_starts", 0, low=0)
    with pytest.raises(ValueError, match=r"^learning_starts must be an integer >= 0, got -1$"):
        check_int("learning_starts", -1, low=0)


@pytest.mark.parametrize("value", [0, -2, 2.0, "3", None, True, np.float32(4.0)])
def test_check_int_refuses_non_integers_bools_and_small_values(value):
    message = f"Fig2Budget.seeds must be an integer >= 1, got {value!r}"
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        check_int("Fig2Budget.seeds", value)
