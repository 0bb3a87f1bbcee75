"""The README's results table, written from ``benchmarks/paper_scale.csv`` between two markers (``make bench-paper``
rewrites it; a test fails when the README disagrees with the CSV).

Each row says where IML/S stands against **the fastest baseline**: the same RecNN on its own pattern with the ray
caster's empty-space skipping on (DESIGN.md). Rows timed on both ray casters in one run give ``speedup_vs_fastest``;
rows timed only with skipping give their speed-up against that (the faster) ray caster; rows timed only without
skipping, whose networks are gone, say so and give no speed-up against the fastest.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

from .metrics_csv import number
from .writer import atomic_write_text, md_table

README_BEGIN = "<!-- results:begin (written from benchmarks/paper_scale.csv by make bench-paper) -->"
README_END = "<!-- results:end -->"
COLUMNS = ["scene", "RecNN", "bilinear / RecNN alone", "share of C", "**vs the fastest RecNN alone**",
           "vs the RecNN alone, no skipping", "gap", "test views"]


def _x(v: float) -> str:
    return f"{v:.2f}x" if math.isfinite(v) else "–"


def _skip_timed(row: Mapping[str, Any]) -> bool:
    """Whether the row's own times were taken with empty-space skipping (``skip_empty``; rows before it: true)."""
    return str(row.get("skip_empty", "true")).strip().lower() not in ("false", "0")


def vs_fastest_value(row: Mapping[str, Any]) -> float:
    """IML/S against the fastest RecNN alone: ``speedup_vs_fastest``, else the speed-up of a row timed with skipping
    only (the faster ray caster), else NaN (a row timed only without skipping)."""
    v = number(row.get("speedup_vs_fastest"))
    if math.isfinite(v):
        return v
    return number(row.get("speedup")) if _skip_timed(row) else math.nan


def noskip_value(row: Mapping[str, Any]) -> float:
    """IML/S against the RecNN alone when both march every sample: from the twins' times, else the speed-up of a row
    timed only without skipping, else NaN."""
    r, i = number(row.get("recnn_noskip_ms")), number(row.get("imls_noskip_ms"))
    if math.isfinite(r) and math.isfinite(i) and i > 0:
        return r / i
    return math.nan if _skip_timed(row) else number(row.get("speedup"))


def vs_fastest_cell(row: Mapping[str, Any]) -> str:
    """IML/S against the fastest RecNN alone.

    Example:
        >>> vs_fastest_cell({"speedup_vs_fastest": "0.91", "speedup_vs_fastest_low": "0.85", "speedup_vs_fastest_high": "0.97"})
        '**0.91x** (0.85-0.97)'
        >>> vs_fastest_cell({"speedup_vs_fastest": "", "skip_empty": "true", "speedup": "0.88"})
        '0.88x (skipping only)'
        >>> vs_fastest_cell({"speedup_vs_fastest": "", "skip_empty": "false", "speedup": "1.73"})
        'not timed: networks lost'
    """
    v = vs_fastest_value(row)
    if math.isfinite(number(row.get("speedup_vs_fastest"))):
        lo, hi = number(row.get("speedup_vs_fastest_low")), number(row.get("speedup_vs_fastest_high"))
        return f"**{v:.2f}x**" + (f" ({lo:.2f}-{hi:.2f})" if math.isfinite(lo) and math.isfinite(hi) else "")
    return f"{_x(v)} (skipping only)" if math.isfinite(v) else "not timed: networks lost"


def noskip_cell(row: Mapping[str, Any]) -> str:
    """IML/S against the RecNN alone when both march every sample (the CUDA ``volumeRender`` sample's ray caster).

    Example:
        >>> noskip_cell({"recnn_noskip_ms": "1900", "imls_noskip_ms": "860"}), noskip_cell({"skip_empty": "true"})
        ('2.21x', '–')
    """
    v = noskip_value(row)
    if math.isfinite(number(row.get("imls_noskip_ms"))) or not math.isfinite(v):
        return _x(v)
    return f"{_x(v)} (old trajectory)"


