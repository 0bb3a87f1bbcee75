"""The evaluation package (``imls_lightning.evaluation``): the examples of every module that has them.

The package's own examples are skipped (they need checkpoints); the other modules run networks, the renderer and the
report on a whole evaluation (``tests/test_evaluate.py``)."""
from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize("module", [".operating_point"])
def test_module_doctests(module):
    result = doctest.testmod(importlib.import_module(f"imls_lightning.evaluation{module}"))
    assert result.attempted > 0 and result.failed == 0, result
