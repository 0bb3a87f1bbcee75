"""The classical two-pass sampler in an evaluation ("beat the simplest alternative"): what a user would do instead
of training an IMS, measured beside the product on the same views.

Its share of C is an operating point like the product's, so it is chosen the same way: on the ORP's own search
views (:func:`~imls_lightning.evaluation.operating_point.search_views`), the smallest share of
:data:`~imls_lightning.estimate.needed_share.NEEDED_SHARES` above the first pass whose protocol bound
(:func:`~imls_lightning.orp.search.protocol_gap_record`: passes, bands of camera distance) stays within
``epsilon_db`` of the RecNN alone. With ``orp_by_distance``, as the product's mean value, each band of camera
distance then gets its own share (:func:`band_shares`): the smallest that keeps the band's own bound, never above the
share that held in every band. The evaluated (test) views are never looked at. Then
:class:`~imls_lightning.inference.two_pass.TwoPassFill` runs at that share (each view at its band's) on the real ray
caster like every other method.

Example:
    >>> point = two_pass_point(s, cfg, cache, scene, nets, pattern, "cpu", future_views=120)   # doctest: +SKIP
    >>> point.value, point.found                                                                # doctest: +SKIP
    (0.7, True)
"""
from __future__ import annotations

import sys
from typing import Any

import numpy as np
import torch

from ..estimate.needed_share import NEEDED_SHARES, share_gaps
from .networks import Networks
from .baseline_point import SearchedPoint, band_values, choose, say_value
from .operating_point import SearchViews, judged, search_views
from .settings import Settings


#: the report's line on where the two-pass sampler runs and why (``point``: its :class:`~.baseline_point.SearchedPoint`)
describe_two_pass = SearchedPoint.describe


def candidate_shares(base: float) -> list[float]:
    """The shares searched: those of :data:`NEEDED_SHARES` above the first pass (it is part of the share).

    Example:
        >>> candidate_shares(0.8)
        [0.85, 0.9, 0.95, 1.0]
    """
    return [x for x in NEEDED_SHARES if x > base + 1e-9]


def two_pass_point(s: Settings, cfg, cache, scene, nets: Networks, pattern, device,
                   future_views: int | None = None) -> SearchedPoint:
    """Search the two-pass sampler's share on the ORP's search views (``s.two_pass_base``, ``s.two_pass_floor``;
    the bound at ``s.orp_confidence`` for ``future_views`` new views, within ``s.epsilon_db``)."""
    v = search_views(s, cfg, cache, scene)
    base, floor = float(s.two_pass_base), float(s.two_pass_floor)
    print(f"[evaluate] two-pass sampler (first pass {base:.0%} of C): its share searched on {v.where}, judged by the "
          f"{s.orp_confidence:.0%} upper bound on the mean gap of {judged(v, future_views)}", file=sys.stderr, flush=True)
    recnn = nets.recnn.to(device).eval()
    shares = candidate_shares(base)

    def rebuild(c: torch.Tensor) -> torch.Tensor:
        return recnn(c.to(device)).float().cpu()

    frames = [np.asarray(v.cache.images[r]) for r in v.rows]
    kept, gaps = share_gaps(rebuild, pattern, frames, shares, floor=floor, base=base)
    chosen, searched, by_distance = choose(v, s, shares, kept, gaps, future_views, "the two-pass sampler",
                                           lambda x: say_value("share", x))
    rows = [{**r, "share": r["value"], "c_share": r["kept"]} for r in searched]
    chosen = None if chosen is None else {**chosen, "share": chosen["value"], "c_share": chosen["kept"]}
    by_distance = None if by_distance is None else shares_named(by_distance)
    return SearchedPoint("share", float(chosen["share"]) if chosen else 1.0, found=chosen is not None, where=v.where,
                         epsilon_db=float(s.epsilon_db), record=chosen, rows=rows, by_distance=by_distance,
                         settings={"base": base, "floor": floor})


def band_shares(v: SearchViews, shares: list[float], kept: np.ndarray, gaps: np.ndarray, confidence: float,
                epsilon_db: float, future_views: int | None) -> dict[str, Any] | None:
    """Each band of camera distance's own share (:func:`~imls_lightning.evaluation.baseline_point.band_values`):
    ``edges``, and per band near to far ``shares``, ``c_shares``, ``gaps_db``, ``bounds_db``, ``views``, ``lo``,
    ``hi``; ``None`` where the views' distances do not separate the bands."""
    out = band_values(v, shares, kept, gaps, confidence, epsilon_db, future_views)
    return None if out is None else shares_named(out)


def shares_named(b: dict[str, Any]) -> dict[str, Any]:
    """:func:`~imls_lightning.evaluation.baseline_point.band_values`' output under the two-pass sampler's names
    (``values`` -> ``shares``, ``kept`` -> ``c_shares``), in place."""
    b["shares"], b["c_shares"] = b.pop("values"), b.pop("kept")
    return b


def two_pass_method(point: SearchedPoint, renderer, pattern, recnn, opts):
    """The method the evaluation measures at ``point``."""
    from ..inference.two_pass import TwoPassFill

    return TwoPassFill(renderer, pattern, recnn, share=point.value, base=point.settings["base"], floor=point.settings["floor"], opts=opts,
                       by_distance=point.values_by_distance())


__all__ = ["describe_two_pass", "candidate_shares", "two_pass_point", "band_shares", "shares_named", "two_pass_method"]
