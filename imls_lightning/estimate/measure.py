"""Measurements of the before-training estimate: render costs, untrained networks, bilinear C -> FR.

Everything is measured on views drawn like the training views (never the test trajectory: choosing
scenes and sizes is tuning). Times are medians of ``repeats`` runs per view (one by default: the views, not the
runs, carry the variance), the renderer warmed by one untimed ray cast before the first view. Render times
are then averaged over the views, as a benchmark row averages its timed views' totals (its speed-up is the
ratio of those means); per-pixel costs and network times take the median over the views.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import torch
import torch.nn.functional as F

from imls_lightning.base.errors import InputError

from ..base.config import decoder_fill_for
from ..core.compaction import compact, decompact
from ..core.metrics import psnr_per_image
from ..core.patterns import SamplingPattern, crop_pattern, plastic_rank_pattern
from ..inference.pipeline import NetOptions, pick_device, prepare_net
from ..models.ims import IMSGenerator, IMSMaskHead
from ..models.iml import IMLNet
from ..core.pull_push import pull_push_inpaint
from .bound import RenderCost, RenderCurve

#: a C pixel counts as background when no channel differs from the background colour by more than this (of 255)
BACKGROUND_TOLERANCE = 2


def median_ms(fn: Callable[[], Any], repeats: int, warmup: int = 1, before: Callable[[], Any] | None = None) -> float:
    """Median wall time of ``fn()`` in ms over ``repeats`` runs after ``warmup`` untimed ones; ``before()``, when
    given, runs untimed before each run (what the product does between two calls of ``fn``)."""
    for _ in range(warmup):
        if before is not None:
            before()
        fn()
    times = []
    for _ in range(repeats):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


class PassTimer:
    """One view's timing pass: the median time of ray-casting a set of pixels, each set cast once per pass (a set
    timed again, such as the whole pattern that is every mask's share-1 set, is read back). ``timing``: the
    :func:`median_ms` to use (a caller's own, so that a test's stand-in reaches it).

    Example:
        >>> class Renderer:
        ...     calls = 0
        ...     def render_pixels(self, view, resolution, pixels):
        ...         Renderer.calls += 1
        >>> cast = PassTimer(Renderer(), None, 8, repeats=2)
        >>> _ = cast(np.arange(4)), cast(np.arange(4)), cast(np.arange(3))
        >>> Renderer.calls, len(cast)
        (4, 2)
    """

    def __init__(self, renderer, view, resolution: int, repeats: int, warmup: int = 0,
                 timing: Callable[..., float] | None = None):
        self.renderer, self.view, self.resolution = renderer, view, resolution
        self.repeats, self.warmup, self.timing = repeats, warmup, timing
        self._times: dict[tuple[int, bytes], float] = {}

    def __call__(self, pixels: np.ndarray) -> float:
        key = (len(pixels), np.asarray(pixels).tobytes())
        if key not in self._times:
            timing = self.timing or median_ms
            self._times[key] = timing(lambda: self.renderer.render_pixels(self.view, self.resolution, pixels),
                                      self.repeats, self.warmup)
        return self._times[key]

    def __len__(self) -> int:
        return len(self._times)


def object_pixels(colours: np.ndarray, background) -> np.ndarray:
    """``(K,)`` bool: the C pixels ``(K, 3)`` uint8 whose colour is not the background's."""
    bg = np.round(np.asarray(background, np.float64) * 255.0)
    return (np.abs(colours.astype(np.float64) - bg[None, :]) > BACKGROUND_TOLERANCE).any(axis=1)


def upsampler_name(pattern: SamplingPattern) -> str:
    """The classical C -> FR upsampling :func:`upsample_c_image` uses for ``pattern``: ``"bilinear"`` on a regular grid,
    ``"pull-push"`` otherwise."""
    return "bilinear" if pattern.kind == "downsample" else "pull-push"


