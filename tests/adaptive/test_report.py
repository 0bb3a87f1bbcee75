"""imls_lightning.adaptive.report: the reference of each method and the CSV writer (the number formatting is
``imls_lightning.report.writer``'s, tested in ``tests/report/test_writer.py``).
The whole report (adaptive.md, plots) is checked end to end in ``tests/adaptive/test_cli.py``."""
from __future__ import annotations

import csv

from imls_lightning.adaptive.report import reference_method, write_csv


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


def test_write_csv_takes_the_union_of_the_keys_and_six_digits(tmp_path):
    write_csv(tmp_path / "a.csv", [{"view": 0, "u": 1 / 3}, {"view": 1, "gap": 0.5}])
    assert (tmp_path / "a.csv").read_text() == "view,u,gap\n0,0.333333,\n1,,0.5\n"
