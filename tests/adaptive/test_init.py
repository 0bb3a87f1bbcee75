"""The adaptive package (``imls_lightning.adaptive``): the examples of every module that has them.

``.renderer`` has none: its renderers need trained networks (``tests/adaptive/test_renderer.py``)."""
from __future__ import annotations

import pytest


@pytest.mark.parametrize("module", ["", ".checks", ".labels", ".predictor", ".tradeoff", ".settings",
                                    ".report", ".cli"])
def test_module_doctests(module):
    import doctest
    import importlib

    result = doctest.testmod(importlib.import_module(f"imls_lightning.adaptive{module}"))
    assert result.attempted > 0 and result.failed == 0, result
