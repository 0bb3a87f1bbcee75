"""imls_lightning.adaptive.report: number formatting, the reference of each method, and the CSV writer.
The whole report (adaptive.md, plots) is checked end to end in ``tests/adaptive/test_cli.py``."""
from __future__ import annotations

import csv

from imls_lightning.adaptive.report import fmt, reference_method, write_csv


def test_fmt():
    assert fmt(1.23456) == "1.235" and fmt(2, ".1f") == "2.0" and fmt(0.5, ".0%") == "50%"
    assert fmt(None) == "–" and fmt(float("nan")) == "–" and fmt(float("inf")) == "–"


def test_reference_method():
    assert reference_method("imls_adaptive", "recnn") == "recnn" and reference_method("recnn", "iml") == "recnn"
    assert reference_method("iml_adaptive", "iml") == "iml_fixed"
    assert reference_method("imls_adaptive", "iml") == "imls_fixed"


def test_write_csv_round_trip(tmp_path):
    rows = [{"view": 0, "u": 0.1}, {"view": 1, "u": 0.25}]
    write_csv(tmp_path / "a.csv", rows)
    with open(tmp_path / "a.csv", newline="") as f:
        back = list(csv.DictReader(f))
    assert [(int(r["view"]), float(r["u"])) for r in back] == [(0, 0.1), (1, 0.25)]
