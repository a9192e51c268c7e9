"""The one argument-check module: what counts as an integer, a number, a fraction, a choice."""

import numpy as np
import pytest

from lfring.core.validate import (
    check_bool,
    check_callable,
    check_choice,
    check_fraction,
    check_int,
    check_number,
    check_odd_px,
    check_threads,
    check_view_index,
    is_integer,
    is_number,
)
from lfring.errors import DeviceError, InvalidInputError


def test_bools_are_neither_integers_nor_numbers():
    assert [is_integer(v) for v in (3, np.int16(3), True, np.bool_(True), 3.0, "3")] == [True, True, False, False, False,
                                                                                         False]
    assert [is_number(v) for v in (3, 2.5, np.float32(2.5), True, None, "1")] == [True, True, True, False, False, False]


def test_check_int_converts_and_bounds():
    assert check_int(np.int64(7), "n", minimum=2) == 7 and type(check_int(np.int64(7), "n")) is int
    assert check_int(None, "n", allow_none=True) is None
    for bad in (1, 11, 2.0, True, None, "5"):
        with pytest.raises(InvalidInputError, match=r"n must be an integer >= 2 and <= 10, got"):
            check_int(bad, "n", minimum=2, maximum=10)


def test_check_number_refuses_nan_infinity_and_bounds():
    assert check_number(np.float32(0.25), "z", above=0.0) == 0.25
    assert check_number(float("inf"), "z", finite=False) == float("inf")
    for bad in (0.0, -1.0, float("nan"), float("inf"), True, "0.5", 10 ** 400):
        with pytest.raises(InvalidInputError, match="z must be a distance > 0"):
            check_number(bad, "z", above=0.0, what="a distance")
    with pytest.raises(InvalidInputError, match="z must be a number >= 0 and < 1"):
        check_number(1.0, "z", minimum=0.0, below=1.0)
    with pytest.raises(DeviceError, match="focal"):
        check_number(-1.0, "focal", above=0.0, error=DeviceError)


def test_check_fraction_choice_bool_odd_threads_view_callable():
    assert check_fraction(1, "f") == 1.0
    with pytest.raises(InvalidInputError, match=r"f must be a number in \[0, 1\]"):
        check_fraction(1.5, "f")
    assert check_choice("b", "kind", ("a", "b")) == "b"
    for bad in ("c", True, ["a"], None):
        with pytest.raises(InvalidInputError, match="kind must be one of a, b"):
            check_choice(bad, "kind", ("a", "b"))
    assert check_bool(np.bool_(False), "flag") is False
    with pytest.raises(InvalidInputError, match="flag must be True or False"):
        check_bool("no", "flag")
    assert check_odd_px(5, "w") == 5
    for bad in (4, 0, -3, 5.0, True):
        with pytest.raises(InvalidInputError, match="w must be an odd positive integer"):
            check_odd_px(bad, "w")
    assert check_threads(None) is None and check_threads(2) == 2
    with pytest.raises(InvalidInputError, match="threads must be an integer >= 1"):
        check_threads(0)
    assert check_view_index("center", "ref", 4, allow_center=True) == "center"
    with pytest.raises(InvalidInputError, match=r"ref must be a view index 0..3"):
        check_view_index(4, "ref", 4)
    assert check_callable(None, "cb") is None
    with pytest.raises(InvalidInputError, match="cb must be a callable"):
        check_callable(3, "cb")
