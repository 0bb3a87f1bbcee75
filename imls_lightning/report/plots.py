"""Plots of the evaluation report: matplotlib's object-oriented API on the Agg canvas (no pyplot
global state, no display), saved as PNGs atomically."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.metrics import psnr_from_mse
from ..inference.pipeline import STAGES
from .metrics_csv import number
from .names import METHOD_COLORS, METHOD_LABELS, STAGE_COLORS, STAGE_LABELS


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
        rs = sorted((r for r in rows if r["method"] == m), key=lambda r: number(r["view"]))
        if not rs:
            continue
        xs = [number(r["view"]) for r in rs]
        ys = [number(r["psnr"]) for r in rs]
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


def plot_front(points: Sequence[Mapping[str, Any]], path: str | Path, title: str = "Speed-quality front") -> Path:
    """The speed-quality front: median latency (x) against PSNR (y), one colour per method (its sweep's
    points joined in the order of their setting: share, mean value or IPR; its operating point a larger
    marker), the Pareto front as a dashed step line through its points (ringed).

    Args:
        points: :func:`~imls_lightning.report.front.front_points`'s points (``method``, ``label``,
            ``note``, ``latency_ms``, ``psnr``, ``on_front``). An exact point (the full ray cast,
            PSNR >= 100 dB) is drawn as a vertical line instead of a point off the scale.
    """
    from .front import EXACT_PSNR_DB

    fig = new_figure(8.0, 5.0)
    ax = fig.add_subplot(111)
    finite = [p for p in points if math.isfinite(number(p["latency_ms"])) and math.isfinite(number(p["psnr"]))]
    drawn = [p for p in finite if p["psnr"] < EXACT_PSNR_DB]
    markers = {"imls": "*", "recnn": "s", "recnn_sparser": "D", "las": "^", "las_searched": "<", "iml": "o", "blue_noise": "v", "imls_fill": "P", "imls_trained": "p", "two_pass": "X"}
    by_method: dict[str, list[Mapping[str, Any]]] = {}
    for p in drawn:
        by_method.setdefault(str(p["method"]), []).append(p)
    for m, ps in by_method.items():
        color, marker = METHOD_COLORS.get(m), markers.get(m, "o")
        swept = sorted((p for p in ps if "setting" in p), key=lambda p: (str(p["setting"]), float(p["value"])))
        alone = [p for p in ps if "setting" not in p]
        label = ps[0]["label"]
        if swept:
            ax.plot([p["latency_ms"] for p in swept], [p["psnr"] for p in swept], marker=marker, ms=6 if m == "imls" else 4,
                    lw=1.0, alpha=0.85, color=color, label=label)
            label = None
        if alone:
            ax.scatter([p["latency_ms"] for p in alone], [p["psnr"] for p in alone], marker=marker, s=110 if m == "imls" else 60,
                       color=color, edgecolors="white", lw=0.8, zorder=5, label=label)
        for p in ps:
            ax.annotate(p["note"], (p["latency_ms"], p["psnr"]), textcoords="offset points", xytext=(3, 3), fontsize=6)
    front = sorted((p for p in drawn if p["on_front"]), key=lambda p: p["latency_ms"])
    if front:
        ax.step([p["latency_ms"] for p in front], [p["psnr"] for p in front], where="post", ls="--", lw=1.2, color="black",
                label="Pareto front")
        ax.scatter([p["latency_ms"] for p in front], [p["psnr"] for p in front], s=140, facecolors="none",
                   edgecolors="black", lw=1.0, zorder=6)
    for p in finite:
        if p["psnr"] >= EXACT_PSNR_DB:
            ax.axvline(p["latency_ms"], color=METHOD_COLORS.get(str(p["method"]), "#555555"), ls=":", lw=1.2,
                       label=f"{p['label']} (exact{', on the front' if p['on_front'] else ''})")
    ax.set_xlabel("median latency (ms)")
    ax.set_ylabel("mean PSNR (dB)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)


def plot_options(rows: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Bars of the IML/S network stages' time under each inference option."""
    fig = new_figure(6.0, 3.6)
    ax = fig.add_subplot(111)
    names = [r["option"] for r in rows]
    x = np.arange(len(rows))
    bottom = np.zeros(len(rows))
    for st in ("importance", "decoder", "recnn"):
        vals = np.array([number(r.get(f"{st}_ms")) for r in rows])
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
    """``|image - truth|`` of two ``(m, m, 3)`` uint8 images, averaged over channels: ``(m, m)`` in [0, 1].

    Example:
        >>> truth = np.zeros((2, 2, 3), np.uint8)
        >>> image = truth.copy(); image[0, 1] = (255, 0, 0)
        >>> error_map(image, truth).tolist()
        [[0.0, 0.3333333432674408], [0.0, 0.0]]
    """
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
