"""The before-training estimate's speed-up against the product's measured one, per render prediction.

    python scripts/estimate_vs_measured.py benchmarks/estimate_check/ct_head.json:0.806066:0.802192 ...
    python scripts/estimate_vs_measured.py --sharpness 3 EST.json:0.343:2.556:benchmarks/seed_whole/eval_metrics.csv

Each argument is ``estimate.json:share:measured speed-up[:metrics.csv]`` (the share and speed-up of a row of
``benchmarks/paper_scale.csv``, or of an evaluation's summary). For each it prints, and writes as CSV with
``--csv``, the speed-up at that share from the silhouette mask's measured render, from the per-pixel model, and
from the slower of the two (the estimate's bound, :func:`imls_lightning.estimate.slower_render`), each with its
error against the measured speed-up (issue 31 asks within 15%); and the row's reading, ``estimated_speedup`` as
``make bench-paper`` writes it (the curve of ``--sharpness``, the sharpness the row's ORP kept), with its 95% interval
over the estimate's views resampled where the estimate kept them (``row_reading_low`` / ``_high``).

With the row's per-view ``metrics.csv`` (an evaluation's), the render is compared apart from the machine: the
fraction of the whole pattern's render the product's mask took in the row (means over its timed views, as its
speed-up is a ratio of means) against the estimate's at the share, and the estimate's fraction on the row's own
stage times (``on_row_times``). A VM's ray caster runs at another speed on another day (seed_whole: the same
pattern in 1024 ms and in 1808 ms), and the networks do not follow it, so an estimate made on another day is
read on the row's times to judge its model.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COLUMNS = ("estimate", "scene", "skip_empty", "share", "measured", "silhouette", "per_pixel_model", "slower", "slower_error",
           "sharpness", "row_reading", "row_reading_error", "row_render_fraction", "estimate_render_fraction", "on_row_times",
           "on_row_times_error", "views", "row_reading_low", "row_reading_high", "seconds")


def row_times(metrics: str | Path) -> dict[str, float]:
    """The RecNN alone's and the product's stage times in a row, means over its timed views (an evaluation's
    ``metrics.csv``: methods ``recnn`` and ``imls``, the rows with a ``total_ms``)."""
    import numpy as np

    with open(metrics, newline="", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r.get("total_ms")]

    def mean(method: str, col: str) -> float:
        vals = [float(r[col]) for r in rows if r["method"] == method and r.get(col)]
        if not vals:
            raise KeyError(f"{method}.{col}")
        return float(np.mean(vals))
    return {"c_render_ms": mean("recnn", "selective_render_ms"), "recnn_ms": mean("recnn", "recnn_ms"),
            "nets_ms": mean("imls", "importance_ms") + mean("imls", "decoder_ms"),
            "render_ms": mean("imls", "selective_render_ms"), "alone_ms": mean("recnn", "total_ms"),
            "imls_ms": mean("imls", "total_ms")}


def compare(path: str, share: float, measured: float, sharpness: float = 1.0, metrics: str | None = None) -> dict:
    from imls_lightning.estimate import (RenderCost, RenderCurve, estimate_interval, slower_render, speedup_at,
                                         speedup_from_estimate)
    from imls_lightning.estimate.bound import estimate_render

    est = json.loads(Path(path).read_text())
    model, silhouette = RenderCost(**est["render_cost"]), RenderCurve(**est["render_curve"])
    if "silhouette_ms" in est:  # an estimate whose render_curve is already the slower one: its silhouette is kept apart
        silhouette = RenderCurve(silhouette.shares, tuple(est["silhouette_ms"]), silhouette.fixed_ms)
    kw = {"c_render_ms": est["c_render_ms"], "nets_ms": est["nets_ms"], "recnn_ms": est["recnn_ms"]}
    density = est["background_density"]
    slower = speedup_at(slower_render(silhouette, model, density), share, **kw)
    reading = speedup_from_estimate(est, share, sharpness)
    out = {"estimate": path, "scene": est["scene"], "skip_empty": est["settings"]["renderer"].get("skip_empty", True),
           "share": share, "measured": measured, "silhouette": speedup_at(silhouette, share, **kw),
           "per_pixel_model": speedup_at(model, share, **kw, background_density=density), "slower": slower,
           "slower_error": slower / measured - 1.0, "sharpness": float(sharpness), "row_reading": reading,
           "row_reading_error": reading / measured - 1.0, "views": len(est.get("per_view") or []) or "",
           "seconds": est.get("seconds", "")}
    interval = estimate_interval(est, share, sharpness)   # the row's reading over the estimate's views resampled
    if interval is not None:
        out.update(row_reading_low=interval.low, row_reading_high=interval.high)
    if metrics:
        frac = estimate_render(est, sharpness).render_ms(share, density) / float(est["c_render_ms"])
        t = row_times(metrics)
        on_row = (t["c_render_ms"] + t["recnn_ms"]) / (t["nets_ms"] + frac * t["c_render_ms"] + t["recnn_ms"])
        out.update(row_render_fraction=t["render_ms"] / t["c_render_ms"], estimate_render_fraction=frac,
                   on_row_times=on_row, on_row_times_error=on_row / measured - 1.0)
    return out


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="estimate.json:share:measured speed-up[:the row's metrics.csv]")
    ap.add_argument("--sharpness", type=float, default=1.0, help="the IMS mask sharpness the rows' ORP kept (default 1)")
    ap.add_argument("--csv", default=None, help="write the comparison here")
    a = ap.parse_args(argv)
    out = []
    for arg in a.rows:
        try:
            head, _, tail = arg.partition(".json:")
            fields = tail.split(":")
            if not _ or len(fields) not in (2, 3):
                raise ValueError("not estimate.json:share:measured[:metrics.csv]")
            row = compare(head + ".json", float(fields[0]), float(fields[1]), a.sharpness,
                          fields[2] if len(fields) == 3 else None)
        except (ValueError, OSError, KeyError) as err:
            raise SystemExit(f"{arg}: expected estimate.json:share:measured speed-up[:metrics.csv] of a readable "
                             f"estimate ({err})")
        out.append(row)
        print(f"{row['scene']} (skip_empty={row['skip_empty']}) at {row['share']:.1%} of C: measured {row['measured']:.2f}x; "
              f"silhouette {row['silhouette']:.2f}x ({row['silhouette'] / row['measured'] - 1:+.0%}), per-pixel model "
              f"{row['per_pixel_model']:.2f}x ({row['per_pixel_model'] / row['measured'] - 1:+.0%}), the estimate (slower) "
              f"{row['slower']:.2f}x ({row['slower_error']:+.0%}); the row's reading (γ = {row['sharpness']:g}) "
              f"{row['row_reading']:.2f}x ({row['row_reading_error']:+.0%})"
              + (f", 95% over its {row['views']} views {row['row_reading_low']:.2f}-{row['row_reading_high']:.2f}x"
                 if "row_reading_low" in row else "")
              + (f"; the mask's render {row['estimate_render_fraction']:.3f} of the pattern (the row's "
                 f"{row['row_render_fraction']:.3f}), on the row's times {row['on_row_times']:.2f}x "
                 f"({row['on_row_times_error']:+.0%})" if "on_row_times" in row else ""), flush=True)
    if a.csv:
        with open(a.csv, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, COLUMNS)
            w.writeheader()
            for row in out:
                w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})  # absent: empty
    return out


if __name__ == "__main__":
    main()
