"""How well does the estimate's needed share predict a trained pair's ORP? The same untrained importance and fill
(:mod:`imls_lightning.estimate.needed_share`), rebuilt by the trained RecNN on a cache's test views.

The estimate measures the needed share before any cache, with a RecNN trained for a few hundred steps, on three
random views. This scores the same masks with the pair's trained RecNN on the test trajectory the pair was
evaluated on, so the two differences can be read apart: the quick RecNN against the trained one, and the untrained
importance and fill against the trained IMS and decoder (the ORP the evaluation measured). Prints the mean gap per
share, the protocol's 95% bound on it (``--future-views`` new views) and the needed share within ``--epsilon``;
``--json`` writes them.

``--base B`` scores the classical two-pass sampler instead (:class:`imls_lightning.inference.two_pass.TwoPassFill`):
the importance from a blue-noise first pass of ``B`` of C only. Choose its share on ``--split val`` (the smallest
share whose bound is within epsilon), then read that share on the test views. ``--time SHARE`` times it against the
RecNN alone in the same run (the scene's renderer rebuilt from the cache's manifest); against the product too with
``scripts/retime_orp.py --two-pass SHARE --base B``.

    python scripts/needed_share_check.py cache/ct_head-a1e18fbae574 runs/paper/recnn-enhancenet-ct_head-ef962bac
    python scripts/needed_share_check.py cache/ct_head-a1e18fbae574 runs/paper/recnn-enhancenet-ct_head-ef962bac \
        --split val --views 40 --base 0.2
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.atomic import atomic_json  # noqa: E402
from data_gen.cache_reader import ViewImageCache  # noqa: E402
from data_gen.errors import InputError, cli_errors  # noqa: E402
from imls_lightning.core.patterns import build_pattern  # noqa: E402
from imls_lightning.estimate.needed_share import NEEDED_SHARES, first_share_within, share_gaps  # noqa: E402
from imls_lightning.inference.checkpoints import load_recnn  # noqa: E402
from imls_lightning.orp.search import gap_upper_bound  # noqa: E402


def time_two_pass(cache, recnn, pattern, share: float, base: float, floor: float, views: int, repeats: int) -> dict:
    """The two-pass sampler against the RecNN alone, alternated run by run on ``views`` test views (medians of
    ``repeats`` runs per view, mean over views); printed as a table and returned."""
    from data_gen.renderers import make_renderer
    from imls_lightning.evaluation.measurement import image_quality, spaced
    from imls_lightning.inference.pipeline import NetOptions, RecNNAlone
    from imls_lightning.inference.two_pass import TwoPassFill

    if views < 1 or repeats < 1:
        raise InputError(f"--time-views={views}, --repeats={repeats}: expected at least 1 each")
    renderer = make_renderer(cache.scene(), cache.manifest["renderer"]["pixel_settings"])
    opts = NetOptions.from_config({"half": "auto"})
    methods = {"RecNN alone": RecNNAlone(renderer, pattern, recnn, opts),
               f"two passes ({base:.0%} first) + fill + RecNN": TwoPassFill(renderer, pattern, recnn, share=share,
                                                                           base=base, floor=floor, opts=opts)}
    test = np.asarray(cache.splits["test"])
    stages = ("low_res_render", "importance", "selective_render", "decoder", "recnn", "total")
    per = {k: [] for k in methods}
    quality = {k: [] for k in methods}
    with torch.inference_mode():
        for row in test[spaced(len(test), views)]:
            view = np.asarray(cache.views[row], np.float64)
            runs, last = {k: [] for k in methods}, {}
            for r in range(1 + repeats):      # one untimed run first; alternated: a disturbance hits both alike
                for name, m in methods.items():
                    last[name] = m.run(view)
                    if r:
                        runs[name].append(dict(last[name].timings, c_share=last[name].info["c_share"]))
            for name in methods:
                per[name].append({k: float(np.median([x.get(k, 0.0) for x in runs[name]])) for k in (*stages, "c_share")})
                quality[name].append(image_quality(last[name].image, np.asarray(cache.images[row]))[0])
    out = {}
    print("| method | C-share | first pass | importance | selective render | fill | RecNN | total | PSNR |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in methods:
        ms = {k: 1e3 * float(np.mean([v[k] for v in per[name]])) for k in stages}
        out[name] = {**ms, "c_share": float(np.mean([v["c_share"] for v in per[name]])), "psnr": float(np.mean(quality[name]))}
        print(f"| {name} | {out[name]['c_share']:.1%} | " + " | ".join(f"{ms[k]:.1f}" for k in stages)
              + f" | {out[name]['psnr']:.2f} |")
    names = list(methods)
    speed = out[names[0]]["total"] / out[names[1]]["total"]
    print(f"speed-up of the two-pass sampler over the RecNN alone: {speed:.2f}x ({views} test views, {repeats} runs each)")
    return {"methods": out, "speedup": speed, "views": views, "repeats": repeats, "share": share}


@cli_errors
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cache", type=Path, help="a finished cache (python -m data_gen) with a test split")
    ap.add_argument("recnn_run", type=Path,
                    help="a RecNN run directory trained on it (its result.json's best checkpoint), or a RecNN .ckpt")
    ap.add_argument("--split", default="test", choices=("val", "test"),
                    help="the views scored: choose a share on val, then read it on test (default test)")
    ap.add_argument("--views", type=int, default=24, help="views scored, evenly spaced (default 24)")
    ap.add_argument("--future-views", type=int, default=120,
                    help="the 95%% bound on the mean gap of this many new views (the ORP search's rule; default 120)")
    ap.add_argument("--epsilon", type=float, default=1.0, help="the ORP's tolerance in dB (default 1)")
    ap.add_argument("--floor", type=float, default=0.25, help="the importance every pixel keeps (the estimate's background_density)")
    ap.add_argument("--base", type=float, default=None,
                    help="a two-pass sampler: the importance from this blue-noise share of C only (rendered first, "
                         "always kept); default: from the whole C-Image, as the estimate")
    ap.add_argument("--time", type=float, default=None, metavar="SHARE",
                    help="with --base: also time the two-pass sampler at this share against the RecNN alone, alternated "
                         "run by run on --time-views test views (the scene's renderer rebuilt from the cache)")
    ap.add_argument("--time-views", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.time is not None and a.base is None:
        raise InputError("--time: expected --base too (it times the two-pass sampler)")
    result = a.recnn_run / "result.json"
    if a.recnn_run.is_file():
        checkpoint = a.recnn_run
    elif result.is_file():
        checkpoint = json.loads(result.read_text())["best_checkpoint"]
    else:
        raise InputError(f"recnn_run={a.recnn_run}: no result.json (expected a finished RecNN run directory or a RecNN .ckpt)")
    recnn, hp = load_recnn(checkpoint)
    recnn.eval()
    cache = ViewImageCache.open(a.cache)
    pattern = build_pattern(hp["pattern"], cache.resolution)
    _, images = cache.split(a.split)
    if a.views < 1:
        raise InputError(f"--views={a.views}: expected at least 1")
    pick = np.linspace(0, len(images) - 1, min(a.views, len(images))).round().astype(int)
    frames = [np.asarray(images[i]) for i in pick]

    def rebuild(c):
        return recnn(c).float()

    kept, gaps = share_gaps(rebuild, pattern, frames, NEEDED_SHARES, floor=a.floor, base=a.base)
    mean_kept, mean_gap = kept.mean(0), gaps.mean(0)
    bounds = [gap_upper_bound(gaps[:, j].tolist(), 0.95, future_views=a.future_views).bound if len(frames) > 1
              else float(gaps[0, j]) for j in range(len(NEEDED_SHARES))]
    need = first_share_within(mean_kept.tolist(), mean_gap.tolist(), a.epsilon)
    within = [s for s, b in zip(NEEDED_SHARES, bounds) if b <= a.epsilon]
    how = f"two passes, the first {a.base:.0%} of C" if a.base else "the importance from the whole C-Image"
    print(f"{a.cache.name}, {a.recnn_run.name}: {len(frames)} {a.split} views; {how}")
    print("share of C  " + " ".join(f"{k:>5.0%}" for k in mean_kept[1::2]))
    print("gap (dB)    " + " ".join(f"{g:>5.2f}" for g in mean_gap[1::2]))
    print("95% bound   " + " ".join(f"{b:>5.2f}" for b in bounds[1::2]))
    print(f"needed share within {a.epsilon:g} dB: " + (f"{need:.1%} of C" if need is not None else "none")
          + "; smallest share whose 95% bound is within it: " + (f"{within[0]:.0%}" if within else "none"))
    timing = time_two_pass(cache, recnn, pattern, a.time, a.base, a.floor, a.time_views, a.repeats) \
        if a.time is not None else None
    if a.json:
        atomic_json(a.json, {"timing": timing, "cache": str(a.cache), "recnn_run": str(a.recnn_run), "views": pick.tolist(),
                             "split": a.split, "epsilon_db": a.epsilon, "floor": a.floor, "base": a.base,
                             "needed_share": need, "bound_share": within[0] if within else None,
                             "future_views": a.future_views,
                             "rows": [{"share": s, "kept": float(k), "gap_db": float(g), "gap_std_db": float(sd),
                                       "bound_db": float(b)}
                                      for s, k, g, sd, b in zip(NEEDED_SHARES, mean_kept, mean_gap, gaps.std(0), bounds)]})
        print(a.json)


if __name__ == "__main__":
    main()
