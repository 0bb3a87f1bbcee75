#!/usr/bin/env python
"""Time the networks IML/S adds and the RecNN under each inference option set, before any training, side by side.

The networks are untrained, of the sizes ``make bench-paper`` trains (latency does not depend on the weights), built
and run as the before-training estimate times them (:func:`imls_lightning.estimate.measure.network_stages`: the
product's mask head at a lifted mean, the IML's decoder module, the RecNN, channels-last C-Images). Every option set
is prepared once; its first call, which pays ``torch.compile``'s compilation, is timed on its own. Then ``--rounds``
rounds each time every option set's stages (``--repeats`` runs after 2 warm-ups), so a slow spell of a shared machine
hits every option set alike; the table gives each stage's median over the rounds and the sum of the three stages
IML/S runs per frame. Option sets: float32, bfloat16 autocast, and each with ``torch.compile``.

``--product-views N`` also times the product path on N views of the scene (the estimate's views: random, distances
stratified, never the test trajectory), the networks following real ray casts as they do in a frame: the RecNN alone
on its whole pattern against IML/S + RecNN (:class:`~imls_lightning.inference.pipeline.IMLSRenderer`: the mask head
runs and is timed, and the pixels ray-cast are the estimate's mask of a trained IMS's shape at ``--share``, the view's
object silhouette blurred, :func:`~imls_lightning.estimate.measure.silhouette_mask`), every option set's two methods
interleaved run by run on each view. Untrained networks make the images meaningless, not the times.

Usage (the overrides are the estimate's, ``conf/estimate.yaml``):
    .venv/bin/python scripts/measure_net_options.py --out benchmarks/net_options_fovolnet.md -- recnn=fovolnet \\
        ++recnn.net.features=8 ++recnn.net.base_channels=8 ++recnn.net.filter_channels=8 ++recnn.net.depth=4 \\
        ++recnn.net.levels=2 ++recnn.net.kernel_size=3     (bench_paper.yaml's recnn_net.fovolnet)
    .venv/bin/python scripts/measure_net_options.py --out benchmarks/net_options_enhancenet.md
    # and the product path on 6 views of seed_whole, the row's ray caster, at the FoVolNet row's share
    .venv/bin/python scripts/measure_net_options.py --sets bfloat16 "bfloat16 + torch.compile" --product-views 6 \
        --share 0.692 -- scene=seed_whole renderer.skip_empty=false recnn=fovolnet ++recnn.net.features=8 ...
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OPTION_SETS = {"float32": {}, "bfloat16": {"half": True}, "float32 + torch.compile": {"compile": True},
               "bfloat16 + torch.compile": {"half": True, "compile": True}}
STAGES = ("ims_ms", "decoder_ms", "recnn_ms")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (default 5)")
    ap.add_argument("--repeats", type=int, default=10, help="timed runs per stage and round (default 10)")
    ap.add_argument("--share", type=float, default=0.3, help="the mask's share of C for the mask head and the decoder")
    ap.add_argument("--sharpness", type=float, default=3.0, help="the mask head's sharpness (the evaluation's gamma)")
    ap.add_argument("--sets", nargs="+", default=list(OPTION_SETS), choices=list(OPTION_SETS), metavar="SET",
                    help=f"option sets to compare (default all: {', '.join(OPTION_SETS)})")
    ap.add_argument("--product-views", type=int, default=0,
                    help="also time RecNN alone against IML/S + RecNN on this many of the scene's views (default 0: not)")
    ap.add_argument("--product-repeats", type=int, default=3, help="timed runs per method and view (default 3, after 1)")
    ap.add_argument("--out", type=Path, help="write the table (markdown) here too")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides of conf/estimate.yaml (recnn=..., recnn.net.*=...)")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.repeats < 1 or args.product_repeats < 1 or args.product_views < 0:
        raise SystemExit("--rounds, --repeats, --product-repeats: expected integers >= 1; --product-views: >= 0")
    if not 0.0 < args.share <= 1.0:
        raise SystemExit(f"--share={args.share}: expected a share of C in (0, 1]")

    import torch
    from hydra import compose, initialize_config_dir
    from hydra.errors import ConfigCompositionException

    from data_gen.errors import InputError
    from imls_lightning.core.patterns import build_pattern
    from imls_lightning.estimate.measure import build_networks, median_ms, network_stages
    from imls_lightning.estimate.run import recnn_net
    from imls_lightning.inference.pipeline import NetOptions

    try:
        with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
            cfg = compose("estimate", overrides=list(args.overrides))
        pattern = build_pattern(cfg.pattern, int(cfg.resolution))
        net_node = recnn_net(cfg)
        build = lambda: build_networks(pattern, net_node, cfg.iml, cfg.ims)  # noqa: E731
        build()  # bad sizes fail here, before any timing
    except (InputError, ConfigCompositionException) as err:
        raise SystemExit(str(err).splitlines()[0])
    torch.manual_seed(0)
    stages, first_s = {}, {}
    for name in args.sets:
        stages[name] = network_stages(build(), pattern, NetOptions(device="cpu", **OPTION_SETS[name]),
                                      share=args.share, sharpness=args.sharpness)
        t0 = time.perf_counter()
        for fn in stages[name].values():
            fn()  # the first call: compiles when the set asks
        first_s[name] = time.perf_counter() - t0
        print(f"[options] {name}: first call of the three stages {first_s[name]:.1f} s", flush=True)
    times = {name: {s: [] for s in STAGES} for name in args.sets}
    for r in range(args.rounds):
        for name in args.sets:
            for s, fn in stages[name].items():
                times[name][s].append(median_ms(fn, args.repeats, 2))
        print(f"[options] round {r + 1}/{args.rounds}", flush=True)
    med = {name: {s: float(np.median(v)) for s, v in times[name].items()} for name in args.sets}
    base = sum(med[args.sets[0]].values())
    kind = f"{cfg.recnn.name} ({', '.join(f'{k}={v}' for k, v in net_node.items() if k != '_target_')})"
    lines = [f"Networks of {kind}, {pattern.kind} pattern {pattern.fr_size}^2 -> {pattern.c_size}^2, untrained; "
             f"mask at {args.share:.0%} of C, sharpness {args.sharpness:g}; {torch.get_num_threads()} threads; "
             f"medians of {args.rounds} interleaved rounds of {args.repeats} runs (ms)", "",
             "| option set | IMS mask head | decoder | RecNN | networks | vs the first set | first call (s) |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name in args.sets:
        total = sum(med[name].values())
        lines.append(f"| {name} | {med[name]['ims_ms']:.1f} | {med[name]['decoder_ms']:.1f} | {med[name]['recnn_ms']:.1f} "
                     f"| {total:.1f} | {total / base:.2f}x | {first_s[name]:.1f} |")
    if args.product_views:
        lines += ["", *product_path(cfg, pattern, build, args)]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = shlex.join(["scripts/measure_net_options.py", *(argv if argv is not None else sys.argv[1:])])
        args.out.write_text(f"`{command}`\n\n" + text)
    return 0


def product_path(cfg, pattern, build, args) -> list[str]:
    """The product-path table of ``--product-views`` (markdown lines): per option set, the stage medians of the RecNN
    alone and of IML/S + RecNN (mean over the views) and the speed-up (median over the views, with its range)."""
    import torch

    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene, register_resolvers
    from imls_lightning.estimate.measure import estimate_mask_head, object_pixels, silhouette_mask
    from imls_lightning.estimate.run import estimate_views
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions, RecNNAlone, time_methods

    register_resolvers()
    scene = build_scene(cfg.scene)
    renderer = make_renderer(scene, cfg.renderer)
    views = estimate_views(scene, args.product_views, int(cfg.seed))
    n, k = pattern.c_size, pattern.count
    methods, order = {}, []
    for name in args.sets:
        nets = build()
        opts = NetOptions(device="cpu", **OPTION_SETS[name])
        head = estimate_mask_head(nets["ims"], pattern, args.sharpness)
        methods[f"{name}|alone"] = RecNNAlone(renderer, pattern, nets["recnn"], opts)
        methods[f"{name}|imls"] = IMLSRenderer(renderer, pattern, head, nets["iml"].decoder, nets["recnn"], opts,
                                               mean=args.share, lift=True)
        order.append(name)
    renderer.render_pixels(views[0], pattern.fr_size, pattern.indices.numpy())  # numba compiles, the volume loads
    stage_runs = {m: [] for m in methods}
    speedups = {name: [] for name in order}
    shares = []
    for i, view in enumerate(views):
        on_object = object_pixels(renderer.render_pixels(view, pattern.fr_size, pattern.indices.numpy()), scene.background)
        pix = silhouette_mask(on_object, args.share, pattern, float(cfg.get("silhouette_blur", 4.0)),
                              float(cfg.get("background_density", 0.25)), args.sharpness)
        im = torch.zeros(n * n, dtype=torch.bool)
        im[:k] = torch.from_numpy(np.isin(pattern.indices.numpy(), pix))
        shares.append(float(im.sum()) / k)
        run_args = {m: {"im": im.view(n, n)} for m in methods if m.endswith("|imls")}
        timed = time_methods(methods, view, repeats=args.product_repeats, warmup=1, run_args=run_args)
        for m, (_, med, _) in timed.items():
            stage_runs[m].append(med)
        for name in order:
            speedups[name].append(timed[f"{name}|alone"][1]["total"] / timed[f"{name}|imls"][1]["total"])
        print(f"[options] product path: view {i + 1}/{len(views)}", flush=True)

    def mean_ms(m: str, stage: str) -> float:
        return 1e3 * float(np.mean([r.get(stage, 0.0) for r in stage_runs[m]]))

    share = float(np.mean(shares))
    lines = [f"The product path on {len(views)} views of scene {cfg.scene.get('name', '?')} (renderer "
             f"{cfg.renderer.get('name', '?')}, skip_empty={cfg.renderer.get('skip_empty', True)}): the RecNN alone against "
             f"IML/S + RecNN at {share:.1%} of C (the estimate's mask of a trained IMS's shape), {args.product_repeats} "
             "runs after 1 per method and view, every method interleaved; stage times in ms, the mean over the views "
             "of each view's medians; speed-up: the ratio of the mean totals, and the median of the views' ratios "
             "(min-max)", "",
             "| option set | RecNN alone: render | RecNN | total | IML/S: importance | render | decoder | RecNN | total "
             "| speed-up | median over views |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name in order:
        a, b = f"{name}|alone", f"{name}|imls"
        sp = speedups[name]
        lines.append(f"| {name} | {mean_ms(a, 'selective_render'):.0f} | {mean_ms(a, 'recnn'):.1f} | {mean_ms(a, 'total'):.0f} "
                     f"| {mean_ms(b, 'importance'):.1f} | {mean_ms(b, 'selective_render'):.0f} | {mean_ms(b, 'decoder'):.1f} "
                     f"| {mean_ms(b, 'recnn'):.1f} | {mean_ms(b, 'total'):.0f} "
                     f"| {mean_ms(a, 'total') / mean_ms(b, 'total'):.2f}x | {float(np.median(sp)):.2f}x ({min(sp):.2f}-{max(sp):.2f}) |")
    return lines


if __name__ == "__main__":
    sys.exit(main())
