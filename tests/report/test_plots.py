"""imls_lightning.report.plots: the plots are written as PNGs."""
from __future__ import annotations

from imls_lightning import report as rep


def test_plots_write_pngs(tmp_path):
    summ = {"recnn": {"label": "RecNN alone", "latency_ms": {"recnn": 1.0, "total": 1.0}}}
    assert rep.plot_stage_breakdown(summ, ["recnn"], tmp_path / "a.png").stat().st_size > 0
    rows = [{"view": 0, "method": "recnn", "psnr": 30.0}, {"view": 1, "method": "recnn", "psnr": 31.0}]
    assert rep.plot_psnr_per_view(rows, ["recnn"], tmp_path / "b.png").stat().st_size > 0


def test_plot_front_writes_a_png_with_an_exact_point_and_a_front(tmp_path):
    pts = [{"method": "full", "label": "Full ray cast", "note": "every pixel", "latency_ms": 10.0, "psnr": 100.0, "on_front": True},
           {"method": "recnn", "label": "RecNN alone", "note": "its pattern", "latency_ms": 5.0, "psnr": 40.0, "on_front": True},
           {"method": "imls", "label": "IML/S + RecNN", "note": "10% of C", "latency_ms": 2.0, "psnr": 36.0, "on_front": True},
           {"method": "las", "label": "LAS", "note": "IPR=0.1", "latency_ms": 6.0, "psnr": float("nan"), "on_front": False}]
    path = rep.plot_front(pts, tmp_path / "front.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*tmp"))  # written atomically
