"""The adaptive package (``imls_lightning.adaptive``): the examples of every module."""
from __future__ import annotations

import pytest


@pytest.mark.parametrize("module", ["", ".checks", ".labels", ".predictor", ".renderer", ".tradeoff", ".settings",
                                    ".report", ".cli"])
def test_module_doctests(module):
    import doctest
    import importlib

    mod = importlib.import_module(f"imls_lightning.adaptive{module}")
    assert doctest.testmod(mod).failed == 0
