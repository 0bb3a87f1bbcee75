"""imls_lightning.report.plots: the plots are written as PNGs."""
from __future__ import annotations

from imls_lightning import report as rep


def test_plots_write_pngs(tmp_path):
    summ = {"recnn": {"label": "RecNN alone", "latency_ms": {"recnn": 1.0, "total": 1.0}}}
    assert rep.plot_stage_breakdown(summ, ["recnn"], tmp_path / "a.png").stat().st_size > 0
    rows = [{"view": 0, "method": "recnn", "psnr": 30.0}, {"view": 1, "method": "recnn", "psnr": 31.0}]
    assert rep.plot_psnr_per_view(rows, ["recnn"], tmp_path / "b.png").stat().st_size > 0
