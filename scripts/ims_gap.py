"""Where the IML/S product path loses against the IML bound: the IMS's mask against the IML's.

For one IMS checkpoint (``model.target=pim``) and a rendered cache, on evenly spaced views of a split:

* how well the IMS's PIM' (from the view alone) matches the IML's PIM' (from the C-Image), per split:
  correlation and MSE over the pattern's pixels (a gap between train and test views = overfitting), and
  the per-view correlation at the pixel and over 4 x 4 and 32 x 32 blocks (low even on training views and
  at coarse blocks = the generator underfits: too few layers, too little training);
* at each C-Image share (each mask brought to it per view, :func:`imls_lightning.inference.baselines.mask_at_share`):
  the density of the mask on the object and on the empty background, the C-level PSNR of the IML
  decoder's C-Image on the object and on the background, and the PSNR after the RecNN, for the IML's
  mask, the IMS's mask and an oracle that keeps every object pixel (background by blue noise).

    python scripts/ims_gap.py runs/demo/ims-.../checkpoints/epoch008.ckpt cache/flame-... [--split test] [--views 24]

``--views-at 22 23`` scores those positions of the split instead (a trajectory's failing views); ``--sharpness 3
--lift`` makes the IMS's masks the ones the product runs at an ORP that kept that sharpness (the IML's and the
oracle's masks do not change).

Prints a markdown table (and ``--json`` writes the rows).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from data_gen.cache import ViewImageCache
from imls_lightning.inference.baselines import iml_pim_at, mask_at_share
from imls_lightning.data import ViewImageDataset
from imls_lightning.core.metrics import psnr_from_mse, psnr_per_image
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.tasks.iml import background_mask

SPLITS = ("train", "val", "test")
#: block sides of the per-view PIM' correlation: the pixel, then coarser and coarser placement
BLOCKS = (1, 4, 32)


def load_views(cache: ViewImageCache, pattern, split: str, count: int, picks=None) -> dict[str, torch.Tensor]:
    """``count`` evenly spaced views of ``split`` (or the views at positions ``picks`` of the split, e.g. a
    trajectory's failing views): ``{"view" (B, 9), "c" (B, 3, n, n), "fr" (B, 3, m, m)}``."""
    rows = np.asarray(cache.splits[split])
    if len(rows) == 0:
        raise SystemExit(f"error: the cache has no {split} views")
    if picks:
        bad = [p for p in picks if not 0 <= p < len(rows)]
        if bad:
            raise SystemExit(f"error: --views-at {bad[0]}: the {split} split has views 0-{len(rows) - 1}")
        rows = rows[list(picks)]
    else:
        rows = rows[np.unique(np.linspace(0, len(rows) - 1, min(count, len(rows))).astype(int))]
    ds = ViewImageDataset(cache.path, rows, pattern, fields=("view", "c", "fr"))
    return {k: torch.stack([ds[i][k] for i in range(len(ds))]).float() for k in ("view", "c", "fr")}


def iml_pim(iml, c: torch.Tensor, mean: float) -> torch.Tensor:
    """The IML's PIM' of C-Images ``c`` at ``mean``, clamped to [0, 1] (what the IMS regresses)."""
    n = c.shape[-1]
    pim, _ = iml.encode(c)
    return iml_pim_at(iml, pim, torch.full((c.shape[0],), mean), iml.valid.bool().view(n, n)).clamp(0, 1)


def block_correlation(got: torch.Tensor, want: torch.Tensor, valid: torch.Tensor, block: int) -> float:
    """Mean over the views of the Pearson correlation of two maps ``(B, 1, n, n)`` after averaging each over
    ``block x block`` blocks of the pattern's pixels ``valid`` ``(n, n)`` (blocks without one are left out):
    how well the IMS places importance at that scale, whatever it misses below it.

    Example:
        >>> x = torch.rand(2, 1, 8, 8)
        >>> round(block_correlation(x, 2 * x + 1, torch.ones(8, 8, dtype=torch.bool), 2), 6)
        1.0
    """
    w = valid.to(got.dtype).view(1, 1, *valid.shape)
    count = F.avg_pool2d(w, block).flatten(1)[0]
    keep = count > 0
    a = (F.avg_pool2d(got * w, block).flatten(1) / count.clamp(min=1e-12))[:, keep]
    b = (F.avg_pool2d(want * w, block).flatten(1) / count.clamp(min=1e-12))[:, keep]
    a, b = a - a.mean(1, keepdim=True), b - b.mean(1, keepdim=True)
    r = (a * b).sum(1) / (a.norm(dim=1) * b.norm(dim=1)).clamp(min=1e-12)
    return float(r.mean())


def pim_agreement(ims, batch: dict[str, torch.Tensor], blocks=BLOCKS) -> dict[str, float]:
    """Correlation and MSE of the IMS's PIM' ``(g + 1) / 2`` against the IML's, over the pattern's pixels
    (pooled over the views), and the per-view correlation at each block size of ``blocks``
    (:func:`block_correlation`: ``corr_<block>``; None for blocks wider than half the mask)."""
    n = batch["c"].shape[-1]
    valid = ims.iml.valid.bool().view(n, n)
    want_map = iml_pim(ims.iml, batch["c"], float(ims.iml.mean))
    got_map = (ims.generator(batch["view"]).float() + 1) / 2
    want, got = want_map[:, :, valid].flatten(), got_map[:, :, valid].flatten()
    out = {"corr": float(torch.corrcoef(torch.stack([got, want]))[0, 1]), "mse": float(((got - want) ** 2).mean())}
    # blocks wider than the mask have no correlation (one value per view): None
    out.update({f"corr_{k}": block_correlation(got_map, want_map, valid, k) if 2 * k <= n else None for k in blocks})
    return out


def object_oracle(obj: torch.Tensor, bg: torch.Tensor, P: torch.Tensor, valid: torch.Tensor, share: float) -> torch.Tensor:
    """Every object pixel, then background pixels by the blue-noise rank ``P`` up to ``share`` of the pattern."""
    extra = share * valid.sum() - obj.flatten(1).sum(1)
    frac = extra.clamp(min=0) / bg.flatten(1).sum(1).clamp(min=1)
    return (obj | (bg & (P < frac.view(-1, 1, 1, 1)))).float()


def gap_rows(ims, batch: dict[str, torch.Tensor], shares, lift: bool = False) -> list[dict]:
    """Per share and mask (``iml``, ``ims``, ``oracle``): densities and PSNRs, means over the views. ``lift``: the
    IMS's masks lifted to their mean value's share, as the product runs them with ``decoder_lift``."""
    iml, recnn = ims.iml, ims.recnn
    c, fr, views = batch["c"], batch["fr"], batch["view"]
    B, n = c.shape[0], c.shape[-1]
    valid = iml.valid.bool().view(n, n)
    P = ims.P.view(1, 1, n, n)
    bg = background_mask(c) & valid
    obj = ~background_mask(c) & valid
    pim, _ = iml.encode(c)
    g = ims.generator(views).float()

    def iml_mask(u):
        return iml_pim_at(iml, pim, u, valid) > P

    rows = []
    for share in shares:
        masks = {"iml": mask_at_share(iml_mask, share, valid, B),
                 "ims": mask_at_share(lambda u: ims.output_to_im_at(g, u, lift), share, valid, B),
                 "oracle": object_oracle(obj, bg, P, valid, share)}
        for name, m in masks.items():
            rec = iml.decoder(m * c, m)
            err = ((rec - c) ** 2).mean(1, keepdim=True)

            def region_psnr(region):
                mse = (err * region).flatten(1).sum(1) / region.flatten(1).sum(1).clamp(min=1)
                return float(psnr_from_mse(mse.clamp(min=1e-10)).mean())

            mb = m.bool()
            rows.append({"share": float(share), "mask": name,
                         "c_share": float((mb & valid).flatten(1).sum(1).float().mean() / valid.sum()),
                         "density_object": float((mb & obj).sum() / obj.sum().clamp(min=1)),
                         "density_background": float((mb & bg).sum() / bg.sum().clamp(min=1)),
                         "c_psnr_object": region_psnr(obj.float()), "c_psnr_background": region_psnr(bg.float()),
                         "fr_psnr": float(psnr_per_image(recnn(rec), fr).mean())})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ims_checkpoint")
    ap.add_argument("cache", help="the rendered cache folder (the evaluation's data)")
    ap.add_argument("--split", default="test", choices=SPLITS)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--views-at", type=int, nargs="+", default=None, metavar="I",
                    help="these positions of the split instead of --views evenly spaced ones (e.g. a trajectory's failing views)")
    ap.add_argument("--lift", action="store_true",
                    help="lift the IMS's masks to their mean value's share, as the product does (model.decoder_lift)")
    ap.add_argument("--sharpness", type=float, default=1.0,
                    help="the IMS mask's sharpness (the evaluation's ims_sharpness its ORP kept; 1: the paper's masks)")
    ap.add_argument("--shares", type=float, nargs="+", default=[0.1, 0.2, 0.4, 0.6])
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--decoder-from", default=None, metavar="IML_CKPT",
                    help="rebuild every mask's pixels with this IML checkpoint's decoder instead of the IMS's "
                         "(e.g. the IML's own, to measure an IMS trained with model.decoder_lr > 0 on the same masks)")
    a = ap.parse_args(argv)
    if a.views < 1 or not all(0 < s <= 1 for s in a.shares):
        ap.error("--views must be >= 1 and every --shares value in (0, 1]")
    if not 1.0 <= a.sharpness <= 8.0:
        ap.error(f"--sharpness {a.sharpness}: expected a mask sharpness in [1, 8]")
    with torch.no_grad():  # not set_grad_enabled(False): main() is also called in-process (tests)
        return _report(a, ap)