def upsample_c_image(c: torch.Tensor, pattern: SamplingPattern) -> tuple[torch.Tensor, str]:
    """The classical C -> FR upsampling a RecNN has to beat: ``(B, 3, n, n)`` -> ``(B, 3, m, m)``.

    Downsampling pattern: bilinear interpolation between the sampled FR positions (C pixel ``j`` is FR
    pixel ``j f + o``; edges clamp). Other patterns: the samples scattered to their FR positions and
    pull-push filled there. Returns the image and the method's name.

    Example:
        >>> from imls_lightning.core.patterns import downsample_pattern
        >>> fr = torch.linspace(0, 1, 8).repeat(1, 3, 8, 1)       # a ramp along x
        >>> p = downsample_pattern(8, 2)
        >>> c = fr[..., ::2, ::2]
        >>> up, name = upsample_c_image(c, p)
        >>> name, round(float((up - fr)[..., :7].abs().max()), 6)   # exact inside, clamped at the edge
        ('bilinear', 0.0)
    """
    m, n = pattern.fr_size, pattern.c_size
    if pattern.kind == "downsample":
        f, o = dict(pattern.params)["factor"], dict(pattern.params)["offset"]
        pos = (torch.arange(m, dtype=torch.float32) - o) / f  # FR pixel -> C coordinate
        g = (pos.clamp(0, n - 1) / max(n - 1, 1)) * 2 - 1
        grid = torch.stack(torch.meshgrid(g, g, indexing="xy"), dim=-1)[None].expand(c.shape[0], m, m, 2)
        up = F.grid_sample(c.float(), grid.to(c.device), mode="bilinear", padding_mode="border", align_corners=True)
        return up, upsampler_name(pattern)
    idx = pattern.indices.to(c.device)
    ones = torch.ones(c.shape[0], 1, pattern.c_size, pattern.c_size, device=c.device)
    return pull_push_inpaint(decompact(c.float(), idx, m), decompact(ones, idx, m)), upsampler_name(pattern)


