"""Could a mask that knows each pixel's ray cost pay against the fastest ray caster? (issue 84's third lever)

With empty-space skipping a background C-pixel is nearly free: its ray skips every brick. IML/S then pays only
by leaving out pixels that cost, the object's, and the paper's masks count pixels, not their cost. This measures,
on views no network trained on, how much of the pattern's **render cost** each kind of mask must keep to stay within
``epsilon_db`` of the RecNN alone, with the product's own decoder and RecNN rebuilding the image:

* **the product's mask** (the IMS at the row's operating point);
* **the IML's mask**, which sees the rendered C-Image (an upper bound on what an IMS can learn to predict), at
  several mean values, with its own decoder;
* **an oracle that sees the C-Image and each pixel's cost**: each C-pixel's unpredictability from its neighbours
  (:func:`~imls_lightning.core.unpredictability.unpredictability`) divided by ``(1 + cost) ** alpha``
  (:func:`cost_aware_score`); ``alpha = 0`` counts pixels as the paper does, ``alpha = 1`` ranks them by
  importance per unit of cost. Its masks are the product's kind (:func:`~imls_lightning.core.unpredictability.importance_mask`),
  rebuilt by the IMS's decoder and the RecNN.

A pixel's cost is the samples its ray interpolated (``NumbaRenderer.last_ray_samples``: skipped bricks and early
ray termination included); :func:`cost_fit` checks that the masks' measured render times follow it.
:func:`speedup_ceiling` turns the cost a mask must keep into the speed-up against the RecNN alone, with the
networks as timed and with free ones.

Example:
    >>> speedup_ceiling(alone_ms=90.0, pattern_ms=75.0, recnn_ms=15.0, nets_ms=15.0, cost_kept=0.4)
    1.5
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_number

from ..core.compaction import compact
from ..core.metrics import psnr_per_image
from ..core.patterns import SamplingPattern
from ..core.unpredictability import importance_mask, unpredictability
from ..estimate.measure import frame_tensor
from ..estimate.needed_share import first_share_within
from .timing import timed

#: the shares of C the oracle masks are made at, and the exponents of cost they divide the importance by
ORACLE_SHARES = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.8)
ALPHAS = (0.0, 0.5, 1.0, 2.0)


def ray_costs(renderer, view, fr_size: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Ray-cast ``pixels`` (flat FR indices, ``(K,)``) of ``view``: ``(colours (K, 3) uint8, cost (K,) float64,
    seconds)``, the cost being each ray's interpolated samples plus one (0: it missed the volume's box).

    Raises:
        InputError: a renderer that does not report its rays' samples (only ``renderer=numba`` does).
    """
    colours = renderer.render_pixels(view, fr_size, pixels)
    samples = getattr(renderer, "last_ray_samples", None)
    if samples is None or len(samples) != len(pixels):
        raise InputError(f"renderer={getattr(renderer, 'name', type(renderer).__name__)}: reports no per-ray samples; "
                         "the cost-aware masks need renderer=numba")
    return colours, np.asarray(samples, np.float64), float(renderer.last_render_seconds)


def cost_aware_score(score: torch.Tensor, cost: torch.Tensor, alpha: float) -> torch.Tensor:
    """Importance per unit of cost: ``score / (1 + cost) ** alpha``; ``(B, 1, n, n)`` like ``score``.

    ``alpha = 0`` returns ``score`` (the paper's count); larger ``alpha`` moves the mask off the dear pixels.

    Example:
        >>> s, c = torch.tensor([[[[4.0, 4.0]]]]), torch.tensor([[[[0.0, 3.0]]]])
        >>> cost_aware_score(s, c, 1.0).flatten().tolist()
        [4.0, 1.0]
    """
    a = check_number(alpha, "alpha", 0.0, what="an exponent >= 0")
    return score if a == 0 else score / (1.0 + cost.clamp_min(0)) ** a


