"""Give the rows of ``benchmarks/paper_scale.csv`` measured before ``speedup_interval`` existed their interval,
from the per-view metrics their evaluations left (``metrics.csv``, committed as ``benchmarks/<scene>/eval_*_metrics.csv``).

    python scripts/speedup_intervals.py seed_whole:enhancenet=benchmarks/seed_whole/eval_floor_by_band_metrics.csv ...
    python -m imls_lightning.bench_paper summarize_only=true   # then: the CSV, paper_scale.md and BENCHMARKS.md

Each metrics file is checked against its pair's record in ``paper_scale_pairs.json`` before it is used: the RecNN
alone's and IML/S's mean totals over the timed views must equal the record's (to 0.01%), so a file of another run is
refused in one line. The interval (:func:`imls_lightning.evaluation.speedup.speedup_interval`) goes into the pair's
summary as an evaluation of today would write it (``speedup_interval``), every method over the RecNN alone.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

from data_gen.atomic import atomic_json
from data_gen.errors import InputError
from imls_lightning.evaluation.speedup import paired_totals, speedup_intervals


def check_matches(rows: list[dict], summary: dict, source: str) -> None:
    """Refuse ``rows`` unless the RecNN alone's and IML/S's mean totals are the summary's (the same run)."""
    for method in ("recnn", "imls"):
        slow, fast = paired_totals(rows, method, method)
        recorded = float(summary["methods"].get(method, {}).get("latency_ms", {}).get("total", math.nan))
        mean = sum(slow) / len(slow) if slow else math.nan
        if not (math.isfinite(mean) and math.isfinite(recorded) and abs(mean - recorded) <= 1e-4 * recorded):
            raise InputError(f"{source}: {method}'s mean total over its timed views is {mean:.2f} ms, the pair's record "
                             f"says {recorded:.2f} ms: not the metrics of that row's evaluation")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", metavar="SCENE:RECNN=METRICS_CSV")
    ap.add_argument("--records", default="benchmarks/paper_scale_pairs.json", help="the benchmark's pair records")
    args = ap.parse_args(argv)
    path = Path(args.records)
    try:
        records = json.loads(path.read_text(encoding="utf-8"))
        for item in args.pairs:
            pair, sep, source = item.partition("=")
            scene, colon, recnn = pair.partition(":")
            if not (sep and colon and scene and recnn and source):
                raise InputError(f"{item!r}: expected SCENE:RECNN=METRICS_CSV")
            name = f"{scene}, {recnn}"
            if name not in records:
                raise InputError(f"{path}: no pair {name!r} (it has {', '.join(records)})")
            try:
                with open(source, newline="", encoding="utf-8") as f:
                    rows = list(csv.DictReader(f))
            except OSError as err:
                raise InputError(f"{source}: cannot read it ({err.strerror})") from None
            summary = records[name]["summary"]
            check_matches(rows, summary, source)
            summary["speedup_interval"] = speedup_intervals(rows)
            iv = summary["speedup_interval"]["imls"]
            print(f"{name}: IML/S {iv['speedup']:.3f}x, 95% interval {iv['low']:.3f}-{iv['high']:.3f}x over {iv['views']} timed views")
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    atomic_json(path, records, indent=1, sort_keys=False)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
