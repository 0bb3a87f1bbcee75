"""The ORP package (``imls_lightning.orp``): the examples of every module that has them.

``.job`` has none: its work trains and evaluates networks (``tests/orp/test_job.py``)."""
from __future__ import annotations

import doctest

import pytest


@pytest.mark.parametrize("module", ["", ".search", ".overrides", ".report"])
def test_module_doctests(module):
    import importlib

    result = doctest.testmod(importlib.import_module(f"imls_lightning.orp{module}"))
    assert result.attempted > 0 and result.failed == 0, result
