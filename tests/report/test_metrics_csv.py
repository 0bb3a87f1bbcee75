"""imls_lightning.report.metrics_csv (number) and report.tables (sweep_label) labels."""
from __future__ import annotations

import math

from imls_lightning import report as rep


def test_number_and_sweep_label():
    assert rep.number("2.5") == 2.5 and math.isnan(rep.number("")) and math.isnan(rep.number(None))
    assert math.isnan(rep.number("x"))
    assert rep.sweep_label("iml", "mean", 0.1) == "u=0.1" and rep.sweep_label("las", "ipr", 0.05) == "IPR=0.05"
