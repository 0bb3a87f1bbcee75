"""The estimate package (``imls_lightning.estimate``): the examples of every module that has them (``.run``'s:
its one-line warning; its work, which renders and times a scene, is tested through the CLI in ``test_measure.py``)."""
from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize("module", ["", ".bound", ".measure", ".needed_share", ".run"])
def test_module_doctests(module):
    result = doctest.testmod(importlib.import_module(f"imls_lightning.estimate{module}"))
    assert result.attempted > 0 and result.failed == 0, result
