"""The operating point (ORP) of an evaluation: searched on the product path on views no network was
trained on (:func:`orp_search_views`, :func:`product_path_orp`, with the IMS's masks lifted when the
paper's rescale finds none: :func:`orp_with_lift`), summarized for the report (:func:`orp_summary`,
:func:`paired_gap`, :func:`gap_by_distance`) and recorded beside the IMS checkpoint (:func:`record_operating_point`);
or taken from a finished evaluation of the same networks instead of searched (:func:`borrowed_point`, ``orp_from``)."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from data_gen.views import camera_distance as view_distance

from ..core.operating_point import Bands, OperatingPoint
from ..core.smallest_within import Within, smallest_within
from ..models.iml import decoder_at
from ..orp.product import product_orp, product_point
from .measurement import spaced, view_loader
from .networks import Networks
from .settings import Settings


def record_from_orp(orp: dict[str, Any], *, scene: str | None = None, report: str | None = None, views: int | None = None):
    """The :class:`~imls_lightning.inference.operating_point.ORPRecord` of an evaluation's ``orp`` summary (its
    ``summary.json``'s ``orp``): what is recorded beside the IMS checkpoint (the point it runs at is
    :func:`point_of` of the same summary)."""
    from ..inference.operating_point import SEARCH_TOLERANCE, ORPRecord

    opt = lambda k: None if orp.get(k) is None else float(orp[k])  # noqa: E731
    bands = orp.get("by_distance") if orp["found"] else None
    # the share of C the search measured at each mean value it tried: the record's share is checked against it on read
    points = [[float(p[0]), float(p[2])] for p in orp.get("points") or [] if p[0] is not None and p[2] is not None]
    return ORPRecord(mean=opt("mean") if orp["found"] else None, lift=bool(orp["lift"]), c_share=opt("c_share"),
                     ipr=opt("ipr"), epsilon_db=float(orp["epsilon_db"]), gap_db=opt("gap_db"),
                     views=int(views) if views is not None else orp.get("views"), scene=scene, report=report,
                     by_distance=None if not bands else {k: bands[k] for k in ("edges", "means", "c_shares", "gaps_db", "views")},
                     sharpness=float(orp.get("sharpness", 1.0)),
                     object_floor=(orp.get("object_floor") or {}).get("chosen") if orp["found"] else None,
                     points=points or None, tolerance=SEARCH_TOLERANCE,
                     decoder=str(orp.get("decoder") or "trained") if orp["found"] else "trained")


def record_operating_point(s: Settings, orp: dict[str, Any], scene: str, report: Path, views: int) -> None:
    """Record the ORP IML/S ran at beside the IMS checkpoint (``<ims.ckpt>.orp.json``, see
    :mod:`imls_lightning.inference.operating_point`), where renderers built from the checkpoint alone
    find it; a folder that cannot be written is a one-line warning (the report holds the point)."""
    from ..inference.operating_point import write_operating_point

    point = record_from_orp(orp, scene=scene, report=str(Path(report).resolve()), views=int(views))
    try:
        path = write_operating_point(s.ims, point)
    except OSError as err:
        print(f"[evaluate] warning: cannot record the operating point beside {s.ims} ({err.strerror or type(err).__name__}): "
              "renderers built from the checkpoint alone run at its trained mean", file=sys.stderr, flush=True)
        return
    print(f"[evaluate] operating point {point.describe()} recorded for the IMS checkpoint: {path}", file=sys.stderr, flush=True)


def orp_search_views(s: Settings, cfg, cache, scene):
    """The views the ORP is searched on: ``(cache, rows, description, paths)``; ``paths`` is a path label per
    row for views along camera paths (``orp_views=path``), else ``None``.

    ``orp_views=val``: ``orp_max_views`` of the cache's validation views, evenly spaced. ``heldout``
    (default): ``orp_max_views`` views (null: as many as the cache has validation views) drawn like the
    training views but from a seed of their own (``orp_views_seed``; null: ``data.seed + 1``), rendered
    into a cache of their own (``data.num_views`` of them, no trajectory): no network was trained on them
    nor on their eye directions. The validation split is not held out from an IMS trained on a larger
    cache of the same seed (the demo's 1,500 views): the first training draws of both caches share their
    eye directions (:func:`data_gen.views.sample_training_views`). ``path``: as many views along an
    exploratory path of their own seed (:func:`data_gen.views.exploration_trajectory`; its cache holds one
    training view besides), so that they are distributed as the test trajectory's are: training views
    take every distance in the shell equally often and every direction, the path dwells at its zoom
    extremes and stays within 45 degrees of the equator. On seed_shell, whose gap grows on close-ups, it
    did not keep the promise either (search gap 0.77 dB, test gap 1.29 dB; ``heldout``: 0.72 / 1.21 dB):
    one path's close-ups fall at other elevations than another's. So the path views lie on ``orp_paths``
    paths of seeds of their own (``orp_views_seed``, +1, ...), ``orp_max_views`` split between them, and the
    search counts passes, not views (:func:`~imls_lightning.orp.search.path_passes`).
    """
    from data_gen.cache import ViewImageCache, ensure_cache

    val = cache.splits["val"]
    if s.orp_views == "val":
        if len(val) == 0:
            raise InputError(f"orp=true: the cache {cache.path} has no validation views to search the ORP on; pass orp=false")
        rows = val[spaced(len(val), s.orp_max_views)]
        return cache, rows, f"{len(rows)} of the cache's validation views", None
    n = s.orp_max_views or max(len(val), 1)
    seed = int(cfg.data.seed) + 1 if s.orp_views_seed is None else int(s.orp_views_seed)
    # a cache of its own (never cache_path, the evaluated cache's exact folder), rendered whole (no shard)
    path = s.orp_views == "path"
    views = {"num_views": 1, "test_views": int(n)} if path else {"num_views": int(n), "test_views": 0}
    trajectory, labels = None, None
    if path:
        trajectory, labels = _search_paths(s, cfg, scene, n, seed)
        views["test_views"] = len(labels)
    data = OmegaConf.merge(cfg.data, {**views, "seed": seed, "val_fraction": 0.0, "test_trajectory": trajectory,
                                      "cache_path": None, "shard": None})
    held = ViewImageCache.open(ensure_cache(scene, data, cfg.renderer, progress=s.progress))
    if path:
        return (held, held.splits["test"], f"{len(labels)} views on {s.orp_paths} exploratory paths of their own (seeds "
                f"{seed}-{seed + s.orp_paths - 1}: no network trained on them)", labels)
    return held, held.splits["train"], f"{n} held-out views (seed {seed}: no network trained on them)", None


def _search_paths(s: Settings, cfg, scene, n: int, seed: int) -> tuple[str, list[int]]:
    """``orp_paths`` exploratory paths of ``ceil(n / orp_paths)`` views each, seeds ``seed``, ``seed + 1``, ...,
    written (content-named, atomically) as a views file under the cache folder: ``(file, path label per view)``."""
    from data_gen.views import exploration_trajectory

    from .protocol import write_views_file

    if int(cfg.data.seed) in range(seed, seed + s.orp_paths):
        raise InputError(f"orp_views_seed={seed}: the search paths' seeds {seed}-{seed + s.orp_paths - 1} include "
                         f"data.seed={cfg.data.seed}, the test trajectory's own: pick a seed outside them")
    per = -(-int(n) // s.orp_paths)
    views = np.concatenate([exploration_trajectory(per, scene.camera_distance, seed=seed + k,
                                                   lookat_jitter=float(cfg.data.lookat_jitter)) for k in range(s.orp_paths)])
    out = write_views_file(views, Path(str(cfg.data.cache_dir)) / "orp_paths")
    return str(out), [i // per for i in range(len(views))]


@dataclass
class SearchViews:
    """The views an operating point is searched on and how the protocol counts them (:func:`search_views`)."""
    cache: Any
    rows: Any
    where: str                        # how the report says where the search ran
    distances: list[float]            # each view's camera distance
    strata: list[int] | None          # each view's band of camera distance (orp_strata > 1)
    passes: list[int] | None          # each view's pass (orp_views=path): a pass, not a view, is one observation
    paths: int                        # the camera paths the views lie on (1 without paths)


def search_views(s: Settings, cfg, cache, scene) -> SearchViews:
    """:func:`orp_search_views` with their bands of camera distance and passes: one home for the product's ORP
    and every other operating point searched beside it (the two-pass sampler's share), so both are judged alike."""
    from ..orp import path_passes, strata_by_rank

    cache, rows, where, paths = orp_search_views(s, cfg, cache, scene)
    # orp_strata > 1: the bound must hold in each band of camera distance, not only on the views' mix of them
    distances = [camera_distance(cache, r) for r in rows]
    strata = strata_by_rank(distances, s.orp_strata) if s.orp_strata > 1 else None
    # views along paths: consecutive views of a path within a band are one pass, one observation
    passes = None if paths is None else path_passes(paths, strata)
    npaths = 1 if paths is None else len(set(paths))
    if passes is not None:
        where += f" ({len(set(passes))} passes: the bound counts passes)"
    if strata is not None:
        where += f", in each of {s.orp_strata} equal-count bands of camera distance"
    return SearchViews(cache, rows, where, distances, strata, passes, npaths)


def judged(v: SearchViews, future_views: int | None) -> str:
    """What the bound is for, in the log's words."""
    return "one new trajectory's passes" if v.passes is not None else f"{future_views or 'all'} new views"


def product_path_orp(s: Settings, cfg, cache, scene, nets: Networks, pattern, device, future_views: int | None = None,
                     renderer=None):
    """The ORP on the product path, searched on :func:`orp_search_views` (see :func:`~imls_lightning.orp.product.product_orp`);
    its bound is for the mean gap of ``future_views`` new views (the evaluated ones).

    With several candidates, ``ims_sharpness`` (mask sharpnesses) by ``orp_decoders`` (the IMS's own decoder, the
    pull-push fill of the same pixels), the whole search (and the bands' own values) runs at each. The point
    kept is the one whose product (IMS mask, exactly its pixels ray-cast by ``renderer``, decoder, RecNN) runs
    fastest on ``ims_sharpness_views`` of the search views, the candidates interleaved run by run
    (:func:`candidate_times`): a sharper mask keeps the object's rays, which march further, so its share of C
    understates its cost; the fill costs no network, so at a larger share it may still be the faster. Without a
    renderer, or with ``ims_sharpness_views=0``, the one that ray-casts the smallest share of C (the smaller
    sharpness, then the trained decoder, on a tie). ``result.sharpness`` and ``result.decoder`` are its own,
    ``result.sharpness_candidates`` what each reached, ``result.object_floor`` the floor chosen; nothing of the IMS
    task changes: every method the evaluation builds gets the point (:func:`point_of`)."""
    v = search_views(s, cfg, cache, scene)
    print(f"[evaluate] ORP: searched on {v.where}, judged by the {s.orp_confidence:.0%} upper bound on the mean gap of "
          f"{judged(v, future_views)}", file=sys.stderr, flush=True)
    ims = nets.ims_task
    results = []
    several = len(s.ims_sharpness) * len(s.orp_decoders) > 1
    for gamma in s.ims_sharpness:
        for decoder in s.orp_decoders:
            if several:
                print(f"[evaluate] ORP at mask sharpness {gamma:g}, decoder {decoder}", file=sys.stderr, flush=True)
            results.append(_orp_at_sharpness(s, v, nets, pattern, device, future_views, gamma, decoder))
            results[-1].sharpness, results[-1].decoder = gamma, decoder
    found = [r for r in results if r.found]
    times = (candidate_times(found, v, nets, pattern, renderer, s.options, s.ims_sharpness_views)
             if len(found) > 1 and renderer is not None and s.ims_sharpness_views > 0 else {})
    trained_first = lambda r: r.decoder != "trained"  # noqa: E731  (a tie keeps the paper's decoder)
    if times:
        best = min(found, key=lambda r: (times[candidate_key(r)], r.sharpness, trained_first(r)))
    else:
        best = min(found, key=lambda r: (operating_share(r), r.sharpness, trained_first(r))) if found else results[0]
    best.sharpness_candidates = [{"sharpness": r.sharpness, "decoder": r.decoder, "found": r.found, "mean": r.mean,
                                  "c_share": operating_share(r), "lift": r.lifted, "ms": times.get(candidate_key(r)),
                                  # its bands, so the evaluation can run a candidate not kept beside the kept one
                                  **({"by_distance": r.by_distance} if getattr(r, "by_distance", None) else {})}
                                 for r in results] if several else None
    if several:
        print("[evaluate] ORP candidates: " + "; ".join(
            f"{c['sharpness']:g}, {c['decoder']}: " + (f"{c['c_share']:.1%} of C" + (f", {c['ms']:.0f} ms" if c["ms"] is not None else "")
                                                       if c["found"] else "none") for c in best.sharpness_candidates)
            + f"; kept {best.sharpness:g}, {best.decoder}" + (f" (the fastest on {s.ims_sharpness_views} search views)" if times
                                                             else " (the smallest share of C)"), file=sys.stderr, flush=True)
    best.object_floor = None
    if s.orp_object_floor and best.found:
        best.object_floor = object_floor_point(s, cache, nets, pattern, device, best, future_views)
    return best


def object_floor_point(s: Settings, cache, nets: Networks, pattern, device, result, future_views: int | None) -> dict[str, Any]:
    """The object floor's margin (``orp_object_floor``) for a found operating point: IML/S + RecNN at the point's mean
    value (or its bands'), each view raised to its object's share plus each candidate margin
    (:meth:`~imls_lightning.models.ims.IMSMaskHead.with_object_floor`), on the evaluated cache's validation views.

    Not on the search views: the bands were chosen to hold there, so no floor would ever look needed. The
    validation views are drawn like the training views (every distance, every direction) and no network was trained
    on them; the test trajectory is never looked at. Each candidate is judged as the search judges a band: the
    bound for ``future_views`` new views (with ``orp_strata``, in each band of camera distance) within
    ``epsilon_db``. Of those that hold (no floor among them), the one that ray-casts the smallest share of C is
    chosen (:func:`choose_object_floor`).

    Returns:
        ``{"tau", "views", "candidates": [{"margin" (None: no floor), "gap_db", "gap_bound_db", "c_share",
        "strata_gap_db", "views_over_epsilon"}], "chosen": {"margin", "tau", "c_share", "gap_db", "gap_bound_db",
        "views"} or None (no floor: the bands alone held, or were the cheapest that did)}``.

    Raises:
        InputError: the cache has no validation views.
    """
    from ..orp import strata_by_rank

    rows = cache.splits["val"]
    if len(rows) == 0:
        raise InputError(f"orp_object_floor: the cache {cache.path} has no validation views to choose the floor's margin on "
                         "(data.val_fraction > 0), or pass orp_object_floor=null")
    ims, tau = nets.ims_task, s.orp_object_floor_tau
    bands = distance_means(result)
    u = bands.to(device) if bands is not None else float(result.mean)
    distances = [camera_distance(cache, r) for r in rows]
    strata = strata_by_rank(distances, s.orp_strata) if s.orp_strata > 1 else None
    recnn = nets.recnn.to(device).eval()
    candidates = []
    with torch.inference_mode():
        batches = list(view_loader(cache, rows, pattern))
        head = ims.mask_head.with_sharpness(float(getattr(result, "sharpness", 1.0)))  # the masks the point was searched with
        rebuild = decoder_at(candidate_key(result)[1], ims.decoder, ims.pattern)  # and its decoder
        for margin in [None, *s.orp_object_floor]:
            rec = product_point(head.with_object_floor(margin, tau), rebuild, recnn, batches, u, device=device,
                                confidence=s.orp_confidence, lift=result.lifted, future_views=future_views, strata=strata,
                                per_view=True)
            candidates.append({"margin": margin, "gap_db": rec["gap_db"], "gap_bound_db": rec["gap_bound_db"],
                               "c_share": rec["c_share"], "strata_gap_db": rec.get("strata_gap_db"),
                               "views_over_epsilon": int(sum(g > s.epsilon_db for g in rec["gaps_db"])), "views": len(rows),
                               "gaps_db": rec["gaps_db"], "c_shares": rec["c_shares"]})
            c = candidates[-1]
            print(f"[evaluate] object floor on {len(rows)} validation views: " + ("no floor" if margin is None else
                  f"object + {margin:g}") + f": {c['c_share']:.1%} of C, gap {c['gap_db']:.2f} dB (bound {c['gap_bound_db']:.2f}), "
                  f"{c['views_over_epsilon']} views over {s.epsilon_db:g} dB", file=sys.stderr, flush=True)
    if s.orp_object_floor_by_band:
        return _object_floor_by_band(s, cache, rows, bands, candidates, tau, future_views)
    pick = object_floor_pick(candidates, s.epsilon_db, s.orp_object_floor_tail, otherwise="least")
    if not pick.found:
        print(f"[evaluate] warning: object floor: no margin keeps the bound within {s.epsilon_db:g} dB on the validation "
              "views; keeping the one with the smallest bound", file=sys.stderr, flush=True)
    c = pick.item
    chosen = None if c["margin"] is None else {"margin": float(c["margin"]), "tau": float(tau), "c_share": c["c_share"],
                                               "gap_db": c["gap_db"], "gap_bound_db": c["gap_bound_db"], "views": len(rows)}
    print("[evaluate] object floor: " + ("none (the operating point alone is the cheapest that holds)" if chosen is None else
          f"each view at least its object (PIM' > {tau:g}) + {chosen['margin']:g} of C"), file=sys.stderr, flush=True)
    return {"tau": float(tau), "views": len(rows), "candidates": [_brief(c) for c in candidates], "chosen": chosen}


def _brief(candidate: dict[str, Any]) -> dict[str, Any]:
    """A candidate for the summary: its per-view lists left out."""
    return {k: v for k, v in candidate.items() if k not in ("gaps_db", "c_shares")}


def _object_floor_by_band(s: Settings, cache, rows, bands, candidates: list[dict[str, Any]], tau: float,
                          future_views: int | None) -> dict[str, Any]:
    """``orp_object_floor_by_band``: each band of camera distance (``bands``, the point's
    :class:`~imls_lightning.models.ims.DistanceMeans`) keeps its own margin, judged on its own validation views as
    :func:`object_floor_point` judges one for all (the bound for the band's share of ``future_views`` within
    ``epsilon_db``, at most ``orp_object_floor_tail`` of its views over it; the cheapest that holds, no floor among
    them). A band no validation view falls in takes the largest candidate margin. The chosen record's ``margin`` is
    the largest band margin (for consumers that take one), ``band_margins`` the bands' (``None``: no floor there)."""
    from ..orp import stratified_gap_bound

    if bands is None:
        raise InputError("orp_object_floor_by_band=true: the operating point has no bands of camera distance "
                         "(orp_by_distance=true)")
    views = torch.as_tensor(np.stack([np.asarray(cache.views[r], np.float32) for r in rows]))
    label = bands.band(views.to(bands.edges.device)).cpu().numpy()
    k_bands = int(bands.means.numel())
    present = sorted(set(label.tolist()))  # stratified_gap_bound's order of its per-stratum bounds
    for c in candidates:  # each candidate's record per band, beside its record over all views
        g, sh = np.asarray(c["gaps_db"], np.float64), np.asarray(c["c_shares"], np.float64)
        _, each = stratified_gap_bound(g, label, s.orp_confidence, future_views)
        bound = dict(zip(present, (b.bound for b in each)))
        c["band_bounds_db"] = [bound.get(k) for k in range(k_bands)]
        c["band_c_shares"] = [float(sh[label == k].mean()) if (label == k).any() else None for k in range(k_bands)]
        c["band_views_over_epsilon"] = [int((g[label == k] > s.epsilon_db).sum()) for k in range(k_bands)]
    largest = max(range(len(candidates)), key=lambda i: -1.0 if candidates[i]["margin"] is None else candidates[i]["margin"])
    choice, warned = [], []
    for k in range(k_bands):
        n_k = int((label == k).sum())
        if n_k == 0:
            choice.append(largest)
            warned.append(f"band {k}: no validation view, the largest margin")
            continue
        band = [{"gap_bound_db": c["band_bounds_db"][k], "c_share": c["band_c_shares"][k],
                 "views_over_epsilon": c["band_views_over_epsilon"][k], "views": n_k} for c in candidates]
        pick = object_floor_pick(band, s.epsilon_db, s.orp_object_floor_tail, otherwise="least")
        if not pick.found:
            warned.append(f"band {k}: nothing holds, the smallest bound")
        choice.append(pick.index)
    for w in warned:
        print(f"[evaluate] warning: object floor by band: {w}", file=sys.stderr, flush=True)
    margins = [candidates[i]["margin"] for i in choice]
    gaps = np.array([candidates[choice[k]]["gaps_db"][j] for j, k in enumerate(label)])
    shares = np.array([candidates[choice[k]]["c_shares"][j] for j, k in enumerate(label)])
    bounds = [candidates[choice[k]]["band_bounds_db"][k] for k in range(k_bands)]
    chosen = None
    if any(m is not None for m in margins):
        chosen = {"margin": float(max(m for m in margins if m is not None)), "tau": float(tau),
                  "band_margins": [None if m is None else float(m) for m in margins],
                  "c_share": float(shares.mean()), "gap_db": float(gaps.mean()),
                  "gap_bound_db": float(max(b for b in bounds if b is not None)), "views": len(rows),
                  "views_over_epsilon": int((gaps > s.epsilon_db).sum())}
    print("[evaluate] object floor by band (near to far): " + " / ".join("none" if m is None else f"{m:g}" for m in margins)
          + f": {shares.mean():.1%} of C, gap {gaps.mean():.2f} dB, {int((gaps > s.epsilon_db).sum())} of {len(rows)} "
          f"validation views over {s.epsilon_db:g} dB", file=sys.stderr, flush=True)
    return {"tau": float(tau), "views": len(rows), "by_band": True, "tail": s.orp_object_floor_tail,
            "candidates": [_brief(c) for c in candidates], "chosen": chosen}


def choose_object_floor(candidates: Sequence[dict[str, Any]], epsilon_db: float, tail: float = 1.0) -> int | None:
    """Of ``candidates`` (each with ``gap_bound_db`` and ``c_share``) whose bound stays within ``epsilon_db``, the index of
    the one with the smallest share of C (the fastest; the earlier on a tie); ``None`` where none holds. With
    ``tail < 1`` a candidate that also has ``views_over_epsilon`` and ``views`` must leave at most ``tail * views`` of
    its views over ``epsilon_db`` (a promise per view beside the one on the mean).

    Example:
        >>> cands = [{"gap_bound_db": 1.4, "c_share": 0.30}, {"gap_bound_db": 0.9, "c_share": 0.41},
        ...          {"gap_bound_db": 0.6, "c_share": 0.45}]
        >>> choose_object_floor(cands, 1.0), choose_object_floor(cands, 0.5)
        (1, None)
        >>> cands[1].update(views_over_epsilon=2, views=10)
        >>> choose_object_floor(cands, 1.0, tail=0.1)
        2
    """
    return object_floor_pick(candidates, epsilon_db, tail).index


def object_floor_pick(candidates: Sequence[dict[str, Any]], epsilon_db: float, tail: float = 1.0,
                      otherwise: str | None = None) -> Within:
    """:func:`choose_object_floor`'s choice as :func:`~imls_lightning.core.smallest_within.smallest_within` gives it
    (``found``: whether it holds); with ``otherwise="least"``, where none holds, the candidate of the smallest bound
    (the earlier on a tie)."""
    def tail_holds(c) -> bool:
        return tail >= 1.0 or c.get("views") is None or int(c["views_over_epsilon"]) <= tail * int(c["views"])

    return smallest_within(candidates, epsilon_db, gap=lambda c: float(c["gap_bound_db"]),
                           value=lambda c: float(c["c_share"]), holds=tail_holds, otherwise=otherwise)


def candidate_times(found: Sequence[Any], v: "SearchViews", nets: Networks, pattern, renderer, opts, views: int,
                    repeats: int = 3) -> dict[float, float]:
    """Each found candidate's product at its operating point (its sharpness, decoder, mean value or bands, lift), timed
    on ``views`` of the search views spaced along them, the candidates interleaved run by run
    (:func:`~imls_lightning.evaluation.timing.time_methods`): ``{candidate_key: mean over the views of the median total
    ms}``."""
    from ..inference.pipeline import IMLSRenderer
    from .timing import time_methods

    ims = nets.ims_task
    products = {candidate_key(r): IMLSRenderer(renderer, pattern, ims.mask_head, ims.decoder, nets.recnn, opts,
                                               point=point_of(r, float(r.mean), bool(r.lifted)))
                for r in found}
    rows = [int(v.rows[i]) for i in spaced(len(v.rows), views)]
    per_view: dict[float, list[float]] = {g: [] for g in products}
    for row in rows:
        timed = time_methods(products, np.asarray(v.cache.views[row], np.float64), repeats=repeats, warmup=1)
        for g, (_, med, _) in timed.items():
            per_view[g].append(1e3 * med["total"])
    return {g: float(np.mean(t)) for g, t in per_view.items()}


def candidate_key(result) -> tuple[float, str]:
    """A searched candidate's ``(sharpness, decoder)``: what :func:`candidate_times` keys its time by."""
    return float(getattr(result, "sharpness", 1.0)), str(getattr(result, "decoder", "trained"))


def operating_share(result) -> float | None:
    """The share of C an operating point ray-casts on its search views: the mean over its bands of camera distance
    (equal-count bands) where it has them, else its single mean value's."""
    bands = getattr(result, "by_distance", None)
    if bands and bands.get("c_shares"):
        return float(np.mean(bands["c_shares"]))
    rec = result.best.record if result.best is not None else {}
    return rec.get("c_share")


def _orp_at_sharpness(s: Settings, v: "SearchViews", nets: Networks, pattern, device, future_views: int | None,
                      sharpness: float = 1.0, decoder: str = "trained"):
    """One ORP search (and its bands' values) with the IMS's masks at ``sharpness`` and the point's ``decoder``
    (``"trained"``: the IMS's own; ``"fill"``: the pull-push fill of the same pixels)."""
    cache, rows, where, distances, strata, passes, npaths = v.cache, v.rows, v.where, v.distances, v.strata, v.passes, v.paths
    ims = nets.ims_task.to(device)
    head = ims.mask_head.with_sharpness(sharpness)  # a head view at this sharpness: the task is left as it is
    rebuild = decoder_at(decoder, ims.decoder, pattern)
    with torch.inference_mode():
        batches = list(view_loader(cache, rows, pattern))
        recnn = nets.recnn.to(device).eval()
        result = orp_with_lift(lambda lift: product_orp(head, rebuild, recnn, batches, s.epsilon_db, device=device,
                                                        confidence=s.orp_confidence, lift=lift, future_views=future_views,
                                                        strata=strata, passes=passes, paths=npaths),
                               s.ims_lift)
        result.by_distance = None
        if s.orp_by_distance and result.found:
            result.by_distance = band_means(s, cache, rows, distances, strata, ims, recnn, pattern, device, result, future_views,
                                            passes, npaths, head=head, decoder=rebuild)
            where += "; then each band's own mean value"
    result.where = (where + ("" if sharpness == 1.0 else f"; masks at sharpness {sharpness:g}")
                    + ("" if decoder == "trained" else "; the pull-push fill as decoder"))
    return result


def band_means(s: Settings, cache, rows, distances, strata, ims, recnn, pattern, device, result, future_views: int | None,
               passes: Sequence[int] | None = None, paths: int = 1, head=None, decoder=None) -> dict[str, Any] | None:
    """The by-distance operating point (``orp_by_distance``): each band of camera distance searched on its own
    search views, with its share of the bound's new views; a band keeps the value that held in every band
    (``result.mean``) where its own search finds none below it. The bands split at the midpoints between
    neighbouring bands' distances.

    Returns the ``by_distance`` record: ``edges``, ``means`` (near to far), and per band ``c_shares``,
    ``gaps_db``, ``bounds_db``, ``views`` and the distance range ``lo`` / ``hi`` of its search views (with
    ``passes``, path views' pass labels, each band's bound counts its passes); ``None``
    (one line says so) where the views' distances do not separate the bands."""
    head = ims.mask_head if head is None else head  # the IMS's masks (``head``: at the search's sharpness)
    decoder = ims.decoder if decoder is None else decoder  # the point's decoder (the search's: its own, or the fill)
    bands = split_bands(strata, future_views, passes)
    out: dict[str, list] = {k: [] for k in ("means", "c_shares", "gaps_db", "bounds_db", "views", "lo", "hi")}
    for band in bands:
        k, idx, share, own_passes = band.label, band.idx, band.future_views, band.passes
        batches = list(view_loader(cache, [rows[i] for i in idx], pattern))
        own = product_orp(head, decoder, recnn, batches, s.epsilon_db, device=device, confidence=s.orp_confidence,
                          lift=result.lifted, future_views=share, passes=own_passes, paths=paths)
        if own.found and own.mean <= result.mean:
            u, rec = float(own.mean), own.best.record
        else:  # the value that held in every band, this band's numbers at it
            u = float(result.mean)
            rec = product_point(head, decoder, recnn, batches, u, device=device, confidence=s.orp_confidence,
                                lift=result.lifted, future_views=share, passes=own_passes, paths=paths)
        d = [distances[i] for i in idx]
        for key, value in (("means", u), ("c_shares", rec["c_share"]), ("gaps_db", rec["gap_db"]),
                           ("bounds_db", rec["gap_bound_db"]), ("views", len(idx)), ("lo", min(d)), ("hi", max(d))):
            out[key].append(float(value) if key != "views" else int(value))
        print(f"[evaluate] ORP by distance: band {k + 1} of {len(bands)} ({min(d):.2f}-{max(d):.2f}): u = {u:.3f}, "
              f"{rec['c_share']:.1%} of C, gap {rec['gap_db']:.2f} dB (bound {rec['gap_bound_db']:.2f})", file=sys.stderr, flush=True)
    out["edges"] = band_edges(out["lo"], out["hi"])
    if out["edges"] is None:
        print("[evaluate] warning: orp_by_distance: the search views' camera distances do not separate the bands; "
              f"every view runs at u = {result.mean:.3f}", file=sys.stderr, flush=True)
        return None
    return out


@dataclass
class Band:
    """One band of camera distance among an operating point's search views (:func:`split_bands`)."""
    label: int
    idx: list[int]                # the band's search views (indices into the search views)
    future_views: int | None      # its share of the new views the bound is for
    passes: list[int] | None      # its views' pass labels (views along paths), else None


def split_bands(strata: Sequence[int], future_views: int | None, passes: Sequence[int] | None = None) -> list[Band]:
    """The search views of each band of camera distance, near to far, as every by-distance operating point judges
    them (the ORP's mean values, the two-pass sampler's shares): their indices, the band's share of the
    ``future_views`` new views its bound is for, and their passes.

    Example:
        >>> [(b.label, b.idx, b.future_views) for b in split_bands([0, 1, 0, 1, 1], future_views=10)]
        [(0, [0, 2], 4), (1, [1, 3, 4], 6)]
    """
    out = []
    for k in sorted(set(strata)):
        idx = [i for i, lab in enumerate(strata) if lab == k]
        own = None if future_views is None else max(1, round(future_views * len(idx) / len(strata)))
        out.append(Band(k, idx, own, None if passes is None else [passes[i] for i in idx]))
    return out


def band_edges(lo: Sequence[float], hi: Sequence[float]) -> list[float] | None:
    """The distances between neighbouring bands of camera distance, each the midpoint between one band's farthest
    search view (``hi``) and the next band's nearest (``lo``), near to far; ``None`` where the bands' views do not
    separate (a band reaching into the next). One home for every by-distance operating point (the ORP's mean
    values, the two-pass sampler's shares).

    Example:
        >>> band_edges([2.5, 3.0, 3.5], [2.75, 3.25, 4.0])
        [2.875, 3.375]
        >>> band_edges([2.8, 2.9], [3.0, 3.3]) is None
        True
    """
    if any(h >= l for h, l in zip(hi[:-1], lo[1:])):
        return None
    return [0.5 * (h + l) for h, l in zip(hi[:-1], lo[1:])]


def point_of(result, share: float | None, lift: bool) -> OperatingPoint:
    """The :class:`~imls_lightning.core.operating_point.OperatingPoint` IML/S runs at after a search (``result``, or its
    summary :func:`orp_summary`, a dict; ``None``: no search): ``share`` (``None``: the trained one) with ``lift``, the
    search's bands of camera distance, its mask sharpness, decoder and the object floor chosen (a point found only)."""
    if result is None:
        return OperatingPoint(share=share, lift=lift)
    get = result.get if isinstance(result, dict) else lambda key: getattr(result, key, None)
    chosen = ((get("object_floor") or {}).get("chosen") if get("found") else None) or {}
    bands = get("by_distance")
    return OperatingPoint(share=share, lift=lift, sharpness=float(get("sharpness") or 1.0),
                          bands=Bands(bands["edges"], bands["means"], chosen.get("band_margins")) if bands else None,
                          object_floor=(chosen["margin"], chosen["tau"]) if chosen else None,
                          decoder=str(get("decoder") or "trained") if get("found") else "trained")


def trained_decoder_point(orp: dict[str, Any] | None) -> OperatingPoint | None:
    """Where the search kept the pull-push fill (``orp_decoders``), the point its candidate with the IMS's own decoder
    found at the same sharpness (its mean value or bands, lift; the object floor was chosen for the kept point only,
    so none), for the evaluation to run beside the kept one on the same views; ``None`` otherwise (the kept point is
    the trained decoder's, or that candidate found none).

    Example:
        >>> orp = {"found": True, "decoder": "fill", "sharpness": 3.0, "sharpness_candidates": [
        ...     {"sharpness": 3.0, "decoder": "trained", "found": True, "mean": 0.8, "lift": True},
        ...     {"sharpness": 3.0, "decoder": "fill", "found": True, "mean": 0.85, "lift": True}]}
        >>> trained_decoder_point(orp)
        OperatingPoint(share=0.8, lift=True, bands=None, sharpness=3.0, object_floor=None, decoder='trained')
    """
    if not orp or not orp.get("found") or orp.get("decoder", "trained") == "trained":
        return None
    for c in orp.get("sharpness_candidates") or []:
        if c.get("decoder", "trained") == "trained" and c.get("found") and c["sharpness"] == orp.get("sharpness", 1.0):
            return point_of({"found": True, "by_distance": c.get("by_distance"), "sharpness": c["sharpness"]},
                            float(c["mean"]), bool(c.get("lift")))
    return None


def distance_means(result):
    """The :class:`~imls_lightning.models.ims.DistanceMeans` IML/S runs at after a by-distance search (``None``: one
    mean value for every view); ``result`` the search's or its summary (:func:`orp_summary`, a dict)."""
    get = result.get if isinstance(result, dict) else lambda key: getattr(result, key, None)
    bands = get("by_distance") if result is not None else None
    if not bands:
        return None
    from ..models.ims import DistanceMeans

    chosen = (get("object_floor") or {}).get("chosen") or {}
    return DistanceMeans(bands["edges"], bands["means"], chosen.get("band_margins"))


def camera_distance(cache, row: int) -> float:
    """The camera's distance from the volume's centre in view ``row`` of ``cache`` (its eye position's norm)."""
    return view_distance(cache.views[int(row)])


def orp_with_lift(search: Callable[[bool], Any], lift: bool | str) -> Any:
    """Run the ORP ``search(lift)`` with the IMS's masks lifted or not, as ``lift`` says (``ims_lift``).

    ``auto``: the paper's rescale first; when it finds no ORP (its share saturates short of
    the bound), search again with the masks lifted to their mean value, which then stay lifted for the
    rest of the evaluation. The result keeps the first search's points as ``rescale_points``, and
    ``lifted``: whether its masks were lifted.
    """
    lifted = lift is True
    result = search(lifted)
    if lift == "auto" and not result.found:
        print(f"[evaluate] ORP: none with the paper's rescale (largest share {_largest_share(result):.1%} of C); "
              "searching again with the IMS's masks lifted to their mean value (ims_lift=auto)", file=sys.stderr, flush=True)
        lifted = True
        plain = _points(result)
        result = search(lifted)
        result.rescale_points = plain  # kept for the report: what the paper's rescale reached
    result.lifted = lifted
    return result


def _points(result) -> list[tuple]:
    """``(u, mean gap, C-share, gap bound)`` of every mean value the search tried, by ``u``."""
    return sorted(((e.u, (e.record or {}).get("gap_db"), (e.record or {}).get("c_share"), (e.record or {}).get("gap_bound_db"))
                   for e in result.evaluations))


def _largest_share(result) -> float:
    shares = [(e.record or {}).get("c_share") for e in result.evaluations]
    return max((float(x) for x in shares if x is not None), default=float("nan"))


def paired_gap(rows: Sequence[dict[str, Any]], reference: str, method: str) -> dict[str, Any] | None:
    """The per-view PSNR gap ``reference - method`` over the views both were scored on, summarized as the
    ORP's validation gap is (:func:`~imls_lightning.orp.search.gap_upper_bound` at confidence 0.5: mean,
    sample std, views) plus both mean PSNRs; ``None`` when they share no view.

    Example:
        >>> rows = [{"view": 0, "method": "recnn", "psnr": 40.0}, {"view": 0, "method": "imls", "psnr": 39.0},
        ...         {"view": 1, "method": "recnn", "psnr": 38.0}, {"view": 1, "method": "imls", "psnr": 36.0}]
        >>> paired_gap(rows, "recnn", "imls")["gap_db"]
        1.5
    """
    from ..orp import gap_upper_bound

    ref, got, views = _paired(rows, reference, method)
    if not views:
        return None
    b = gap_upper_bound([ref[v] - float(got[v]["psnr"]) for v in views], 0.5)
    return {"gap_db": b.mean, "gap_std_db": b.std, "views": b.views, "psnr_recnn": float(np.mean([ref[v] for v in views])),
            "psnr_imls": float(np.mean([float(got[v]["psnr"]) for v in views]))}


def _paired(rows: Sequence[dict[str, Any]], reference: str, method: str) -> tuple[dict[int, float], dict[int, dict], list[int]]:
    """``reference``'s PSNR and ``method``'s rows by view, over the views both were scored on (sorted)."""
    ref = {int(r["view"]): float(r["psnr"]) for r in rows if r["method"] == reference and r.get("psnr") is not None}
    got = {int(r["view"]): r for r in rows if r["method"] == method and r.get("psnr") is not None}
    return ref, got, sorted(set(ref) & set(got))


def gap_by_distance(rows: Sequence[dict[str, Any]], distance: Callable[[int], float], reference: str = "recnn",
                    method: str = "imls", bins: int = 4) -> list[dict[str, Any]]:
    """The per-view gap ``reference - method`` in ``bins`` equal-count bins of the camera distance (``distance`` of a
    row's cache ``row``): where on the trajectory an operating point loses its promise. Each bin: its distance range,
    views, mean and largest gap, the method's mean C-share, and where both were timed there, the speed-up
    ``sum(reference totals) / sum(method totals)`` over its ``timed_views`` (else None): where the trade pays.
    Empty when the two share no view.

    Example:
        >>> rows = [{"view": v, "row": v, "method": m, "psnr": p, "c_share": 0.8}
        ...         for v, (a, b) in enumerate([(40, 37), (40, 38), (38, 37.9), (38, 38)]) for m, p in (("recnn", a), ("imls", b))]
        >>> [(b["lo"], b["views"], round(b["gap_db"], 2)) for b in gap_by_distance(rows, lambda r: 2.0 + r, bins=2)]
        [(2.0, 2, 2.5), (4.0, 2, 0.05)]
        >>> [(b["speedup"], b["timed_views"]) for b in gap_by_distance(rows, lambda r: 2.0 + r, bins=2)]
        [(None, 0), (None, 0)]
    """
    from ..report.speedup import paired_totals

    ref, got, views = _paired(rows, reference, method)
    if not views:
        return []
    d = np.array([float(distance(int(got[v]["row"]))) for v in views])
    gap = np.array([ref[v] - float(got[v]["psnr"]) for v in views])
    share = np.array([float(got[v].get("c_share") or np.nan) for v in views])
    order = np.argsort(d, kind="stable")
    out = []
    for part in np.array_split(order, min(bins, len(views))):
        members = {views[i] for i in part}
        slow, fast = paired_totals([r for r in rows if int(r["view"]) in members], reference, method)
        out.append({"lo": float(d[part].min()), "hi": float(d[part].max()), "views": int(len(part)),
                    "gap_db": float(gap[part].mean()), "max_gap_db": float(gap[part].max()),
                    "c_share": float(np.nanmean(share[part])) if np.isfinite(share[part]).any() else None,
                    "speedup": sum(slow) / sum(fast) if slow else None, "timed_views": len(slow)})
    return out


def orp_summary(result, s: Settings, lifted: bool = False) -> dict[str, Any]:
    best = result.best
    rec = best.record if best is not None else {}
    return {"found": result.found, "mean": result.mean, "epsilon_db": s.epsilon_db, "gap_db": rec.get("gap_db"),
            "gap_std_db": rec.get("gap_std_db"), "gap_bound_db": rec.get("gap_bound_db"), "views": rec.get("views"),
            "confidence": s.orp_confidence, "future_views": rec.get("future_views"), "passes": rec.get("passes"),
            "where": getattr(result, "where", None),
            "c_share": rec.get("c_share"), "ipr": rec.get("ipr"), "psnr_imls": rec.get("psnr_imls"),
            "psnr_recnn": rec.get("psnr_recnn"), "evaluations": len(result.evaluations), "lift": lifted,
            "points": _points(result), "rescale_points": getattr(result, "rescale_points", None),
            "strata": s.orp_strata, "strata_gap_db": rec.get("strata_gap_db"), "by_distance": getattr(result, "by_distance", None),
            "sharpness": float(getattr(result, "sharpness", 1.0)),
            # written only where the search kept the fill: summaries of the paper's decoder stay as they were
            **({"decoder": result.decoder} if getattr(result, "decoder", "trained") != "trained" else {}),
            "sharpness_candidates": getattr(result, "sharpness_candidates", None),
            "object_floor": getattr(result, "object_floor", None)}


#: the checkpoints an operating point belongs to: the search ran the IMS (its decoder inside) and the RecNN alone
POINT_NETWORKS = ("ims", "recnn")


def borrowed_point(s: Settings, ck_hashes: dict[str, str], scene: str) -> dict[str, Any]:
    """The operating point a finished evaluation searched (``orp_from``: its folder), for this run to use unsearched:
    ``{"orp", "imls_mean", "lift", "two_pass", "notes"}`` as :class:`~.resume.EvaluationProgress` keeps a point.

    The point belongs to its networks: the IMS and RecNN checkpoints of that evaluation (the hashes its
    ``summary.json`` records, else the files its ``config.yaml`` names) must be byte for byte this run's
    (``ck_hashes``, :func:`~imls_lightning.base.config.file_hash` by checkpoint key). The scene may differ: that is how an
    operating point is tried on a volume nobody tuned it for. Its gaps on the new views are measured afresh; what the
    summary says of its own test views is dropped. Anything else is a one-line :class:`InputError`.
    """
    import json

    from ..base.config import file_hash

    folder = Path(str(s.orp_from))
    where = f"orp_from={s.orp_from}"
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        config = OmegaConf.load(folder / "config.yaml")
    except (OSError, ValueError) as err:
        raise InputError(f"{where}: its summary.json or config.yaml is unreadable ({type(err).__name__})") from None
    orp = summary.get("orp") if isinstance(summary, dict) else None
    if not isinstance(orp, dict) or not orp.get("found"):
        raise InputError(f"{where}: that evaluation found no operating point to use (its summary.json has no found ORP)")
    theirs = summary.get("checkpoints_sha256")
    for key in POINT_NETWORKS:  # None on both sides: the RecNN inside the IMS checkpoint, the same when the IMS is
        mine = ck_hashes.get(key)
        if isinstance(theirs, dict):
            other = theirs.get(key)
        else:  # an evaluation from before the hashes were recorded: the files its config.yaml names
            path = OmegaConf.select(config, f"checkpoints.{key}", default=None)
            if path and not Path(str(path)).expanduser().is_file():
                raise InputError(f"{where}: its checkpoints.{key} ({path}) is gone, so whether it is this run's cannot "
                                 "be checked")
            other = file_hash(Path(str(path)).expanduser()) if path else None
        if other != mine:
            raise InputError(f"{where}: its checkpoints.{key} is not this run's checkpoints.{key} (an operating point "
                             "belongs to the networks it was searched with)")
    fresh = ("test", "test_by_distance")  # measured again on this run's views
    two_pass, las = summary.get("two_pass"), summary.get("las_searched")
    note = (f"Operating point: not searched here; the one the evaluation in {folder} searched on "
            f"{orp.get('where') or 'its validation views'}" + (f" (scene {summary.get('scene')})" if summary.get("scene") != scene else "")
            + " (orp_from), with the same IMS and RecNN checkpoints.")
    return {"orp": {k: v for k, v in orp.items() if k not in fresh}, "imls_mean": float(orp["mean"]),
            "lift": bool(orp.get("lift")), "notes": [note],
            "two_pass": None if not isinstance(two_pass, dict) else {k: v for k, v in two_pass.items() if k not in fresh},
            # LAS at the promise: its searched IPRs travel with the point too (a reproduction chooses nothing again)
            "las_searched": None if not isinstance(las, dict) else {k: v for k, v in las.items() if k not in fresh}}
