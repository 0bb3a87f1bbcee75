"""Generic validators (:mod:`imls_lightning.base.validate`): values accepted, canonical types, one-line errors."""
from __future__ import annotations

import doctest

import numpy as np
import pytest

from imls_lightning.base import validate
from imls_lightning.base.errors import InputError
from omegaconf import OmegaConf

from imls_lightning.base.validate import check_integer, check_mapping, check_number, check_numbers, expected, shown


def test_doctests():
    result = doctest.testmod(validate)
    assert result.attempted > 0 and result.failed == 0, result


# ---- shown / expected -------------------------------------------------------------------------

def test_shown_uses_plain_python_forms():
    assert shown(np.int64(3)) == "3" and shown(np.array([1.5, 2.0])) == "[1.5, 2.0]"
    assert shown("8") == "'8'" and shown((1, np.float32(0.5))) == "[1, 0.5]" and shown(None) == "None"


def test_expected_builds_a_one_line_input_error():
    err = expected("data.num_views", 0, "an integer\n>= 1")
    assert isinstance(err, InputError) and isinstance(err, ValueError)
    assert str(err) == "data.num_views=0: expected an integer >= 1"


# ---- check_integer ----------------------------------------------------------------------------

@pytest.mark.parametrize("value, lo, hi, want", [
    (3, 1, None, 3), (3.0, 1, 60, 3), ("7", 0, None, 7), (np.int32(5), 5, 5, 5), (-4, None, None, -4),
    (0, None, 0, 0),
])
def test_check_integer_accepts(value, lo, hi, want):
    got = check_integer(value, "k", lo, hi)
    assert got == want and type(got) is int


@pytest.mark.parametrize("value, lo, hi, message", [
    (0, 1, None, "k=0: expected an integer >= 1"),
    (61, 1, 60, "k=61: expected an integer in [1, 60]"),
    (2.5, 1, None, "k=2.5: expected an integer >= 1"),
    (True, 0, None, "k=True: expected an integer >= 0"),
    ("x", 0, None, "k='x': expected an integer >= 0"),
    (float("nan"), None, None, "k=nan: expected an integer"),
    (None, None, 3, "k=None: expected an integer <= 3"),
])
def test_exception_check_integer(value, lo, hi, message):
    with pytest.raises(InputError) as e:
        check_integer(value, "k", lo, hi)
    assert str(e.value) == message


@pytest.mark.parametrize("value", [3.0, "8", True, np.float64(2.0)])
def test_exception_check_integer_strict_refuses_non_int_objects(value):
    with pytest.raises(InputError, match=r"^resolution=.*: expected a positive integer$"):
        check_integer(value, "resolution", 1, strict=True, what="a positive integer")
    assert check_integer(np.uint8(3), "resolution", 1, strict=True) == 3


# ---- check_number -----------------------------------------------------------------------------

@pytest.mark.parametrize("value, kw, want", [
    (0.5, {}, 0.5), ("1e-3", {"lo": 0, "lo_open": True}, 1e-3), (0, {"lo": 0, "hi": 1, "hi_open": True}, 0.0),
    (np.float32(1.0), {"lo": 0.01, "hi": 1.0}, 1.0), (-3, {"hi": 0}, -3.0),
])
def test_check_number_accepts(value, kw, want):
    got = check_number(value, "x", **kw)
    assert got == want and type(got) is float


@pytest.mark.parametrize("value, kw, message", [
    (float("inf"), {}, "x=inf: expected a finite number"),
    (True, {}, "x=True: expected a finite number"),
    ("abc", {"lo": 0.01, "hi": 1.0}, "x='abc': expected a number in [0.01, 1.0]"),
    (0, {"lo": 0, "lo_open": True}, "x=0: expected a number > 0"),
    (1, {"lo": 0, "hi": 1, "hi_open": True}, "x=1: expected a number in [0, 1)"),
    (0.5, {"hi": 0.1, "hi_open": True}, "x=0.5: expected a number < 0.1"),
    (-1, {"lo": 0, "what": "a finite number of dB >= 0"}, "x=-1: expected a finite number of dB >= 0"),
])
def test_exception_check_number(value, kw, message):
    with pytest.raises(InputError) as e:
        check_number(value, "x", **kw)
    assert str(e.value) == message


# ---- check_numbers ----------------------------------------------------------------------------

def test_check_numbers_accepts_sequences_arrays_and_broadcast():
    assert check_numbers([1, 2.5, "3"], "s", 3) == (1.0, 2.5, 3.0)
    assert check_numbers(np.array([2, 3, 4]), "d", 3, lo=2, integer=True) == (2, 3, 4)
    assert check_numbers(0.5, "s", 3, lo=0, lo_open=True, broadcast=True) == (0.5, 0.5, 0.5)
    assert all(type(v) is int for v in check_numbers((4.0, 5.0), "d", 2, integer=True))


@pytest.mark.parametrize("value, kw, message", [
    ([1, 2], {}, "s=[1, 2]: expected 3 numbers"),
    (2.0, {}, "s=2.0: expected 3 numbers"),
    ("abc", {"broadcast": True}, "s='abc': expected 3 numbers"),
    ([1, 0, 1], {"lo": 0, "lo_open": True}, "s=[1, 0, 1]: expected 3 numbers, each > 0"),
    ([2, 2, 1], {"lo": 2, "integer": True}, "s=[2, 2, 1]: expected 3 integers, each >= 2"),
    ([2, 2.5, 2], {"integer": True}, "s=[2, 2.5, 2]: expected 3 integers"),
    ([1, float("nan"), 1], {}, "s=[1, nan, 1]: expected 3 numbers"),
    ([1, True, 1], {}, "s=[1, True, 1]: expected 3 numbers"),
    ([[1, 2, 3]], {}, "s=[[1, 2, 3]]: expected 3 numbers"),
    ([[1, 2], [3]], {}, "s=[[1, 2], [3]]: expected 3 numbers"),
    ([1, "x", 1], {"what": "three positive numbers (sx, sy, sz)"}, "s=[1, 'x', 1]: expected three positive numbers (sx, sy, sz)"),
])
def test_exception_check_numbers(value, kw, message):
    with pytest.raises(InputError) as e:
        check_numbers(value, "s", 3, **kw)
    assert str(e.value) == message


# ---- check_mapping ----------------------------------------------------------------------------

def test_check_mapping_resolves_omegaconf_and_copies():
    node = OmegaConf.create({"a": 2, "b": "${a}"})
    assert check_mapping(node, "data") == {"a": 2, "b": 2}
    src = {"x": 1}
    out = check_mapping(src, "data")
    assert out == src and out is not src and type(out) is dict


@pytest.mark.parametrize("value, name", [(None, "NoneType"), ([1], "list"), ("a=1", "str")])
def test_exception_check_mapping(value, name):
    with pytest.raises(InputError) as e:
        check_mapping(value, "scene", "a mapping of scene settings")
    assert str(e.value) == f"scene: expected a mapping of scene settings, got {name}"
