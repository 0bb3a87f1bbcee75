"""The evaluation report package (``imls_lightning.report``): its modules' examples and the seams
between them. The report end to end is checked in ``tests/test_evaluate.py``."""
from __future__ import annotations

import doctest
import importlib

import pytest


# .names holds constants only; .document's report needs a whole evaluation (tests/test_evaluate.py)
@pytest.mark.parametrize("module", ["", ".writer", ".metrics_csv", ".machine", ".tables", ".plots", ".speedup"])
def test_module_doctests(module):
    result = doctest.testmod(importlib.import_module(f"imls_lightning.report{module}"))
    assert result.attempted > 0 and result.failed == 0, result
