"""The before-training speed-up bound: what IML/S + RecNN can gain over the RecNN alone on a scene.

One home for the arithmetic of :mod:`imls_lightning.estimate`. The product path costs

    T_imls(s) = T_ims + R(s) + T_decoder + T_recnn,

the RecNN alone ``T_alone = R(1) + T_recnn``, so the bound at a share ``s`` of the C-Image is
``T_alone / T_imls(s)``. ``R(s)``, the selective ray cast of ``s K`` of the pattern's ``K`` pixels,
is predicted two ways, and the estimate takes the slower at each share (:func:`slower_render`):

* measured (:class:`RenderCurve`): the render of exactly the pixels of a mask of the shape a
  trained IMS makes (the object's silhouette blurred, with a floor), at each share;
* modelled from three measurements (:class:`RenderCost`): a fixed cost per call and a cost per
  pixel on the object and on the background, the object kept first and the background sampled at
  a density ``b`` times the object's (``background_density``; the demo's IMS samples the
  background at 1/6 of the object's density, ct_head's at 0.24).

The model alone is optimistic where rays that miss the object still march (no empty-space
skipping): the background pixels a trained mask keeps lie next to the object, inside the volume's
box, and cost more than the background's mean (flame_whole: the model said 2.31x at 30% of C, the
product measured 1.72x; the silhouette 1.73x). The silhouette alone is optimistic at high shares
with skipping (ct_head at 81% of C: 0.98x against a measured 0.80x; the model 0.82x).

Example:
    >>> cost = RenderCost(fixed_ms=1.0, object_ms_per_px=0.004, background_ms_per_px=0.0005,
    ...                   object_px=40000, background_px=25536)
    >>> round(cost.render_ms(1.0), 2)
    173.77
    >>> b = bound_table(cost, c_render_ms=173.0, nets_ms=32.0, recnn_ms=16.0)
    >>> [round(r["speedup"], 2) for r in b[:3]], share_for_speedup(b, 2.0)
    ([2.62, 1.99, 1.6], 0.1)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from imls_lightning.base.errors import InputError

#: the shares of C at which the bound is tabulated (issue 31: 0.1, 0.2, ..., 1.0)
SHARES = tuple(round(0.1 * i, 1) for i in range(1, 11))


@dataclass(frozen=True)
class RenderCost:
    """Selective ray-cast cost: ``fixed_ms + n_obj * object_ms_per_px + n_bg * background_ms_per_px``.

    ``object_px`` / ``background_px``: the pattern's pixels on the object and on the background.
    """

    fixed_ms: float
    object_ms_per_px: float
    background_ms_per_px: float
    object_px: int
    background_px: int

    @property
    def pixels(self) -> int:
        return int(self.object_px + self.background_px)

    @property
    def object_fraction(self) -> float:
        return self.object_px / max(self.pixels, 1)

    def pixels_at(self, share: float, background_density: float = 0.25) -> tuple[float, float]:
        """``(object pixels, background pixels)`` a mask of ``share`` of the pattern keeps, the
        background sampled at ``background_density`` times the object's density (the object full
        first: beyond it the rest comes from the background)."""
        s = _share(share)
        b = _density(background_density)
        n = s * self.pixels
        denom = self.object_px + b * self.background_px
        d = n / denom if denom > 0 else 1.0
        if d <= 1.0:
            return d * self.object_px, d * b * self.background_px
        return float(self.object_px), min(n - self.object_px, float(self.background_px))

    def render_ms(self, share: float, background_density: float = 0.25) -> float:
        """Modelled time of ray-casting ``share`` of the pattern (ms)."""
        n_obj, n_bg = self.pixels_at(share, background_density)
        return self.fixed_ms + n_obj * self.object_ms_per_px + n_bg * self.background_ms_per_px

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class RenderCurve:
    """Selective ray-cast time measured at ``shares`` (ascending, in (0, 1]): ``times_ms[i]`` renders
    ``shares[i]`` of the pattern; linear in between and from ``fixed_ms`` at share 0.

    Example:
        >>> curve = RenderCurve(shares=(0.5, 1.0), times_ms=(60.0, 100.0), fixed_ms=0.0)
        >>> curve.render_ms(0.25), curve.render_ms(0.75)
        (30.0, 80.0)
    """

    shares: tuple[float, ...]
    times_ms: tuple[float, ...]
    fixed_ms: float = 0.0

    def __post_init__(self):
        s = [float(x) for x in self.shares]
        if not s or len(s) != len(self.times_ms) or any(not 0.0 < x <= 1.0 for x in s) or s != sorted(s):
            raise InputError(f"render_curve: expected ascending shares in (0, 1] with one time each, got "
                             f"shares={list(self.shares)} times_ms={list(self.times_ms)}")

    def render_ms(self, share: float, background_density: float | None = None) -> float:
        """Measured time of ray-casting ``share`` of the pattern (ms); ``background_density`` is unused (the
        measured mask has its own), accepted so that the curve and :class:`RenderCost` are interchangeable."""
        s = _share(share)
        return float(np.interp(s, (0.0, *map(float, self.shares)), (float(self.fixed_ms), *map(float, self.times_ms))))

    def to_dict(self) -> dict[str, Any]:
        return {"shares": list(self.shares), "times_ms": list(self.times_ms), "fixed_ms": self.fixed_ms}


def slower_render(curve: RenderCurve, model: RenderCost, background_density: float = 0.25) -> RenderCurve:
    """At each of ``curve``'s shares, the slower of the two predictions of the selective render: the measured
    silhouette mask (``curve``) and the per-pixel model. Each misses a cost the other sees: the silhouette's
    background lies next to the object, inside the volume's box (rays that march there without empty-space
    skipping); the model's pixels are spread as a dithered mask spreads them (a contiguous silhouette keeps
    neighbouring rays together, which the renderer casts faster: ct_head's trained mask at 81% of C cost the
    model's time, the silhouette's read 22% fast).

    Example:
        >>> model = RenderCost(fixed_ms=0.0, object_ms_per_px=0.01, background_ms_per_px=0.01, object_px=500, background_px=500)
        >>> slower_render(RenderCurve((0.5, 1.0), (2.0, 12.0)), model).times_ms
        (5.0, 12.0)
    """
    times = tuple(max(float(t), model.render_ms(s, background_density)) for s, t in zip(curve.shares, curve.times_ms))
    return RenderCurve(tuple(curve.shares), times, curve.fixed_ms)


def _share(share: float) -> float:
    s = float(share)
    if not 0.0 <= s <= 1.0:
        raise InputError(f"share={share}: expected a share of the C-Image in [0, 1]")
    return s


def _density(b: float) -> float:
    v = float(b)
    if not 0.0 < v <= 1.0:
        raise InputError(f"background_density={b}: expected a number in (0, 1] (the background's sampling density "
                         "relative to the object's)")
    return v


def speedup_at(cost: RenderCost | RenderCurve, share: float, *, c_render_ms: float, nets_ms: float, recnn_ms: float,
               background_density: float = 0.25) -> float:
    """The bound ``T_alone / T_imls(share)``; ``nets_ms`` = the IMS and the decoder together."""
    alone = float(c_render_ms) + float(recnn_ms)
    return alone / (float(nets_ms) + cost.render_ms(share, background_density) + float(recnn_ms))


def bound_table(cost: RenderCost | RenderCurve, *, c_render_ms: float, nets_ms: float, recnn_ms: float,
                background_density: float = 0.25, shares: Sequence[float] = SHARES) -> list[dict[str, float]]:
    """``[{"share", "speedup", "render_ms", "limit"}]`` per share: the bound with the networks and the
    limit without them (the share's pixels alone against the RecNN alone)."""
    alone = float(c_render_ms) + float(recnn_ms)
    rows = []
    for s in shares:
        r = cost.render_ms(s, background_density)
        rows.append({"share": float(s), "speedup": alone / (float(nets_ms) + r + float(recnn_ms)),
                     "render_ms": r, "limit": alone / r if r > 0 else float("inf")})
    return rows


def share_for_speedup(table: Sequence[dict[str, float]], target: float) -> float | None:
    """The largest tabulated share whose bound reaches ``target``; None if none does."""
    ok = [r["share"] for r in table if r["speedup"] >= float(target)]
    return max(ok) if ok else None


def sharpness_key(gamma: float) -> str:
    """The key of an IMS mask sharpness in ``estimate.json``'s ``by_sharpness``.

    Example:
        >>> sharpness_key(2.0), sharpness_key(1.5)
        ('2', '1.5')
    """
    return f"{float(gamma):g}"


def estimate_render(estimate: dict[str, Any], sharpness: float = 1.0) -> RenderCost | RenderCurve:
    """The selective render an ``estimate.json``'s content predicts for masks of ``sharpness``: that sharpness's own
    curve (``by_sharpness``) when the estimate has one, else the paper's masks' curve, or the render-cost model of an
    estimate made before the curve. Raises ``KeyError`` / ``TypeError`` on a malformed estimate."""
    own = (estimate.get("by_sharpness") or {}).get(sharpness_key(sharpness)) if float(sharpness) != 1.0 else None
    curve = own["render_curve"] if own else estimate.get("render_curve")
    return RenderCurve(**curve) if curve else RenderCost(**estimate["render_cost"])


def speedup_from_estimate(estimate: dict[str, Any], share: float, sharpness: float = 1.0) -> float:
    """The bound at any ``share`` from an ``estimate.json``'s content (its measured render curve, or the
    render-cost model of an estimate made before the curve, and its stage times): a benchmark row's
    ``estimated_speedup`` at the share it measured. ``sharpness``: the IMS mask sharpness the row's ORP kept;
    its own curve (``by_sharpness``) when the estimate has one, else the paper's masks' curve."""
    try:
        return speedup_at(estimate_render(estimate, sharpness), share, c_render_ms=estimate["c_render_ms"], nets_ms=estimate["nets_ms"],
                          recnn_ms=estimate["recnn_ms"], background_density=estimate["background_density"])
    except (KeyError, TypeError) as err:
        raise InputError(f"estimate: missing or malformed key {err} (expected an estimate.json of python -m "
                         "imls_lightning.estimate)") from None


def estimate_interval(estimate: dict[str, Any], share: float, sharpness: float = 1.0, confidence: float = 0.95,
                      resamples: int = 10_000, seed: int = 0):
    """:func:`speedup_from_estimate` with a percentile bootstrap interval over the estimate's views, or None for an
    estimate that kept no per-view render times (made before ``per_view``, or by the model alone) or whose per-view
    times do not give back its own render curve (to 0.1%: an estimate made by an earlier method).

    The estimate draws a few views (6, their distances stratified) and averages their renders: each view's whole
    pattern ``c_render_ms[v]`` and its silhouette masks' times as fractions of it (``per_view``; a sharpened mask's
    in ``by_sharpness``). A resample draws the views with replacement and makes the same means, the slower of that
    curve and the per-pixel model at each share (:func:`slower_render`; the model and the network times stay as
    measured), then the bound at ``share``. It says how far the views drawn move the estimate, as
    :func:`~imls_lightning.report.speedup.speedup_interval` says it of a row; not a sitting's machine speed.

    Returns:
        :class:`~imls_lightning.report.speedup.SpeedupInterval` or None.

    Example:
        >>> est = {"c_render_ms": 150.0, "nets_ms": 10.0, "recnn_ms": 10.0, "background_density": 0.25,
        ...        "render_cost": {"fixed_ms": 0.0, "object_ms_per_px": 0.0, "background_ms_per_px": 0.0,
        ...                        "object_px": 1, "background_px": 1},
        ...        "per_view": [{"c_render_ms": c, "silhouette_fractions": [0.1 * i for i in range(1, 11)]}
        ...                     for c in (100.0, 200.0)]}
        >>> iv = estimate_interval(est, 0.3)
        >>> round(iv.speedup, 3), iv.views, iv.low <= iv.speedup <= iv.high
        (2.462, 2, True)
    """
    from ..report.speedup import SpeedupInterval

    bounds = _resampled_bounds(estimate, (share,), sharpness, resamples, seed)
    if bounds is None:
        return None
    point, draws = bounds
    lo, hi = np.quantile(draws[:, 0], [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0])
    return SpeedupInterval(float(point[0]), float(lo), float(hi), len(estimate["per_view"]), float(confidence))


def bound_intervals(estimate: dict[str, Any], sharpness: float = 1.0, confidence: float = 0.95) -> list[dict[str, float]] | None:
    """``[{"share", "low", "high"}]`` at every :data:`SHARES`: :func:`estimate_interval` of the bound (``estimate.json``'s
    ``bound_interval``; a sharpness's own under ``by_sharpness``), or None where the estimate has no per-view times."""
    bounds = _resampled_bounds(estimate, SHARES, sharpness)  # one set of draws serves every share
    if bounds is None:
        return None
    lo, hi = np.quantile(bounds[1], [(1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0], axis=0)
    return [{"share": float(sh), "low": float(a), "high": float(b)} for sh, a, b in zip(SHARES, lo, hi)]


def _resampled_bounds(estimate: dict[str, Any], shares: Sequence[float], sharpness: float = 1.0, resamples: int = 10_000,
                      seed: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
    """The bound at ``shares`` on all the estimate's views ``(len(shares),)`` and on ``resamples`` draws of them with
    replacement ``(resamples, len(shares))``. Each draw's render is made as the estimate makes its own: the mean over
    the drawn views of each view's fractions on that view's pattern (``measure.on_own_patterns``), then
    :func:`slower_render` and :func:`speedup_at`. None for an estimate without per-view times, or whose views do not
    give back its own curve."""
    views = estimate.get("per_view") or []
    if not views or any(k not in estimate for k in ("render_cost", "c_render_ms", "nets_ms", "recnn_ms", "background_density")):
        return None
    own = (estimate.get("by_sharpness") or {}).get(sharpness_key(sharpness)) if float(sharpness) != 1.0 else None
    if own is not None:
        fractions, density = own.get("silhouette_fractions_per_view"), own.get("background_density")
    else:
        fractions, density = [v.get("silhouette_fractions") for v in views], estimate["background_density"]
    if density is None or not fractions or len(fractions) != len(views) or any(not f or len(f) != len(SHARES) for f in fractions):
        return None
    c = np.array([float(v["c_render_ms"]) for v in views])
    frac = np.array(fractions, dtype=np.float64)
    model = RenderCost(**estimate["render_cost"])
    stages = dict(nets_ms=estimate["nets_ms"], recnn_ms=estimate["recnn_ms"], background_density=float(density))

    def bounds(idx: np.ndarray) -> tuple[RenderCurve, list[float]]:
        curve = RenderCurve(SHARES, tuple((frac[idx] * c[idx, None]).mean(axis=0)), model.fixed_ms)
        curve = slower_render(curve, model, float(density))
        c_ms = float(c[idx].mean())
        return curve, [speedup_at(curve, s, c_render_ms=c_ms, **stages) for s in shares]

    # never trust a record that does not give back its own curve: an estimate of an earlier method (a median over
    # views) kept per-view times its curve was not made from
    whole, point = bounds(np.arange(len(c)))
    own_curve = estimate_render(estimate, sharpness)
    if isinstance(own_curve, RenderCurve) and not np.allclose(whole.times_ms, own_curve.times_ms, rtol=1e-3):
        return None
    draws = np.random.default_rng(seed).integers(0, len(c), size=(int(resamples), len(c)))
    return np.array(point), np.array([bounds(idx)[1] for idx in draws])


__all__ = ["SHARES", "RenderCost", "RenderCurve", "slower_render", "speedup_at", "bound_table", "share_for_speedup", "sharpness_key",
           "estimate_render", "speedup_from_estimate", "estimate_interval",
           "bound_intervals"]
