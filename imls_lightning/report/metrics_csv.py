"""The metrics CSV: written atomically (temporary name + rename), read back, and summarized per method."""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..inference.pipeline import STAGES
from .names import METHOD_LABELS, METRIC_COLUMNS
from .writer import write_csv


def _fmt_cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(round(v, 6))
    return v


def write_metrics_csv(rows: Sequence[Mapping[str, Any]], path: str | Path, columns: Sequence[str] = METRIC_COLUMNS) -> Path:
    """One row per (view, method); missing stages are empty cells. Atomic."""
    return write_csv(path, rows, columns, _fmt_cell)


def read_csv(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a CSV written here; numeric cells as float (empty -> NaN), text cells as str."""
    p = Path(path)
    if not p.is_file():
        from imls_lightning.base.errors import InputError

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

def _nanmean(values: Iterable[float]) -> float:
    a = np.asarray([v for v in values], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else math.nan


def summarize_rows(rows: Sequence[Mapping[str, Any]], key: str = "method") -> dict[str, dict[str, Any]]:
    """Per-method (or per ``key``) averages of metric rows; see :func:`summary`.

    Example:
        >>> rows = [{"method": "recnn", "total_ms": 2.0, "psnr": 30.0}, {"method": "recnn", "total_ms": "4", "psnr": ""}]
        >>> s = summarize_rows(rows)["recnn"]
        >>> s["label"], s["views"], s["latency_ms"], s["psnr"]
        ('RecNN alone', 2, {'total': 3.0}, 30.0)
    """
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(str(r[key]), []).append(r)
    out: dict[str, dict[str, Any]] = {}
    for name, rs in groups.items():
        lat = {}
        for s in list(STAGES) + ["total"]:
            v = _nanmean(number(r.get(f"{s}_ms")) for r in rs)
            if math.isfinite(v):
                lat[s] = v
        out[name] = {
            "label": METHOD_LABELS.get(name, name),
            "views": len(rs),
            "latency_ms": lat,
            **{k: _nanmean(number(r.get(k)) for r in rs) for k in ("psnr", "ssim", "ipr", "c_share", "rendered_pixels")},
        }
    return out


def number(v: Any) -> float:
    """A cell as a float: None, an empty or a non-numeric cell -> NaN.

    Example:
        >>> number("2.5"), number(3), number(""), number(None), number("n/a")
        (2.5, 3.0, nan, nan, nan)
    """
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
