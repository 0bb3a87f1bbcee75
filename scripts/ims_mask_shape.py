"""Where a trained IMS puts its pixels, and what they cost to ray-cast against masks of a modelled shape.

    python scripts/ims_mask_shape.py --ims runs/paper/ims-enhancenet-flame_whole-ded2f6f6/checkpoints/epoch001.ckpt \\
        --cache cache/flame_whole-365f416a1ab9 --mean 0.3 --views 6 --time renderer.skip_empty=false

On ``--views`` validation views of the cache (spread over camera distance; never the test trajectory), it prints per
view, as one JSON line: the mask's share of C, its density on the object, on the background by distance to the object
(C-pixels) and inside / outside the volume's box. With ``--time`` it also times the render of exactly the mask's pixels
and of the estimate's silhouette masks of the same share (:func:`imls_lightning.estimate.measure.silhouette_mask`,
blurs 0, 2, 4), each as a ratio to the mask's (the evidence for the estimate's ``silhouette_blur``). Trailing
arguments are renderer overrides (``key=value`` of ``conf/renderer``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RINGS = ((1, 4), (4, 8), (8, 16), (16, 32), (32, 10**9))


def distance_to_object(on_object: np.ndarray, n: int, k: int) -> np.ndarray:
    """``(k,)``: each pattern pixel's chessboard distance on the C grid to the nearest object pixel (0 on it;
    a large number when there is no object)."""
    import torch
    import torch.nn.functional as F

    grid = torch.zeros(n * n)
    grid[:k] = torch.from_numpy(on_object.astype(np.float32))
    cur = grid.view(1, 1, n, n)
    dist = torch.where(cur.flatten() > 0, 0, 10**9)
    for step in range(1, n):
        cur = F.max_pool2d(cur, 3, 1, 1)
        new = (cur.flatten() > 0) & (dist == 10**9)
        if not new.any():
            break
        dist[new] = step
    return dist[:k].numpy()


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ims", required=True, help="the IMS checkpoint (model=ims, target=pim)")
    ap.add_argument("--cache", required=True, help="the scene's cache directory (its val split is used)")
    ap.add_argument("--mean", type=float, default=0.3, help="the mean value the mask runs at")
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--time", action="store_true", help="also time the renders (give the job the cores to itself)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("overrides", nargs="*", help="renderer overrides, e.g. skip_empty=false")
    a = ap.parse_args(argv)
    import torch

    from data_gen.cache_reader import ViewImageCache
    from data_gen.errors import InputError
    from data_gen.render_numba import ray_hit_mask
    from imls_lightning.estimate.measure import median_ms, object_pixels, silhouette_mask
    from imls_lightning.inference.pipeline import IMLSRenderer

    if a.views < 1:
        raise SystemExit(f"--views={a.views}: expected at least 1")
    try:
        cache = ViewImageCache.open(a.cache)
    except (InputError, OSError) as err:
        raise SystemExit(f"--cache={a.cache}: {err}")
    scene = cache.scene()
    from omegaconf import OmegaConf

    # key=value of conf/renderer, with or without the "renderer." prefix, typed as Hydra types them
    dotlist = [o[len("renderer."):] if o.startswith("renderer.") else o for o in a.overrides]
    renderer_cfg = {"name": "numba", **OmegaConf.to_container(OmegaConf.from_dotlist(dotlist))}
    from data_gen.renderers import make_renderer

    renderer = make_renderer(scene, renderer_cfg)
    product = IMLSRenderer.from_checkpoints(a.ims, renderer=renderer, mean=a.mean)
    pattern = product.pattern
    idx, k, n = pattern.indices.numpy(), pattern.count, pattern.c_size
    if cache.resolution != pattern.fr_size:
        raise SystemExit(f"--cache={a.cache}: its images are {cache.resolution}^2, the IMS's pattern is {pattern.fr_size}^2")
    views, images = cache.split("val")
    distance = np.linalg.norm(views[:, :3] - views[:, 3:6], axis=1)
    order = np.argsort(distance)
    pick = order[np.linspace(0, len(order) - 1, min(a.views, len(order))).astype(int)]
    bounds = np.asarray(scene.volume.bounds, np.float64)
    rows = []
    for i in pick:
        view, fr = views[i], images[i]
        with torch.inference_mode():
            im = product.predict_im(torch.as_tensor(view, dtype=torch.float32, device=product.device)[None])
        kept = im[0, 0].bool().flatten()[:k].cpu().numpy()
        obj = object_pixels(fr.reshape(-1, 3)[idx], scene.background)
        hit = ray_hit_mask(view, pattern.fr_size, float(scene.view_angle), bounds, pixels=idx)
        dist = distance_to_object(obj, n, k)

        def density(sel):
            return round(float(kept[sel].mean()), 3) if sel.any() else None
        row = {"camera_distance": round(float(distance[i]), 3), "share": round(float(kept.mean()), 4),
               "object": round(float(obj.mean()), 4), "density_object": density(obj),
               "density_background_in_box": density(~obj & hit), "density_background_outside": density(~hit)}
        row.update({f"density_ring_{lo}_{hi if hi < 10**9 else 'inf'}": density(~obj & (dist >= lo) & (dist < hi))
                    for lo, hi in RINGS})
        if a.time:
            mask_ms = median_ms(lambda: renderer.render_pixels(view, pattern.fr_size, idx[kept]), a.repeats, 1)
            row["mask_ms"] = round(mask_ms, 1)
            row["pattern_ratio"] = round(median_ms(lambda: renderer.render_pixels(view, pattern.fr_size, idx), a.repeats, 0) / mask_ms, 3)
            for blur in (0.0, 2.0, 4.0):
                pix = silhouette_mask(obj, float(kept.mean()), pattern, blur)
                row[f"silhouette_{blur:g}_ratio"] = round(
                    median_ms(lambda: renderer.render_pixels(view, pattern.fr_size, pix), a.repeats, 0) / mask_ms, 3)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


if __name__ == "__main__":
    main()
