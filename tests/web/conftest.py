"""Browser tests: Selenium Manager sends no usage statistics to an outside host."""
from __future__ import annotations

import pytest


@pytest.fixture(autouse=True, scope="session")
def _selenium_sends_no_statistics():
    """``SE_AVOID_STATS=true`` before any Selenium call (Selenium Manager reads it from the
    environment it inherits), for every test here."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SE_AVOID_STATS", "true")
        yield