def psnr_db(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR of one ``(1, 3, m, m)`` image in ``[0, 1]`` against another (the project's formula)."""
    return float(psnr_per_image(a, b)[0])


@dataclass
class ViewMeasurement:
    """One view's render costs; the full frame and what is scored on it only on the views whose frame was rendered
    (:func:`measure_view`'s ``full_frame``), None on the others."""
    full_ms: float | None
    c_render_ms: float
    empty_ms: float
    object_ms: float
    background_ms: float
    object_px: int
    background_px: int
    bilinear_db: float | None
    fr: np.ndarray | None          # (m, m, 3) uint8
    upsampled: np.ndarray | None   # (m, m, 3) uint8
    on_object: np.ndarray          # (K,) bool: the pattern's pixels on the object


def measure_view(renderer, pattern: SamplingPattern, view, background, repeats: int, warmup: int,
                 full_frame: bool = True) -> ViewMeasurement:
    """Render costs and, with ``full_frame``, the classical upsampling's PSNR on one view.

    With ``full_frame`` the FR frame is rendered once (timed once: it is the cache's cost, not a stage of any
    method); the downsampling pattern's C-Image is its subset, so it is not rendered again for the PSNR. Without
    it, no FR frame is rendered: the last timed run of the pattern gives its colours (which pixels are on the
    object; seed_whole: a 512^2 frame costs 3x its C pattern). Every view times its object's and its background's
    pixels apart: the per-pixel model's medians taken over the 6 frame views alone put its costs 23-34% above the
    18 views' (seed_whole), and the bound would have followed the model.
    """
    m = pattern.fr_size
    idx = pattern.indices.numpy()
    fr = full_ms = None
    if full_frame:
        t0 = time.perf_counter()
        fr = renderer.render(view, m)
        full_ms = (time.perf_counter() - t0) * 1e3
        colours = fr.reshape(-1, 3)[idx]
        c_ms = median_ms(lambda: renderer.render_pixels(view, m, idx), repeats, warmup)
    else:
        runs: list[np.ndarray] = []
        c_ms = median_ms(lambda: runs.append(renderer.render_pixels(view, m, idx)), repeats, warmup)
        colours = runs[-1]
    obj = object_pixels(colours, background)
    obj_idx, bg_idx = idx[obj], idx[~obj]
    empty = np.zeros(0, np.int64)
    empty_ms = median_ms(lambda: renderer.render_pixels(view, m, empty), repeats, warmup)
    obj_ms = median_ms(lambda: renderer.render_pixels(view, m, obj_idx), repeats, warmup) if len(obj_idx) else empty_ms
    bg_ms = median_ms(lambda: renderer.render_pixels(view, m, bg_idx), repeats, warmup) if len(bg_idx) else empty_ms
    if fr is None:
        return ViewMeasurement(None, c_ms, empty_ms, obj_ms, bg_ms, int(obj.sum()), int((~obj).sum()), None, None,
                               None, obj)
    n = pattern.c_size
    flat = np.zeros((n * n, 3), np.float32)
    flat[: len(idx)] = colours.astype(np.float32) / 255.0
    c = torch.from_numpy(flat).view(1, n, n, 3).permute(0, 3, 1, 2)
    up, _ = upsample_c_image(c, pattern)
    target = frame_tensor(fr)
    up_u8 = (up[0].permute(1, 2, 0).clamp(0, 1).numpy() * 255.0 + 0.5).astype(np.uint8)
    return ViewMeasurement(full_ms, c_ms, empty_ms, obj_ms, bg_ms, int(obj.sum()), int((~obj).sum()),
                           psnr_db(up, target), fr, up_u8, obj)


def frame_subset(distances, count: int) -> list[int]:
    """The indices of ``count`` of the views whose full frame is rendered (the quality half: the classical
    upsampling's PSNR, the contact sheet, the needed share), spread over their camera distances: the views
    ranked by distance and cut into ``count`` equal slices of ranks, the middle view of each (all of them when
    ``count`` >= their number), in the views' order.

    The timing half needs many views (the views, not the runs, carry a speed-up's variance: 6 views gave a
    95% interval of 14-25% either side, 18 views 7%), the quality half few (its PSNR varies little between
    views), and a full frame costs several C patterns: so only this subset renders one.

    Example:
        >>> frame_subset([4.0, 3.0, 5.0, 3.5, 4.5], 3)     # the nearest (1), the middle (0) and the farthest (2)
        [0, 1, 2]
        >>> frame_subset([4.0, 3.0, 5.0], 1), frame_subset([4.0, 3.0], 6)
        ([0], [0, 1])
    """
    d = np.asarray(distances, np.float64)
    if count >= len(d):
        return list(range(len(d)))
    order = np.argsort(d, kind="stable")
    ranks = ((np.arange(count) + 0.5) * len(d) / count).astype(int)   # the middle rank of each of count slices
    return sorted(int(i) for i in order[ranks])


def render_cost(views: list[ViewMeasurement]) -> RenderCost:
    """Median per-pixel costs over the views (each view's fixed cost taken off first)."""
    fixed = float(np.median([v.empty_ms for v in views]))
    obj = [max(v.object_ms - v.empty_ms, 0.0) / v.object_px for v in views if v.object_px]
    bg = [max(v.background_ms - v.empty_ms, 0.0) / v.background_px for v in views if v.background_px]
    return RenderCost(fixed_ms=fixed, object_ms_per_px=float(np.median(obj)) if obj else 0.0,
                      background_ms_per_px=float(np.median(bg)) if bg else 0.0,
                      object_px=int(np.median([v.object_px for v in views])),
                      background_px=int(np.median([v.background_px for v in views])))


def on_own_patterns(times: np.ndarray, own_whole: np.ndarray, c_render_ms) -> np.ndarray:
    """``(S,)``: each share's render, averaged over the views, each view's times ``(V, S)`` taken as fractions of
    its own whole pattern timed in the same pass (``own_whole``, ``(V,)``) and put on that view's whole-pattern
    render as the estimate measured it (``c_render_ms``, ``(V,)``): ``mean_v(times[v] / own_whole[v] * c_render_ms[v])``.

    The fractions: the same pixels timed minutes apart differed by up to 30% (rt_plumes), so a mask's time is only
    comparable with a whole pattern of its own pass. The mean over views, weighted so by each view's cost: a row's
    speed-up is the ratio of its timed views' mean totals, where a dear view counts for more (seed_whole's row:
    2.56x as that ratio, 2.24x as a ratio of medians), and a mean of curves that rise with the share rises too,
    where a median per share jumped between views. At share 1 the curve is the mean ``c_render_ms`` exactly.

    Example:
        >>> on_own_patterns(np.array([[1.0, 2.0], [6.0, 12.0]]), np.array([2.0, 12.0]), [4.0, 10.0]).tolist()
        [3.5, 7.0]
    """
    t = np.asarray(times, np.float64)
    whole = np.asarray(own_whole, np.float64)
    c = np.asarray(c_render_ms, np.float64)
    if t.ndim != 2 or whole.shape != (t.shape[0],) or c.shape != whole.shape or t.shape[0] == 0:
        raise InputError(f"on_own_patterns: expected (V, S) times with one whole pattern and one c_render_ms per view; "
                         f"got {t.shape}, {whole.shape}, {c.shape}")
    return (t / np.maximum(whole, 1e-9)[:, None] * c[:, None]).mean(axis=0)


def mean_c_render_ms(measured: list[ViewMeasurement]) -> float:
    """The whole pattern's ray cast, the mean over the views (the bound's RecNN alone; :func:`on_own_patterns`)."""
    return float(np.mean([float(v.c_render_ms) for v in measured]))


def gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """``(B, 1, n, n)`` blurred by a separable Gaussian of ``sigma`` pixels (replicated edges); ``sigma <= 0``:
    ``x`` as it is."""
    if sigma <= 0:
        return x
    r = max(int(math.ceil(3.0 * sigma)), 1)
    t = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    w = torch.exp(-t * t / (2.0 * sigma * sigma))
    w = w / w.sum()
    x = F.conv2d(F.pad(x, (r, r, 0, 0), mode="replicate"), w.view(1, 1, 1, -1))
    return F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), w.view(1, 1, -1, 1))


