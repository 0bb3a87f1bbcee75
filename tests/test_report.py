"""The evaluation report package (``imls_lightning.report``): its modules' examples and the seams
between them. The report end to end is checked in ``tests/test_evaluate.py``."""
from __future__ import annotations

import doctest
import importlib
import math

import pytest

from imls_lightning import report as rep


@pytest.mark.parametrize("module", ["", ".names", ".metrics_csv", ".machine", ".tables", ".plots", ".document"])
def test_module_doctests(module):
    mod = importlib.import_module(f"imls_lightning.report{module}")
    assert doctest.testmod(mod).failed == 0


def test_number_and_sweep_label():
    assert rep.number("2.5") == 2.5 and math.isnan(rep.number("")) and math.isnan(rep.number(None))
    assert math.isnan(rep.number("x"))
    assert rep.sweep_label("iml", "mean", 0.1) == "u=0.1" and rep.sweep_label("las", "ipr", 0.05) == "IPR=0.05"


def test_summary_round_trip_and_tables(tmp_path):
    rows = [{"view": v, "row": v, "method": m, "total_ms": t, "recnn_ms": 1.0, "ipr": 0.25, "c_share": 0.5,
             "psnr": p, "ssim": 0.9} for v in (0, 1) for m, t, p in (("recnn", 4.0, 30.0), ("imls", 2.0, 29.0))]
    summ = rep.summary(rep.write_metrics_csv(rows, tmp_path / "metrics.csv"))
    assert list(summ) == ["recnn", "imls"] and summ["imls"]["latency_ms"]["total"] == 2.0
    assert summ["imls"]["label"] == rep.METHOD_LABELS["imls"] and summ["recnn"]["views"] == 2
    text = rep.speedup_table(summ, over=("recnn",))
    assert "**2.00×**" in text and "-1.00 dB" in text
    assert rep.latency_table(summ, ["recnn", "imls"]).count("\n") == 3  # header, rule, two rows


def test_plots_write_pngs(tmp_path):
    summ = {"recnn": {"label": "RecNN alone", "latency_ms": {"recnn": 1.0, "total": 1.0}}}
    assert rep.plot_stage_breakdown(summ, ["recnn"], tmp_path / "a.png").stat().st_size > 0
    rows = [{"view": 0, "method": "recnn", "psnr": 30.0}, {"view": 1, "method": "recnn", "psnr": 31.0}]
    assert rep.plot_psnr_per_view(rows, ["recnn"], tmp_path / "b.png").stat().st_size > 0
