"""Re-time the product at its recorded operating point against the RecNN alone, interleaved, with nothing else.

The evaluation times one method after the other on each view, so a second job that starts on the same cores
for a minute slows some methods and not others. This script answers the headline question again from one run,
in the product's own terms: the renderer built from the IMS checkpoint alone
(``IMLSRenderer.from_checkpoints``: it runs at the ORP the evaluation recorded for that checkpoint) and the
RecNN alone on its whole pattern, sharing the same ray caster and RecNN, alternated run by run on the same
views. It prints the per-stage medians (mean over views), the speed-up, the limit (the RecNN alone against
ray-casting the ORP's pixels alone, networks free) and each method's PSNR against the cached full ray cast.

Usage:
    .venv/bin/python scripts/retime_orp.py runs/paper/ims-.../checkpoints/epoch004.ckpt cache/rayleigh_taylor-... \
        --views 6 --repeats 10
    # and the classical two-pass sampler at the share it needs on the validation views (needed_share_check.py)
    .venv/bin/python scripts/retime_orp.py <ims ckpt> <cache> --two-pass 0.6 --base 0.2
    # the same networks and pixels on a ray caster without empty-space skipping (renderer.skip_empty=false): where
    # a background ray inside the volume's box costs as much as an object ray, as in the paper's renderer
    .venv/bin/python scripts/retime_orp.py <ims ckpt> <cache> --no-skip-empty
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def searched_two_pass(path: Path) -> dict:
    """The two-pass sampler's searched point in ``path``: an evaluation's ``summary.json`` (``two_pass``) or
    ``scripts/orp_promise.py --two-pass``'s rows (the first's ``two_pass``). Exits with one line otherwise."""
    import json

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise SystemExit(f"--two-pass-from {path}: cannot read it as JSON ({err})")
    tp = data.get("two_pass") if isinstance(data, dict) else (data[0].get("two_pass") if data and isinstance(data[0], dict) else None)
    if not isinstance(tp, dict) or not {"share", "base", "floor"} <= set(tp):
        raise SystemExit(f"--two-pass-from {path}: expected an evaluation's summary.json or orp_promise.py --two-pass rows "
                         "with a two_pass point (share, base, floor, by_distance)")
    return tp


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("ims_checkpoint", help="a model=ims checkpoint with an evaluation's <ckpt>.orp.json beside it")
    ap.add_argument("cache", help="the scene's cache (its test split gives the views and the ground truth)")
    ap.add_argument("--views", type=int, default=6, help="test views, evenly spaced (default 6)")
    ap.add_argument("--repeats", type=int, default=10, help="timed runs per view and method (default 10)")
    ap.add_argument("--warmup", type=int, default=1, help="untimed runs per view and method first (default 1)")
    ap.add_argument("--recnn", default=None, help="the RecNN checkpoint (default: the one inside the IMS checkpoint)")
    ap.add_argument("--two-pass", type=float, default=None, metavar="SHARE",
                    help="also the classical two-pass sampler at this share of C (choose it on validation views: "
                         "scripts/needed_share_check.py --split val --base B), alternated with the others")
    ap.add_argument("--base", type=float, default=0.2, help="the two-pass sampler's first pass, a share of C (default 0.2)")
    ap.add_argument("--two-pass-from", type=Path, default=None, metavar="JSON",
                    help="also the two-pass sampler at the operating point searched for it: an evaluation's summary.json "
                         "(its two_pass) or scripts/orp_promise.py --two-pass's JSON (its first row); a share per band "
                         "of camera distance where it has one")
    ap.add_argument("--also", nargs="+", default=[], metavar="IMS_CKPT",
                    help="also the product built from these IMS checkpoints at their own recorded points (e.g. a copy of "
                         "the same checkpoint recorded at another object floor: scripts/object_floor_by_band.py), on the "
                         "same ray caster, alternated with the others")
    ap.add_argument("--fill", action="store_true",
                    help="also each IML/S product's own mask with the untrained pull-push fill in place of its decoder "
                         "(the evaluation's imls_fill: the simplest alternative on the same pixels)")
    ap.add_argument("--blocked", action="store_true",
                    help="per view, each method's runs back to back (as the evaluation times them: its working set stays in "
                         "the caches, as from one frame to the next of one renderer) instead of alternated run by run (each "
                         "run after the other method's: the caches hold the other's data)")
    ap.add_argument("--no-skip-empty", action="store_true",
                    help="ray-cast without empty-space skipping (renderer.skip_empty=false: the same pixels, the costs of "
                         "a ray caster without it)")
    ap.add_argument("--half", choices=("auto", "true", "false"), default="auto",
                    help="the networks' precision, as the evaluation's options.half (default auto: bfloat16 autocast on the "
                         "CPU, float16 on CUDA, where it is faster here; the evaluation's default too)")
    a = ap.parse_args(argv)
    if a.views < 1 or a.repeats < 1 or a.warmup < 0:
        ap.error("--views and --repeats must be >= 1, --warmup >= 0")

    from data_gen.cache import ViewImageCache
    from imls_lightning.evaluation.measurement import image_quality, spaced
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions, RecNNAlone, time_methods

    renderer_cfg = None
    if a.no_skip_empty:
        from imls_lightning.config import load_checkpoint

        # the renderer the IMS was trained with, from its hyper-parameters (no network is built for it)
        trained = dict(load_checkpoint(a.ims_checkpoint, what="ims").get("hyper_parameters", {}).get("renderer") or {})
        if trained.get("name") != "numba":
            print(f"error: --no-skip-empty: the IMS was trained with renderer={trained.get('name')!r}; only numba skips "
                  "empty space", file=sys.stderr)
            return 2
        renderer_cfg = {**trained, "skip_empty": False}
    opts = NetOptions.from_config({"half": a.half if a.half == "auto" else a.half == "true"})
    product = IMLSRenderer.from_checkpoints(a.ims_checkpoint, recnn_checkpoint=a.recnn, renderer_cfg=renderer_cfg, opts=opts)
    if product.operating_point is None or not product.operating_point.found:
        print(f"error: {a.ims_checkpoint}: no recorded operating point (the evaluation writes it beside the checkpoint)",
              file=sys.stderr)
        return 2
    alone = RecNNAlone(product.renderer, product.pattern, product.recnn, product.opts)
    cache = ViewImageCache.open(a.cache)
    test = np.asarray(cache.splits["test"])
    rows = test[spaced(len(test), a.views)]

    methods = {"RecNN alone": alone, "IML/S + RecNN (recorded ORP)": product}
    for other in a.also:
        also = IMLSRenderer.from_checkpoints(other, recnn_checkpoint=a.recnn, renderer=product.renderer, opts=opts)
        if also.operating_point is None or not also.operating_point.found:
            print(f"error: --also {other}: no recorded operating point", file=sys.stderr)
            return 2
        methods[f"IML/S + RecNN ({Path(other).parent.name}'s record)"] = also
    if a.fill:
        from imls_lightning.models.iml import FillDecoder

        for name in [n for n in methods if n.startswith("IML/S")]:
            r = methods[name]
            methods[name.replace("IML/S + RecNN", "IMS mask + fill + RecNN")] = IMLSRenderer(
                r.renderer, r.pattern, r.predict_im, FillDecoder(r.pattern), r.recnn, r.opts)
    if a.two_pass is not None:
        from imls_lightning.inference.two_pass import TwoPassFill

        name = f"two passes ({a.base:.0%} first) + fill + RecNN"
        methods[name] = TwoPassFill(product.renderer, product.pattern, product.recnn, share=a.two_pass, base=a.base,
                                    opts=product.opts)
    if a.two_pass_from is not None:
        from imls_lightning.evaluation.two_pass import TwoPassPoint, two_pass_method

        point = TwoPassPoint.from_dict(searched_two_pass(a.two_pass_from))
        method = two_pass_method(point, product.renderer, product.pattern, product.recnn, product.opts)
        methods["two passes, its searched " + ("shares per band" if point.by_distance else "share") + " ("
                + " / ".join(f"{x:.0%}" for x in method.shares) + ")"] = method
    per_view: dict[str, list[dict[str, float]]] = {k: [] for k in methods}
    quality: dict[str, list[tuple[float, float]]] = {k: [] for k in methods}
    for i, row in enumerate(rows):
        # alternated run by run (a disturbance hits every method alike), or --blocked: each method's runs back to back
        timed = time_methods(methods, np.asarray(cache.views[row], np.float64), repeats=a.repeats, warmup=a.warmup,
                             order="blocked" if a.blocked else "interleaved")
        for name, (image, med, info) in timed.items():
            per_view[name].append(dict(med, c_share=info["c_share"]))
            quality[name].append(image_quality(image, np.asarray(cache.images[row])))
        print(f"[retime] view {i + 1}/{len(rows)} (row {row}): "
              + ", ".join(f"{n} {1e3 * per_view[n][-1]['total']:.1f} ms" for n in methods), file=sys.stderr)

    stages = ["low_res_render", "importance", "selective_render", "decoder", "recnn", "total"]
    mean = {n: {k: 1e3 * float(np.mean([v.get(k, 0.0) for v in per_view[n]])) for k in stages} for n in methods}
    share = {n: float(np.mean([v["c_share"] for v in per_view[n]])) for n in methods}
    skip = getattr(product.renderer, "skip_empty", True)
    precision = ("float16" if product.device.type == "cuda" else "bfloat16") + " autocast" if opts.half else "float32"
    print(f"ray caster: {product.renderer.name}, empty-space skipping {'on' if skip else 'off'}; networks: {precision}"
          f"{' (--half auto)' if a.half == 'auto' else ''}")
    print(f"ORP: u = {product.mean:.4f} (lift {product.lift}), recorded by the evaluation; {len(rows)} test views "
          f"(rows {', '.join(map(str, rows))}), median of {a.repeats} {'back-to-back' if a.blocked else 'interleaved'} runs each, "
          "mean over views\n")
    print("| method | C-share | first pass (ms) | importance (ms) | selective render (ms) | decoder or fill (ms) | RecNN (ms) "
          "| total (ms) | PSNR (dB) | SSIM |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for n in methods:
        p = np.mean([q[0] for q in quality[n]])
        s = np.mean([q[1] for q in quality[n]])
        cells = " | ".join(f"{mean[n][k]:.1f}" for k in stages)
        print(f"| {n} | {100 * share[n]:.1f}% | {cells} | {p:.2f} | {s:.4f} |")
    base, imls = mean["RecNN alone"]["total"], mean["IML/S + RecNN (recorded ORP)"]["total"]
    limit = base / max(mean["IML/S + RecNN (recorded ORP)"]["selective_render"], 1e-9)
    print(f"\nspeed-up of IML/S + RecNN over the RecNN alone: {base / imls:.2f}x; "
          f"limit (the ORP's pixels ray-cast alone, networks free): {limit:.2f}x")
    for n in list(methods)[2:]:
        limit_n = f"; limit {base / max(mean[n]['selective_render'], 1e-9):.2f}x" if n.startswith("IML/S") else ""
        print(f"speed-up of {n} over the RecNN alone: {base / mean[n]['total']:.2f}x{limit_n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
