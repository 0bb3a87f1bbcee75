"""imls_lightning.report.tables: the paper-style tables, from a summary of a real metrics CSV."""
from __future__ import annotations

from imls_lightning import report as rep


def test_summary_round_trip_and_tables(tmp_path):
    rows = [{"view": v, "row": v, "method": m, "total_ms": t, "recnn_ms": 1.0, "ipr": 0.25, "c_share": 0.5,
             "psnr": p, "ssim": 0.9} for v in (0, 1) for m, t, p in (("recnn", 4.0, 30.0), ("imls", 2.0, 29.0))]
    summ = rep.summary(rep.write_metrics_csv(rows, tmp_path / "metrics.csv"))
    assert list(summ) == ["recnn", "imls"] and summ["imls"]["latency_ms"]["total"] == 2.0
    assert summ["imls"]["label"] == rep.METHOD_LABELS["imls"] and summ["recnn"]["views"] == 2
    text = rep.speedup_table(summ, over=("recnn",))
    assert "**2.00×**" in text and "-1.00 dB" in text
    assert rep.latency_table(summ, ["recnn", "imls"]).count("\n") == 3  # header, rule, two rows
