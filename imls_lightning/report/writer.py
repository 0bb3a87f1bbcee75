"""The one report writer: the Markdown table, the number in a cell, and the Markdown, CSV and YAML files.

Every report of the tools (the evaluation's ``report.md``, ``adaptive.md``, the ORP's ``orp.yaml``, the
benchmarks' tables, the estimate's and the size search's files) formats its tables with :func:`md_table` and
:func:`fmt` and writes its files through :func:`write_markdown`, :func:`write_csv`, :func:`write_yaml` or
:func:`write_config`, all atomic (:func:`imls_lightning.base.atomic.atomic_write_text`, the lowest home of a
file write): a reader never sees half a report.

Example:
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> lines = ["# Result", "", md_table(["method", "PSNR (dB)"], [["RecNN", fmt(31.234)], ["IML/S", fmt(None)]])]
    >>> print(write_markdown(d / "r.md", lines).read_text(), end="")
    # Result
    <BLANKLINE>
    | method | PSNR (dB) |
    | --- | ---: |
    | RecNN | 31.23 |
    | IML/S | – |
    >>> print(write_csv(d / "r.csv", [{"view": 0, "u": 0.1}, {"view": 1, "gap": 0.5}]).read_text(), end="")
    view,u,gap
    0,0.1,
    1,,0.5
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from imls_lightning.base.atomic import atomic_write_text

__all__ = ["md_table", "fmt", "fmt_pct", "csv_text", "write_csv", "markdown_text", "write_markdown", "write_yaml",
           "write_config", "atomic_write_text"]

#: what a cell shows for a missing or non-finite number
MISSING = "–"


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]], align: str | None = None,
             tight_rule: bool = False) -> str:
    """A GitHub Markdown table; ``align`` one of ``l``/``r`` per column (default: first left, rest right).

    ``tight_rule``: the rule under the header as ``|---|---|`` (every column left, no spaces), the form
    ``adaptive.md`` has always had. A ``|`` inside a cell is escaped.

    Example:
        >>> print(md_table(["method", "ms"], [["RecNN", fmt(1.5)], ["a|b", fmt(None)]]))
        | method | ms |
        | --- | ---: |
        | RecNN | 1.50 |
        | a\\|b | – |
        >>> print(md_table(["method", "ms"], [["RecNN", "1.5"]], tight_rule=True))
        | method | ms |
        |---|---|
        | RecNN | 1.5 |
    """
    if tight_rule:
        rule = "|" + "---|" * len(header)
    else:
        align = align or ("l" + "r" * (len(header) - 1))
        rule = "| " + " | ".join("---" if a == "l" else "---:" for a in align) + " |"
    lines = ["| " + " | ".join(str(h) for h in header) + " |", rule]
    for r in rows:
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in r) + " |")
    return "\n".join(lines)


def fmt(v: Any, digits: int = 2, suffix: str = "", spec: str | None = None) -> str:
    """A number for a table cell: ``digits`` decimals (or the format ``spec``, e.g. ``"+.2f"``, ``".0%"``,
    applied to ``v`` itself, so that an int keeps ``"d"``), then ``suffix``; None, NaN, infinity and anything
    that is not a number -> an en dash.

    Example:
        >>> fmt(1.234), fmt(0.5, 1, " dB"), fmt(0.123, spec="+.2f"), fmt(3, spec="d"), fmt(float("nan")), fmt("x")
        ('1.23', '0.5 dB', '+0.12', '3', '–', '–')
    """
    try:
        x = float(v)
    except (TypeError, ValueError):
        return MISSING
    if not math.isfinite(x):
        return MISSING
    return (format(v, spec) if spec is not None else f"{x:.{digits}f}") + suffix


def fmt_pct(v: Any, digits: int = 1) -> str:
    """A share as a percentage for a table cell; a missing or non-finite value -> an en dash.

    Example:
        >>> fmt_pct(0.1234), fmt_pct(None)
        ('12.3%', '–')
    """
    try:
        x = float(v)
    except (TypeError, ValueError):
        return MISSING
    return MISSING if not math.isfinite(x) else f"{100 * x:.{digits}f}%"


def csv_text(rows: Iterable[Mapping[str, Any]], columns: Sequence[str] | None = None,
             cell: Callable[[Any], Any] = lambda v: v) -> str:
    """``rows`` as CSV text: a header, then each row's ``cell(value)`` per column (a missing key is None, an empty
    cell); keys outside ``columns`` are left out. ``columns`` default: the union of the rows' keys in first-seen
    order (``["view"]`` for no rows)."""
    rows = list(rows)
    if columns is None:
        columns = list(dict.fromkeys(k for r in rows for k in r)) or ["view"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([cell(r.get(c)) for c in columns])
    return buf.getvalue()


def write_csv(path: str | Path, rows: Iterable[Mapping[str, Any]], columns: Sequence[str] | None = None,
              cell: Callable[[Any], Any] = lambda v: v) -> Path:
    """:func:`csv_text` written atomically at ``path``; returns ``path``."""
    return atomic_write_text(path, csv_text(rows, columns, cell))


def markdown_text(lines: Iterable[str]) -> str:
    """A Markdown document from its lines (a line may hold several, e.g. a :func:`md_table`): joined by newlines,
    with one newline at the end."""
    return "\n".join(lines) + "\n"


def write_markdown(path: str | Path, lines: Iterable[str] | str, unique: bool = False) -> Path:
    """A Markdown report written atomically at ``path``: ``lines`` through :func:`markdown_text`, or a finished text
    as it is. ``unique``: see :func:`~imls_lightning.base.atomic.atomic_write`. Returns ``path``."""
    return atomic_write_text(path, lines if isinstance(lines, str) else markdown_text(lines), unique=unique)


def write_yaml(path: str | Path, data: Mapping[str, Any], unique: bool = False) -> Path:
    """Plain ``data`` as YAML (keys in their order, short lists inline), written atomically; returns ``path``."""
    import yaml

    return atomic_write_text(path, yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120),
                             unique=unique)


def write_config(path: str | Path, config: Any, header: str = "") -> Path:
    """A run's settings (a mapping or an OmegaConf node) as OmegaConf's YAML after ``header`` (comment lines),
    written atomically; returns ``path``."""
    from omegaconf import OmegaConf

    return atomic_write_text(path, header + OmegaConf.to_yaml(OmegaConf.create(config)))
