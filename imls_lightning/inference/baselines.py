"""The untrained baselines every report shows beside the learned parts, at equal C-Image share.

A learned part earns its place only by beating the simplest thing that needs no training, on the
same pixels and with the same RecNN:

* **decoder vs fill**: the same mask's pixels rebuilt by the trained IML decoder, or by the
  untrained pull-push fill (:func:`~imls_lightning.core.pull_push.fill_c_image`), each then
  through the RecNN;
* **mask vs blue noise**: the learned mask (IML from the C-Image, IMS from the view) against the
  blue-noise plastic mask ``u > P`` of the same share, each through a decoder trained for it (the
  blue-noise decoder is an IML trained with ``model.importance=uniform``), and each through the fill.

Every mask is brought to the same share of the pattern's pixels per view by
:func:`mask_at_share` (bisection on the mean value ``u``; the IMS's regressed PIM' is rescaled, no
ground truth is used), so the comparison is at equal rendering cost. Quality is measured on the
cache's pixels, which are exactly what the selective ray cast of the same renderer returns.

Also reported per mask: its sampling density on empty background (ground truth black) and on the
object, the measure of whether importance is learned at all.

Example:
    >>> rows = equal_share_rows(c, fr, views, recnn, iml, ims_task=ims, blue=blue_iml)  # doctest: +SKIP
    >>> print(equal_share_markdown(summarize_equal_share([rows])))                     # doctest: +SKIP

(:func:`~imls_lightning.report.equal_share_markdown`, with the report's other tables).
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from imls_lightning.base.errors import InputError

from ..core.pull_push import fill_c_image
from ..core.metrics import psnr_per_image
from ..core.smallest_within import bisect_monotone
from ..tasks.iml import background_mask

__all__ = ["SHARES", "mask_at_share", "iml_pim_at", "equal_share_rows", "summarize_equal_share"]

#: the C-Image shares every report compares at (the issue's 10 %, 20 % and 40 % of C)
SHARES = (0.1, 0.2, 0.4)


def mask_at_share(mask_at: Callable[[torch.Tensor], torch.Tensor], share: float, valid: torch.Tensor,
                  batch: int, steps: int = 24, bracket: Sequence[float] = (1e-3, 1.0)) -> torch.Tensor:
    """The mask, per image, at the mean value ``u`` whose mask keeps about ``share`` of the valid pixels.

    Bisection in ``log u`` per image (:func:`~imls_lightning.core.smallest_within.bisect_monotone`); the mask's
    count grows with ``u``. The smallest ``u`` whose count reaches the target is taken (the share may overshoot by
    the pixels that switch at once).

    Args:
        mask_at: ``u (B,) float32 -> (B, 1, n, n)`` bool or 0/1 mask at those means.
        share: target share of the valid pixels in ``(0, 1]``.
        valid: ``(n, n)`` bool, the pattern's pixels.
        batch: ``B``.
        steps: bisection rounds.
        bracket: ``(lo, hi)`` of ``u``; ``hi`` is used when even it keeps fewer pixels.

    Returns:
        ``(B, 1, n, n)`` float32 0/1 mask.

    Example:
        >>> P = torch.rand(8, 8)
        >>> m = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P, 0.25, torch.ones(8, 8, dtype=torch.bool), 2)
        >>> m.mean(dim=(1, 2, 3)).tolist()
        [0.25, 0.25]
    """
    if not (0.0 < float(share) <= 1.0):
        raise ValueError(f"share={share}: expected a number in (0, 1]")
    target = float(share) * float(valid.sum())
    lo = torch.full((batch,), float(bracket[0]), dtype=torch.float64)
    hi = torch.full((batch,), float(bracket[1]), dtype=torch.float64)

    def count(u: torch.Tensor) -> torch.Tensor:
        m = mask_at(u.float()).bool() & valid.to(torch.bool)
        return m.flatten(1).sum(1).double().cpu()

    hi = bisect_monotone(count, target - 0.5, lo, hi, steps).hi
    return (mask_at(hi.float()).bool() & valid.to(torch.bool)).float()


def iml_pim_at(iml: torch.nn.Module, pim: torch.Tensor, u: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """PIM' of the IML ``iml``'s encoder output ``pim (B, 1, n, n)`` normalized per image to its own mean
    value ``u (B,)`` (the IML's ``lower`` and ``delta``), over the ``valid (n, n)`` pixels."""
    from ..core.importance import normalize_importance

    lower, delta = iml.normalization.lower, iml.normalization.delta
    return torch.cat([normalize_importance(pim[i:i + 1], float(u[i]), lower, delta, valid) for i in range(pim.shape[0])])


def _densities(im: torch.Tensor, c: torch.Tensor, valid: torch.Tensor) -> tuple[float, float]:
    bg = background_mask(c) & valid
    obj = ~background_mask(c) & valid
    d_bg = float((im.bool() & bg).sum()) / max(int(bg.sum()), 1)
    d_obj = float((im.bool() & obj).sum()) / max(int(obj.sum()), 1)
    return d_bg, d_obj


@torch.no_grad()
def equal_share_rows(c: torch.Tensor, fr: torch.Tensor, views: torch.Tensor | None, recnn: torch.nn.Module,
                     iml: torch.nn.Module | None = None, ims_task: Any = None, blue: torch.nn.Module | None = None,
                     shares: Sequence[float] = SHARES, valid: torch.Tensor | None = None, pattern: Any = None,
                     ims_lift: bool = False, ims_head: Any = None) -> list[dict[str, Any]]:
    """Per-image PSNR after the RecNN for every (share, mask, reconstruction) on one batch.

    Args:
        c: ``(B, 3, n, n)`` C-Images (the pattern's rendered pixels).
        fr: ``(B, 3, m, m)`` ground-truth FR-Images.
        views: ``(B, 9)`` views (for the IMS mask) or ``None``.
        recnn: the RecNN, the same for every row.
        iml: the :class:`~imls_lightning.models.iml.IMLNet` whose encoder gives the IML mask and
            whose decoder rebuilds its pixels (``None``: no IML rows).
        ims_task: an ``IMSTask`` trained with ``target=pim`` (its PIM' is rescaled to each share); its
            own decoder (the IML's, or fine-tuned on its masks) rebuilds the IMS masks' pixels.
        blue: an ``IMLNet`` trained with ``importance="uniform"`` (its decoder is the one trained
            for blue-noise masks), or ``None`` (blue-noise masks get the fill only).
        shares: C-Image shares.
        valid: ``(n, n)`` bool pattern pixels (default: ``iml.valid`` or all).
        pattern: the C-Images' sampling pattern: a foveal one is filled at the samples' FR positions
            (:func:`~imls_lightning.core.pull_push.fill_c_image`); ``None``: filled as a grid.
        ims_lift: lift the IMS's masks to the share of each mean value (the evaluation's ``ims_lift``).
        ims_head: the IMS's :class:`~imls_lightning.models.ims.IMSMaskHead` its masks are made with (at the operating
            point's sharpness and floor); ``None``: ``ims_task.mask_head``.

    Returns:
        rows ``{"share", "mask", "reconstruction", "psnr" (B,), "c_share" (B,), "density_background",
        "density_object"}``; ``mask`` in ``iml | ims | blue_noise``, ``reconstruction`` in
        ``decoder | fill``.
    """
    n = c.shape[-1]
    B = c.shape[0]
    net = iml if iml is not None else blue
    if valid is None:
        valid = net.valid.bool().view(n, n) if net is not None else torch.ones(n, n, dtype=torch.bool)
    valid = valid.to(c.device)
    P = (net.sampling.P if net is not None else ims_task.P).to(c.device).view(1, 1, n, n)
    sources: dict[str, tuple[Callable[[torch.Tensor], torch.Tensor], torch.nn.Module | None]] = {}
    if iml is not None and iml.encoder is not None:
        pim, _ = iml.encode(c)

        def iml_mask(u: torch.Tensor) -> torch.Tensor:
            return iml_pim_at(iml, pim, u, valid) > P

        sources["iml"] = (iml_mask, iml.decoder)
    if ims_task is not None and views is not None and ims_task.target == "pim":
        head = ims_task.mask_head if ims_head is None else ims_head
        g = head.generator(views.to(c.device).float()).float()
        # the product's decoder: the IML's, or the one fine-tuned on the IMS's masks (model.decoder_lr > 0)
        sources["ims"] = (lambda u: head.threshold(g, u.to(c.device), ims_lift), ims_task.decoder)
    sources["blue_noise"] = (lambda u: u.to(c.device).view(-1, 1, 1, 1) > P, blue.decoder if blue is not None else None)

    rows: list[dict[str, Any]] = []
    for share in shares:
        for name, (mask_at, decoder) in sources.items():
            im = mask_at_share(mask_at, share, valid, B)
            d_bg, d_obj = _densities(im, c, valid)
            got = im.flatten(1).sum(1) / valid.sum()
            recs = {"fill": fill_c_image(im * c, im, pattern)}
            if decoder is not None:
                recs["decoder"] = decoder(im * c, im)
            for rec_name, c_rec in recs.items():
                rows.append({"share": float(share), "mask": name, "reconstruction": rec_name,
                             "psnr": psnr_per_image(recnn(c_rec), fr).cpu().numpy(), "c_share": got.cpu().numpy(),
                             "density_background": d_bg, "density_object": d_obj})
    return rows


def summarize_equal_share(batches: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """Merge the rows of several batches: mean PSNR and share per (share, mask, reconstruction);
    densities weighted by the batches' sizes."""
    acc: dict[tuple, dict[str, Any]] = {}
    for rows in batches:
        for r in rows:
            k = (r["share"], r["mask"], r["reconstruction"])
            a = acc.setdefault(k, {"share": r["share"], "mask": r["mask"], "reconstruction": r["reconstruction"],
                                   "psnr": [], "c_share": [], "bg": [], "obj": [], "w": []})
            a["psnr"].append(np.asarray(r["psnr"]))
            a["c_share"].append(np.asarray(r["c_share"]))
            a["bg"].append(r["density_background"])
            a["obj"].append(r["density_object"])
            a["w"].append(len(np.asarray(r["psnr"]).reshape(-1)))
    out = []
    for a in acc.values():
        w = np.asarray(a["w"], float)
        out.append({"share": a["share"], "mask": a["mask"], "reconstruction": a["reconstruction"],
                    "psnr": float(np.concatenate(a["psnr"]).mean()), "c_share": float(np.concatenate(a["c_share"]).mean()),
                    "density_background": float(np.average(a["bg"], weights=w)),
                    "density_object": float(np.average(a["obj"], weights=w)), "views": int(w.sum())})
    return out
