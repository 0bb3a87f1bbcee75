"""Does an operating point keep its promise on the test trajectory? The ORP searched several ways, each tested.

For one finished evaluation (its ``config.yaml``: scene, cache, checkpoints, settings), each variant searches the ORP
on the product path exactly as the evaluation does (:func:`imls_lightning.evaluation.operating_point.product_path_orp`:
the search views of ``orp_views``, the bound at ``orp_confidence``, in each of ``orp_strata`` bands of camera
distance; with ``orp_by_distance`` a mean value per band), then runs IML/S at that point on the evaluation's test-trajectory views and reports the gap to the
RecNN alone there, overall and by camera distance. The test views only score the chosen points; nothing is chosen on
them. IML/S runs here on the cached pixels (what the selective ray cast returns) in float32, so the first variant
(the evaluation's own settings) also checks this against the evaluation's measured test gap.

    .venv/bin/python scripts/orp_promise.py runs/paper/eval/seed_shell-enhancenet-fe47d42a \\
        --variant orp_views=path --variant orp_views=path,orp_strata=4 \\
        --variant orp_views=path,orp_strata=4,orp_by_distance=true --json benchmarks/orp_promise_seed_shell.json

Prints a markdown table; ``--json`` writes the rows. ``--two-pass``: for each variant also the classical two-pass
sampler's share, searched as the evaluation searches it (:func:`imls_lightning.evaluation.two_pass.two_pass_point`: a
share per band of camera distance with ``orp_by_distance``), tested the same way on the cached test views.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

KEYS = {"orp_views": str, "orp_strata": int, "orp_confidence": float, "orp_max_views": int, "orp_views_seed": int, "orp_paths": int,
        "orp_by_distance": lambda v: v.lower() in ("1", "true", "yes")}


def parse_variant(text: str) -> dict:
    """``"orp_views=path,orp_strata=4"`` -> ``{"orp_views": "path", "orp_strata": 4}`` (keys of :data:`KEYS`)."""
    out = {}
    for part in filter(None, text.split(",")):
        key, _, value = part.partition("=")
        if key not in KEYS:
            raise SystemExit(f"--variant {text}: {key!r} is not one of {list(KEYS)}")
        out[key] = KEYS[key](value)
    return out


def test_gap(nets, cache, rows, pattern, u, lift: bool) -> dict:
    """IML/S at ``(u, lift)`` against the RecNN alone on ``rows``: per-view gaps, the paired mean, by distance.
    ``u``: a mean value, or a module view ``(B, 9)`` -> ``u`` ``(B,)`` (a
    :class:`~imls_lightning.models.ims.DistanceMeans`: each view at its band's)."""
    from imls_lightning.core.metrics import psnr_per_image
    from imls_lightning.evaluation.measurement import view_loader
    from imls_lightning.evaluation.operating_point import camera_distance

    head, decoder, recnn = nets.ims_task.mask_head, nets.ims_task.decoder, nets.recnn.eval()
    gaps, shares = [], []
    with torch.inference_mode():
        for b in view_loader(cache, rows, pattern):
            c, fr = b["c"], b["fr"]
            v = b["view"].float()
            per_view = u(v) if isinstance(u, torch.nn.Module) else torch.full((c.shape[0],), float(u))
            im = head.threshold(head.generator(v).float(), per_view, lift).float()
            gaps += (psnr_per_image(recnn(c), fr) - psnr_per_image(recnn(decoder(im * c, im)), fr)).tolist()
            shares += (im.flatten(1).sum(1) / head.valid.sum()).tolist()
    d = np.array([camera_distance(cache, r) for r in rows])
    g = np.array(gaps)
    quarters = [float(g[part].mean()) for part in np.array_split(np.argsort(d, kind="stable"), 4)]
    return {"test_gap_db": float(g.mean()), "test_gap_std_db": float(g.std(ddof=1)), "test_c_share": float(np.mean(shares)),
            "test_gap_by_distance_quarter_db": quarters, "test_views": len(gaps), "test_gaps_db": g.tolist()}


def two_pass_test(s, cfg, cache, scene, nets, pattern, rows) -> dict:
    """The two-pass sampler's share searched as the evaluation does, then its gap to the RecNN alone on ``rows`` (the
    cached pixels: :func:`~imls_lightning.estimate.needed_share.share_gaps` with its first pass, each view at its
    band's share): the search's record and bands, the test gap, its C-share and the gap by distance quarter."""
    from imls_lightning.estimate.needed_share import share_gaps
    from imls_lightning.evaluation.operating_point import camera_distance
    from imls_lightning.evaluation.two_pass import two_pass_method, two_pass_point

    point = two_pass_point(s, cfg, cache, scene, nets, pattern, "cpu", future_views=len(rows))
    method = two_pass_method(point, None, pattern, nets.recnn, None)  # for its share per view only: no ray is cast
    recnn = nets.recnn.eval()
    gaps, kept, one = [], [], []
    for r in rows:
        share = method.share_for(np.asarray(cache.views[r], np.float64))
        both = sorted({share, point.share})  # its band's share, and the one share that held in every band
        k, g = share_gaps(lambda c: recnn(c).float(), pattern, [np.asarray(cache.images[r])], both,
                          floor=point.floor, base=point.base)
        gaps.append(float(g[0, both.index(share)]))
        kept.append(float(k[0, both.index(share)]))
        one.append(float(g[0, both.index(point.share)]))
    d = np.array([camera_distance(cache, r) for r in rows])
    g = np.array(gaps)
    return {"shares": method.shares, "share": point.share, "record": point.record, "by_distance": point.by_distance,
            "test_gap_db": float(g.mean()), "test_c_share": float(np.mean(kept)), "test_gap_one_share_db": float(np.mean(one)),
            "test_gap_by_distance_quarter_db": [float(g[part].mean()) for part in np.array_split(np.argsort(d, kind="stable"), 4)]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("evaluation", type=Path, help="a finished evaluation's folder (config.yaml, summary.json)")
    ap.add_argument("--variant", action="append", default=[], help="search settings, e.g. orp_views=path,orp_strata=4 "
                    "(repeatable; the evaluation's own settings always come first)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    ap.add_argument("--two-pass", action="store_true", help="also search and test the two-pass sampler's share per variant")
    a = ap.parse_args(argv)
    from data_gen.scene import build_scene
    from data_gen.scene import register_resolvers as register_scene_resolvers
    from imls_lightning.config import register_resolvers
    from imls_lightning.evaluation.networks import load_networks
    from imls_lightning.evaluation.operating_point import distance_means, product_path_orp
    from imls_lightning.evaluation.run import open_views
    from imls_lightning.evaluation.settings import parse_settings

    register_resolvers()
    register_scene_resolvers()
    conf = OmegaConf.load(a.evaluation / "config.yaml")
    summary = json.loads((a.evaluation / "summary.json").read_text())
    cfg = OmegaConf.merge(conf, conf.settings, {"progress": False, "reuse": False, "output_dir": None})
    s = parse_settings(cfg)
    scene = build_scene(cfg.scene)
    nets = load_networks(s, int(cfg.data.resolution))
    pattern = nets.ims_task.pattern
    cache, rows_all, positions = open_views(cfg, s, scene, int(cfg.data.resolution))
    rows = [int(rows_all[p]) for p in positions]
    measured = (summary.get("orp") or {}).get("test") or {}
    out = []
    for variant in [{}, *map(parse_variant, a.variant)]:
        sv = dataclasses.replace(s, **variant)
        t = time.perf_counter()
        res = product_path_orp(sv, cfg, cache, scene, nets, pattern, "cpu", future_views=len(positions))
        rec = res.best.record if res.best is not None else {}
        row = {"variant": ",".join(f"{k}={v}" for k, v in variant.items()) or "the evaluation's own",
               "orp_views": sv.orp_views, "orp_strata": sv.orp_strata, "orp_confidence": sv.orp_confidence,
               "found": res.found, "mean": res.mean, "lift": bool(res.lifted), "search_gap_db": rec.get("gap_db"),
               "search_bound_db": rec.get("gap_bound_db"), "search_c_share": rec.get("c_share"),
               "search_strata_gap_db": rec.get("strata_gap_db"), "by_distance": getattr(res, "by_distance", None)}
        if res.found:
            sched = distance_means(res)
            row.update(test_gap(nets, cache, rows, pattern, res.mean if sched is None else sched, bool(res.lifted)))
        if a.two_pass:
            row["two_pass"] = two_pass_test(sv, cfg, cache, scene, nets, pattern, rows)
        row["seconds"] = round(time.perf_counter() - t, 1)
        if not variant:
            row["evaluation_test_gap_db"] = measured.get("gap_db")
            row["evaluation_two_pass_test_gap_db"] = ((summary.get("two_pass") or {}).get("test") or {}).get("gap_db")
        out.append(row)
        print(json.dumps(row, default=float), file=sys.stderr, flush=True)
    print(f"\n{summary.get('scene')} / {summary.get('recnn')}: ORP variants, each tested on {len(rows)} test-trajectory views\n")
    print("| search | strata | u (lifted) | search gap / bound | search C-share | test gap | test C-share | test gap by distance quarter (near → far) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for r in out:
        if not r["found"]:
            print(f"| {r['orp_views']} | {r['orp_strata']} | none | – | – | – | – | – |")
            continue
        q = " / ".join(f"{x:.2f}" for x in r["test_gap_by_distance_quarter_db"])
        u = f"{r['mean']:.3f}" if not r.get("by_distance") else " / ".join(f"{x:.3f}" for x in r["by_distance"]["means"])
        print(f"| {r['orp_views']} | {r['orp_strata']} | {u}{' (lifted)' if r['lift'] else ''} | "
              f"{r['search_gap_db']:.2f} / {r['search_bound_db']:.2f} dB | {r['search_c_share']:.1%} | **{r['test_gap_db']:.2f} dB** | "
              f"{r['test_c_share']:.1%} | {q} |")
    if a.two_pass:
        print("\nThe two-pass sampler, its share searched as the evaluation searches it, on the same test views:\n")
        print("| search | strata | share of C (near → far) | search gap / bound | test gap | test C-share | test gap by distance quarter (near → far) "
              "| test gap at the one share |")
        print("| --- | ---: | --- | ---: | ---: | ---: | --- | ---: |")
        for r in out:
            tp = r["two_pass"]
            shares = " / ".join(f"{x:.0%}" for x in tp["shares"])
            q = " / ".join(f"{x:.2f}" for x in tp["test_gap_by_distance_quarter_db"])
            rec = tp["record"] or {}
            print(f"| {r['orp_views']} | {r['orp_strata']} | {shares} | {rec.get('gap_db', float('nan')):.2f} / "
                  f"{rec.get('gap_bound_db', float('nan')):.2f} dB | **{tp['test_gap_db']:.2f} dB** | {tp['test_c_share']:.1%} | {q} "
                  f"| {tp['test_gap_one_share_db']:.2f} dB at {tp['share']:.0%} |")
    if a.two_pass and out and out[0].get("evaluation_two_pass_test_gap_db") is not None:
        print(f"\nCheck: the evaluation measured the two-pass sampler's test gap at {out[0]['evaluation_two_pass_test_gap_db']:.2f} dB "
              f"(its one share, selective ray cast); here {out[0]['two_pass']['test_gap_one_share_db']:.2f} dB at "
              f"{out[0]['two_pass']['share']:.0%} of C.")
    if out and out[0].get("evaluation_test_gap_db") is not None and out[0]["found"]:
        print(f"\nCheck: the evaluation measured a test gap of {out[0]['evaluation_test_gap_db']:.2f} dB at its own ORP "
              f"(selective ray cast, its network options); here {out[0]['test_gap_db']:.2f} dB.")
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
