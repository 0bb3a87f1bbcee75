"""Markdown tables of the evaluation report (GitHub tables, paper-style: latency per stage, speed-up,
quality, the latency / PSNR sweep, the inference options, the equal-share comparison)."""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..inference.pipeline import STAGES
from .metrics_csv import number, summarize_rows
from .names import MASK_LABELS, METHOD_LABELS, STAGE_LABELS
from .speedup import paired_totals, speedup_interval
from .writer import fmt, fmt_pct, md_table


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


def speedup(slow_ms: Any, fast_ms: Any) -> str:
    """``slow / fast`` as ``2.07×`` (the paper's speed-up); missing or non-positive -> an en dash.

    Example:
        >>> speedup(4.14, "2.0"), speedup(4.0, 0), speedup(None, 1.0), fmt_pct(0.1234)
        ('2.07×', '–', '–', '12.3%')
    """
    try:
        slow, fast = float(slow_ms), float(fast_ms)
    except (TypeError, ValueError):
        return "–"
    if not (math.isfinite(slow) and math.isfinite(fast)) or fast <= 0:
        return "–"
    return f"{slow / fast:.2f}×"


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


def sweep_label(method: str, setting: str, value: float) -> str:
    """A sweep point's setting as shown: ``u=0.1`` (a mean value), ``20% of C`` (a share of the
    C-Image) or ``IPR=0.05``."""
    if setting == "share":
        return f"{100 * value:g}% of C"
    return f"u={value:g}" if setting == "mean" else f"IPR={value:g}"


def sweep_table(points: Mapping[tuple[str, float], Mapping[str, Any]]) -> str:
    """The latency/PSNR sweep: one line per (method, setting value)."""
    rank = {"iml": 0, "iml_selective": 1, "las": 2, "imls": 3, "blue_noise": 4}
    rows = []
    for (method, value), s in sorted(points.items(), key=lambda kv: (rank.get(kv[0][0], 9), kv[0][1])):
        rows.append([METHOD_LABELS.get(method, method), sweep_label(method, s["setting"], value),
                     fmt(s["latency_ms"].get("total"), 2), fmt_pct(s["ipr"]), fmt_pct(s["c_share"]),
                     fmt(s["psnr"], 2), fmt(s["ssim"], 4), s["views"]])
    return md_table(["Method", "setting", "latency (ms)", "IPR", "C-Image share", "PSNR (dB)", "SSIM", "views"], rows)


def speedup_table(summ: Mapping[str, Mapping[str, Any]], target: str = "imls",
                  over: Sequence[str] = ("recnn", "las", "las_searched", "full", "iml", "two_pass"),
                  rows: Sequence[Mapping[str, Any]] | None = None) -> str:
    """Speed-up of ``target`` (IML/S + RecNN) over each baseline: ``their total / its total`` and the PSNR change;
    with the metric ``rows``, also its 95% bootstrap interval over the timed views
    (:func:`~imls_lightning.report.speedup.speedup_interval`)."""

    t = summ[target]
    t_ms = t["latency_ms"].get("total", math.nan)
    out = []
    for o in over:
        if o not in summ:
            continue
        s = summ[o]
        o_ms = s["latency_ms"].get("total", math.nan)
        dp = (t["psnr"] - s["psnr"]) if o != "full" else math.nan
        line = [f"over {s['label']}", fmt(o_ms, 2), fmt(t_ms, 2), f"**{speedup(o_ms, t_ms)}**"]
        if rows is not None:
            slow, fast = paired_totals(rows, o, target)
            line.append(f"{speedup_interval(slow, fast).text()} ({len(slow)} views)" if slow else "–")
        out.append(line + [fmt(dp, 2, " dB") if o != "full" else "– (exact reference)"])
    head = [f"{t['label']}", "their latency (ms)", "IML/S latency (ms)", "speed-up"]
    head += ["95% interval (timed views resampled)"] if rows is not None else []
    return md_table(head + ["PSNR change"], out)


def quality_table(rows: Sequence[Mapping[str, Any]], summ: Mapping[str, Mapping[str, Any]], methods: Sequence[str]) -> str:
    """Average PSNR / SSIM per method over the views (with their spread)."""
    out = []
    for m in methods:
        ps = np.array([number(r.get("psnr")) for r in rows if r["method"] == m])
        ss = np.array([number(r.get("ssim")) for r in rows if r["method"] == m])
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
