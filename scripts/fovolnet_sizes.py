"""FoVolNet's size table: the latency half (the before-training estimate, measured here) joined with the quality half
(each candidate trained side by side on a lent GPU, ``scripts/lent_gpu_fovolnet.py``), and the choice it makes.

The choice is the cheapest candidate whose validation PSNR, at the last epoch every candidate reached, is within
``--bound-db`` of the default's (the mean over the default's seeds; their spread is printed beside it). The test
trajectory's PSNR is reported only, never used to choose.

    .venv/bin/python scripts/fovolnet_sizes.py benchmarks/lent/fovolnet_sizes_rayleigh_taylor.json \
        runs/estimate/rayleigh_taylor-fovolnet-0cc9169a/estimate.json --out benchmarks/fovolnet_sizes_rayleigh_taylor

Writes ``<out>.csv``, ``<out>.md`` and ``<out>.png`` (validation PSNR per epoch, one line per candidate) and
prints the markdown table.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

DEFAULT_SIZES = {"features": 16, "base_channels": 16, "filter_channels": 16, "depth": 4, "levels": 3, "kernel_size": 5}
COLUMNS = ["candidate", "features", "base_channels", "filter_channels", "depth", "levels", "kernel_size", "recnn_ms",
           "bound_20", "share_for_target", "val_epoch", "val_psnr", "val_minus_default", "epochs", "test_psnr", "chosen"]


def latency_of(estimate: dict, sizes: dict) -> dict:
    """The estimate's row for these sizes (its candidates list only what differs from the default)."""
    if sizes == DEFAULT_SIZES:
        return {"recnn_ms": estimate["recnn_ms"], "bound_20": next(b["speedup"] for b in estimate["bound"]
                                                                    if abs(b["share"] - 0.2) < 1e-9),
                "share_for_target": estimate.get("share_for_target")}
    for c in estimate.get("candidates", []):
        if {**DEFAULT_SIZES, **c["sizes"]} == sizes:
            return {k: c[k] for k in ("recnn_ms", "bound_20", "share_for_target")}
    raise SystemExit(f"estimate: no candidate with sizes {sizes}; run the estimate with candidates=[...] naming them")


def table(summary: dict, estimate: dict, bound_db: float) -> tuple[list[dict], float, list[float]]:
    cands = summary["candidates"]
    common = min(max(int(e) for e in c["val_psnr"]) for c in cands.values() if c.get("val_psnr"))
    at = {name: c["val_psnr"].get(str(common), c["val_psnr"].get(common)) for name, c in cands.items()}
    defaults = [at[n] for n, c in cands.items() if c["sizes"] == DEFAULT_SIZES]
    if not defaults:
        raise SystemExit("summary: no run of the default FoVolNet to compare with")
    ref = sum(defaults) / len(defaults)
    rows = []
    for name, c in cands.items():
        if c["sizes"] == DEFAULT_SIZES and c.get("seed", 0) != 0:
            continue  # the second seed of the default enters the reference, not the table
        rows.append({"candidate": name, **c["sizes"], **latency_of(estimate, c["sizes"]), "val_epoch": common,
                     "val_psnr": at[name], "val_minus_default": round(at[name] - ref, 3),
                     "epochs": c.get("result", {}).get("epochs"),
                     "test_psnr": round(c.get("result", {}).get("test", {}).get("test/fr_psnr", float("nan")), 3)})
    ok = [r for r in rows if r["val_minus_default"] >= -bound_db]
    best = min(ok, key=lambda r: r["recnn_ms"])
    for r in rows:
        r["chosen"] = r is best
    return sorted(rows, key=lambda r: -r["recnn_ms"]), ref, defaults


def markdown(rows: list[dict], ref: float, defaults: list[float], bound_db: float) -> str:
    head = ("| FoVolNet (features / base / filter, depth, levels, kernel) | RecNN (ms, 2 cores) | bound at 20% of C "
            f"| val PSNR at epoch {rows[0]['val_epoch'] + 1} | − default | test PSNR (epochs) |\n| --- | ---: | ---: | ---: | ---: | ---: |")
    lines = [head]
    for r in rows:
        name = (f"{r['features']} / {r['base_channels']} / {r['filter_channels']}, {r['depth']}, {r['levels']}, "
                f"{r['kernel_size']}" + (" (default)" if r["candidate"] == "default" else ""))
        mark = "**" if r["chosen"] else ""
        lines.append(f"| {mark}{name}{mark} | {r['recnn_ms']:.1f} | {r['bound_20']:.2f}x | {r['val_psnr']:.2f} dB "
                     f"| {r['val_minus_default']:+.2f} dB | {r['test_psnr']:.2f} dB ({r['epochs']}) |")
    spread = max(defaults) - min(defaults)
    lines.append(f"\nReference: the default's validation PSNR, mean of {len(defaults)} seed(s), {ref:.2f} dB "
                 f"(seed spread {spread:.2f} dB). Bold: the cheapest within {bound_db} dB of it.")
    return "\n".join(lines)


def plot(summary: dict, path: Path) -> None:
    from imls_lightning.report.plots import new_figure, save_figure

    fig = new_figure(7.0, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    for name, c in summary["candidates"].items():
        ep = sorted(int(e) for e in c.get("val_psnr", {}))
        ax.plot([e + 1 for e in ep], [c["val_psnr"][str(e)] for e in ep], marker="o", ms=3,
                ls="--" if c.get("seed", 0) else "-", label=name)
    ax.set_xlabel("epoch")
    ax.set_ylabel("validation PSNR (dB)")
    ax.set_title(f"FoVolNet sizes on {summary.get('scene')} at 512², trained side by side on one {summary.get('gpu')}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("summary", type=Path, help="lent_gpu_fovolnet.py's summary.json")
    ap.add_argument("estimate", type=Path, help="the estimate.json of `estimate recnn=fovolnet candidates=[...]`")
    ap.add_argument("--out", type=Path, required=True, help="output stem: <out>.csv, .md, .png")
    ap.add_argument("--bound-db", type=float, default=0.5)
    a = ap.parse_args(argv)
    for p in (a.summary, a.estimate):
        if not p.is_file():
            ap.error(f"{p}: no such file")
    summary, estimate = json.loads(a.summary.read_text()), json.loads(a.estimate.read_text())
    rows, ref, defaults = table(summary, estimate, a.bound_db)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with open(a.out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    md = markdown(rows, ref, defaults, a.bound_db)
    a.out.with_suffix(".md").write_text(md + "\n")
    plot(summary, a.out.with_suffix(".png"))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
