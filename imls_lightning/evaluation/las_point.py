"""LAS at the product's promise: its IPR searched on the ORP's search views, as the two-pass sampler's share is.

"LAS at equal IPR" ray-casts as many pixels as IML/S, so it compares two samplers at one cost, not at one quality
(IML/S was 1.8-7.4 dB better there on every paper-regime scene). What a user who chose LAS would run is LAS at the
smallest IPR that keeps the same promise as the product: within ``epsilon_db`` of the RecNN alone by the protocol's
bound (:func:`~imls_lightning.evaluation.baseline_point.smallest_within`), and with ``orp_by_distance`` an IPR per band
of camera distance. Each search view's LAS input is a real low-res render of it (LAS's own); its sampled pixels come
from the cached FR-Image, which the ray caster would return for them. The evaluated (test) views are never looked at.

Example:
    >>> point = las_point(s, cfg, cache, scene, nets, renderer, "cpu", future_views=120)   # doctest: +SKIP
    >>> point.value, point.found                                                            # doctest: +SKIP
    (0.15, True)
"""
from __future__ import annotations

import sys
from typing import Any, Sequence

import numpy as np
import torch

from ..core.compaction import compact
from ..core.metrics import psnr_per_image
from ..core.smallest_within import smallest_within
from ..estimate.measure import frame_tensor
from .baseline_point import SearchedPoint, choose, say_value
from .networks import Networks
from .operating_point import judged, search_views
from .settings import Settings


def las_gaps(las_net: torch.nn.Module, recnn: torch.nn.Module, pattern, renderer, views: Sequence, frames: Sequence,
             iprs: Sequence[float], device="cpu") -> tuple[np.ndarray, np.ndarray]:
    """Per view and IPR, the IPR LAS kept and its PSNR gap to the RecNN alone on its whole pattern: two
    ``(views, len(iprs))`` arrays.

    Args:
        las_net: a :class:`~imls_lightning.models.las.LASNet` (its ``low_res`` is the side of the render it sees).
        recnn: the RecNN alone, C-Image ``(1, 3, n, n)`` -> FR ``(1, 3, m, m)``.
        pattern: the RecNN's :class:`~imls_lightning.core.patterns.SamplingPattern`.
        renderer: renders each view's low-res input (``render(view, side)``).
        views, frames: the views ``(9,)`` and their FR frames ``(m, m, 3)`` uint8 (the ray caster's pixels).
        iprs: the IPRs tried, each in ``(0, 1]``; LAS's mean is bisected per view to each (its protocol).
    """
    kept = np.zeros((len(frames), len(iprs)))
    gaps = np.zeros_like(kept)
    h = int(las_net.low_res)
    with torch.inference_mode():
        for i, (view, fr) in enumerate(zip(views, frames)):
            target = frame_tensor(fr).to(device)
            c = compact(target, pattern.indices.to(device), pattern.c_size)
            ref = float(psnr_per_image(recnn(c).float().clamp(0, 1), target)[0])
            low = renderer.render(np.asarray(view, np.float64), h)
            raw = las_net.importance_net(frame_tensor(low).to(device))
            for j, ipr in enumerate(iprs):
                mask = las_net.mask_at(raw, las_net.mean_for_ipr(raw, float(ipr))).float()
                out = las_net.reconstruct(target * mask, mask).float().clamp(0, 1)
                gaps[i, j] = ref - float(psnr_per_image(out, target)[0])
                kept[i, j] = float(mask.mean())
    return kept, gaps