def _report(a: argparse.Namespace, ap: argparse.ArgumentParser) -> int:
    ims = load_task(a.ims_checkpoint, expect="IMSTask", what="ims_checkpoint").eval()
    if ims.target != "pim" or ims.recnn is None:
        ap.error("ims_checkpoint: needs an IMS trained with model.target=pim that carries a RecNN")
    if a.decoder_from:
        other = load_task(a.decoder_from, expect="IMLTask", what="--decoder-from").eval()
        if other.pattern.fingerprint() != ims.pattern.fingerprint():
            ap.error("--decoder-from: an IML trained on another sampling pattern than the IMS")
        ims.iml.decoder = other.iml.decoder
    ims.mask_sharpness = a.sharpness
    cache = ViewImageCache.open(a.cache)
    agreement = {s: pim_agreement(ims, load_views(cache, ims.pattern, s, a.views)) for s in SPLITS if len(cache.splits[s])}
    batch = load_views(cache, ims.pattern, a.split, a.views, a.views_at)
    alone = float(psnr_per_image(ims.recnn(batch["c"]), batch["fr"]).mean())
    rows = gap_rows(ims, batch, a.shares, a.lift)
    print("| split | PIM' correlation IMS vs IML | MSE | " + " | ".join(f"per view, {k} x {k} blocks" for k in BLOCKS)
          + " |\n|---|---:|---:|" + "---:|" * len(BLOCKS))
    for s, r in agreement.items():
        print(f"| {s} | {r['corr']:.3f} | {r['mse']:.4f} | " + " | ".join("–" if r[f"corr_{k}"] is None else f"{r[f'corr_{k}']:.3f}" for k in BLOCKS) + " |")
    print(f"\nRecNN alone on {batch['c'].shape[0]} {a.split} views: {alone:.2f} dB\n")
    print("| share | mask | kept | density object | density background | C PSNR object | C PSNR background | PSNR after RecNN |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['share']:.2f} | {r['mask']} | {r['c_share']:.3f} | {r['density_object']:.3f} | {r['density_background']:.3f} | "
              f"{r['c_psnr_object']:.2f} | {r['c_psnr_background']:.2f} | {r['fr_psnr']:.2f} |")
    if a.json:
        a.json.write_text(json.dumps({"agreement": agreement, "recnn_alone": alone, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
