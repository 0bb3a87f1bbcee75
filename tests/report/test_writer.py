"""imls_lightning.report.writer: the one Markdown table, number formatter and atomic Markdown / CSV / YAML writer."""
from __future__ import annotations

import csv

import yaml

from imls_lightning.report import (csv_text, fmt, fmt_pct, markdown_text, md_table, write_config, write_csv, write_markdown,
                                   write_yaml)


def test_fmt_digits_spec_and_missing():
    assert fmt(1.23456) == "1.23" and fmt(1.23456, 3) == "1.235" and fmt(0.5, 1, " dB") == "0.5 dB"
    assert fmt(2, spec=".1f") == "2.0" and fmt(0.5, spec=".0%") == "50%" and fmt(3, spec="d") == "3"
    assert fmt(0.123, spec="+.2f") == "+0.12" and fmt("1.5") == "1.50"
    for missing in (None, float("nan"), float("inf"), "x"):
        assert fmt(missing) == "–" and fmt(missing, spec=".1f") == "–" and fmt_pct(missing) == "–"
    assert fmt_pct(0.1234) == "12.3%" and fmt_pct(0.5, 0) == "50%"


def test_md_table_aligns_escapes_and_tight_rule():
    assert md_table(["a", "b", "c"], [[1, "x|y", None]], "lrl").splitlines() == [
        "| a | b | c |", "| --- | ---: | --- |", "| 1 | x\\|y | None |"]
    assert md_table(["a", "b"], [["1", "2"]], tight_rule=True).splitlines() == ["| a | b |", "|---|---|", "| 1 | 2 |"]
    assert md_table(["a", "b"], []).splitlines()[1] == "| --- | ---: |"


def test_csv_text_columns_cells_and_quoting():
    rows = [{"a": 1.5, "b": None, "c": "x,y"}, {"a": 2.0, "d": "ignored"}]
    assert csv_text(rows, ["a", "b", "c"]) == 'a,b,c\n1.5,,"x,y"\n2.0,,\n'
    assert csv_text(rows, ["a"], cell=lambda v: f"{v:.3g}") == "a\n1.5\n2\n"
    assert csv_text(rows) == 'a,b,c,d\n1.5,,"x,y",\n2.0,,,ignored\n' and csv_text([]) == "view\n"


def test_files_are_written_whole_and_read_back(tmp_path):
    assert markdown_text(["# t", "", "x"]) == "# t\n\nx\n"
    p = write_markdown(tmp_path / "r.md", ["# t", md_table(["a"], [[1]])])
    assert p.read_text() == "# t\n| a |\n| --- |\n| 1 |\n"
    assert write_markdown(tmp_path / "s.md", "as it is").read_text() == "as it is"
    rows = [{"view": 0, "u": 0.1}]
    with open(write_csv(tmp_path / "a.csv", rows), newline="") as f:
        assert list(csv.DictReader(f)) == [{"view": "0", "u": "0.1"}]
    data = {"orp": {"c_share": 0.3, "bracket": [0.05, 1.0]}, "jobs": [{"job": 0}], "found": None}
    text = write_yaml(tmp_path / "orp.yaml", data, unique=True).read_text()
    assert yaml.safe_load(text) == data and text.index("orp") < text.index("jobs") and "[0.05, 1.0]" in text
    cfg = write_config(tmp_path / "config.yaml", {"b": 1, "a": {"c": [1, 2]}}, header="# a header\n").read_text()
    assert cfg.startswith("# a header\nb: 1\n") and yaml.safe_load(cfg) == {"b": 1, "a": {"c": [1, 2]}}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "config.yaml", "orp.yaml", "r.md", "s.md"]  # no temporaries