def cost_on_grid(cost: np.ndarray, pattern: SamplingPattern) -> torch.Tensor:
    """The pattern's per-pixel costs ``(K,)`` laid on the C grid ``(1, 1, n, n)`` (0 off the pattern)."""
    n = pattern.c_size
    grid = torch.zeros(n * n, dtype=torch.float32)
    grid[: len(cost)] = torch.from_numpy(np.asarray(cost, np.float32))
    return grid.view(1, 1, n, n)


def cost_kept(mask: np.ndarray, cost: np.ndarray) -> float:
    """The share of the pattern's render cost a mask keeps: ``cost[mask].sum() / cost.sum()`` (1 when nothing costs).

    Example:
        >>> cost_kept(np.array([True, False, False]), np.array([8.0, 1.0, 1.0]))
        0.8
    """
    total = float(cost.sum())
    return 1.0 if total <= 0 else float(cost[np.asarray(mask, bool)].sum()) / total


def speedup_ceiling(alone_ms: float, pattern_ms: float, recnn_ms: float, nets_ms: float, cost_kept: float) -> float:
    """The speed-up over the RecNN alone (``alone_ms``: the whole pattern's ``pattern_ms`` + ``recnn_ms``) of a
    method that ray-casts ``cost_kept`` of the pattern's cost and adds ``nets_ms`` (mask + decoder; 0: free).

    Example:
        >>> speedup_ceiling(90.0, 75.0, 15.0, 0.0, 1.0)
        1.0
    """
    return float(alone_ms / (nets_ms + cost_kept * pattern_ms + recnn_ms))


def cost_at_gap(costs: Sequence[float], gaps: Sequence[float], epsilon_db: float) -> float | None:
    """The smallest cost kept whose gap is within ``epsilon_db``, linear between the last point outside and the
    first inside, the points taken in order of cost (the estimate's needed share, on cost); None when none is within.

    Example:
        >>> cost_at_gap([0.9, 0.5, 0.7], [0.5, 3.0, 1.5], 1.0)
        0.8
    """
    order = np.argsort(np.asarray(costs, float))
    return first_share_within(np.asarray(costs, float)[order], np.asarray(gaps, float)[order], epsilon_db)


def cost_fit(cost: Sequence[float], ms: Sequence[float]) -> dict[str, float]:
    """The least-squares line ``ms = fixed + per_unit * cost`` over the timed masks and its ``r2``: how well the
    samples predict the render time (the fixed part is the call's overhead)."""
    x, y = np.asarray(cost, float), np.asarray(ms, float)
    if x.size < 2 or np.ptp(x) == 0:
        return {"fixed_ms": float(y.mean()) if y.size else 0.0, "per_unit_ms": 0.0, "r2": 0.0}
    slope, intercept = np.polyfit(x, y, 1)
    resid = y - (intercept + slope * x)
    r2 = 1.0 - float((resid ** 2).sum()) / max(float(((y - y.mean()) ** 2).sum()), 1e-12)
    return {"fixed_ms": float(intercept), "per_unit_ms": float(slope), "r2": r2}


@dataclass
class ViewCosts:
    """One view's measurements: the RecNN alone's PSNR and stage times, the product's, and every mask's rows."""
    view: int
    recnn_db: float
    alone_ms: dict[str, float]
    product_ms: dict[str, float]
    object_share: float             # C-pixels whose ray interpolated a sample
    object_cost: float              # their share of the pattern's cost
    rows: list[dict[str, Any]] = field(default_factory=list)


def _psnr(image: np.ndarray, target: torch.Tensor) -> float:
    return float(psnr_per_image(frame_tensor(image), target)[0])


def _row(kind: str, setting: float, mask: np.ndarray, cost: np.ndarray, obj: np.ndarray, db: float, ref: float,
         render_ms: float) -> dict[str, Any]:
    return {"mask": kind, "setting": float(setting), "kept": float(mask.mean()), "cost_kept": cost_kept(mask, cost),
            "object_density": float(mask[obj].mean()) if obj.any() else 0.0,
            "background_density": float(mask[~obj].mean()) if (~obj).any() else 0.0,
            "psnr_db": db, "gap_db": ref - db, "render_ms": render_ms}


