"""What the IMS mask's sharpness buys: the gap to the RecNN alone against the share of C and the render cost.

    python scripts/mask_sharpness.py --ims runs/paper/ims-enhancenet-flame_whole-ded2f6f6/checkpoints/epoch001.ckpt \\
        --cache cache/flame_whole-97472ce22d5a --split test --views 12 --time renderer.skip_empty=false

On ``--views`` views of ``--split`` of the cache (spread over camera distance; pass the ORP's own search-view cache
and its ``test`` split, or any cache's ``val``: never the evaluated test trajectory), for each sharpness ``gamma``
(``--sharpness``) and mean value ``u`` (``--means``; the masks lifted to their share above the trained mean, as the
evaluation's ``ims_lift=true``): the mask of the product's head (:meth:`IMSMaskHead.with_sharpness
<imls_lightning.models.ims.IMSMaskHead.with_sharpness>`), the C-Image's pixels taken from the cached full render (the
pattern's pixels are a subset of it), the decoder and the RecNN; the PSNR gap to the RecNN alone on the whole pattern.
With ``--time`` it also ray-casts exactly the mask's pixels (best of ``--repeats``) and the whole pattern. One line per
(gamma, u): the share of C, the mean and largest gap, the render time as a fraction of the whole pattern's. Trailing
arguments are renderer overrides (``key=value`` of ``conf/renderer``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def best_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * min(times)


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ims", required=True, help="the IMS checkpoint (model=ims, target=pim)")
    ap.add_argument("--cache", required=True, help="a cache of the scene at the IMS's resolution")
    ap.add_argument("--split", default="val", choices=("val", "test", "train"), help="its views to use (default val)")
    ap.add_argument("--views", type=int, default=12)
    ap.add_argument("--sharpness", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    ap.add_argument("--means", type=float, nargs="+", default=[0.2, 0.3, 0.45, 0.65, 0.9])
    ap.add_argument("--time", action="store_true", help="also time the renders (give the job the cores to itself)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("overrides", nargs="*", help="renderer overrides, e.g. skip_empty=false")
    a = ap.parse_args(argv)
    if a.views < 1 or a.repeats < 1:
        raise SystemExit(f"--views={a.views} --repeats={a.repeats}: expected at least 1 each")
    import torch
    from omegaconf import OmegaConf

    from data_gen.cache_reader import ViewImageCache
    from data_gen.errors import InputError
    from data_gen.renderers import make_renderer
    from imls_lightning.core.importance import check_mean, check_sharpness
    from imls_lightning.evaluation.measurement import image_quality
    from imls_lightning.inference.pipeline import IMLSRenderer, to_uint8_image

    try:
        gammas = [check_sharpness(g, "--sharpness") for g in a.sharpness]
        means = [check_mean(u, "--means") for u in a.means]
        cache = ViewImageCache.open(a.cache)
    except (InputError, OSError) as err:
        raise SystemExit(f"{err}")
    dotlist = [o[len("renderer."):] if o.startswith("renderer.") else o for o in a.overrides]
    renderer = make_renderer(cache.scene(), {"name": "numba", **OmegaConf.to_container(OmegaConf.from_dotlist(dotlist))})
    product = IMLSRenderer.from_checkpoints(a.ims, renderer=renderer, mean="trained")
    head, pattern = product.mask_head, product.pattern
    idx, k, n = pattern.indices.numpy(), pattern.count, pattern.c_size
    if cache.resolution != pattern.fr_size:
        raise SystemExit(f"--cache={a.cache}: its images are {cache.resolution}^2, the IMS's pattern is {pattern.fr_size}^2")
    views, images = cache.split(a.split)
    if len(views) == 0:
        raise SystemExit(f"--split={a.split}: the cache {a.cache} has no such views")
    distance = np.linalg.norm(views[:, :3] - views[:, 3:6], axis=1)
    order = np.argsort(distance)
    pick = order[np.linspace(0, len(order) - 1, min(a.views, len(order))).astype(int)]
    per: dict[tuple[float, float], list[tuple[float, float, float]]] = {}
    full = []
    with torch.inference_mode():
        for j, i in enumerate(pick):
            view, fr = views[i], np.asarray(images[i])
            flat = torch.zeros(n * n, 3)
            flat[:k] = torch.from_numpy(fr.reshape(-1, 3)[idx].astype(np.float32) / 255.0)
            c = flat.view(1, n, n, 3).permute(0, 3, 1, 2).to(product.device)
            alone = image_quality(to_uint8_image(product.recnn(c)), fr)[0]
            v = torch.as_tensor(view, dtype=torch.float32, device=product.device)[None]
            g = head.generator(v)
            if a.time:
                full.append(best_ms(lambda: renderer.render_pixels(view, pattern.fr_size, idx), a.repeats))
            for gamma in gammas:
                sharp = head.with_sharpness(gamma)
                for u in means:
                    im = sharp.threshold(g, u, lift=True)
                    out = product.recnn(product.decoder(c * im, im.to(c.dtype)))
                    gap = alone - image_quality(to_uint8_image(out), fr)[0]
                    kept = np.flatnonzero(im[0, 0].flatten()[:k].cpu().numpy())
                    ms = best_ms(lambda: renderer.render_pixels(view, pattern.fr_size, idx[kept]), a.repeats) if a.time else float("nan")
                    per.setdefault((gamma, u), []).append((len(kept) / k, gap, ms))
            print(f"[sharpness] view {j + 1}/{len(pick)} (camera distance {distance[i]:.2f})", file=sys.stderr, flush=True)
    whole = float(np.mean(full)) if full else float("nan")
    rows = []
    for (gamma, u), vals in sorted(per.items()):
        arr = np.asarray(vals)
        row = {"sharpness": gamma, "mean": u, "share": float(arr[:, 0].mean()), "gap_db": float(arr[:, 1].mean()),
               "max_gap_db": float(arr[:, 1].max()), "render_ms": float(arr[:, 2].mean()),
               "render_fraction": float(arr[:, 2].mean() / whole)}
        rows.append(row)
        print(f"sharpness {gamma:g}  u {u:.2f}: {row['share']:.1%} of C, gap {row['gap_db']:.2f} dB (largest "
              f"{row['max_gap_db']:.2f})" + (f", render {row['render_ms']:.0f} ms = {row['render_fraction']:.3f} of the "
                                              f"whole pattern's {whole:.0f} ms" if a.time else ""))
    return rows


if __name__ == "__main__":
    main()