def silhouette_mask(on_object: np.ndarray, share: float, pattern: SamplingPattern, blur: float = 4.0,
                    floor: float = 0.25, sharpness: float = 1.0) -> np.ndarray:
    """The pattern pixels ``(K',)`` (FR raster indices) of a mask of the shape a trained IMS makes, before training:
    the object's silhouette on the C grid blurred by ``blur`` C-pixels (the IMS sees only the view, so its
    importance is smooth and spills onto the background next to the object), plus the ``floor`` everywhere,
    made into the product's mask of ``share`` of the pattern (:func:`~imls_lightning.core.unpredictability.importance_mask`),
    sharpened by ``sharpness`` as the IMS's mask head sharpens its own (1: the paper's masks).

    ``on_object``: ``(K,)`` bool, the pattern's pixels on the object (:func:`object_pixels`).

    Example:
        >>> from imls_lightning.core.patterns import build_pattern
        >>> p = build_pattern({"kind": "downsample", "factor": 2}, 64)    # 32^2 C
        >>> on_object = np.zeros(p.count, bool); on_object[:256] = True     # the top quarter of C
        >>> pix = silhouette_mask(on_object, 0.3, p)
        >>> round(len(pix) / p.count, 2), bool(np.isin(pix, p.indices.numpy()[on_object]).mean() > 0.6)
        (0.29, True)
    """
    from ..core.unpredictability import importance_mask

    k, n = pattern.count, pattern.c_size
    obj = np.asarray(on_object, bool)
    if obj.shape != (k,):
        raise InputError(f"on_object: expected ({k},) bool, one per pattern pixel; got shape {obj.shape}")
    grid = torch.zeros(n * n)
    grid[:k] = torch.from_numpy(obj.astype(np.float32))
    score = gaussian_blur(grid.view(1, 1, n, n), float(blur))
    keep = importance_mask(score, share, pattern, floor, sharpness=sharpness).flatten()[:k].numpy()
    return pattern.indices.numpy()[keep]


