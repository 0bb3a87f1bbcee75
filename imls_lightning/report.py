"""Evaluation report: the metrics CSV, its per-method summary, paper-style Markdown tables and plots.

:mod:`imls_lightning.evaluate` measures; this module only formats. Every file is written atomically
(temporary name + rename), so an interrupted run never leaves a half-written CSV, PNG or report.

Plots use matplotlib's object-oriented API on the Agg canvas (no pyplot global state, no display).

Example:
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> rows = [{"view": 0, "row": 40, "method": "recnn", "total_ms": 2.0, "recnn_ms": 1.0,
    ...          "selective_render_ms": 1.0, "ipr": 0.25, "psnr": 30.0, "ssim": 0.9}]
    >>> p = write_metrics_csv(rows, d / "metrics.csv")
    >>> summary(p)["recnn"]["latency_ms"]["total"]
    2.0
"""
from __future__ import annotations

import csv
import math
import os
import platform
import sys
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .pipeline import STAGES

#: method key -> label in tables and plots (the paper's names)
METHOD_LABELS = {
    "full": "Full ray cast",
    "recnn": "RecNN alone",
    "las": "LAS",
    "iml": "IML + RecNN",
    "imls": "IML/S + RecNN",
    "iml_selective": "IML IM, selectively rendered",
}
METHOD_ORDER = ("full", "recnn", "las", "iml", "imls")
STAGE_LABELS = {
    "low_res_render": "low-res render",
    "render": "render",
    "importance": "importance",
    "selective_render": "selective render",
    "decoder": "decoder",
    "recnn": "RecNN",
}
# colours of the paper's time-breakdown figure: rendering blue/green, importance orange, RecNN red
STAGE_COLORS = {
    "low_res_render": "#1f77b4",
    "render": "#6baed6",
    "importance": "#ff7f0e",
    "selective_render": "#2ca02c",
    "decoder": "#9467bd",
    "recnn": "#d62728",
}
METHOD_COLORS = {"full": "#555555", "recnn": "#1f77b4", "las": "#2ca02c", "iml": "#ff7f0e",
                 "imls": "#d62728", "iml_selective": "#9467bd"}

#: columns of metrics.csv, in order
METRIC_COLUMNS = (
    ["view", "row", "method"]
    + [f"{s}_ms" for s in STAGES]
    + ["total_ms", "ipr", "c_share", "rendered_pixels", "psnr", "ssim"]
)
SWEEP_COLUMNS = ["view", "row", "method", "setting", "value"] + METRIC_COLUMNS[3:]


# ------------------------------------------------------------------------------------------------
# atomic files


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and a rename (never half-written)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8", newline="") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(p)
    return p


def _csv_text(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> str:
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _fmt_cell(r.get(k)) for k in columns})
    return buf.getvalue()


def _fmt_cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(round(v, 6))
    return v


def write_metrics_csv(rows: Sequence[Mapping[str, Any]], path: str | Path, columns: Sequence[str] = METRIC_COLUMNS) -> Path:
    """One row per (view, method); missing stages are empty cells. Atomic."""
    return atomic_write_text(path, _csv_text(rows, columns))


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a CSV written here; numeric cells as float (empty -> NaN), text cells as str."""
    p = Path(path)
    if not p.is_file():
        from data_gen.errors import InputError

        raise InputError(f"metrics_csv={path}: file not found")
    out = []
    with open(p, newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            row: dict[str, Any] = {}
            for k, v in r.items():
                if k in ("method", "setting"):
                    row[k] = v
                    continue
                try:
                    row[k] = float(v) if v != "" else math.nan
                except ValueError:
                    row[k] = v
            out.append(row)
    return out


# ------------------------------------------------------------------------------------------------
# summary


def _nanmean(values: Iterable[float]) -> float:
    a = np.asarray([v for v in values], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else math.nan


def summarize_rows(rows: Sequence[Mapping[str, Any]], key: str = "method") -> dict[str, dict[str, Any]]:
    """Per-method (or per ``key``) averages of metric rows; see :func:`summary`."""
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(str(r[key]), []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for name, rs in groups.items():
        lat = {}
        for s in list(STAGES) + ["total"]:
            v = _nanmean(_num(r.get(f"{s}_ms")) for r in rs)
            if math.isfinite(v):
                lat[s] = v
        out[name] = {
            "label": METHOD_LABELS.get(name, name),
            "views": len(rs),
            "latency_ms": lat,
            **{k: _nanmean(_num(r.get(k)) for r in rs) for k in ("psnr", "ssim", "ipr", "c_share", "rendered_pixels")},
        }
    return out


def _num(v: Any) -> float:
    try:
        return float(v) if v not in (None, "") else math.nan
    except (TypeError, ValueError):
        return math.nan


def summary(metrics_csv: str | Path) -> dict[str, dict[str, Any]]:
    """Per-method averages over the views of an evaluation's ``metrics.csv``.

    Returns:
        ``{method: {"label", "views", "latency_ms": {stage: mean ms, ..., "total": mean ms},
        "psnr", "ssim", "ipr", "c_share", "rendered_pixels"}}`` in the CSV's method order; stages
        a method does not have are absent, metrics it does not have are NaN.

    Example:
        >>> s = summary("runs/eval/tiny-enhancenet-1a2b3c4d/metrics.csv")   # doctest: +SKIP
        >>> s["imls"]["latency_ms"]["total"], s["imls"]["psnr"]             # doctest: +SKIP
        (1.21, 27.3)
    """
    return summarize_rows(read_csv(metrics_csv))


# ------------------------------------------------------------------------------------------------
# machine


def machine_info(device: str = "cpu") -> dict[str, str]:
    """CPU model, cores, library versions and the device the networks ran on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {"cpu": cpu, "cores": str(os.cpu_count()), "python": platform.python_version(),
            "platform": platform.platform()}
    try:
        import torch

        info["torch"] = torch.__version__
        info["torch threads"] = str(torch.get_num_threads())
        if str(device).startswith("cuda") and torch.cuda.is_available():
            info["device"] = f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
        else:
            info["device"] = str(device)
    except Exception:  # informative only
        info["device"] = str(device)
    for mod, attr in (("numba", "__version__"), ("vtk", None)):
        try:
            m = __import__(mod)
            info[mod] = m.vtkVersion.GetVTKVersion() if mod == "vtk" else getattr(m, attr)
        except Exception:
            info[mod] = "not installed"
    return info


