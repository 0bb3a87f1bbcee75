"""The ORP on the product path: the smallest mean value ``u`` whose IML/S + RecNN (the IMS mask from the view,
exactly those C-pixels, the IML decoder, the RecNN) stays within epsilon of the RecNN alone on the given views
(:func:`product_orp`), and the record of one mean value on them (:func:`product_point`).

The search itself is :class:`~imls_lightning.orp.search.ORPSearch` with the bounds of :mod:`.search`; this module
runs the product's networks for it, so unlike the rest of the package it loads torch (``imls_lightning.orp`` does
not import it: the sweeper plugin imports the package while Hydra scans its plugins).

Example:
    >>> res = product_orp(ims.mask_head, ims.decoder, recnn, batches, 1.0, confidence=0.95)   # doctest: +SKIP
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import torch

from imls_lightning.base.errors import InputError

from ..core.metrics import psnr_per_image
from ..inference.operating_point import SEARCH_TOLERANCE
from .search import ORPSearch, gap_upper_bound, protocol_gap_record

__all__ = ["product_orp", "product_point"]


@torch.no_grad()
def _prepare_product_views(mask_head: Any, recnn: torch.nn.Module, batches: Sequence[Mapping[str, torch.Tensor]], device):
    """Per batch: the C-Image, the FR truth, the IMS generator's output, the RecNN alone's per-view PSNR and the views."""
    prepared = []
    for b in batches:
        c, fr, v = b["c"].to(device), b["fr"].to(device), b["view"].to(device).float()
        prepared.append((c, fr, mask_head.generator(v).float(), psnr_per_image(recnn(c), fr), v))
    return prepared


def _product_record(mask_head: Any, decoder: torch.nn.Module, recnn: torch.nn.Module, prepared, u, lift: bool,
                    confidence: float, future_views: int | None, strata: Sequence[int] | None,
                    passes: Sequence[int] | None = None, paths: int = 1, per_view: bool = False) -> dict[str, Any]:
    """IML/S + RecNN at mean value ``u`` (a number, or a module of the views ``(B, 9) -> (B,)``, e.g. a
    :class:`~imls_lightning.models.ims.DistanceMeans`) against the RecNN alone on the prepared views: the record of
    :func:`product_orp` (one home for both the search and :func:`product_point`); ``per_view`` adds each view's
    ``gaps_db`` and ``c_shares``."""
    ps, pr, shares = [], [], []
    for c, fr, g, p_rec, v in prepared:
        means = u(v).float() if callable(u) else torch.full((c.shape[0],), float(u))
        margins = u.floor_margin(v) if hasattr(u, "floor_margin") else None  # a floor per band of camera distance
        im = mask_head.threshold(g, means, lift, margins).float()
        ps.append(psnr_per_image(recnn(decoder(im * c, im)), fr))
        pr.append(p_rec)
        shares.append(im.flatten(1).sum(1))
    p_imls, p_rec, cnt = torch.cat(ps), torch.cat(pr), torch.cat(shares).float().mean()
    gaps = (p_rec - p_imls).double().cpu().tolist()
    k = float(mask_head.valid.sum())
    m2 = float(prepared[0][1].shape[-1]) ** 2
    rec = protocol_gap_record(gaps, confidence, future_views, strata, passes, paths)
    rec.update({"psnr_imls": float(p_imls.mean()), "psnr_recnn": float(p_rec.mean()), "c_share": float(cnt) / k,
                "ipr": float(cnt) / m2})
    if per_view:
        rec.update(gaps_db=gaps, c_shares=(torch.cat(shares).float() / k).cpu().tolist())
    return rec


def product_point(mask_head: Any, decoder: torch.nn.Module, recnn: torch.nn.Module, batches: Sequence[Mapping[str, torch.Tensor]],
                  mean, device: torch.device | str = "cpu", confidence: float = 0.5, lift: bool = False,
                  future_views: int | None = None, passes: Sequence[int] | None = None, paths: int = 1,
                  strata: Sequence[int] | None = None, per_view: bool = False) -> dict[str, Any]:
    """IML/S + RecNN at one mean value (or a module of the views giving each its own, e.g. the bands of camera
    distance) on the given views: the record one :func:`product_orp` evaluation makes (``per_view``: with each
    view's ``gaps_db`` and ``c_shares``)."""
    gap_upper_bound([0.0], confidence, future_views)
    prepared = _prepare_product_views(mask_head, recnn, batches, device)
    if not prepared:
        raise InputError("product_point: no views")
    return _product_record(mask_head, decoder, recnn, prepared, mean, lift, confidence, future_views, strata, passes, paths,
                           per_view)


def product_orp(mask_head: Any, decoder: torch.nn.Module, recnn: torch.nn.Module, batches: Sequence[Mapping[str, torch.Tensor]],
                epsilon_db: float = 1.0, tolerance: float = SEARCH_TOLERANCE, device: torch.device | str = "cpu",
                confidence: float = 0.5, lift: bool = False, future_views: int | None = None,
                strata: Sequence[int] | None = None, passes: Sequence[int] | None = None, paths: int = 1):
    """The ORP on the product path: the smallest mean value ``u`` whose IML/S + RecNN (IMS mask from
    the view at ``u``, exactly those C-pixels, the IML decoder, the RecNN) stays within
    ``epsilon_db`` of the RecNN alone on the given (validation) views, with a margin for unseen views:
    the one-sided upper bound at ``confidence`` on the mean per-view gap (of all such views, or of
    ``future_views`` new ones; :func:`~imls_lightning.orp.search.gap_upper_bound`) must stay within
    ``epsilon_db`` (``confidence=0.5``: the mean gap itself).

    One IMS serves every ``u``: it regresses PIM' at its trained mean, rescaled to ``u``
    (:meth:`IMSMaskHead.threshold <imls_lightning.models.ims.IMSMaskHead.threshold>`; needs ``target=pim``).

    Args:
        mask_head: the IMS's :class:`~imls_lightning.models.ims.IMSMaskHead` (on ``device``).
        batches: dicts with ``view (B, 9)``, ``c (B, 3, n, n)``, ``fr (B, 3, m, m)``.
        confidence: in ``[0.5, 1)``.
        future_views: the number of new views the bound is for (``None``: a confidence bound on the mean).
        lift: lift the IMS's masks to the share ``u`` (the evaluation's ``ims_lift``).
        strata: a stratum label per view, in the batches' order (e.g. camera-distance bins,
            :func:`~imls_lightning.orp.search.strata_by_rank`): the bound must then hold in every stratum
            (:func:`~imls_lightning.orp.search.stratified_gap_bound`). ``None``: over all views at once.
        passes: with views along ``paths`` camera paths, a pass label per view
            (:func:`~imls_lightning.orp.search.path_passes`): the bounds then count passes, not views, and are
            for the passes one new path makes (:func:`~imls_lightning.orp.search.pass_gap_bound`).

    Returns:
        :class:`~imls_lightning.orp.ORPResult`; each evaluation's ``record`` has ``gap_db`` (the mean
        per-view gap), ``gap_std_db``, ``gap_bound_db`` (what the search compares with epsilon; with strata the
        largest stratum's), ``views``, ``confidence``, ``future_views``, ``psnr_imls``, ``psnr_recnn``, ``c_share``,
        ``ipr``, and with strata ``strata_gap_db`` (each stratum's mean gap).

    Example:
        >>> res = product_orp(ims.mask_head, ims.decoder, recnn, batches, 1.0, confidence=0.95)   # doctest: +SKIP
        >>> res.best.record["gap_db"] <= res.best.record["gap_bound_db"] <= 1.0         # doctest: +SKIP
        True
    """
    gap_upper_bound([0.0], confidence, future_views)  # a bad confidence fails before any network runs
    views = sum(int(b["c"].shape[0]) for b in batches)
    if strata is not None and len(strata) != views:
        raise InputError(f"product_orp: {len(strata)} stratum labels for {views} views")
    if passes is not None and len(passes) != views:
        raise InputError(f"product_orp: {len(passes)} pass labels for {views} views")
    prepared = _prepare_product_views(mask_head, recnn, batches, device)

    def objective(us: Sequence[float]) -> list[dict[str, float]]:
        return [_product_record(mask_head, decoder, recnn, prepared, u, lift, confidence, future_views, strata, passes, paths)
                for u in us]

    return ORPSearch(epsilon_db=epsilon_db, tolerance=tolerance, max_rounds=12, criterion="gap_bound_db").run(objective)
