"""Does a floor on each view's share, from the object the IMS sees, keep the 1 dB promise where a band's share does not?

seed_whole's failing test views had a share within a few points of their own object's fraction of C
(BENCHMARKS.md, "seed_whole's failing views"). Here each view runs at ``u = max(u_band, object + margin)``, where
``object`` is the fraction of the pattern's C-pixels whose IMS PIM' (from the view alone) exceeds ``--tau``, and
``u_band`` is the finished evaluation's ORP for the view's band of camera distance (its masks lifted, so a view's
share is its ``u``). For each margin, on the cache's validation views (where a margin is chosen) and then on the
evaluation's test-trajectory views (never chosen on): the mean gap to the RecNN alone, the views over ``epsilon``,
the mean share of C, and the gap by distance quarter. IML/S runs on the cached pixels in float32, as in
``scripts/orp_promise.py``; a margin of ``none`` is the evaluation's own operating point.

    .venv/bin/python scripts/object_floor.py runs/paper/eval/seed_whole-enhancenet-5c0076b2 \\
        --margins 0 0.05 0.1 --json benchmarks/seed_whole/object_floor.json

The chosen point: of those whose validation views keep the promise in every quarter of camera distance, judged as the
ORP search judges a band (by the 95% upper bound on its mean gap, for a quarter of the test views), the one with the
smallest mean share of C. ``--band-scales 0.8 0.9 1`` also lets the bands' u fall under the floor (a joint search).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _orp_promise():
    spec = importlib.util.spec_from_file_location("orp_promise", ROOT / "scripts" / "orp_promise.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class ObjectFloor(torch.nn.Module):
    """View ``(B, 9)`` -> ``u`` ``(B,)``: the band's mean value, raised to the object's predicted fraction of the
    pattern plus ``margin`` where that is larger (at most 1). ``bands``: a view -> u module
    (:class:`~imls_lightning.models.ims.DistanceMeans`); ``generator``: the IMS's (view -> ``g`` in [-1, 1]);
    ``valid``: the pattern's C-pixels ``(n, n)``; ``margin`` None: the bands alone.

    Example:
        >>> class Flat(torch.nn.Module):
        ...     def forward(self, v):   # PIM' 0.9 on the left half, 0 elsewhere
        ...         g = -torch.ones(v.shape[0], 1, 4, 4); g[..., :2] = 0.8; return g
        >>> f = ObjectFloor(lambda v: torch.full((v.shape[0],), 0.3), Flat(), torch.ones(4, 4, dtype=torch.bool), 0.1, 0.2)
        >>> [round(u, 2) for u in f(torch.zeros(2, 9)).tolist()]
        [0.6, 0.6]
    """

    def __init__(self, bands, generator, valid: torch.Tensor, margin: float | None, tau: float):
        super().__init__()
        self.bands, self.generator, self.margin, self.tau = bands, generator, margin, float(tau)
        self.register_buffer("valid", valid.bool())

    def object_fraction(self, views: torch.Tensor) -> torch.Tensor:
        from imls_lightning.core.importance import object_fraction

        return object_fraction((self.generator(views).float() + 1) / 2, self.valid, self.tau)

    def forward(self, views: torch.Tensor) -> torch.Tensor:
        # the product's formula (IMSMaskHead's object_floor; the evaluation's orp_object_floor), on the bands' u
        from imls_lightning.core.importance import floored_mean

        u = self.bands(views).float()
        if self.margin is None:
            return u
        return floored_mean(u, self.object_fraction(views), self.margin)


def quarter_bounds(gaps: np.ndarray, distances: np.ndarray, confidence: float, future_views: int | None) -> list[float]:
    """The upper bound on the mean gap in each quarter of the views by camera distance, near to far: the ORP search's
    (:func:`~imls_lightning.orp.gap_upper_bound`, for ``future_views`` new views of a quarter)."""
    from imls_lightning.orp.search import gap_upper_bound

    return [gap_upper_bound(gaps[part], confidence, future_views).bound
            for part in np.array_split(np.argsort(distances, kind="stable"), 4)]


def floor_rows(test_gap, nets, cache, rows, pattern, bands, margins, tau: float, epsilon: float,
               confidence: float, future_views: int | None = None, scales=(1.0,)) -> list[dict]:
    """For each scale of the bands' u and each margin (None first: the bands alone), IML/S at the floored u on
    ``rows``."""
    from imls_lightning.evaluation.operating_point import camera_distance

    n = pattern.c_size
    valid = nets.ims_task.valid.bool().view(n, n)
    distances = np.array([camera_distance(cache, r) for r in rows])
    out = []
    for scale in scales:
        scaled = (lambda v, k=float(scale): (bands(v) * k).clamp(0.01, 1.0)) if scale != 1.0 else bands
        for m in [None, *margins]:
            floor = ObjectFloor(scaled, nets.ims_task.generator, valid, m, tau)
            r = test_gap(nets, cache, rows, pattern, floor, True)
            gaps = np.asarray(r.pop("test_gaps_db"))
            out.append({"band_scale": float(scale), "margin": m, **r, "views_over_epsilon": int((gaps > epsilon).sum()),
                        "worst_gap_db": float(gaps.max()), "quarter_bounds_db": quarter_bounds(gaps, distances, confidence,
                                                                                                future_views)})
    return out


def choose(rows: list[dict], epsilon: float) -> int | None:
    """Of ``rows`` whose bound on the mean gap stays within ``epsilon`` in every distance quarter (the ORP search's
    criterion, per quarter), the one with the smallest mean share of C (the fastest): its index; None when none
    holds. Ties go to the earlier row."""
    from imls_lightning.evaluation.operating_point import choose_object_floor

    return choose_object_floor([{"gap_bound_db": max(r["quarter_bounds_db"]), "c_share": r["test_c_share"]} for r in rows],
                               epsilon)


def open_evaluation(evaluation: Path):
    """A finished evaluation's folder, opened as it ran: ``(summary, orp, settings, networks, pattern, cache, rows,
    positions)``, its IMS at the ORP's sharpness. Exits with one line unless its ORP was found by distance bands with
    lifted masks. The folder's ``orp_object_floor`` (the record of its candidates) is left out of the settings."""
    from data_gen.scene import build_scene
    from data_gen.scene import register_resolvers as register_scene_resolvers
    from imls_lightning.config import register_resolvers
    from imls_lightning.evaluation.networks import load_networks
    from imls_lightning.evaluation.run import open_views
    from imls_lightning.evaluation.settings import parse_settings

    register_resolvers()
    register_scene_resolvers()
    summary = json.loads((evaluation / "summary.json").read_text())
    orp = summary.get("orp") or {}
    if not orp.get("found") or not orp.get("by_distance") or not orp.get("lift"):
        raise SystemExit(f"error: {evaluation}: expected an ORP found by distance bands with lifted masks")
    conf = OmegaConf.load(evaluation / "config.yaml")
    cfg = OmegaConf.merge(conf, conf.settings, {"progress": False, "reuse": False, "output_dir": None})
    cfg.orp_object_floor = None
    s = parse_settings(cfg)
    scene = build_scene(cfg.scene)
    nets = load_networks(s, int(cfg.data.resolution))
    nets.ims_task.mask_sharpness = float(orp.get("sharpness") or 1.0)
    cache, rows, positions = open_views(cfg, s, scene, int(cfg.data.resolution))
    return summary, orp, s, nets, nets.ims_task.pattern, cache, rows, positions


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("evaluation", type=Path, help="a finished evaluation's folder (config.yaml, summary.json) with a by-distance ORP")
    ap.add_argument("--margins", type=float, nargs="+", default=[0.0, 0.05, 0.1])
    ap.add_argument("--band-scales", type=float, nargs="+", default=[1.0],
                    help="also scale the bands' u by these (a floor may let the bands fall: a joint search)")
    ap.add_argument("--tau", type=float, default=0.2, help="PIM' above this counts as the object (its background sits near 0.02)")
    ap.add_argument("--confidence", type=float, default=0.95, help="the bound on each quarter's mean gap (the ORP search's)")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    if not all(0 <= m <= 1 for m in a.margins) or not 0 < a.tau < 1 or not 0 < a.confidence < 1:
        ap.error("--margins must lie in [0, 1], --tau and --confidence in (0, 1)")
    if not all(0 < k <= 2 for k in a.band_scales):
        ap.error("--band-scales must lie in (0, 2]")
    op = _orp_promise()
    from imls_lightning.models.ims import DistanceMeans

    summary, orp, s, nets, pattern, cache, rows_all, positions = open_evaluation(a.evaluation)
    bands = DistanceMeans(orp["by_distance"]["edges"], orp["by_distance"]["means"])
    eps = float(orp.get("epsilon_db", 1.0))
    splits = {"val": [int(r) for r in cache.splits["val"]], "test": [int(rows_all[p]) for p in positions]}
    result = {}
    with torch.inference_mode():
        for name, rows in splits.items():
            # the bound a quarter of validation views puts on a quarter of the test trajectory's views
            result[name] = floor_rows(op.test_gap, nets, cache, rows, pattern, bands, a.margins, a.tau, eps, a.confidence,
                                      future_views=max(1, len(splits["test"]) // 4), scales=a.band_scales)
            print(f"[object-floor] {name}: {len(rows)} views done", file=sys.stderr, flush=True)
    pick = choose(result["val"], eps)
    chosen = None if pick is None else (result["val"][pick]["band_scale"], result["val"][pick]["margin"])
    print(f"\n{summary.get('scene')} / {summary.get('recnn')}: u = max(band's u, the IMS's object (PIM' > {a.tau:g}) + margin)\n")
    print("| bands' u x | margin | views | mean gap | gap by distance quarter (near → far) | its 95% bound | views over 1 dB | "
          "worst | mean share of C |")
    print("| ---: | --- | --- | ---: | --- | --- | ---: | ---: | ---: |")
    for name in ("val", "test"):
        for r in result[name]:
            m = "bands alone" if r["margin"] is None else f"{r['margin']:.2f}"
            mark = " (chosen)" if chosen == (r["band_scale"], r["margin"]) else ""
            q = " / ".join(f"{x:.2f}" for x in r["test_gap_by_distance_quarter_db"])
            print(f"| {r['band_scale']:.2f} | {m}{mark} | {name} ({r['test_views']}) | "
                  f"{r['test_gap_db']:.2f} dB | {q} | {' / '.join(f'{x:.2f}' for x in r['quarter_bounds_db'])} | "
                  f"{r['views_over_epsilon']} | {r['worst_gap_db']:.2f} dB | {r['test_c_share']:.1%} |")
    print("\nchosen on the validation views: " + ("nothing keeps the promise" if chosen is None else
                                                  f"the bands' u x {chosen[0]:.2f}, " +
                                                  ("no floor" if chosen[1] is None else f"margin {chosen[1]:.2f}")))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"tau": a.tau, "confidence": a.confidence,
                                      "chosen": None if chosen is None else {"band_scale": chosen[0], "margin": chosen[1]},
                                      **result}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