# ------------------------------------------------------------------------------------------------
# Markdown


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]], align: str | None = None) -> str:
    """A GitHub Markdown table; ``align`` one of ``l``/``r`` per column (default: first left, rest right)."""
    align = align or ("l" + "r" * (len(header) - 1))
    sep = ["---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(str(h) for h in header) + " |", "| " + " | ".join(sep) + " |"]
    for r in rows:
        lines.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(lines)


def fmt(v: Any, digits: int = 2, suffix: str = "") -> str:
    """Number for a table cell; NaN/None -> an en dash."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "–"
    if not math.isfinite(x):
        return "–"
    return f"{x:.{digits}f}{suffix}"


def fmt_pct(v: Any, digits: int = 1) -> str:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if not math.isfinite(x) else f"{100 * x:.{digits}f}%"


def speedup(slow_ms: float, fast_ms: float) -> str:
    """``slow / fast`` as ``2.07×`` (the paper's speed-up)."""
    if not (math.isfinite(slow_ms) and math.isfinite(fast_ms)) or fast_ms <= 0:
        return "–"
    return f"{slow_ms / fast_ms:.2f}×"


def latency_table(summ: Mapping[str, Mapping[str, Any]], methods: Sequence[str], reference: str | None = "recnn") -> str:
    """Average latency per method and stage (ms) with IPR, speed-up over ``reference``, PSNR, SSIM."""
    stages = [s for s in STAGES if any(s in summ[m]["latency_ms"] for m in methods)]
    header = ["Method", "IPR", "C-Image share"] + [f"{STAGE_LABELS[s]} (ms)" for s in stages] + ["total (ms)"]
    if reference in summ:
        header.append(f"speed-up vs {METHOD_LABELS.get(reference, reference)}")
    header += ["PSNR (dB)", "SSIM"]
    rows = []
    for m in methods:
        s = summ[m]
        lat = s["latency_ms"]
        r = [s["label"], fmt_pct(s["ipr"]), fmt_pct(s["c_share"])]
        r += [fmt(lat.get(st), 2) for st in stages] + [f"**{fmt(lat.get('total'), 2)}**"]
        if reference in summ:
            r.append(speedup(summ[reference]["latency_ms"].get("total", math.nan), lat.get("total", math.nan)))
        r += [fmt(s["psnr"], 2), fmt(s["ssim"], 4)]
        rows.append(r)
    return md_table(header, rows)


# ------------------------------------------------------------------------------------------------
# plots (Agg canvas, atomic PNGs)


def _figure(w: float = 7.0, h: float = 4.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | Path) -> Path:
    """Save a figure as PNG atomically."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    fig.savefig(tmp, format="png", bbox_inches="tight")
    tmp.replace(p)
    return p


def plot_stage_breakdown(summ: Mapping[str, Mapping[str, Any]], methods: Sequence[str], path: str | Path) -> Path:
    """Stacked bars: average time of each stage per method (the paper's time-breakdown figure)."""
    fig = _figure(max(5.0, 1.3 * len(methods) + 2), 4.2)
    ax = fig.add_subplot(111)
    x = np.arange(len(methods))
    bottom = np.zeros(len(methods))
    for st in STAGES:
        vals = np.array([summ[m]["latency_ms"].get(st, 0.0) for m in methods])
        if not vals.any():
            continue
        ax.bar(x, vals, 0.6, bottom=bottom, label=STAGE_LABELS[st], color=STAGE_COLORS[st])
        bottom += vals
    for xi, tot in zip(x, bottom):
        ax.text(xi, tot, f"{tot:.1f}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x)
    ax.set_xticklabels([summ[m]["label"] for m in methods], rotation=15, ha="right", fontsize=8)
    ax.set_ylabel("average latency (ms)")
    ax.set_title("Time breakdown per method (median of repeats, mean over views)")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.grid(axis="y", alpha=0.3)
    return save_figure(fig, path)


def plot_psnr_per_view(rows: Sequence[Mapping[str, Any]], methods: Sequence[str], path: str | Path) -> Path:
    """PSNR of every view along the trajectory, one line per method (the full ray cast is exact)."""
    fig = _figure(8.0, 4.0)
    ax = fig.add_subplot(111)
    for m in methods:
        rs = sorted((r for r in rows if r["method"] == m), key=lambda r: _num(r["view"]))
        if not rs:
            continue
        xs = [_num(r["view"]) for r in rs]
        ys = [_num(r["psnr"]) for r in rs]
        ax.plot(xs, ys, marker="o", ms=3, lw=1.2, label=METHOD_LABELS.get(m, m), color=METHOD_COLORS.get(m))
    ax.set_xlabel("view (position on the trajectory)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title("PSNR per view (full ray cast = ground truth, not shown)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_latency_vs_psnr(curves: Mapping[str, Sequence[tuple[float, float, str]]],
                         points: Mapping[str, tuple[float, float]], full_ms: float | None, path: str | Path) -> Path:
    """Latency (x) vs PSNR (y): ``curves`` label -> [(ms, psnr, annotation)], ``points`` label -> (ms, psnr),
    the full ray cast as a vertical line (exact image, PSNR unbounded)."""
    fig = _figure(7.5, 4.8)
    ax = fig.add_subplot(111)
    markers = iter(["o", "s", "^", "D", "v"])
    for label, pts in curves.items():
        pts = [p for p in pts if math.isfinite(p[0]) and math.isfinite(p[1])]
        if not pts:
            continue
        key = next((k for k, v in METHOD_LABELS.items() if label.startswith(v)), None)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=next(markers, "o"), lw=1.2, label=label,
                color=METHOD_COLORS.get(key))
        for x, y, note in pts:
            ax.annotate(note, (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    for label, (x, y) in points.items():
        if math.isfinite(x) and math.isfinite(y):
            key = next((k for k, v in METHOD_LABELS.items() if label.startswith(v)), None)
            ax.scatter([x], [y], s=90, marker="*" if key == "imls" else "X", zorder=5, label=label,
                       color=METHOD_COLORS.get(key))
    if full_ms is not None and math.isfinite(full_ms):
        ax.axvline(full_ms, color=METHOD_COLORS["full"], ls="--", lw=1, label=f"{METHOD_LABELS['full']} (exact)")
    ax.set_xlabel("average latency (ms)")
    ax.set_ylabel("average PSNR (dB)")
    ax.set_title("Speed / accuracy trade-off")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    return save_figure(fig, path)


def plot_options(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Bars of the IML/S network stages' time under each inference option."""
    fig = _figure(6.0, 3.6)
    ax = fig.add_subplot(111)
    names = [r["option"] for r in rows]
    x = np.arange(len(rows))
    bottom = np.zeros(len(rows))
    for st in ("importance", "decoder", "recnn"):
        vals = np.array([_num(r.get(f"{st}_ms")) for r in rows])
        vals = np.nan_to_num(vals)
        ax.bar(x, vals, 0.6, bottom=bottom, label=STAGE_LABELS[st], color=STAGE_COLORS[st])
        bottom += vals
    ax.set_xticks(x)
    ax.set_xticklabels(names, fontsize=8)
    ax.set_ylabel("ms (median, mean over views)")
    ax.set_title("IML/S network stages per inference option")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


__all__ = [
    "METHOD_LABELS", "METHOD_ORDER", "METRIC_COLUMNS", "SWEEP_COLUMNS", "STAGE_LABELS", "atomic_write_text",
    "write_metrics_csv", "read_csv", "summarize_rows", "summary", "machine_info", "md_table", "fmt", "fmt_pct",
    "speedup", "latency_table", "plot_stage_breakdown", "plot_psnr_per_view", "plot_latency_vs_psnr",
    "plot_options", "save_figure",
]
