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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from .metrics import psnr_from_mse
from .pipeline import STAGES

#: method key -> label in tables and plots (the paper's names)
METHOD_LABELS = {
    "full": "Full ray cast",
    "recnn": "RecNN alone",
    "las": "LAS",
    "iml": "IML + RecNN",
    "imls": "IML/S + RecNN",
    "imls_fill": "IML/S mask + fill + RecNN",
    "blue_noise": "blue noise + decoder + RecNN",
    "iml_selective": "IML IM, selectively rendered",
}
METHOD_ORDER = ("full", "recnn", "las", "iml", "imls", "imls_fill", "blue_noise")
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
                 "imls": "#d62728", "iml_selective": "#9467bd", "imls_fill": "#8c564b", "blue_noise": "#7f7f7f"}

#: columns of metrics.csv, in order
METRIC_COLUMNS = (
    ["view", "row", "method"]
    + [f"{s}_ms" for s in STAGES]
    + ["total_ms", "ipr", "c_share", "rendered_pixels", "psnr", "ssim"]
)
SWEEP_COLUMNS = ["view", "row", "method", "setting", "value"] + METRIC_COLUMNS[3:]
#: columns of options.csv (IML/S network stages under each inference option, mean over views)
OPTION_COLUMNS = ["option", "first_call_s", "importance_ms", "selective_render_ms", "decoder_ms", "recnn_ms",
                  "networks_ms", "total_ms", "psnr", "error"]


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


def hydra_command(module: str, fallback: str) -> str:
    """The command line of the running Hydra app (``python -m <module> <overrides>``, an override
    with a space quoted), for reports; ``fallback`` when not run through Hydra.

    Example:
        >>> hydra_command("imls_lightning.evaluate", "evaluate(cfg) through the Python API")
        'evaluate(cfg) through the Python API'
    """
    try:
        from shlex import quote

        from hydra.core.hydra_config import HydraConfig

        if HydraConfig.initialized():
            args = " ".join(quote(a) if " " in a else a for a in HydraConfig.get().overrides.task)
            return f"python -m {module} {args}".rstrip()
    except Exception:  # informative only
        pass
    return fallback


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


MASK_LABELS = {"ims": "IMS (from the view)", "iml": "IML (from the C-Image)", "blue_noise": "blue noise (untrained)"}


def equal_share_markdown(summary: Sequence[Mapping[str, Any]]) -> str:
    """Markdown table: per share and mask, PSNR after the RecNN with the trained decoder and with the
    fill, the decoder's gain, and the mask's density on background vs object."""
    by = {(r["share"], r["mask"], r["reconstruction"]): r for r in summary}
    shares = sorted({r["share"] for r in summary})
    masks = [m for m in ("ims", "iml", "blue_noise") if any(k[1] == m for k in by)]
    rows = []
    for s in shares:
        blue_dec = by.get((s, "blue_noise", "decoder"))
        for m in masks:
            dec, fill = by.get((s, m, "decoder")), by.get((s, m, "fill"))
            any_row = dec or fill
            if any_row is None:
                continue
            gain = dec["psnr"] - fill["psnr"] if dec and fill else float("nan")
            vs_blue = dec["psnr"] - blue_dec["psnr"] if dec and blue_dec and m != "blue_noise" else float("nan")
            ratio = any_row["density_background"] / any_row["density_object"] if any_row["density_object"] > 0 else float("nan")
            rows.append([f"{100 * s:.0f} %", MASK_LABELS.get(m, m), f"{100 * any_row['c_share']:.1f} %",
                         fmt(dec["psnr"]) if dec else "–", fmt(fill["psnr"]) if fill else "–",
                         fmt(gain, 2, " dB") if np.isfinite(gain) else "–",
                         fmt(vs_blue, 2, " dB") if np.isfinite(vs_blue) else "–",
                         f"{100 * any_row['density_background']:.1f} %", f"{100 * any_row['density_object']:.1f} %",
                         fmt(ratio, 2) if np.isfinite(ratio) else "–"])
    return md_table(["target share of C", "mask", "share kept", "decoder PSNR (dB)", "fill PSNR (dB)",
                     "decoder − fill", "mask − blue noise", "density: background", "density: object",
                     "background / object"], rows, "llrrrrrrrr")


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


