"""A finished evaluation's operating point with its object floor chosen again per band of camera distance.

The evaluation's ``orp_object_floor`` keeps one margin for every view, chosen so that the bound holds in every quarter
of camera distance; on seed_whole the close-ups need 0.12 and the views from afar nothing, so the far views pay for
the near ones. This reruns only that choice, with the product's own function
(:func:`~imls_lightning.evaluation.operating_point.object_floor_point` with ``orp_object_floor_by_band`` and
``orp_object_floor_tail``), on the evaluated cache's validation views at the evaluation's searched bands; reports the
result on the evaluation's test-trajectory views (never chosen on: gap, share, views over epsilon, by band); and
records the point beside a copy of the IMS checkpoint in ``--out``, so that ``scripts/retime_orp.py`` times the product
at it (``IMLSRenderer.from_checkpoints`` reads the record). The evaluation's own record is left as it is.

    .venv/bin/python scripts/object_floor_by_band.py runs/paper/eval/seed_whole-enhancenet-aca5ee79 \\
        --margins 0 0.02 0.04 0.06 0.08 0.1 0.12 0.14 0.16 0.2 --tail 0.1 --out runs/paper/by_band \\
        --json benchmarks/seed_whole/object_floor_by_band.json
    .venv/bin/python scripts/retime_orp.py runs/paper/by_band/<ims>.ckpt <cache> --views 12 --repeats 10
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def test_record(nets, cache, rows, pattern, bands, floor: dict, epsilon: float) -> dict:
    """IML/S + RecNN at the bands with the chosen floor on ``rows`` (the product's record, per view): the mean gap,
    share of C, views over ``epsilon`` and the same by band."""
    from imls_lightning.evaluation.measurement import view_loader
    from imls_lightning.inference.baselines import product_point
    from imls_lightning.models.iml import FillDecoder

    chosen = floor.get("chosen")
    head = nets.ims_task.mask_head.with_object_floor(None if chosen is None else chosen["margin"], floor["tau"])
    batches = list(view_loader(cache, rows, pattern))
    rec = product_point(head, nets.ims_task.decoder, nets.recnn.eval(), batches, bands, lift=True, per_view=True)
    # the simplest alternative on the same pixels: the untrained pull-push fill in place of the decoder
    fill = product_point(head, FillDecoder(pattern), nets.recnn.eval(), batches, bands, lift=True, per_view=True)
    views = torch.as_tensor(np.stack([np.asarray(cache.views[r], np.float32) for r in rows]))
    label = bands.band(views).numpy()
    g, s = np.asarray(rec["gaps_db"]), np.asarray(rec["c_shares"])
    k = int(bands.means.numel())
    return {"views": len(rows), "gap_db": float(g.mean()), "c_share": float(s.mean()), "worst_gap_db": float(g.max()),
            "views_over_epsilon": int((g > epsilon).sum()), "psnr_imls": rec["psnr_imls"], "psnr_recnn": rec["psnr_recnn"],
            "band_views": [int((label == b).sum()) for b in range(k)],
            "band_gap_db": [float(g[label == b].mean()) if (label == b).any() else None for b in range(k)],
            "band_c_share": [float(s[label == b].mean()) if (label == b).any() else None for b in range(k)],
            "band_views_over_epsilon": [int((g[label == b] > epsilon).sum()) for b in range(k)],
            "fill": {"gap_db": float(np.mean(fill["gaps_db"])), "psnr": fill["psnr_imls"],
                     "views_over_epsilon": int((np.asarray(fill["gaps_db"]) > epsilon).sum())}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("evaluation", type=Path, help="a finished evaluation's folder (config.yaml, summary.json) with a by-distance ORP")
    ap.add_argument("--margins", type=float, nargs="+", default=[0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.2])
    ap.add_argument("--tail", type=float, default=0.1,
                    help="the share of a band's validation views a margin may leave over epsilon (1: the bound alone)")
    ap.add_argument("--out", type=Path, required=True, help="a folder for the IMS checkpoint's copy and its record")
    ap.add_argument("--json", type=Path, help="write the choice and the test-trajectory record here")
    a = ap.parse_args(argv)
    if not all(0 <= m <= 1 for m in a.margins) or not 0 <= a.tail <= 1:
        ap.error("--margins and --tail must lie in [0, 1]")
    import importlib.util

    from imls_lightning.evaluation.operating_point import distance_means, object_floor_point, record_operating_point

    spec = importlib.util.spec_from_file_location("object_floor", ROOT / "scripts" / "object_floor.py")
    object_floor = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(object_floor)
    summary, orp, s, nets, pattern, cache, rows_all, positions = object_floor.open_evaluation(a.evaluation)
    s = dataclasses.replace(s, orp_object_floor=sorted(set(a.margins)), orp_object_floor_by_band=True,
                            orp_object_floor_tail=float(a.tail))
    point = SimpleNamespace(by_distance=orp["by_distance"], mean=float(orp["mean"]), lifted=True, object_floor=None)
    with torch.inference_mode():
        floor = object_floor_point(s, cache, nets, pattern, "cpu", point, orp.get("future_views"))
        point.object_floor = floor
        bands = distance_means(point)
        test = test_record(nets, cache, [int(rows_all[p]) for p in positions], pattern, bands, floor, s.epsilon_db)
    a.out.mkdir(parents=True, exist_ok=True)
    ck = a.out / Path(s.ims).name
    shutil.copy(s.ims, ck)
    record_operating_point(dataclasses.replace(s, ims=str(ck)), {**orp, "object_floor": floor}, summary.get("scene"),
                           a.evaluation / "report.md", int(orp.get("views") or 0))
    c = floor["chosen"]
    margins = "no floor" if c is None else " / ".join("none" if m is None else f"{m:g}" for m in c["band_margins"])
    print(f"\n{summary.get('scene')}: object floor by band (near to far) {margins}, tail {a.tail:g}; "
          f"the evaluation's one margin: {((orp.get('object_floor') or {}).get('chosen') or {}).get('margin')}")
    if c is not None:
        print(f"validation ({c['views']} views, chosen here): {c['c_share']:.1%} of C, gap {c['gap_db']:.2f} dB, "
              f"bound {c['gap_bound_db']:.2f} dB, {c['views_over_epsilon']} views over {s.epsilon_db:g} dB")
    print(f"test trajectory ({test['views']} views, never chosen on): {test['c_share']:.1%} of C, gap {test['gap_db']:.2f} dB "
          f"(worst {test['worst_gap_db']:.2f}), {test['views_over_epsilon']} views over {s.epsilon_db:g} dB; by band: "
          + " | ".join(f"{n} views, {sh:.1%}, {g:.2f} dB, {o} over" for n, sh, g, o in
                       zip(test["band_views"], test["band_c_share"], test["band_gap_db"], test["band_views_over_epsilon"])
                       if n)
          + f"; the IMS mask + pull-push fill instead of the decoder: gap {test['fill']['gap_db']:.2f} dB, "
          f"{test['fill']['views_over_epsilon']} views over")
    if a.json:
        from data_gen.atomic import atomic_json

        a.json.parent.mkdir(parents=True, exist_ok=True)
        atomic_json(a.json, {"evaluation": str(a.evaluation), "margins": sorted(set(a.margins)), "tail": a.tail,
                             "object_floor": floor, "test": test, "checkpoint": str(ck)})
    print(ck)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
