"""The before-training estimate's speed-up against the product's measured one, per render prediction.

    python scripts/estimate_vs_measured.py benchmarks/estimate_check/ct_head.json:0.806066:0.802192 ...

Each argument is ``estimate.json:share:measured speed-up`` (the share and speed-up of a row of
``benchmarks/paper_scale.csv``, or of an evaluation's summary). For each it prints, and writes as CSV with
``--csv``, the speed-up at that share from the silhouette mask's measured render, from the per-pixel model, and
from the slower of the two (the estimate's bound, :func:`imls_lightning.estimate.slower_render`), each with its
error against the measured speed-up (issue 31 asks within 15%).
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COLUMNS = ("estimate", "scene", "skip_empty", "share", "measured", "silhouette", "per_pixel_model", "slower", "slower_error")


def compare(path: str, share: float, measured: float) -> dict:
    from imls_lightning.estimate import RenderCost, RenderCurve, slower_render, speedup_at

    est = json.loads(Path(path).read_text())
    model, silhouette = RenderCost(**est["render_cost"]), RenderCurve(**est["render_curve"])
    if "silhouette_ms" in est:  # an estimate whose render_curve is already the slower one: its silhouette is kept apart
        silhouette = RenderCurve(silhouette.shares, tuple(est["silhouette_ms"]), silhouette.fixed_ms)
    kw = {"c_render_ms": est["c_render_ms"], "nets_ms": est["nets_ms"], "recnn_ms": est["recnn_ms"]}
    density = est["background_density"]
    slower = speedup_at(slower_render(silhouette, model, density), share, **kw)
    return {"estimate": path, "scene": est["scene"], "skip_empty": est["settings"]["renderer"].get("skip_empty", True),
            "share": share, "measured": measured, "silhouette": speedup_at(silhouette, share, **kw),
            "per_pixel_model": speedup_at(model, share, **kw, background_density=density), "slower": slower,
            "slower_error": slower / measured - 1.0}


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="estimate.json:share:measured speed-up")
    ap.add_argument("--csv", default=None, help="write the comparison here")
    a = ap.parse_args(argv)
    out = []
    for arg in a.rows:
        try:
            path, share, measured = arg.rsplit(":", 2)
            row = compare(path, float(share), float(measured))
        except (ValueError, OSError, KeyError) as err:
            raise SystemExit(f"{arg}: expected estimate.json:share:measured speed-up of a readable estimate ({err})")
        out.append(row)
        print(f"{row['scene']} (skip_empty={row['skip_empty']}) at {row['share']:.1%} of C: measured {row['measured']:.2f}x; "
              f"silhouette {row['silhouette']:.2f}x ({row['silhouette'] / row['measured'] - 1:+.0%}), per-pixel model "
              f"{row['per_pixel_model']:.2f}x ({row['per_pixel_model'] / row['measured'] - 1:+.0%}), the estimate (slower) "
              f"{row['slower']:.2f}x ({row['slower_error']:+.0%})", flush=True)
    if a.csv:
        with open(a.csv, "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, COLUMNS)
            w.writeheader()
            for row in out:
                w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})
    return out


if __name__ == "__main__":
    main()