def las_point(s: Settings, cfg, cache, scene, nets: Networks, renderer, device, future_views: int | None = None) -> SearchedPoint:
    """Search LAS's IPR on the ORP's search views (``s.las_search_iprs``; the bound at ``s.orp_confidence`` for
    ``future_views`` new views, within ``s.epsilon_db``)."""
    v = search_views(s, cfg, cache, scene)
    iprs = sorted(s.las_search_iprs)
    print(f"[evaluate] LAS at the promise: its IPR searched among {', '.join(f'{x:.1%}' for x in iprs)} on {v.where}, "
          f"judged by the {s.orp_confidence:.0%} upper bound on the mean gap of {judged(v, future_views)}",
          file=sys.stderr, flush=True)
    las = nets.las_task.net.to(device).eval()
    recnn = nets.recnn.to(device).eval()
    views = [v.cache.views[r] for r in v.rows]
    frames = [np.asarray(v.cache.images[r]) for r in v.rows]
    kept, gaps = las_gaps(las, recnn, nets.ims_task.pattern, renderer, views, frames, iprs, device)
    chosen, rows, by_distance = choose(v, s, iprs, kept, gaps, future_views, "LAS at the promise",
                                     lambda x: say_value("ipr", x))
    rows = [{"ipr": r["value"], "kept": r["kept"], "gap_db": r["gap_db"], "gap_bound_db": r["gap_bound_db"]} for r in rows]
    return SearchedPoint("ipr", float(chosen["value"]) if chosen else float(iprs[-1]), found=chosen is not None, where=v.where,
                         epsilon_db=float(s.epsilon_db), record=chosen, rows=rows, by_distance=by_distance)


#: the report's line on where LAS at the promise runs and why (``point``: its :class:`~.baseline_point.SearchedPoint`)
describe_las = SearchedPoint.describe

#: "equal quality" with IML/S (issue 84): LAS's mean validation gap within this much of IML/S's
EQUAL_QUALITY_DB = 0.1


def imls_validation_gap(orp: dict[str, Any] | None) -> float | None:
    """IML/S's mean gap to the RecNN alone on the validation views at its operating point: the object floor's chosen
    record where there is one (the point IML/S runs at), else the ORP's; None without a found point.

    Example:
        >>> imls_validation_gap({"found": True, "gap_db": 0.4, "object_floor": {"chosen": {"gap_db": 0.21}}})
        0.21
        >>> imls_validation_gap({"found": True, "gap_db": 0.4}), imls_validation_gap({"found": False})
        (0.4, None)
    """
    if not orp or not orp.get("found"):
        return None
    chosen = (orp.get("object_floor") or {}).get("chosen") or {}
    gap = chosen.get("gap_db", orp.get("gap_db"))
    return None if gap is None else float(gap)


def equal_quality_point(searched: SearchedPoint, imls_gap_db: float, margin_db: float = EQUAL_QUALITY_DB) -> SearchedPoint:
    """LAS at IML/S's quality: of the IPRs LAS's promise search scored (``searched.rows``, their mean gaps on the same
    search views), the smallest whose mean gap is within ``margin_db`` of IML/S's validation gap (not better by a dB:
    "equal quality" compares like with like). No new render: the search's gaps are reused. Where none is, the one
    closest to that gap.

    Example:
        >>> pt = SearchedPoint("ipr", 0.3, True, "views", 1.0, None, rows=[{"ipr": 0.05, "gap_db": 2.0}, {"ipr": 0.1, "gap_db": 0.5},
        ...                                                                {"ipr": 0.2, "gap_db": 0.2}])
        >>> equal_quality_point(pt, 0.45).value
        0.1
    """
    rows = sorted(searched.rows, key=lambda r: float(r["ipr"]))
    target = float(imls_gap_db) + float(margin_db)
    chosen = smallest_within(rows, target, gap=lambda r: float(r["gap_db"]), otherwise="closest")
    pick = chosen.item
    return SearchedPoint("ipr", float(pick["ipr"]), found=chosen.found, where=searched.where, epsilon_db=target,
                    record={"gap_db": float(pick["gap_db"]), "imls_gap_db": float(imls_gap_db), "margin_db": float(margin_db)},
                    rows=list(rows))


def las_searched_method(point: SearchedPoint, renderer, las_task, fr_size: int, opts):
    """The method the evaluation measures at ``point`` (key ``las_searched``)."""
    from ..inference.pipeline import LASMethod

    method = LASMethod(renderer, las_task.net, fr_size, int(las_task.hparams["low_res"]), ipr=point.value, opts=opts,
                       by_distance=point.values_by_distance())
    method.name = "las_searched"
    return method


__all__ = ["describe_las", "equal_quality_point", "imls_validation_gap", "las_gaps", "las_point", "las_searched_method"]
