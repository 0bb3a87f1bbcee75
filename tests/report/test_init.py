"""The evaluation report package (``imls_lightning.report``): its modules' examples and the seams
between them. The report end to end is checked in ``tests/test_evaluate.py``."""
from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize("module", ["", ".names", ".metrics_csv", ".machine", ".tables", ".plots", ".document"])
def test_module_doctests(module):
    mod = importlib.import_module(f"imls_lightning.report{module}")
    assert doctest.testmod(mod).failed == 0