def is_current(row: Mapping[str, Any]) -> bool:
    """Whether a row was measured on a fresh trajectory against both ray casters (its networks committed, so
    ``make reproduce`` re-measures it): the rows the README cites. The others stay in BENCHMARKS.md's table.

    Example:
        >>> is_current({"trajectory_seed": "1207", "speedup_vs_fastest": "0.84"}), is_current({"trajectory_seed": ""})
        (True, False)
    """
    return bool(str(row.get("trajectory_seed") or "").strip()) and math.isfinite(number(row.get("speedup_vs_fastest")))


def results_table(rows: Sequence[Mapping[str, Any]], current_only: bool = False) -> str:
    """The table of ``paper_scale.csv``'s rows (the newest measurement of each scene and RecNN); ``current_only``: only
    the rows :func:`is_current` keeps (the README's), with one line on how many older rows BENCHMARKS.md keeps."""
    kept = [r for r in rows if is_current(r)] if current_only else list(rows)
    body = []
    for r in kept:
        bil, rec = number(r.get("bilinear_db")), number(r.get("psnr_recnn_db"))
        seed = str(r.get("trajectory_seed") or "").strip()
        body.append([f"`{r['scene']}`", str(r["recnn"]), f"{bil:.1f} / {rec:.1f} dB" if math.isfinite(bil) else f"– / {rec:.1f} dB",
                     f"{number(r.get('c_share')):.1%}", vs_fastest_cell(r), noskip_cell(r), f"{number(r.get('gap_db')):.2f} dB",
                     f"fresh, seed {seed}" if seed else "seed 0 (read while designing)"])
    table = md_table(COLUMNS, body)
    if current_only and len(kept) < len(rows):
        old_rows = [f"`{r['scene']}` {r['recnn']}" for r in rows if not is_current(r)]
        table += (f"\n\n{len(rows) - len(kept)} older rows ({', '.join(old_rows)}) were measured on the test trajectory their "
                  "design read, most without the fastest baseline beside them, and their networks were not kept: they are "
                  "left out here, and BENCHMARKS.md keeps them as history.")
    return table


def update_between(path: Path, begin: str, end: str, text: str) -> Path:
    """Put ``text`` between the markers ``begin`` and ``end`` of ``path`` (appended with them when they are missing;
    the rest of the file is kept), atomically."""
    old = path.read_text(encoding="utf-8") if path.is_file() else ""
    block = f"{begin}\n{text.rstrip()}\n{end}"
    if begin in old and end in old:
        head, rest = old.split(begin, 1)
        new = head + block + rest.split(end, 1)[1]
    else:
        new = old.rstrip() + ("\n\n" if old else "") + block + "\n"
    return atomic_write_text(path, new)


def between(text: str, begin: str = README_BEGIN, end: str = README_END) -> str | None:
    """What lies between the markers in ``text`` (None without them)."""
    if begin not in text or end not in text:
        return None
    return text.split(begin, 1)[1].split(end, 1)[0].strip()


def plot_results(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """``paper_scale_results.png``: per row, IML/S against the fastest RecNN alone (or, timed on the skipping ray caster
    alone, against that) and against the RecNN alone without skipping; the 1x line is where it stops paying."""
    import numpy as np

    from .plots import new_figure, save_figure

    labels = [f"{r['scene']}\n{r['recnn']}" for r in rows]
    fastest = [vs_fastest_value(r) for r in rows]
    noskip = [noskip_value(r) for r in rows]
    fig = new_figure(max(7.0, 0.9 * len(rows)), 4.0)
    ax = fig.add_subplot(111)
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [0 if not math.isfinite(v) else v for v in fastest], 0.4, color="#d62728",
           label="vs the fastest RecNN alone (empty-space skipping)")
    ax.bar(x + 0.2, [0 if not math.isfinite(v) else v for v in noskip], 0.4, color="#aaaaaa",
           label="vs the RecNN alone, both marching every sample")
    for i, v in enumerate(fastest):
        if not math.isfinite(v):
            ax.text(x[i] - 0.2, 0.05, "lost", rotation=90, ha="center", va="bottom", fontsize=7)
    ax.axhline(1.0, color="black", lw=0.8)
    ax.set_xticks(x, labels, fontsize=7, rotation=30, ha="right")
    ax.set_ylabel("IML/S + RecNN speed-up")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Where IML/S pays, and against which ray caster (benchmarks/paper_scale.csv)", fontsize=9)
    return save_figure(fig, path)
