"""The speed-quality front of an evaluation: every method as one or more points (PSNR and SSIM against
median latency) from the same run on the same views, the Pareto front marked, and where IML/S lies.

A point is on the Pareto front when no other point is at least as fast (median latency) and at least
as good (mean PSNR) and strictly better in one of the two (:func:`pareto_front`). The points come
from the evaluation's rows (``metrics.csv``: one per view and method, at the evaluation's operating
point) and sweep rows (``sweep.csv``: IML + RecNN at several mean values, LAS at several IPRs, IML/S
and blue noise at several shares of C), restricted to the views every point was measured on
(:func:`front_points`). Latency of a point: the median over those views of the per-view medians of
the repeated runs; quality: the mean over the views.

Example:
    >>> pareto_front([1.0, 2.0, 3.0, 2.5], [30.0, 32.0, 31.0, 33.0])
    [True, True, False, True]
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .metrics_csv import number
from .names import METHOD_LABELS
from .tables import speedup, sweep_label
from .writer import fmt, fmt_pct, md_table

__all__ = ["pareto_front", "front_point", "front_points", "front_markdown", "front_verdict", "EXACT_PSNR_DB"]

#: the PSNR the metrics give identical images (the full ray cast against its own cache)
EXACT_PSNR_DB = 100.0


def pareto_front(latency_ms: Sequence[float], psnr: Sequence[float]) -> list[bool]:
    """Which points lie on the speed-quality Pareto front (lower latency and higher PSNR are better).

    A point is on the front when no other point has ``latency <= its latency`` and ``psnr >= its
    psnr`` with one of the two strict. Equal points are all on the front; a point with a non-finite
    coordinate never is (and dominates nothing).

    Args:
        latency_ms: ``(N,)`` latencies.
        psnr: ``(N,)`` qualities (any "higher is better" score).

    Returns:
        ``N`` booleans.

    Example:
        >>> pareto_front([1.0, 1.0, 2.0, float("nan")], [30.0, 29.0, 31.0, 40.0])
        [True, False, True, False]
    """
    lat = np.asarray(latency_ms, dtype=np.float64).reshape(-1)
    q = np.asarray(psnr, dtype=np.float64).reshape(-1)
    if lat.shape != q.shape:
        raise ValueError(f"pareto_front: {lat.size} latencies but {q.size} PSNRs")
    ok = np.isfinite(lat) & np.isfinite(q)
    on = np.zeros(lat.size, dtype=bool)
    idx = np.flatnonzero(ok)
    # sweep by latency (ties: best quality first); a point is on the front when its quality reaches the
    # best of every strictly faster point and the best of the equally fast ones
    order = idx[np.lexsort((-q[idx], lat[idx]))]
    best_faster = -math.inf  # best quality among points strictly faster than the current latency
    i = 0
    while i < len(order):
        j = i
        while j < len(order) and lat[order[j]] == lat[order[i]]:
            j += 1
        group = order[i:j]
        top = q[group[0]]  # the best of this latency (sorted first)
        for k in group:
            on[k] = q[k] == top and q[k] > best_faster
        best_faster = max(best_faster, top)
        i = j
    return on.tolist()


def front_point(rows: Sequence[Mapping[str, Any]], method: str, note: str, views: Sequence[int] | None = None,
                label: str | None = None) -> dict[str, Any] | None:
    """One point of the front from the rows of one method and setting (one row per view).

    Args:
        rows: metric rows (``view``, ``total_ms``, ``psnr``, ``ssim``, ``c_share``, ``ipr``).
        method: the method key (its label from :data:`~imls_lightning.report.names.METHOD_LABELS`).
        note: the setting as shown (``"ORP u=0.52"``, ``"20% of C"``).
        views: keep only these view positions (``None``: all rows).

    Returns:
        ``{"method", "label", "note", "latency_ms" (median over views), "psnr", "ssim", "c_share",
        "ipr" (means), "views"}``, or ``None`` without rows.

    Example:
        >>> p = front_point([{"view": 0, "total_ms": 2.0, "psnr": 30.0}, {"view": 1, "total_ms": 4.0, "psnr": 32.0},
        ...                  {"view": 2, "total_ms": 9.0, "psnr": 31.0}], "recnn", "its pattern")
        >>> p["latency_ms"], p["psnr"], p["views"]
        (4.0, 31.0, 3)
    """
    keep = None if views is None else {int(v) for v in views}
    rs = [r for r in rows if keep is None or int(number(r.get("view"))) in keep]
    if not rs:
        return None

    def mean(key: str) -> float:
        a = np.asarray([number(r.get(key)) for r in rs], dtype=np.float64)
        a = a[np.isfinite(a)]
        return float(a.mean()) if a.size else math.nan

    lat = np.asarray([number(r.get("total_ms")) for r in rs], dtype=np.float64)
    lat = lat[np.isfinite(lat)]
    return {"method": method, "label": label or METHOD_LABELS.get(method, method), "note": note,
            "latency_ms": float(np.median(lat)) if lat.size else math.nan, "psnr": mean("psnr"), "ssim": mean("ssim"),
            "c_share": mean("c_share"), "ipr": mean("ipr"), "views": len(rs)}


def front_points(rows: Sequence[Mapping[str, Any]], sweep_rows: Sequence[Mapping[str, Any]], views: Sequence[int],
                 notes: Mapping[str, str] | None = None, skip: Sequence[str] = ("iml_selective",)) -> list[dict[str, Any]]:
    """Every point of the front on ``views``, the Pareto front marked (``on_front``).

    Args:
        rows: ``metrics.csv`` rows: each method at the evaluation's operating point.
        sweep_rows: ``sweep.csv`` rows (``method``, ``setting`` in ``mean | ipr | share``, ``value``).
        views: the view positions every point is measured on (the sweep's views).
        notes: method -> how its operating point is shown (``{"imls": "ORP u=0.52"}``); default
            ``"as evaluated"``.
        skip: sweep methods left out (``iml_selective`` is no method a user can run).

    Returns:
        points as :func:`front_point` returns them plus ``on_front``: the main rows' methods first
        (in their order), then the sweeps' points by method and setting.
    """
    notes = dict(notes or {})
    points: list[dict[str, Any]] = []
    methods = list(dict.fromkeys(str(r["method"]) for r in rows))
    for m in methods:
        p = front_point([r for r in rows if r["method"] == m], m, notes.get(m, "as evaluated"), views)
        if p is not None:
            points.append(p)
    groups: dict[tuple[str, str, float], list[Mapping[str, Any]]] = {}
    for r in sweep_rows:
        if str(r["method"]) in skip:
            continue
        groups.setdefault((str(r["method"]), str(r.get("setting", "")), float(r["value"])), []).append(r)
    for (m, setting, value), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][1], kv[0][2])):
        p = front_point(rs, m, sweep_label(m, setting, value), views)
        if p is not None:
            p.update(setting=setting, value=value)
            points.append(p)
    for p, on in zip(points, pareto_front([p["latency_ms"] for p in points], [p["psnr"] for p in points])):
        p["on_front"] = bool(on)
    return points


def front_markdown(points: Sequence[Mapping[str, Any]]) -> str:
    """The front as a Markdown table, fastest first; points on the Pareto front in bold, marked ``◆``."""
    rows = []
    for p in sorted(points, key=lambda p: (number(p["latency_ms"]) if math.isfinite(number(p["latency_ms"])) else math.inf)):
        exact = number(p["psnr"]) >= EXACT_PSNR_DB
        b = (lambda s: f"**{s}**") if p["on_front"] else (lambda s: s)
        rows.append([b(p["label"]), p["note"], b(fmt(p["latency_ms"], 2)), "exact" if exact else b(fmt(p["psnr"], 2)),
                     fmt(p["ssim"], 4), fmt_pct(p.get("c_share")), fmt_pct(p.get("ipr")), p["views"],
                     "◆" if p["on_front"] else ""])
    return md_table(["Method", "setting", "median latency (ms)", "PSNR (dB)", "SSIM", "C-share", "IPR", "views",
                     "Pareto front"], rows, "llrrrrrrl")


def _dominators(p: Mapping[str, Any], points: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The points that dominate ``p`` (as fast or faster and as good or better, one strictly)."""
    out = []
    for o in points:
        if o is p:
            continue
        faster, better = o["latency_ms"] <= p["latency_ms"], o["psnr"] >= p["psnr"]
        if faster and better and (o["latency_ms"] < p["latency_ms"] or o["psnr"] > p["psnr"]):
            out.append(o)
    return out


def _name(p: Mapping[str, Any]) -> str:
    quality = "exact" if number(p["psnr"]) >= EXACT_PSNR_DB else f"{fmt(p['psnr'], 2)} dB"
    return f"{p['label']} ({p['note']}: {fmt(p['latency_ms'], 2)} ms, {quality})"


def front_verdict(points: Sequence[Mapping[str, Any]], scene: str, product: str = "imls",
                  operating_note: str | None = None) -> str:
    """One paragraph: where IML/S (``product``) lies on the front of ``scene``: which of its points are
    on the Pareto front, what dominates its operating point, and how it compares with the RecNN alone
    on its pattern and on a sparser pattern.

    ``operating_note``: the note of the operating point (the ORP); default: the main rows' point.
    """
    ours = [p for p in points if p["method"] == product]
    if not ours:
        return f"**{scene}**: no IML/S point was measured."
    op = next((p for p in ours if p["note"] == operating_note), None) if operating_note else None
    op = op or next((p for p in ours if "setting" not in p), ours[0])
    on = [p for p in ours if p["on_front"]]
    label = ours[0]["label"]
    parts = [f"**{scene}**: "]
    if on:
        parts.append(f"{len(on)} of the {len(ours)} {label} points lie on the Pareto front "
                     f"({', '.join(p['note'] for p in on)}). ")
    else:
        parts.append(f"none of the {len(ours)} {label} points lies on the Pareto front. ")
    doms = _dominators(op, points)
    if op["on_front"]:
        parts.append(f"Its operating point ({op['note']}, {fmt(op['latency_ms'], 2)} ms, {fmt(op['psnr'], 2)} dB) is on the front.")
    else:
        best = sorted(doms, key=lambda o: (-o["psnr"], o["latency_ms"]))[:3]
        parts.append(f"Its operating point ({op['note']}, {fmt(op['latency_ms'], 2)} ms, {fmt(op['psnr'], 2)} dB) is dominated "
                     f"by {len(doms)} point(s), e.g. " + "; ".join(_name(o) for o in best) + ".")
    for key in ("recnn", "recnn_sparser"):
        ref = next((p for p in points if p["method"] == key and "setting" not in p), None)
        if ref is None or not math.isfinite(ref["latency_ms"]) or op["latency_ms"] <= 0:
            continue
        parts.append(f" Against {ref['label']} ({fmt(ref['latency_ms'], 2)} ms, {fmt(ref['psnr'], 2)} dB) the operating "
                     f"point's speed-up is {speedup(ref['latency_ms'], op['latency_ms'])}, its PSNR change "
                     f"{op['psnr'] - ref['psnr']:+.2f} dB.")
    if not any(p["method"] == "recnn_sparser" for p in points):
        parts.append(" (No RecNN on a sparser pattern in this run: pass checkpoints.recnn_sparser=<.ckpt>.)")
    return "".join(parts)
