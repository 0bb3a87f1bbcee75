"""The ORP package (``imls_lightning.orp``): the examples of every module."""
from __future__ import annotations

import doctest

import pytest


@pytest.mark.parametrize("module", ["", ".search", ".overrides", ".job", ".report"])
def test_module_doctests(module):
    import importlib

    mod = importlib.import_module(f"imls_lightning.orp{module}")
    assert doctest.testmod(mod).failed == 0