def render_curves(renderer, pattern: SamplingPattern, views, measured: list[ViewMeasurement], shares, *, blur: float,
                  floor: float, repeats: int, fixed_ms: float, sharpnesses=(1.0,),
                  progress: Callable[[str], None] | None = None,
                  per_view: dict | None = None) -> dict[float, RenderCurve]:
    """The render of exactly a :func:`silhouette_mask`'s pixels at each share (the renderer is warm: no untimed
    run); ``fixed_ms``: the cost of a call with no pixel (:attr:`RenderCost.fixed_ms`).

    Each view's times are taken as fractions of its own whole pattern's render, put on that view's ``c_render_ms``
    and averaged over the views (:func:`on_own_patterns`; at share 1 the bound's RecNN alone,
    :func:`mean_c_render_ms`): a median over views per share picked another view at each share when their costs
    differ (flame_whole's three views: 0.59-1.11 s), and the curve went down and up (0.70 s at 90% of C after 0.71 s
    at 80%), where a larger share's mask holds the smaller's pixels.

    The whole pattern a fraction divides by is timed in this pass (share 1.0's mask when it kept every pixel, or the
    pattern itself), not taken from ``measured``: the same pixels timed minutes apart differed by up to 30%
    (rt_plumes: share 1.0 read 0.70-1.04 of ``c_render_ms``, 0.90 on average), so the curve sat 10% under the
    RecNN alone it is compared with, and the bound at share 1 read 1.04x, more than the RecNN alone with networks
    added can be.

    Every sharpness in ``sharpnesses`` gets its curve from the same pass: a view's masks of all of them are timed
    one after the other, against one whole pattern, and a mask whose pixels were already timed in the view's pass
    (the whole pattern at share 1, at every sharpness) is not cast again: a second sharpness's curve took as long as
    the first (seed_whole: 204 s of a 581 s estimate) and its masks were timed minutes after the first's.

    ``per_view``: a mapping that gets, per sharpness, each view's fractions of its own pattern, one list per view
    (the spread the mean hides: a mask of one share costs 0.23-0.51 of its view's pattern on seed_whole)."""
    gammas = [float(g) for g in sharpnesses]
    times = np.zeros((len(gammas), len(views), len(shares)))
    own_whole = np.zeros(len(views))
    all_pix = pattern.indices.numpy()
    t0 = time.perf_counter()
    for v, (view, meas) in enumerate(zip(views, measured)):
        cast = PassTimer(renderer, view, pattern.fr_size, repeats, timing=median_ms)
        for j, s in enumerate(shares):
            for i, g in enumerate(gammas):
                times[i, v, j] = cast(silhouette_mask(meas.on_object, s, pattern, blur, floor, g))
        own_whole[v] = cast(all_pix)   # share 1's mask when it kept every pixel, else one more render
        if progress is not None:
            which = ", ".join(f"sharpness {g:g}" for g in gammas if g != 1.0)
            progress(f"render curve{f' (and {which})' if which else ''}: view {v + 1}/{len(views)}, "
                     f"{len(cast)} masks ({time.perf_counter() - t0:.0f} s)")
    c_render = [float(meas.c_render_ms) for meas in measured]
    out = {}
    for i, g in enumerate(gammas):
        if per_view is not None:
            per_view.setdefault(g, []).extend((times[i] / np.maximum(own_whole, 1e-9)[:, None]).tolist())
        curve = on_own_patterns(times[i], own_whole, c_render)
        out[g] = RenderCurve(tuple(float(s) for s in shares), tuple(curve.tolist()), float(fixed_ms))
    return out


def render_curve(renderer, pattern: SamplingPattern, views, measured: list[ViewMeasurement], shares, *, blur: float,
                 floor: float, repeats: int, fixed_ms: float, progress: Callable[[str], None] | None = None,
                 sharpness: float = 1.0, per_view: list | None = None) -> RenderCurve:
    """:func:`render_curves` of one ``sharpness``; ``per_view``: a list that gets each view's fractions."""
    fractions: dict = {}
    curve = render_curves(renderer, pattern, views, measured, shares, blur=blur, floor=floor, repeats=repeats,
                          fixed_ms=fixed_ms, sharpnesses=(sharpness,), progress=progress, per_view=fractions)
    if per_view is not None:
        per_view.extend(fractions[float(sharpness)])
    return curve[float(sharpness)]


def build_networks(pattern: SamplingPattern, recnn_net: Mapping[str, Any], iml: Mapping[str, Any],
                   ims: Mapping[str, Any]) -> dict[str, torch.nn.Module]:
    """Untrained networks of the chosen sizes: latency does not depend on the weights.

    ``recnn_net``: the ``recnn.net`` node (``_target_`` + sizes); ``iml``: ``depth``, ``base_channels``,
    ``decoder``; ``ims``: ``layers``, ``base_channels``, ``max_channels``.
    """
    from ..tasks.recnn import build_recnn

    n = pattern.c_size
    try:
        recnn = build_recnn(recnn_net, pattern)
    except InputError:
        raise
    except Exception as err:  # Hydra wraps the model's own error: name the node and the cause in one line
        cause = err.__cause__ or err
        raise InputError(f"recnn.net: cannot build the RecNN ({type(cause).__name__}: {str(cause).splitlines()[0]})") from None
    iml_net = IMLNet(n, plastic_rank_pattern(n), depth=int(iml["depth"]), base_channels=int(iml["base_channels"]),
                     valid=pattern.valid, decoder=str(iml.get("decoder", "refine")),
                     fill_pattern=pattern if decoder_fill_for(pattern.kind) == "fr" else None)  # as model.fill's default
    gen = IMSGenerator(n, layers=int(ims["layers"]), base_channels=int(ims["base_channels"]),
                       max_channels=int(ims["max_channels"]))
    return {"recnn": recnn, "iml": iml_net, "ims": gen}