def measure_view(v: int, view, truth: np.ndarray, alone, product, iml_methods: dict[float, Any],
                 shares: Sequence[float] = ORACLE_SHARES, alphas: Sequence[float] = ALPHAS, floor: float = 0.25) -> ViewCosts:
    """Every mask on one view (``truth``: its full frame ``(m, m, 3)`` uint8).

    Args:
        alone: the RecNN alone (:class:`~imls_lightning.inference.pipeline.RecNNAlone`) on the ray caster.
        product: the product (:class:`~imls_lightning.inference.pipeline.IMLSRenderer`) at the row's point;
            its ``run(view, im=...)`` rebuilds any mask with the IMS's decoder and the RecNN.
        iml_methods: IML + RecNN (:class:`~imls_lightning.inference.pipeline.IMLPlusRecNN`) by mean value.
    """
    pattern: SamplingPattern = product.pattern
    k = pattern.count
    target = frame_tensor(truth)
    _, cost, _ = ray_costs(product.renderer, view, pattern.fr_size, pattern.indices.numpy())
    obj = cost > 1
    alone, product = timed(alone), timed(product)  # each run's stages timed (the methods themselves read no clock)
    a = alone.run(view)
    ref = _psnr(a.image, target)
    p = product.run(view)
    out = ViewCosts(v, ref, dict(a.timings), dict(p.timings), float(obj.mean()), cost_kept(obj, cost))
    im = p.info["im"].reshape(-1)[:k].numpy()
    # one point for the product whatever each view's band of camera distance ran at (its share differs by view)
    out.rows.append(_row("product", float(product.mean or 0.0), im, cost, obj, _psnr(p.image, target), ref,
                         1000 * p.timings["selective_render"]))
    for u, method in iml_methods.items():
        q = method.run(view)
        out.rows.append(_row("iml", u, q.info["im"].reshape(-1)[:k].numpy(), cost, obj, _psnr(q.image, target), ref,
                             float("nan")))
    with torch.inference_mode():
        score = unpredictability(compact(target, pattern.indices, pattern.c_size), pattern, seed=0)
    grid = cost_on_grid(cost, pattern)
    for alpha in alphas:
        weighted = cost_aware_score(score, grid, alpha)
        for s in shares:
            m = importance_mask(weighted, s, pattern, floor)[0, 0]
            q = product.run(view, im=m)
            out.rows.append(_row(f"oracle_alpha{alpha:g}", s, m.reshape(-1)[:k].numpy(), cost, obj,
                                 _psnr(q.image, target), ref, 1000 * q.timings["selective_render"]))
    return out


def stage_medians(views: Sequence[ViewCosts]) -> dict[str, float]:
    """The stage times measured with the masks (ms, medians over the views): the whole pattern's ray cast, the
    RecNN, and the IMS + decoder the product adds."""
    med = lambda key, part: 1000 * float(np.median([getattr(v, part)[key] for v in views]))  # noqa: E731
    return {"pattern_ms": med("selective_render", "alone_ms"), "recnn_ms": med("recnn", "alone_ms"),
            "nets_ms": med("importance", "product_ms") + med("decoder", "product_ms")}