def new_figure(w: float = 7.0, h: float = 4.0):
    """A matplotlib figure of ``w`` x ``h`` inches on the Agg canvas (no display needed), for :func:`save_figure`."""
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
    fig = new_figure(max(5.0, 1.3 * len(methods) + 2), 4.2)
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
    fig = new_figure(8.0, 4.0)
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
    fig = new_figure(7.5, 4.8)
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
    fig = new_figure(6.0, 3.6)
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


def error_map(image: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``|image - truth|`` of two ``(m, m, 3)`` uint8 images, averaged over channels: ``(m, m)`` in [0, 1]."""
    a = np.asarray(image, np.float32) / 255.0
    b = np.asarray(truth, np.float32) / 255.0
    if a.shape != b.shape:
        raise ValueError(f"error_map: image {a.shape} and truth {b.shape} differ in shape")
    return np.abs(a - b).mean(axis=-1)


def im_to_fr_mask(im: Any, pattern: Any, fr_size: int) -> np.ndarray:
    """The IM ``(n, n)`` bool (C-Image) shown at FR: ``(m, m)`` uint8, 2 = important pixel, 1 = pattern
    pixel left out, 0 = not in the pattern. Without a pattern, the IM itself (0/2)."""
    a = np.asarray(im.cpu().numpy() if hasattr(im, "cpu") else im).astype(bool)
    if pattern is None:
        return a.astype(np.uint8) * 2
    idx = np.asarray(pattern.indices.cpu().numpy() if hasattr(pattern.indices, "cpu") else pattern.indices, np.int64)
    k = len(idx)
    flat = np.zeros(int(fr_size) ** 2, np.uint8)
    flat[idx] = 1
    flat[idx[a.reshape(-1)[:k]]] = 2
    return flat.reshape(fr_size, fr_size)


def plot_image_grid(grid: Mapping[int, Mapping[str, Any]], methods: Sequence[str], path: str | Path,
                    pattern: Any = None, fr_size: int | None = None) -> Path:
    """The image grid: one row per view; columns: ground truth, each method's image, each method's error
    map ``|method - truth|`` (magma, one scale for the whole grid, colour bar on the right), and the
    IML/S importance mask at FR when the row has one (``imls_im``).

    Args:
        grid: ``{view position: {"truth": (m, m, 3) uint8, method: (m, m, 3) uint8, ..., "imls_im": (n, n) bool}}``.
        methods: the method columns, in order (missing entries are left blank).
    """
    from matplotlib import colormaps

    views = sorted(grid)
    if not views:
        raise ValueError("plot_image_grid: no views")
    with_im = any(grid[v].get("imls_im") is not None for v in views)
    cols = ["truth"] + [m for m in methods] + [f"err:{m}" for m in methods] + (["imls_im"] if with_im else [])
    errs = {(v, m): error_map(grid[v][m], grid[v]["truth"]) for v in views for m in methods if grid[v].get(m) is not None}
    # one colour scale for every error map: the 99th percentile of all errors (at least one grey level)
    vmax = max([float(np.percentile(e, 99)) for e in errs.values()] + [1.0 / 255.0])
    size = 1.45
    fig = new_figure(size * len(cols) + 0.8, size * len(views) + 0.5)
    axes = fig.subplots(len(views), len(cols), squeeze=False)
    cmap = colormaps["magma"]
    im_handle = None
    for r, v in enumerate(views):
        g = grid[v]
        truth = g["truth"]
        m = truth.shape[0]
        for c, col in enumerate(cols):
            ax = axes[r][c]
            ax.set_xticks([])
            ax.set_yticks([])
            title = ""
            if col == "truth":
                ax.imshow(truth, interpolation="nearest")
                title = "ground truth"
            elif col == "imls_im":
                if g.get("imls_im") is not None:
                    mask = im_to_fr_mask(g["imls_im"], pattern, fr_size or m)
                    ax.imshow(mask, cmap="gray", vmin=0, vmax=2, interpolation="nearest")
                    ax.set_xlabel(f"IPR {float((mask == 2).mean()):.1%}", fontsize=6)
                title = "IML/S IM\n(white; grey: pattern)"
            elif col.startswith("err:"):
                name = col[4:]
                e = errs.get((v, name))
                if e is not None:
                    im_handle = ax.imshow(e, cmap=cmap, vmin=0.0, vmax=vmax, interpolation="nearest")
                    ax.set_xlabel(f"mean {e.mean():.3f}", fontsize=6)
                title = f"|{METHOD_LABELS.get(name, name)} − truth|"
            else:
                img = g.get(col)
                if img is not None:
                    ax.imshow(img, interpolation="nearest")
                    mse = float(((np.asarray(img, np.float64) - truth) / 255.0).__pow__(2).mean())
                    ax.set_xlabel("exact" if mse == 0 else f"{float(psnr_from_mse(mse)):.1f} dB", fontsize=6)
                title = METHOD_LABELS.get(col, col)
            if r == 0:
                ax.set_title(title, fontsize=6)
            if c == 0:
                ax.set_ylabel(f"view {v}", fontsize=7)
    if im_handle is not None:
        cb = fig.colorbar(im_handle, ax=[axes[r][c] for r in range(len(views)) for c in range(len(cols))],
                          fraction=0.015, pad=0.01)
        cb.ax.tick_params(labelsize=6)
        cb.set_label("|error| (mean over RGB)", fontsize=6)
    return save_figure(fig, path)


# ------------------------------------------------------------------------------------------------
# the report


@dataclass
class ReportContext:
    """Everything :func:`write_report` formats (filled by :func:`imls_lightning.evaluate.evaluate`).

    ``rows`` / ``sweep_rows`` / ``option_rows`` are the rows of metrics.csv / sweep.csv / options.csv;
    ``grid`` is :func:`plot_image_grid`'s input; ``order`` the evaluated methods in table order.
    """

    out: Path
    scene: str
    recnn_name: str
    resolution: int
    c_size: int
    pattern: str
    renderer: str
    views: str
    positions: list[int]
    trajectory_len: int
    repeats: int
    warmup: int
    options: dict[str, Any]
    device: str
    checkpoints: dict[str, str]
    iml_mean: float
    rows: list[dict[str, Any]]
    sweep_rows: list[dict[str, Any]] = field(default_factory=list)
    option_rows: list[dict[str, Any]] = field(default_factory=list)
    order: list[str] = field(default_factory=lambda: list(METHOD_ORDER))
    sweep_positions: list[int] = field(default_factory=list)
    grid: dict[int, dict[str, Any]] = field(default_factory=dict)
    pattern_obj: Any = None
    notes: list[str] = field(default_factory=list)
    las_ipr: float | None = None
    machine: dict[str, str] = field(default_factory=dict)
    command: str = ""
    cache: str = ""
    orp: dict[str, Any] | None = None
    equal_share: list[dict[str, Any]] = field(default_factory=list)


def sweep_points(sweep_rows: Sequence[Mapping[str, Any]]) -> dict[tuple[str, float], dict[str, Any]]:
    """Mean over views of each (method, setting value) of sweep.csv: ``{(method, value): summary}``
    (the :func:`summarize_rows` fields plus ``setting`` and ``value``), in first-seen order."""
    groups: dict[tuple[str, float], list[Mapping[str, Any]]] = {}
    for r in sweep_rows:
        groups.setdefault((str(r["method"]), float(r["value"])), []).append(r)
    out = {}
    for key, rs in groups.items():
        s = summarize_rows(rs)[key[0]]
        s.update(setting=str(rs[0].get("setting", "")), value=key[1])
        out[key] = s
    return out


def _sweep_label(method: str, setting: str, value: float) -> str:
    return f"u={value:g}" if setting == "mean" else f"IPR={value:g}"


def sweep_table(points: Mapping[tuple[str, float], Mapping[str, Any]]) -> str:
    """The latency/PSNR sweep: one line per (method, setting value)."""
    rank = {"iml": 0, "iml_selective": 1, "las": 2}
    rows = []
    for (method, value), s in sorted(points.items(), key=lambda kv: (rank.get(kv[0][0], 9), kv[0][1])):
        rows.append([METHOD_LABELS.get(method, method), _sweep_label(method, s["setting"], value),
                     fmt(s["latency_ms"].get("total"), 2), fmt_pct(s["ipr"]), fmt_pct(s["c_share"]),
                     fmt(s["psnr"], 2), fmt(s["ssim"], 4), s["views"]])
    return md_table(["Method", "setting", "latency (ms)", "IPR", "C-Image share", "PSNR (dB)", "SSIM", "views"], rows)


def speedup_table(summ: Mapping[str, Mapping[str, Any]], target: str = "imls",
                  over: Sequence[str] = ("recnn", "las", "full", "iml")) -> str:
    """Speed-up of ``target`` (IML/S + RecNN) over each baseline: ``their total / its total`` and the PSNR change."""
    t = summ[target]
    t_ms = t["latency_ms"].get("total", math.nan)
    rows = []
    for o in over:
        if o not in summ:
            continue
        s = summ[o]
        o_ms = s["latency_ms"].get("total", math.nan)
        dp = (t["psnr"] - s["psnr"]) if o != "full" else math.nan
        rows.append([f"over {s['label']}", fmt(o_ms, 2), fmt(t_ms, 2), f"**{speedup(o_ms, t_ms)}**",
                     fmt(dp, 2, " dB") if o != "full" else "– (exact reference)"])
    return md_table([f"{t['label']}", "their latency (ms)", "IML/S latency (ms)", "speed-up", "PSNR change"], rows)


def quality_table(rows: Sequence[Mapping[str, Any]], summ: Mapping[str, Mapping[str, Any]], methods: Sequence[str]) -> str:
    """Average PSNR / SSIM per method over the views (with their spread)."""
    out = []
    for m in methods:
        ps = np.array([_num(r.get("psnr")) for r in rows if r["method"] == m])
        ss = np.array([_num(r.get("ssim")) for r in rows if r["method"] == m])
        ps, ss = ps[np.isfinite(ps)], ss[np.isfinite(ss)]
        out.append([summ[m]["label"], fmt(summ[m]["psnr"], 2), fmt(ps.std() if ps.size else math.nan, 2),
                    fmt(ps.min() if ps.size else math.nan, 2), fmt(summ[m]["ssim"], 4),
                    fmt(ss.min() if ss.size else math.nan, 4), summ[m]["views"]])
    return md_table(["Method", "PSNR (dB)", "PSNR std", "PSNR min", "SSIM", "SSIM min", "views"], out)


def options_table(option_rows: Sequence[Mapping[str, Any]]) -> str:
    """IML/S network stages under each inference option (mean over views of per-view medians)."""
    rows = []
    for r in option_rows:
        if r.get("error"):
            rows.append([r["option"], "–", "–", "–", "–", "–", "–", "–", f"failed: {r['error']}"])
            continue
        rows.append([r["option"], fmt(r.get("importance_ms")), fmt(r.get("decoder_ms")), fmt(r.get("recnn_ms")),
                     f"**{fmt(r.get('networks_ms'))}**", fmt(r.get("total_ms")), fmt(r.get("first_call_s"), 2),
                     fmt(r.get("psnr"), 2), ""])
    return md_table(["option", "importance (ms)", "decoder (ms)", "RecNN (ms)", "networks (ms)", "total (ms)",
                     "first call (s)", "PSNR (dB)", "note"], rows)


def _latency_points(ctx: ReportContext, summ, points) -> tuple[dict, dict, float | None]:
    curves: dict[str, list[tuple[float, float, str]]] = {}
    for (method, value), s in sorted(points.items(), key=lambda kv: kv[0][1]):
        label = METHOD_LABELS.get(method, method) + (" (sweep)" if method == "las" else "")
        note = _sweep_label(method, s["setting"], value)
        if method == "iml_selective":
            note = f"{note}, IPR {fmt_pct(s['ipr'])}"
        curves.setdefault(label, []).append((s["latency_ms"].get("total", math.nan), s["psnr"], note))
    pts = {}
    for m in ctx.order:
        if m == "full":
            continue
        s = summ[m]
        extra = f" (u={ctx.iml_mean:g})" if m == "iml" else (f" (IPR {fmt_pct(s['ipr'])})" if m in ("imls", "las") else "")
        pts[f"{s['label']}{extra}"] = (s["latency_ms"].get("total", math.nan), s["psnr"])
    full = summ["full"]["latency_ms"].get("total") if "full" in summ else None
    return curves, pts, full


def _md_image(name: str, alt: str) -> str:
    return f"![{alt}]({name})"


def write_report(ctx: ReportContext) -> Path:
    """Write the plots, the image grid and (last, atomically) ``report.md`` into ``ctx.out``.

    Files: ``stage_breakdown.png``, ``psnr_per_view.png``, ``latency_vs_psnr.png`` (with sweep rows),
    ``options.png`` (with option rows), ``image_grid.png`` (with grid views), ``report.md``.
    Returns the path of ``report.md``.
    """
    out = Path(ctx.out)
    out.mkdir(parents=True, exist_ok=True)
    if not ctx.rows:
        raise ValueError("write_report: no metric rows")
    summ = summarize_rows(ctx.rows)
    order = [m for m in ctx.order if m in summ]
    figures: list[tuple[str, str]] = []

    plot_stage_breakdown(summ, order, out / "stage_breakdown.png")
    figures.append(("stage_breakdown.png", "Time breakdown per method"))
    approx = [m for m in order if m != "full"]  # the full ray cast is the ground truth
    plot_psnr_per_view(ctx.rows, approx, out / "psnr_per_view.png")
    figures.append(("psnr_per_view.png", "PSNR per view"))
    points = sweep_points(ctx.sweep_rows) if ctx.sweep_rows else {}
    curves, pts, full_ms = _latency_points(ctx, summ, points)
    plot_latency_vs_psnr(curves, pts, full_ms, out / "latency_vs_psnr.png")
    figures.append(("latency_vs_psnr.png", "Latency vs PSNR"))
    if ctx.option_rows:
        ok = [r for r in ctx.option_rows if not r.get("error")]
        if ok:
            plot_options(ok, out / "options.png")
            figures.append(("options.png", "IML/S network stages per inference option"))
    if ctx.grid:
        plot_image_grid(ctx.grid, order, out / "image_grid.png", ctx.pattern_obj, ctx.resolution)
        figures.append(("image_grid.png", "Image grid: ground truth, each method, error maps"))

    text = render_markdown(ctx, summ, order, points, figures)
    return atomic_write_text(out / "report.md", text)


def render_markdown(ctx: ReportContext, summ, order: Sequence[str], points, figures: Sequence[tuple[str, str]]) -> str:
    """The text of report.md (paper-style tables; see :func:`write_report`)."""
    L: list[str] = []
    L.append(f"# IML/S evaluation: {ctx.scene}, {ctx.recnn_name}")
    L.append("")
    n_views = len(ctx.positions)
    opts = ", ".join(f"{k}={v}" for k, v in ctx.options.items())
    mach = ctx.machine or {}
    machine = ", ".join(f"{k} {v}" for k, v in mach.items() if k not in ("device",))
    header = [
        ("scene", ctx.scene),
        ("RecNN", ctx.recnn_name),
        ("resolution (FR-Image)", f"{ctx.resolution}×{ctx.resolution}"),
        ("C-Image size", f"{ctx.c_size}×{ctx.c_size}"),
        ("sampling pattern", ctx.pattern),
        ("renderer", ctx.renderer),
        ("views", f"{n_views} of the {ctx.trajectory_len} '{ctx.views}' views"
                  + (" (the test trajectory)" if ctx.views == "test" else "")),
        ("timing", f"per view and stage: median of {ctx.repeats} runs after {ctx.warmup} warm-up run(s); tables: mean over views"),
        ("device (networks)", mach.get("device", ctx.device)),
        ("inference options", opts),
        ("machine", machine or "–"),
        ("command", f"`{ctx.command}`" if ctx.command else "–"),
        ("cache", f"`{ctx.cache}`" if ctx.cache else "–"),
    ]
    header += [(f"checkpoint: {k}", f"`{v}`" if v and v != "–" else "–") for k, v in ctx.checkpoints.items()]
    header.append(("IML mean u (as trained)", fmt(ctx.iml_mean, 4)))
    if ctx.las_ipr is not None:
        header.append(("LAS IPR", fmt_pct(ctx.las_ipr, 2)))
    L.append(md_table(["", ""], [(k, str(v).replace("|", "\\|")) for k, v in header], "ll"))
    L.append("")

    L.append("## Average latency per method and stage (ms)")
    L.append("")
    L.append(latency_table(summ, order, reference="recnn"))
    L.append("")
    L.append("IPR: ray-cast important pixels / FR pixels (the RecNN alone and IML + RecNN ray-cast their whole "
             "pattern; IML + RecNN's IPR is the IML mask it keeps). C-Image share: important / pattern pixels. "
             "Total: median of the per-run sums of the stages.")
    L.append("")

    if ctx.orp is not None:
        o = ctx.orp
        L.append("## ORP on the product path")
        L.append("")
        if o["found"]:
            L.append(f"The smallest mean value u whose IML/S + RecNN (IMS mask from the view, exactly those pixels "
                     f"ray-cast, IML decoder, RecNN) stays within ε = {fmt(o['epsilon_db'], 2)} dB of the RecNN alone on "
                     f"the validation views: **u = {fmt(o['mean'], 4)}**, C-share {fmt_pct(o['c_share'])}, IPR "
                     f"{fmt_pct(o['ipr'], 2)}, gap {fmt(o['gap_db'], 2)} dB ({o['evaluations']} means tried). IML/S + RecNN "
                     "and IML + RecNN below run at this u (one IMS regressing PIM', rescaled to u).")
        else:
            L.append(f"No mean value in [0.01, 1] keeps IML/S + RecNN within ε = {fmt(o['epsilon_db'], 2)} dB of the RecNN "
                     "alone on the validation views; IML/S runs at its trained mean.")
        L.append("")
        L.append(md_table(["u", "gap (dB)", "C-share"], [[fmt(u, 4), fmt(g, 2), fmt_pct(c)] for u, g, c in o["points"]], "rrr"))
        L.append("")

    if "imls" in summ:
        L.append("## Speed-up of IML/S + RecNN")
        L.append("")
        L.append(speedup_table(summ))
        L.append("")

    L.append("## Average image quality")
    L.append("")
    L.append(quality_table(ctx.rows, summ, order))
    L.append("")
    if "full" in summ:
        L.append("Ground truth = the cache's full ray cast by the same renderer, so the full ray cast scores "
                 "100 dB (identical images; the PSNR is capped there) unless the renderer is not deterministic.")
        L.append("")

    if ctx.equal_share:
        L.append("## Learned parts against untrained baselines, at equal share")
        L.append("")
        L.append("Each mask is brought to the target share of the C-Image per view (bisection on u, no ground truth); "
                 "its pixels are rebuilt by the decoder trained for that mask or by the untrained pull-push fill, then "
                 "by the same RecNN. PSNR after the RecNN, mean over the evaluated views. \"decoder − fill\": what the "
                 "trained decoder adds on the same pixels; \"mask − blue noise\": what the learned mask adds over the "
                 "blue-noise mask of the same share, each through its own trained decoder. Density: share of the empty "
                 "background (ground truth black) and of the object that the mask samples.")
        L.append("")
        L.append(equal_share_markdown(ctx.equal_share))
        L.append("")

    if points:
        L.append("## Latency / PSNR sweep")
        L.append("")
        L.append(f"On {len(ctx.sweep_positions)} view(s) (positions {_positions(ctx.sweep_positions)}). "
                 "IML + RecNN at each inference mean u; \"IML IM, selectively rendered\": the IML/S pipeline "
                 "with the IML's mask of that u in place of the IMS output (the latency IML/S would have if "
                 "its IMS reproduced that mask)"
                 + ("; LAS at each IPR." if any(k[0] == "las" for k in points) else "."))
        L.append("")
        L.append(sweep_table(points))
        L.append("")

    if ctx.option_rows:
        L.append("## Inference options (IML/S network stages)")
        L.append("")
        L.append(options_table(ctx.option_rows))
        L.append("")

    L.append("## Notes")
    L.append("")
    for note in ctx.notes:
        L.append(f"- {note}")
    L.append("- Selective rendering is real: the renderer ray-casts only the chosen pixels, so its stage time "
             "falls with the IPR; IML + RecNN renders the whole pattern (its importance comes from the "
             "rendered C-Image), so it bounds quality, not speed.")
    L.append(f"- Evaluated view positions: {_positions(ctx.positions)}.")
    L.append("- Files: `metrics.csv` (view × method), `sweep.csv`"
             + (", `options.csv`" if ctx.option_rows else "") + ", `config.yaml`.")
    L.append("")

    L.append("## Figures")
    L.append("")
    for name, alt in figures:
        L.append(f"### {alt}")
        L.append("")
        L.append(_md_image(name, alt))
        L.append("")
    return "\n".join(L)


def _positions(ps: Sequence[int], limit: int = 24) -> str:
    ps = [int(p) for p in ps]
    if len(ps) > 1 and ps == list(range(ps[0], ps[-1] + 1)):
        return f"{ps[0]}–{ps[-1]}"
    s = ", ".join(str(p) for p in ps[:limit])
    return s + (f", … ({len(ps)} in all)" if len(ps) > limit else "")


__all__ = [
    "METHOD_LABELS", "METHOD_ORDER", "METRIC_COLUMNS", "SWEEP_COLUMNS", "OPTION_COLUMNS", "STAGE_LABELS",
    "atomic_write_text", "write_metrics_csv", "read_csv", "summarize_rows", "summary", "machine_info", "md_table",
    "fmt", "fmt_pct", "speedup", "latency_table", "speedup_table", "quality_table", "sweep_table", "options_table",
    "sweep_points", "error_map", "im_to_fr_mask", "plot_stage_breakdown", "plot_psnr_per_view",
    "plot_latency_vs_psnr", "plot_options", "plot_image_grid", "new_figure", "save_figure", "ReportContext", "write_report",
    "render_markdown",
]