@dataclass
class RecNNLead:
    """A quickly trained RecNN against the classical upsampling on the estimate's own views."""
    steps: int
    train_views: int
    recnn_db: float          # mean PSNR of the trained RecNN over the evaluation views
    upsampled_db: float      # the classical upsampling's, on the same views
    seconds: float
    net: torch.nn.Module | None = field(default=None, repr=False, compare=False)  # the trained RecNN (eval mode)

    @property
    def lead_db(self) -> float:
        return self.recnn_db - self.upsampled_db

    def to_dict(self) -> dict[str, float]:
        return {"steps": self.steps, "train_views": self.train_views, "recnn_db": self.recnn_db,
                "upsampled_db": self.upsampled_db, "lead_db": self.lead_db, "seconds": self.seconds}


def frame_tensor(fr: np.ndarray) -> torch.Tensor:
    """A rendered frame ``(m, m, 3)`` uint8 (or a cache's memory-mapped row) -> ``(1, 3, m, m)`` float in [0, 1]."""
    return torch.from_numpy(np.asarray(fr, np.float32) / 255.0).permute(2, 0, 1)[None]


def recnn_lead(recnn: torch.nn.Module, pattern: SamplingPattern, train_frames: list[np.ndarray],
               eval_frames: list[np.ndarray], steps: int, crop: int = 128, batch: int = 8, lr: float = 1e-3,
               seed: int = 0, device: str = "auto") -> RecNNLead:
    """Does the scene hold structure a RecNN can learn? Trains ``recnn`` (untrained, the size make bench-paper
    trains) for ``steps`` Adam steps on random grid-aligned ``crop`` x ``crop`` patches of ``train_frames``
    (the loss of the RecNN stage: MSE) and scores it and the classical upsampling on ``eval_frames``.

    A few hundred steps on a few views already show the lead a full training reaches, less a few tenths of a
    dB (BENCHMARKS.md: the three paper-regime scenes): a scene of pixel-scale noise shows none, whatever the
    training. Regular-grid patterns only (the RecNN must take a crop of a C-Image).

    Example:
        >>> from imls_lightning.core.patterns import downsample_pattern
        >>> from imls_lightning.models.enhancenet import EnhanceNet
        >>> p = downsample_pattern(16, 2)
        >>> frames = [(np.random.default_rng(i).random((16, 16, 3)) * 255).astype(np.uint8) for i in range(2)]
        >>> lead = recnn_lead(EnhanceNet(p, channels=4, blocks=1), p, frames, frames[:1], steps=2, crop=8, batch=2)
        >>> lead.steps, bool(np.isfinite(lead.lead_db))
        (2, True)
    """
    from ..tasks.recnn import reconstruction_loss

    if pattern.kind != "downsample":
        raise InputError(f"recnn_lead.steps={steps}: the quick RecNN trains on crops of a regular grid; "
                         f"the {pattern.kind} pattern has none (set recnn_lead.steps=0)")
    f, m = int(pattern.param_dict["factor"]), pattern.fr_size
    crop = min(int(crop) // f * f, m // f * f)
    if crop < f or not train_frames or not eval_frames:
        raise InputError(f"recnn_lead: expected a crop of at least {f} pixels and views to train and score on")
    window = crop_pattern(pattern, crop)  # a grid-aligned window's C-pixels, as data.crop trains the RecNN stage
    t0 = time.perf_counter()
    dev = pick_device(device)
    net = recnn.to(dev).train()
    opt = torch.optim.Adam(net.parameters(), lr=float(lr))
    frames = torch.cat([frame_tensor(fr) for fr in train_frames]).to(dev)
    g = torch.Generator().manual_seed(int(seed))
    cells = (m - crop) // f + 1
    for _ in range(int(steps)):
        ids = torch.randint(0, len(frames), (batch,), generator=g).tolist()
        ys = (torch.randint(0, cells, (batch,), generator=g) * f).tolist()
        xs = (torch.randint(0, cells, (batch,), generator=g) * f).tolist()
        target = torch.stack([frames[i, :, y:y + crop, x:x + crop] for i, y, x in zip(ids, ys, xs)])
        loss = reconstruction_loss(net(compact(target, window.indices, window.c_size)), target, "mse", 0.0)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    net.eval()
    rec, up = [], []
    with torch.inference_mode():
        for fr in eval_frames:
            target = frame_tensor(fr).to(dev)
            c = compact(target, pattern.indices, pattern.c_size)
            rec.append(psnr_db(net(c).clamp(0, 1), target))
            up.append(psnr_db(upsample_c_image(c, pattern)[0], target))
    return RecNNLead(int(steps), len(train_frames), float(np.mean(rec)), float(np.mean(up)), time.perf_counter() - t0, net)


def estimate_mask_head(generator: torch.nn.Module, pattern: SamplingPattern, sharpness: float = 1.0,
                       trained_mean: float = 0.2) -> IMSMaskHead:
    """The product's mask head around an (untrained) IMS generator, as the estimate times it: PIM' regressed
    (``target="pim"``), sharpened to ``sharpness``, rescaled from ``trained_mean``."""
    return IMSMaskHead(generator, plastic_rank_pattern(pattern.c_size), pattern.valid, "pim",
                       trained_mean=float(trained_mean), sharpness=float(sharpness))


def network_stages(nets: Mapping[str, torch.nn.Module], pattern: SamplingPattern, opts: NetOptions,
                   share: float = 0.3, sharpness: float = 1.0, trained_mean: float = 0.2) -> dict[str, Callable[[], Any]]:
    """The stages IML/S adds and the RecNN, prepared as the product path runs them (on ``opts``'s device, in its
    precision and layout, compiled when it asks), each a call ``() -> output`` on fixed inputs: ``ims_ms`` (the
    product's mask head, :func:`estimate_mask_head`: the generator, then its PIM' sharpened to ``sharpness``, rescaled
    from ``trained_mean`` to the mean ``share`` and lifted to that share, as the evaluation's lifted ORP runs it),
    ``decoder_ms`` (the IML's decoder module on a mask of ``share``) and ``recnn_ms``. A compiled stage compiles on its
    first call. The inputs come channels-last, as the renderer hands a C-Image over."""
    device = pick_device(opts.device)
    n = pattern.c_size
    recnn = prepare_net(nets["recnn"], device, opts)
    decoder = prepare_net(nets["iml"].decoder, device, opts)  # the module the product runs (compiled when asked)
    gen = prepare_net(nets["ims"], device, opts)
    head = estimate_mask_head(gen, pattern, sharpness, trained_mean).to(device)
    view = torch.tensor([[0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]], device=device)
    c = torch.rand(1, n, n, 3, device=device).permute(0, 3, 1, 2)  # channels-last memory, as the renderer hands it over
    im = ((torch.rand(1, 1, n, n, device=device) < share) & pattern.valid.to(device)).to(c.dtype)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def stage(network: Callable[[], torch.Tensor], after: Callable[[torch.Tensor], Any] = lambda x: x):
        @torch.inference_mode()
        def run():
            with opts.autocast(device):
                out = network()
            out = after(out)  # outside autocast: the mask head thresholds in float32
            sync()
            return out
        return run

    return {"ims_ms": stage(lambda: gen(view), lambda g: head.threshold(g, float(share), True)),
            "decoder_ms": stage(lambda: decoder(im * c, im)), "recnn_ms": stage(lambda: recnn(c))}


def network_ms(nets: Mapping[str, torch.nn.Module], pattern: SamplingPattern, opts: NetOptions, repeats: int,
               warmup: int, share: float = 0.3, sharpness: float = 1.0, trained_mean: float = 0.2,
               before: Callable[[], Any] | None = None) -> dict[str, float]:
    """Median ms of each stage IML/S adds and of the RecNN, as the product path runs them (:func:`network_stages`).

    ``before``: run untimed before each timed call, e.g. a ray cast. In the product the networks follow a ray cast,
    which leaves the caches holding the volume's data; back to back, each network's weights and activations stay
    cached (flame_whole: 13 / 27 / 18 ms in the product's run, 10 / 20 / 13 back to back)."""
    stages = network_stages(nets, pattern, opts, share, sharpness, trained_mean)
    return {name: median_ms(fn, repeats, warmup, before=before) for name, fn in stages.items()}


__all__ = ["median_ms", "on_own_patterns", "mean_c_render_ms", "object_pixels", "upsampler_name", "upsample_c_image", "psnr_db", "ViewMeasurement", "measure_view", "frame_subset", "PassTimer",
           "render_cost", "render_curve", "render_curves", "build_networks", "estimate_mask_head", "network_stages", "network_ms", "RecNNLead", "recnn_lead", "frame_tensor", "BACKGROUND_TOLERANCE"]