def summarize(views: Sequence[ViewCosts], epsilon_db: float = 1.0, times: dict[str, float] | None = None) -> dict[str, Any]:
    """Per mask kind: its mean curve (cost kept, gap, densities per setting) and the cost it must keep within
    ``epsilon_db``; the stage medians; the fit of render time to cost; the ceilings at that cost.

    ``times``: ``{pattern_ms, recnn_ms, nets_ms}`` the ceilings use (e.g. the row's own evaluation, timed on a quiet
    machine with 10 runs a view); None: the medians measured here (:func:`stage_medians`), reported either way."""
    eps = check_number(epsilon_db, "epsilon_db", 0.0, lo_open=True, what="a positive PSNR tolerance in dB")
    if not views:
        raise InputError("cost masks: no views measured")
    here = stage_medians(views)
    t = here if times is None else times
    pattern_ms, recnn_ms, nets_ms = (float(t[k]) for k in ("pattern_ms", "recnn_ms", "nets_ms"))
    alone = pattern_ms + recnn_ms
    kinds: dict[str, Any] = {}
    for kind in dict.fromkeys(r["mask"] for v in views for r in v.rows):
        settings = sorted({r["setting"] for v in views for r in v.rows if r["mask"] == kind})
        curve = []
        for s in settings:
            rows = [r for v in views for r in v.rows if r["mask"] == kind and r["setting"] == s]
            point = {key: float(np.mean([r[key] for r in rows]))
                     for key in ("setting", "kept", "cost_kept", "object_density", "background_density", "gap_db")}
            timed = [r["render_ms"] for r in rows if r["render_ms"] == r["render_ms"]]  # the IML's masks are not cast
            curve.append({**point, "render_ms": float(np.mean(timed)) if timed else None})
        need = cost_at_gap([c["cost_kept"] for c in curve], [c["gap_db"] for c in curve], eps)
        kinds[kind] = {"curve": curve, "cost_at_epsilon": need,
                       "speedup_at_epsilon": None if need is None else speedup_ceiling(alone, pattern_ms, recnn_ms, nets_ms, need),
                       "free_networks_at_epsilon": None if need is None else speedup_ceiling(alone, pattern_ms, recnn_ms, 0.0, need)}
    # each mask's cost on its own view's pattern time (a view's pattern costs 0.5-1.8x another's)
    timed = [(r["cost_kept"] * 1000 * v.alone_ms["selective_render"], r["render_ms"]) for v in views for r in v.rows
             if r["render_ms"] == r["render_ms"]]
    fit = cost_fit([c for c, _ in timed], [ms for _, ms in timed])
    return {"epsilon_db": eps, "views": len(views), "pattern_ms": pattern_ms, "recnn_ms": recnn_ms, "nets_ms": nets_ms,
            "times": "measured here" if times is None else str(times.get("source", "given")), "measured_here": here,
            "alone_ms": alone, "object_share": float(np.mean([v.object_share for v in views])),
            "object_cost": float(np.mean([v.object_cost for v in views])), "render_fit": fit, "masks": kinds,
            "needed_for": {f"{t:g}x": needed_cost(t, alone, pattern_ms, recnn_ms, nets_ms) for t in (1.0, 1.5)},
            "needed_for_free_networks": {f"{t:g}x": needed_cost(t, alone, pattern_ms, recnn_ms, 0.0) for t in (1.5,)}}


def needed_cost(target: float, alone_ms: float, pattern_ms: float, recnn_ms: float, nets_ms: float) -> float:
    """The share of the pattern's cost a method may keep to run ``target`` times the RecNN alone (< 0: none can).

    Example:
        >>> needed_cost(1.5, 90.0, 75.0, 15.0, 0.0)
        0.6
    """
    return float((alone_ms / target - recnn_ms - nets_ms) / pattern_ms)


def measure_all(views: Sequence, truths: Callable[[int], np.ndarray], alone, product, iml_methods: dict[float, Any],
                progress: Callable[[str], None] | None = None, **kw: Any) -> list[ViewCosts]:
    """:func:`measure_view` on every view, a progress line after each (``truths(i)``: view ``i``'s full frame)."""
    out, t0 = [], time.perf_counter()
    for i, view in enumerate(views):
        out.append(measure_view(i, view, truths(i), alone, product, iml_methods, **kw))
        if progress is not None:
            v = out[-1]
            progress(f"cost masks: view {i + 1}/{len(views)}: object {v.object_share:.0%} of C, {v.object_cost:.0%} of "
                     f"its cost ({time.perf_counter() - t0:.0f} s)")
    return out


__all__ = ["ORACLE_SHARES", "ALPHAS", "ray_costs", "cost_aware_score", "cost_on_grid", "cost_kept", "speedup_ceiling",
           "cost_at_gap", "cost_fit", "needed_cost", "ViewCosts", "measure_view", "measure_all", "stage_medians", "summarize"]
