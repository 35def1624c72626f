"""The shared argument checks: accepted values pass through normalised, bad ones name the argument."""

import numpy as np
import pytest

from nanoct.core.validation import check_bool, check_choice, check_float, check_int, check_int_list


def test_check_float_bounds():
    assert check_float(1, "a") == 1.0 and isinstance(check_float(np.float32(0.5), "a"), float)
    assert check_float(0.0, "a", low=0.0) == 0.0
    assert check_float(2.0, "a", high=2.0) == 2.0
    for value, kwargs in [
        (0.0, dict(low=0.0, low_open=True)),
        (2.0, dict(high=2.0, high_open=True)),
        (-1e-9, dict(low=0.0)),
        (float("nan"), {}),
        (float("inf"), {}),
        ("0.5", {}),
        (True, {}),
        (None, {}),
    ]:
        with pytest.raises(ValueError, match="^a="):
            check_float(value, "a", **kwargs)
    with pytest.raises(ValueError, match=r"\(0, 2\)"):
        check_float(3.0, "a", low=0.0, high=2.0, low_open=True, high_open=True)
    with pytest.raises(ValueError, match=r"\[1, inf\)"):
        check_float(0.0, "a", low=1.0)


def test_check_choice_and_bool():
    assert check_choice("b", "c", ("a", "b")) == "b"
    for value in ("z", 1, None, ["a"]):
        with pytest.raises(ValueError, match="c=.*use one of a, b"):
            check_choice(value, "c", ("a", "b"))
    assert check_bool(np.bool_(True), "f") is True and check_bool(0, "f") is False
    assert check_bool("False", "f") is False and check_bool("TRUE", "f") is True  # the words, any case
    for value in ("yes", 2, 0.0, None):
        with pytest.raises(ValueError, match="f=.*true or false"):
            check_bool(value, "f")


def test_check_int():
    assert check_int(np.int64(3), "n", 1) == 3
    for value in (0, 1.0, "2", True):
        with pytest.raises(ValueError, match="n="):
            check_int(value, "n", 1)


def test_check_int_list():
    assert check_int_list((np.int64(3), 4), "c", 1) == [3, 4] == check_int_list(np.array([3, 4]), "c", 1)
    for value in ([], "34", 3, [3, 4.0], [3, 0], np.ones((2, 2), int)):
        with pytest.raises(ValueError, match="c="):
            check_int_list(value, "c", 1)
