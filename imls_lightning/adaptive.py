"""Adaptive importance: a per-view mean value instead of one fixed ``u`` (the paper's stated limitation).

The IML normalizes its importance map to a prescribed mean value ``u`` and keeps C-Image pixel ``i``
when ``PIM'_i > P_i``, so about a share ``u`` of the pattern's pixels is rendered, whatever the view.
The ORP (:mod:`imls_lightning.orp`) picks the smallest *fixed* ``u`` whose IML + RecNN stays within
``epsilon`` (1 dB) of the RecNN alone. A simple view (little of the volume on screen) needs fewer
pixels than a busy one for the same quality. This module makes ``u`` a function of the view:

1. **Per-view labels** (:func:`compute_labels`): for each view of a cache split, the smallest
   ``u_v`` in ``[0.01, 1]`` such that the path on that view is within ``epsilon_db`` PSNR of the
   RecNN alone (against the FR ground truth), by bisection in ``log u`` with a fixed number of steps
   (:func:`bisect_mean`), vectorized over a batch of views. The path is the product's, IML/S
   (``source="ims"``: the IMS's PIM' from the view, scaled to ``u_v``, decoder, RecNN), or the
   trained IML's own (``source="iml"``, :func:`iml_pim`, :func:`im_at_means`: encoder,
   normalization at ``u_v``, hard rejection sampling against ``P``, decoder, RecNN).
2. **A mean predictor** (:class:`MeanPredictor`): view ``(B, 9)`` -> ``u`` ``(B,)`` in ``[0.01, 1]``,
   a small MLP with a sigmoid in ``log u``, trained on the labels of the train split by
   :func:`train_predictor` (L1 on ``log u``, full batch, seeded); ``margin`` multiplies predictions.
3. **The adaptive renderer** (:class:`AdaptiveIMLSRenderer`): the IMS (``target="pim"``) regresses
   ``PIM'`` normalized to the IML's trained mean ``u_train``; with ``l = 0`` the normalization is
   linear in ``u``, so ``PIM'(u_v) = PIM'(u_train) * u_v / u_train`` exactly (:func:`scaled_pim_im`);
   the rest (selective render of those pixels, decoder, RecNN) is :class:`IMLSRenderer`'s. Its
   timings add the predictor's stage ``"mean"``. :class:`AdaptiveIMLPlusRecNN` is the upper bound
   (importance from the rendered C-Image at ``u_v``).
4. **The CLI** (:func:`run_adaptive`): labels (cached next to the IMS run and reused), predictor,
   and the comparison on the test trajectory with the fixed-mean alternatives (the trained mean, the
   fixed-mean ORP on the validation views, the fixed mean whose average IPR matches the adaptive one),
   written as ``adaptive.md`` + ``adaptive.csv`` + ``adaptive.png``; and the trade-off
   (:func:`quality_at_means`, :func:`tradeoff`): the predictor at several margins against the whole
   curve of fixed means on the (average IPR, average PSNR) plane (``tradeoff.png`` / ``.csv``).

    python -m imls_lightning.adaptive scene=flame data=small ims_checkpoint=<IMS .ckpt> epsilon_db=1.0

Example:
    >>> import torch
    >>> res = bisect_mean(lambda u: 10 * (0.2 - u).clamp(min=0), 3, epsilon_db=1.0, steps=12)
    >>> [round(x, 3) for x in res.u.tolist()], res.met.tolist()     # gap <= 1 dB from u = 0.1
    ([0.1, 0.1, 0.1], [True, True, True])
"""
from __future__ import annotations

import copy
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence

import hydra
import numpy as np
import torch
from omegaconf import DictConfig
from torch import nn

import data_gen  # noqa: F401  (registers the scene config resolvers)
from data_gen.errors import InputError, checked_command_line, cli_errors, finite_number

from .config import register_resolvers
from .importance import MEAN_RANGE, normalize_importance
from .metrics import psnr_per_image
from .tasks.ims import scaled_pim_im  # noqa: F401  (public here since the adaptive renderer was added)
from .pipeline import (
    IMLPlusRecNN,
    IMLSRenderer,
    NetOptions,
    StageTimer,
    load_ims_and_recnn,
    pick_device,
    prepare_net,
    renderer_for_task,
)

__all__ = [
    "MEAN_RANGE",
    "check_epsilon",
    "BisectResult",
    "bisect_mean",
    "iml_pim",
    "im_at_means",
    "MeanLabels",
    "compute_labels",
    "quality_at_means",
    "TradeoffPoint",
    "tradeoff",
    "view_complexity",
    "MeanPredictor",
    "ConstantMean",
    "train_predictor",
    "scaled_pim_im",
    "AdaptiveIMLSRenderer",
    "AdaptiveIMLPlusRecNN",
    "mean_for_ipr",
    "run_adaptive",
    "main",
]

register_resolvers()

REFERENCES = ("recnn", "iml")
SOURCES = ("ims", "iml")  # whose importance the labels bisect: the IMS (IML/S, the product) or the IML (upper bound)
UNREACHABLE = ("hi", "best")  # the label of a view that no mean in the bracket brings within epsilon


# ------------------------------------------------------------------------------------------------
# validation helpers


def _integer(value: Any, key: str, lo: int, hi: int | None = None) -> int:
    what = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
    x = finite_number(value, key, what)
    if x != int(x) or x < lo or (hi is not None and x > hi):
        raise InputError(f"{key}={value!r}: expected {what}")
    return int(x)


def check_epsilon(epsilon_db: Any, key: str = "epsilon_db") -> float:
    """Validate the PSNR tolerance (dB): a finite number ``>= 0``.

    Example:
        >>> check_epsilon(1)
        1.0
    """
    eps = finite_number(epsilon_db, key, "a finite number of dB >= 0")
    if eps < 0:
        raise InputError(f"{key}={epsilon_db!r}: expected a finite number of dB >= 0")
    return eps


def _clamp_mean(u: float) -> float:
    """A float32 ``0.01`` is ``0.0099999998``: clamp to the range ``check_mean`` accepts."""
    return min(max(float(u), MEAN_RANGE[0]), MEAN_RANGE[1])


# ------------------------------------------------------------------------------------------------
# 1. per-view labels


@dataclass
class BisectResult:
    """Outcome of :func:`bisect_mean` for a batch of views, each ``(B,)``.

    Attributes:
        u: smallest mean value found meeting epsilon; where even the bracket's top fails, the top
            (``unreachable="hi"``) or the smallest ``u`` within epsilon of the gap at the top
            (``unreachable="best"``).
        met: whether ``u`` met epsilon itself (False: no mean in the bracket did).
        gap: the gap (dB) measured at ``u``.
        evaluations: how many times ``gap_fn`` was called (``steps + 2``).
    """

    u: torch.Tensor
    met: torch.Tensor
    gap: torch.Tensor
    evaluations: int


def bisect_mean(gap_fn: Callable[[torch.Tensor], torch.Tensor], batch: int, epsilon_db: float = 1.0,
                steps: int = 8, bracket: Sequence[float] = MEAN_RANGE, unreachable: str = "hi") -> BisectResult:
    """Per-view smallest mean value ``u`` with ``gap(u) <= epsilon_db``, by bisection in ``log u``.

    Assumes ``gap`` decreases as ``u`` grows (more pixels, closer to the RecNN alone). First the
    bracket's ends are evaluated: a view meeting epsilon at ``lo`` gets ``lo``; one failing at
    ``hi`` gets ``hi`` with ``met=False`` (``unreachable="hi"``), or (``unreachable="best"``) is
    bisected like the others against ``gap(hi) + epsilon_db``: the fewest pixels that are within
    epsilon of the best quality this IML reaches on that view, instead of all of them for nothing
    (with a monotone gap, ``gap(hi)`` is that best). Then ``steps`` rounds halve ``[lo, hi]`` in ``log u`` for
    every view at once (``hi`` always meets epsilon, ``lo`` never does), and ``hi`` is the answer:
    known to a factor ``(hi0 / lo0) ** (1 / 2 ** steps)`` (8 steps over ``[0.01, 1]``: 1.8 %).

    Args:
        gap_fn: ``u (B,) float64 tensor -> gap (B,) tensor`` (dB; NaN counts as failing).
        batch: number of views ``B``.
        epsilon_db: allowed gap.
        steps: bisection rounds, ``>= 1``.
        bracket: ``(lo, hi)`` with ``0 < lo < hi``.
        unreachable: ``"hi"`` or ``"best"``, the label of a view that fails at ``hi`` (see above).

    Example:
        >>> target = torch.tensor([0.02, 0.3, 2.0])          # 2.0: not reachable in [0.01, 1]
        >>> r = bisect_mean(lambda u: (target - u).clamp(min=0) * 100, 3, 0.0, steps=10)
        >>> [round(x, 2) for x in r.u.tolist()], r.met.tolist()
        ([0.02, 0.3, 1.0], [True, True, False])
    """
    eps = check_epsilon(epsilon_db)
    steps = _integer(steps, "steps", 1, 60)
    batch = _integer(batch, "batch", 1)
    lo0, hi0 = (finite_number(x, "bracket", "two numbers 0 < lo < hi") for x in bracket)
    if not 0 < lo0 < hi0:
        raise InputError(f"bracket=[{lo0}, {hi0}]: expected 0 < lo < hi")
    if unreachable not in UNREACHABLE:
        raise InputError(f"unreachable={unreachable!r}: expected one of {list(UNREACHABLE)}")

    def gap(u: torch.Tensor) -> torch.Tensor:
        g = torch.as_tensor(gap_fn(u), dtype=torch.float64).detach().cpu().reshape(-1)
        if g.numel() != batch:
            raise ValueError(f"gap_fn returned {g.numel()} gaps for {batch} views")
        return torch.nan_to_num(g, nan=math.inf)

    lo = torch.full((batch,), lo0, dtype=torch.float64)
    hi = torch.full((batch,), hi0, dtype=torch.float64)
    g_hi = gap(hi)
    g_lo = gap(lo)
    met = (g_hi <= eps) | (g_lo <= eps)
    # per-view threshold: epsilon, or (unreachable="best", finite gap at hi) epsilon above the gap at hi
    thr = torch.full_like(g_hi, eps)
    if unreachable == "best":
        thr = torch.where((g_hi > eps) & torch.isfinite(g_hi), g_hi + eps, thr)
    ok_hi, ok_lo = g_hi <= thr, g_lo <= thr
    for _ in range(steps):
        mid = torch.exp(0.5 * (torch.log(lo) + torch.log(hi)))
        g_mid = gap(mid)
        ok = g_mid <= thr
        hi = torch.where(ok, mid, hi)
        g_hi = torch.where(ok, g_mid, g_hi)
        lo = torch.where(ok, lo, mid)
    u = torch.where(ok_lo, torch.full_like(hi, lo0), torch.where(ok_hi, hi, torch.full_like(hi, hi0)))
    g = torch.where(ok_lo, g_lo, g_hi)
    return BisectResult(u=u, met=met, gap=g, evaluations=steps + 2)


def iml_pim(iml: nn.Module, c_image: torch.Tensor) -> torch.Tensor:
    """The IML encoder's preliminary importance ``PIM`` ``(B, 1, n, n)`` (softplus output, float32).

    Example:
        >>> from imls_lightning.models.iml import IMLNet
        >>> iml = IMLNet(8, torch.rand(8, 8), depth=2, base_channels=4).eval()
        >>> iml_pim(iml, torch.rand(2, 3, 8, 8)).shape
        torch.Size([2, 1, 8, 8])
    """
    return iml.encode(c_image)[0]


def im_at_means(iml: nn.Module, pim: torch.Tensor, means: torch.Tensor | Sequence[float]) -> torch.Tensor:
    """Hard IM ``(B, 1, n, n)`` float {0, 1} of each image at its own mean value ``means[b]``.

    Exactly the IML's inference path with ``iml.mean = means[b]`` (its normalization, with its
    ``lower``/``delta`` and valid-pixel mean, then hard rejection sampling against ``P``, 0 on
    padding): each image is normalized by :func:`~imls_lightning.importance.normalize_importance`
    with its own scalar mean.

    Args:
        iml: an :class:`~imls_lightning.models.iml.IMLNet`.
        pim: ``(B, 1, n, n)`` from :func:`iml_pim`.
        means: ``(B,)`` mean values in ``[0.01, 1]`` (clamped into it).

    Example:
        >>> from imls_lightning.models.iml import IMLNet
        >>> iml = IMLNet(8, torch.rand(8, 8), depth=2, base_channels=4).eval()
        >>> pim = iml_pim(iml, torch.rand(2, 3, 8, 8))
        >>> bool((im_at_means(iml, pim, [iml.mean] * 2) == iml.sample(iml.normalization(pim), hard=True)).all())
        True
    """
    iml = getattr(iml, "_orig_mod", iml)
    us = torch.as_tensor(means, dtype=torch.float64).reshape(-1).tolist()
    if len(us) != pim.shape[0]:
        raise InputError(f"means: expected {pim.shape[0]} mean values (one per image), got {len(us)}")
    norm = iml.normalization
    valid = None if iml._all_valid else iml.valid
    pim_norm = torch.cat([normalize_importance(pim[b:b + 1], _clamp_mean(u), norm.lower, norm.delta, valid)
                          for b, u in enumerate(us)])
    return iml.sample(pim_norm, hard=True)


@dataclass
class MeanLabels:
    """Per-view mean-value labels of one cache split (plain arrays; :meth:`save` / :meth:`load` as ``.npz``).

    Attributes (each ``(N,)`` unless noted): ``rows`` (cache rows), ``views`` ``(N, 9)``, ``u``
    (smallest mean meeting epsilon; 1 where none does), ``met``, ``gap_db`` (gap at ``u``),
    ``psnr_ref`` (the reference: RecNN alone, or IML + RecNN at the trained mean), ``complexity`` (:func:`view_complexity`); ``meta``: split, epsilon,
    steps, bracket, seconds.
    """

    rows: np.ndarray
    views: np.ndarray
    u: np.ndarray
    met: np.ndarray
    gap_db: np.ndarray
    psnr_ref: np.ndarray
    complexity: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.rows)

    def save(self, path: str | Path) -> Path:
        """Write atomically (temporary name + rename)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(f".{p.stem}.{os.getpid()}.tmp.npz")
        np.savez(tmp, rows=self.rows, views=self.views, u=self.u, met=self.met, gap_db=self.gap_db,
                 psnr_ref=self.psnr_ref, complexity=self.complexity, meta=np.asarray(json.dumps(self.meta)))
        tmp.replace(p)
        return p

    @classmethod
    def load(cls, path: str | Path) -> "MeanLabels":
        try:
            with np.load(Path(path), allow_pickle=False) as z:
                arrays = {k: np.asarray(z[k]) for k in ("rows", "views", "u", "met", "gap_db", "psnr_ref", "complexity")}
                meta = json.loads(str(z["meta"]))
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"labels {path}: unreadable ({type(err).__name__}: {err}); delete it to recompute") from None
        return cls(**arrays, meta=meta)


def view_complexity(images: np.ndarray, background: Sequence[float] = (0.0, 0.0, 0.0), tol: int = 3) -> np.ndarray:
    """Fraction of the FR pixels that are not background, per image: ``(N,)`` float in [0, 1].

    Args:
        images: ``(N, m, m, 3)`` uint8.
        background: the scene's background colour in [0, 1].
        tol: a pixel counts as background when every channel is within ``tol`` (of 255) of it.

    Example:
        >>> img = np.zeros((1, 4, 4, 3), np.uint8); img[0, :2] = 200
        >>> view_complexity(img).tolist()
        [0.5]
    """
    a = np.asarray(images)
    if a.ndim != 4 or a.shape[-1] != 3:
        raise InputError(f"images: expected (N, m, m, 3) uint8 images, got shape {a.shape}")
    bg = np.round(np.asarray(background, np.float64) * 255.0)
    diff = np.abs(a.astype(np.int16) - bg.astype(np.int16)).max(axis=-1)
    return (diff > tol).reshape(len(a), -1).mean(axis=1)


def _check_source(source: str, ims) -> None:
    if source not in SOURCES:
        raise InputError(f"label_source={source!r}: expected one of {list(SOURCES)}")
    if source == "ims" and (ims is None or getattr(ims, "target", None) != "pim"):
        raise InputError("label_source=ims: needs the IMS task (an IMS trained with model.target=pim)")


def _mask_fn(source: str, iml: nn.Module, ims, c: torch.Tensor, view: torch.Tensor) -> Callable[[Any], torch.Tensor]:
    """``u (B,) -> IM (B, 1, n, n)`` in ``c``'s dtype for one batch: the IML's mask at ``u`` from the
    rendered C-Image ``c`` (``source="iml"``) or the IMS's PIM' for ``view`` scaled to ``u``
    (``source="ims"``, the IML/S path). The network runs once here, not per ``u``."""
    if source == "iml":
        pim = iml_pim(iml, c)
        return lambda u: im_at_means(iml, pim, u).to(c.dtype)
    g = ims.generator(view.float()).float()
    u_train = float(iml.mean)
    return lambda u: scaled_pim_im(ims, g, torch.as_tensor(u, dtype=torch.float32).reshape(-1).expand(c.shape[0]),
                                   u_train).to(c.dtype)


def compute_labels(cache, rows: np.ndarray, pattern, iml: nn.Module, recnn_iml: nn.Module, recnn_alone: nn.Module,
                   epsilon_db: float = 1.0, steps: int = 8, batch_size: int = 16, device: str | torch.device = "cpu",
                   progress: bool = True, desc: str = "labels", reference: str = "recnn",
                   bracket: Sequence[float] = MEAN_RANGE, unreachable: str = "hi", source: str = "iml",
                   ims=None) -> MeanLabels:
    """Per-view smallest mean value meeting epsilon, for the cache ``rows`` (see :func:`bisect_mean`).

    For each batch of views: the RecNN alone on the C-Image (once), the IML encoder (once), then per
    bisection step the IM at each view's ``u``, the IML decoder and the RecNN (``recnn_iml``);
    ``gap = PSNR_ref - PSNR_IML+RecNN(u)`` per view against the FR ground truth, where the reference
    is the RecNN alone (``reference="recnn"``, the paper's ORP criterion) or the IML + RecNN at its
    trained mean (``reference="iml"``: "how far can this view's ``u`` drop below the trained one
    without losing more than epsilon"; useful when the IML + RecNN never gets within epsilon of the
    RecNN alone).

    Args:
        cache: an open :class:`~data_gen.cache.ViewImageCache`.
        rows: cache rows to label.
        pattern: the sampling pattern (C-Images are compacted with it).
        iml: the :class:`~imls_lightning.models.iml.IMLNet`; ``recnn_iml`` behind it; ``recnn_alone``
            the reference RecNN (usually the same network).
        epsilon_db, steps, bracket, unreachable: as :func:`bisect_mean` (with ``reference="iml"`` use
            ``(0.01, trained mean)``: its upper end meets epsilon by construction).
        batch_size: views per batch (>= 1).
        device: where the networks run.
        source: whose importance is bisected: ``"iml"`` (the IML encoder on the rendered C-Image, the
            upper bound) or ``"ims"`` (the product path IML/S: the IMS's PIM' from the view alone,
            scaled to ``u`` by :func:`scaled_pim_im`; needs ``ims``, an IMS task with
            ``target="pim"``). With ``"ims"`` and ``reference="iml"`` the reference is IML/S at the
            trained mean.
    """
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from .data import ViewImageDataset

    eps = check_epsilon(epsilon_db)
    steps = _integer(steps, "steps", 1, 60)
    bs = _integer(batch_size, "batch_size", 1)
    if reference not in REFERENCES:
        raise InputError(f"reference={reference!r}: expected one of {list(REFERENCES)}")
    _check_source(source, ims)
    dev = pick_device(device)
    rows = np.asarray(rows, np.int64)
    for net in (iml, recnn_iml, recnn_alone) + ((ims,) if ims is not None else ()):
        net.to(dev).eval()
    ds = ViewImageDataset(cache.path, rows, pattern, fields=("view", "fr", "c"))
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("u", "met", "gap", "psnr")}
    t0 = time.perf_counter()
    loader = DataLoader(ds, batch_size=bs, shuffle=False, num_workers=0)
    with torch.inference_mode():
        for batch in tqdm(loader, total=len(loader), desc=desc, unit="batch", file=sys.stderr,
                          disable=not progress, dynamic_ncols=True):
            c, fr = batch["c"].to(dev), batch["fr"].to(dev)
            mask_at = _mask_fn(source, iml, ims, c, batch["view"].to(dev))
            if reference == "recnn":
                psnr_ref = psnr_per_image(recnn_alone(c), fr)
            else:
                m_ref = mask_at([float(iml.mean)] * c.shape[0])
                psnr_ref = psnr_per_image(recnn_iml(iml.decode(m_ref * c, m_ref)), fr)

            def gap_fn(u: torch.Tensor) -> torch.Tensor:
                m = mask_at(u)
                return psnr_ref - psnr_per_image(recnn_iml(iml.decode(m * c, m)), fr)

            res = bisect_mean(gap_fn, c.shape[0], eps, steps, bracket, unreachable)
            out["u"].append(res.u.numpy())
            out["met"].append(res.met.numpy())
            out["gap"].append(res.gap.numpy())
            out["psnr"].append(psnr_ref.double().cpu().numpy())
    seconds = time.perf_counter() - t0
    bg = cache.manifest.get("scene_config", {}).get("background") if isinstance(cache.manifest.get("scene_config"), Mapping) else None
    cplx = view_complexity(np.asarray(cache.images[rows]) if len(rows) else np.zeros((0, 1, 1, 3), np.uint8),
                           bg if bg is not None else (0.0, 0.0, 0.0))
    cat = (lambda k, dt: np.concatenate(out[k]).astype(dt) if out[k] else np.zeros(0, dt))
    return MeanLabels(
        rows=rows, views=np.asarray(cache.views[rows], np.float32).reshape(-1, 9), u=cat("u", np.float64),
        met=cat("met", bool), gap_db=cat("gap", np.float64), psnr_ref=cat("psnr", np.float64), complexity=cplx,
        meta={"epsilon_db": eps, "reference": reference, "source": source, "steps": steps, "bracket": [float(x) for x in bracket], "unreachable": unreachable, "seconds": round(seconds, 3),
              "views": int(len(rows)), "evaluations_per_view": steps + 2},
    )


def quality_at_means(cache, rows: np.ndarray, pattern, iml: nn.Module, recnn: nn.Module, means: Mapping[str, Any], *,
                     source: str = "ims", ims=None, batch_size: int = 16, device: str | torch.device = "cpu",
                     progress: bool = False, desc: str = "trade-off") -> dict[str, dict[str, np.ndarray]]:
    """Per-view PSNR and IPR of the IML/S (``source="ims"``) or IML (``"iml"``) + RecNN path at given means.

    One pass over the cache ``rows``: per batch the RecNN alone, the importance network (once) and,
    for every entry of ``means``, the mask at that entry's per-view ``u``, the decoder and the RecNN
    on the float images of the cache (the selective render of the masked pixels gives those same
    pixels, up to the uint8 rounding of the real renderer).

    Args:
        means: ``name -> u``: a number (one fixed mean) or an ``(N,)`` array (one mean per row).
        source, ims: as :func:`compute_labels`.

    Returns:
        ``name -> {"psnr": (N,), "ipr": (N,)}`` plus ``"recnn" -> {"psnr": (N,)}`` (the RecNN alone);
        IPR is rendered pixels / FR pixels.

    Example (shapes only; see ``tests/test_adaptive.py``)::

        q = quality_at_means(cache, rows, pattern, iml, recnn, {"fixed": 0.3, "adaptive": u_pred}, ims=ims)
        q["adaptive"]["psnr"].mean(), q["adaptive"]["ipr"].mean()
    """
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from .data import ViewImageDataset

    _check_source(source, ims)
    bs = _integer(batch_size, "batch_size", 1)
    rows = np.asarray(rows, np.int64)
    n_rows = len(rows)
    table: dict[str, np.ndarray] = {}
    for name, u in means.items():
        arr = np.asarray(u, np.float64)
        arr = np.full(n_rows, float(arr)) if arr.ndim == 0 else arr.reshape(-1)
        if arr.shape[0] != n_rows or not np.isfinite(arr).all() or (arr <= 0).any():
            raise InputError(f"means[{name!r}]: expected a positive mean or {n_rows} positive means, got shape {np.shape(u)}")
        table[name] = np.clip(arr, *MEAN_RANGE)
    dev = pick_device(device)
    for net in (iml, recnn) + ((ims,) if ims is not None else ()):
        net.to(dev).eval()
    fr_pixels = float(pattern.fr_size) ** 2
    out: dict[str, dict[str, list[np.ndarray]]] = {k: {"psnr": [], "ipr": []} for k in table}
    out["recnn"] = {"psnr": []}
    ds = ViewImageDataset(cache.path, rows, pattern, fields=("view", "fr", "c"))
    loader = DataLoader(ds, batch_size=bs, shuffle=False, num_workers=0)
    start = 0
    with torch.inference_mode():
        for batch in tqdm(loader, total=len(loader), desc=desc, unit="batch", file=sys.stderr, disable=not progress,
                          dynamic_ncols=True):
            c, fr = batch["c"].to(dev), batch["fr"].to(dev)
            sl = slice(start, start + c.shape[0])
            start += c.shape[0]
            out["recnn"]["psnr"].append(psnr_per_image(recnn(c), fr).double().cpu().numpy())
            mask_at = _mask_fn(source, iml, ims, c, batch["view"].to(dev))
            for name, u in table.items():
                im = mask_at(torch.as_tensor(u[sl]))
                out[name]["psnr"].append(psnr_per_image(recnn(iml.decode(im * c, im)), fr).double().cpu().numpy())
                out[name]["ipr"].append(im.flatten(1).sum(1).double().cpu().numpy() / fr_pixels)
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return {name: {k: cat(v) for k, v in d.items()} for name, d in out.items()}


@dataclass
class TradeoffPoint:
    """One setting on the IPR / quality plane, compared with the fixed-mean curve.

    ``ipr``, ``psnr``: averages over the views; ``within``: share of views within epsilon of the
    reference; ``fixed_psnr``: the fixed-mean curve's average PSNR at this average IPR (linear
    between the curve's points; None outside its IPR range); ``fixed_ipr``: the smallest average
    IPR at which the fixed-mean curve reaches this average PSNR (None: no fixed mean does);
    ``fixed_within``: the curve's within-epsilon share at this IPR.
    """

    name: str
    ipr: float
    psnr: float
    within: float
    fixed_psnr: float | None
    fixed_within: float | None
    fixed_ipr: float | None

    @property
    def d_psnr(self) -> float | None:
        """dB gained over the fixed mean at the same average IPR."""
        return None if self.fixed_psnr is None else self.psnr - self.fixed_psnr

    @property
    def d_ipr(self) -> float | None:
        """Relative change of the pixels rendered vs the fixed mean at the same average PSNR (< 0: fewer)."""
        return None if not self.fixed_ipr else self.ipr / self.fixed_ipr - 1.0


def tradeoff(reference: np.ndarray, fixed: Mapping[float, Mapping[str, np.ndarray]],
             points: Mapping[str, Mapping[str, np.ndarray]], epsilon_db: float = 1.0) -> tuple[list[dict[str, float]], list[TradeoffPoint]]:
    """Compare per-view settings with the curve of fixed means on the (average IPR, average PSNR) plane.

    Args:
        reference: ``(N,)`` per-view reference PSNR (a view is "within" when its PSNR is at most
            ``epsilon_db`` below it).
        fixed: ``u -> {"psnr": (N,), "ipr": (N,)}`` for several fixed means (the curve).
        points: ``name -> {"psnr": (N,), "ipr": (N,)}``: the settings compared (adaptive, oracle).

    Returns:
        ``(curve, compared)``: the curve as ``{"u", "ipr", "psnr", "within"}`` rows sorted by IPR, and
        one :class:`TradeoffPoint` per entry of ``points``.

    Example:
        >>> ref = np.array([30.0, 30.0])
        >>> fixed = {u: {"psnr": np.array([20 + 10 * u, 20 + 10 * u]), "ipr": np.array([u, u])} for u in (0.1, 0.5, 1.0)}
        >>> _, (p,) = tradeoff(ref, fixed, {"a": {"psnr": np.array([25.0, 27.0]), "ipr": np.array([0.2, 0.4])}})
        >>> round(p.d_psnr, 3), round(p.d_ipr, 3)          # +3 dB at IPR 0.3; the curve needs 0.6 for 26 dB
        (3.0, -0.5)
    """
    eps = check_epsilon(epsilon_db)
    ref = np.asarray(reference, np.float64)

    def summary(d: Mapping[str, np.ndarray]) -> tuple[float, float, float]:
        ps = np.asarray(d["psnr"], np.float64)
        if ps.shape != ref.shape:
            raise InputError(f"tradeoff: expected {ref.shape[0]} per-view PSNRs, got shape {ps.shape}")
        return float(np.mean(d["ipr"])), float(ps.mean()), float((ref - ps <= eps + 1e-9).mean())

    curve = sorted(({"u": float(u), **dict(zip(("ipr", "psnr", "within"), summary(d)))} for u, d in fixed.items()),
                   key=lambda r: (r["ipr"], r["u"]))
    if not curve:
        raise InputError("tradeoff: expected at least one fixed mean")
    ci = np.array([r["ipr"] for r in curve])
    cp = np.array([r["psnr"] for r in curve])
    cw = np.array([r["within"] for r in curve])
    env = np.maximum.accumulate(cp)  # best PSNR reachable with at most this IPR

    def fixed_ipr_for(psnr: float) -> float | None:
        if psnr > env[-1]:
            return None
        k = int(np.argmax(env >= psnr))  # first point reaching it; env[k - 1] < psnr <= env[k]
        if k == 0:
            return float(ci[0])
        t = (psnr - env[k - 1]) / (env[k] - env[k - 1])
        return float(ci[k - 1] + t * (ci[k] - ci[k - 1]))

    compared = []
    for name, d in points.items():
        ip, ps, w = summary(d)
        inside = len(ci) > 1 and ci[0] - 1e-12 <= ip <= ci[-1] + 1e-12
        compared.append(TradeoffPoint(name, ip, ps, w, float(np.interp(ip, ci, cp)) if inside else None,
                                      float(np.interp(ip, ci, cw)) if inside else None, fixed_ipr_for(ps)))
    return curve, compared


# ------------------------------------------------------------------------------------------------
# 2. the mean predictor


class MeanPredictor(nn.Module):
    """View ``(B, 9)`` -> mean value ``u`` ``(B,)`` in ``[lo, hi]`` (default ``[0.01, 1]``).

    Features: the 9 view floats, the unit view direction ``lookAt - eye`` and the camera distance
    (13 numbers), standardized with statistics fitted on the training views
    (:meth:`fit_normalization`, stored as buffers). An MLP (``layers`` hidden layers of ``hidden``
    units, SiLU) gives ``z``; ``log u = log lo + (log hi - log lo) sigmoid(z)`` (:meth:`log_mean`,
    what training fits), and ``forward`` returns ``clamp(margin * exp(log u), lo, hi)``: a
    ``margin > 1`` renders a few more pixels than predicted, a safety factor against
    under-prediction. Gradients stay finite for any finite view (the sigmoid saturates, the
    direction is divided by ``max(distance, 1e-6)``).

    Example:
        >>> p = MeanPredictor(hidden=8, layers=1)
        >>> u = p(torch.tensor([[0, 0, 3.0, 0, 0, 0, 0, 1, 0]]))
        >>> u.shape, bool((u >= 0.01).all() and (u <= 1).all())
        (torch.Size([1]), True)
    """

    FEATURES = 13

    def __init__(self, hidden: int = 64, layers: int = 2, margin: float = 1.0, bracket: Sequence[float] = MEAN_RANGE):
        super().__init__()
        hidden = _integer(hidden, "predictor.hidden", 1, 4096)
        layers = _integer(layers, "predictor.layers", 0, 16)
        lo, hi = (finite_number(x, "predictor.bracket", "two numbers in [0.01, 1]") for x in bracket)
        if not MEAN_RANGE[0] <= lo < hi <= MEAN_RANGE[1]:
            raise InputError(f"predictor.bracket=[{lo}, {hi}]: expected {MEAN_RANGE[0]} <= lo < hi <= {MEAN_RANGE[1]}")
        self.hidden, self.layers, self.bracket = hidden, layers, (lo, hi)
        self.margin = margin
        mods: list[nn.Module] = []
        width = self.FEATURES
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        mods.append(nn.Linear(width, 1))
        self.mlp = nn.Sequential(*mods)
        self.register_buffer("feat_mean", torch.zeros(self.FEATURES))
        self.register_buffer("feat_std", torch.ones(self.FEATURES))

    @property
    def margin(self) -> float:
        return self._margin

    @margin.setter
    def margin(self, value: float) -> None:
        m = finite_number(value, "predictor.margin", "a number in (0, 10]")
        if not 0 < m <= 10:
            raise InputError(f"predictor.margin={value!r}: expected a number in (0, 10] (1: no margin)")
        self._margin = m

    def hparams(self) -> dict[str, Any]:
        return {"hidden": self.hidden, "layers": self.layers, "margin": self.margin, "bracket": list(self.bracket)}

    @staticmethod
    def features(view: torch.Tensor) -> torch.Tensor:
        """``(B, 9)`` -> ``(B, 13)``: view, unit direction ``lookAt - eye``, distance."""
        v = torch.as_tensor(view, dtype=torch.float32)
        if v.dim() != 2 or v.shape[1] != 9:
            raise InputError(f"view: expected a (B, 9) tensor of (eye, lookAt, up), got shape {tuple(v.shape)}")
        d = v[:, 3:6] - v[:, 0:3]
        dist = d.norm(dim=1, keepdim=True)
        return torch.cat([v, d / dist.clamp_min(1e-6), dist], dim=1)

    @torch.no_grad()
    def fit_normalization(self, views: torch.Tensor) -> None:
        """Standardize the features with the mean/std of these training views ``(N, 9)``."""
        f = self.features(views)
        if f.shape[0] < 1:
            raise InputError("views: expected at least one training view")
        std = f.std(0, unbiased=False) if f.shape[0] > 1 else torch.ones(self.FEATURES)
        self.feat_mean.copy_(f.mean(0))
        self.feat_std.copy_(torch.where(std < 1e-6, torch.ones_like(std), std))

    def log_mean(self, view: torch.Tensor) -> torch.Tensor:
        """``log u`` ``(B,)`` before the margin, in ``[log lo, log hi]`` (the quantity trained)."""
        f = self.features(view).to(self.feat_mean.device)
        z = self.mlp((f - self.feat_mean) / self.feat_std)[:, 0]
        lo, hi = math.log(self.bracket[0]), math.log(self.bracket[1])
        return lo + (hi - lo) * torch.sigmoid(z)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        u = torch.exp(self.log_mean(view)) * self.margin
        return u.clamp(self.bracket[0], self.bracket[1])

    def save(self, path: str | Path) -> Path:
        """State dict + hyperparameters, loadable with ``torch.load(weights_only=True)``; atomic."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
        torch.save({"hparams": self.hparams(), "state_dict": self.state_dict()}, tmp)
        tmp.replace(p)
        return p

    @classmethod
    def load(cls, path: str | Path, margin: float | None = None) -> "MeanPredictor":
        try:
            d = torch.load(Path(path), map_location="cpu", weights_only=True)
            hp = dict(d["hparams"])
            if margin is not None:
                hp["margin"] = margin
            p = cls(**hp)
            p.load_state_dict(d["state_dict"])
        except (OSError, KeyError, RuntimeError, TypeError) as err:
            raise InputError(f"predictor={path}: not a MeanPredictor file ({type(err).__name__}: {str(err)[:120]})") from None
        return p.eval()


class ConstantMean(nn.Module):
    """The fixed-mean "predictor": ``u`` for every view, ``(B,)`` float32.

    Example:
        >>> ConstantMean(0.2)(torch.zeros(2, 9)).tolist() == [torch.tensor(0.2).item()] * 2
        True
    """

    def __init__(self, u: float):
        super().__init__()
        u = finite_number(u, "u", f"a number in [{MEAN_RANGE[0]}, {MEAN_RANGE[1]}]")
        if not MEAN_RANGE[0] <= u <= MEAN_RANGE[1]:
            raise InputError(f"u={u}: expected a number in [{MEAN_RANGE[0]}, {MEAN_RANGE[1]}]")
        self.u = u

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        return torch.full((view.shape[0],), self.u, dtype=torch.float32, device=view.device)

    def extra_repr(self) -> str:
        return f"u={self.u}"


def train_predictor(views: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor, *,
                    val: tuple[Any, Any] | None = None, hidden: int = 64, layers: int = 2, epochs: int = 600,
                    lr: float = 3e-3, weight_decay: float = 1e-4, seed: int = 0, margin: float = 1.0,
                    progress: bool = False) -> tuple[MeanPredictor, dict[str, Any]]:
    """Fit a :class:`MeanPredictor` to per-view labels: L1 on ``log u``, full-batch Adam on the CPU.

    Deterministic for a given ``seed`` (the global RNG is left as it was).

    Args:
        views: ``(N, 9)`` training views; ``u``: ``(N,)`` labels in ``[0.01, 1]``.
        val: optional ``(views, u)``: the validation L1 is reported and the epoch where it is lowest
            is kept (early stopping by model selection).
        hidden, layers, margin: :class:`MeanPredictor` settings; ``epochs``: full-batch steps.

    Returns:
        ``(predictor in eval mode, history)`` with ``train_l1``, ``val_l1`` (``log u``; None without
        ``val``), ``constant_l1`` (the best constant, the median label: the baseline to beat),
        ``seconds``, ``epochs``, ``best_epoch`` (the kept epoch; ``epochs`` without ``val``).

    Example:
        >>> v = torch.randn(32, 9); y = torch.exp(-2 + v[:, 0].clamp(-1, 1))
        >>> p, h = train_predictor(v, y, epochs=200, hidden=16)
        >>> h["train_l1"] < h["constant_l1"]
        True
    """
    x = torch.as_tensor(np.asarray(views, np.float32))
    y = torch.as_tensor(np.asarray(u, np.float64)).float().reshape(-1)
    if x.dim() != 2 or x.shape[1] != 9 or x.shape[0] < 1 or x.shape[0] != y.shape[0]:
        raise InputError(f"views/u: expected (N, 9) views and (N,) labels with N >= 1, got {tuple(x.shape)} and {tuple(y.shape)}")
    if not bool(torch.isfinite(y).all()) or float(y.min()) <= 0:
        raise InputError("u: expected positive finite labels in [0.01, 1]")
    epochs = _integer(epochs, "predictor.epochs", 1, 1_000_000)
    lr = finite_number(lr, "predictor.lr", "a positive learning rate")
    wd = finite_number(weight_decay, "predictor.weight_decay", "a number >= 0")
    if lr <= 0 or wd < 0:
        raise InputError(f"predictor.lr={lr}, predictor.weight_decay={wd}: expected lr > 0 and weight_decay >= 0")
    target = y.clamp(*MEAN_RANGE).log()
    t0 = time.perf_counter()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        model = MeanPredictor(hidden=hidden, layers=layers, margin=margin)
        model.fit_normalization(x)
        opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=wd)
        has_val = val is not None and len(val[0]) > 0
        if has_val:
            vx = torch.as_tensor(np.asarray(val[0], np.float32))
            vy = torch.as_tensor(np.asarray(val[1], np.float64)).float().clamp(*MEAN_RANGE).log()
        # With validation labels the epoch with the lowest validation L1 is kept: a few hundred views
        # are easily memorized by the MLP (train L1 falls far below a validation L1 that rises).
        best_l1, best_epoch, best_state = math.inf, epochs, None
        with torch.enable_grad():
            for epoch in range(1, epochs + 1):
                model.train()
                loss = (model.log_mean(x) - target).abs().mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                if has_val:
                    model.eval()
                    with torch.no_grad():
                        v_l1 = float((model.log_mean(vx) - vy).abs().mean())
                    if v_l1 < best_l1:
                        best_l1, best_epoch, best_state = v_l1, epoch, copy.deepcopy(model.state_dict())
        if best_state is not None:
            model.load_state_dict(best_state)
    model.eval()
    with torch.no_grad():
        train_l1 = float((model.log_mean(x) - target).abs().mean())
        const = float((target - target.median()).abs().mean())
        val_l1 = None
        val_const = None
        if has_val:
            val_l1 = float((model.log_mean(vx) - vy).abs().mean())
            val_const = float((vy - target.median()).abs().mean())
    return model, {"train_l1": train_l1, "val_l1": val_l1, "constant_l1": const, "val_constant_l1": val_const,
                   "seconds": time.perf_counter() - t0, "epochs": epochs, "best_epoch": best_epoch,
                   "views": int(x.shape[0])}


# ------------------------------------------------------------------------------------------------
# 3. adaptive renderers


def _view_tensor(view, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(np.asarray(view, np.float32))[None].to(device)


def _mean_of(predictor: nn.Module, v: torch.Tensor) -> torch.Tensor:
    with torch.autocast(device_type=v.device.type, enabled=False):
        u = predictor(v).float().reshape(-1)
    return u


class AdaptiveIMLSRenderer(IMLSRenderer):
    """IML/S + RecNN with a per-view mean value: view -> ``u_v`` (predictor) -> IMS PIM' scaled by
    ``u_v / u_train`` -> IM -> ray-cast only those pixels -> IML decoder -> RecNN.

    Stages: ``mean`` (the predictor), then :class:`IMLSRenderer`'s ``importance``,
    ``selective_render``, ``decoder``, ``recnn``; ``info["mean"]`` is the ``u_v`` used.

    Args:
        renderer: the scene's renderer.
        task: a loaded :class:`~imls_lightning.tasks.ims.IMSTask` with ``target="pim"`` (moved to the
            options' device and prepared in place, like :meth:`IMLSRenderer.from_task`).
        predictor: ``view (1, 9) -> u (1,)``, e.g. :class:`MeanPredictor` or :class:`ConstantMean`.
        recnn: a RecNN to use instead of the task's.
        opts: :class:`NetOptions`.

    Raises:
        InputError: the IMS was trained with ``target="im"`` (a binary mask cannot be rescaled), or
            no RecNN.

    Example:
        >>> r = AdaptiveIMLSRenderer.from_checkpoints("ims.ckpt", "mean_predictor.pt")   # doctest: +SKIP
        >>> image, t = r.render(view); sorted(t)                                          # doctest: +SKIP
        ['decoder', 'importance', 'mean', 'recnn', 'selective_render', 'total']
    """

    name = "imls_adaptive"

    def __init__(self, renderer, task, predictor: nn.Module, recnn: nn.Module | None = None,
                 opts: NetOptions | None = None):
        if task.hparams.get("target") != "pim":
            raise InputError(f"ims_checkpoint: its IMS was trained with model.target={task.hparams.get('target')}; the adaptive "
                             "renderer scales the regressed PIM', which needs an IMS trained with model.target=pim")
        opts = opts or NetOptions()
        recnn = task.recnn if recnn is None else recnn
        if recnn is None:
            raise InputError("ims_checkpoint carries no RecNN (its IML was standalone): pass recnn_checkpoint=<RecNN .ckpt>")
        device = pick_device(opts.device)
        task.to(device).eval()
        self.task = task
        self.u_train = float(task.iml.mean)
        self.generator = prepare_net(task.generator, device, opts)
        self.predictor = predictor.to(device).eval()
        super().__init__(renderer, task.pattern, self._predict_im, task.decoder, recnn, opts)

    @classmethod
    def from_checkpoints(cls, ims_checkpoint: str, predictor: str | nn.Module, *, scene=None, renderer=None,
                         renderer_cfg=None, recnn_checkpoint: str | None = None, opts: NetOptions | None = None,
                         margin: float | None = None) -> "AdaptiveIMLSRenderer":
        """Build from an IMS checkpoint and a predictor (module or a :meth:`MeanPredictor.save` file).

        Scene and renderer default to those stored in the IMS checkpoint (as
        :meth:`IMLSRenderer.from_checkpoints`); ``margin`` overrides the predictor file's margin.
        """
        task, recnn = load_ims_and_recnn(ims_checkpoint, recnn_checkpoint)
        if not isinstance(predictor, nn.Module):
            predictor = MeanPredictor.load(predictor, margin=margin)
        elif margin is not None:
            predictor.margin = margin
        return cls(renderer_for_task(task, scene, renderer, renderer_cfg), task, predictor, recnn, opts)

    def _predict_im(self, view: torch.Tensor, u: torch.Tensor | float | None = None) -> torch.Tensor:
        """IM ``(B, 1, n, n)`` of views ``(B, 9)`` at mean ``u`` (``None``: the predictor's)."""
        if u is None:
            u = _mean_of(self.predictor, view)
        with self.opts.autocast(self.device):
            g = self.generator(view)
        return scaled_pim_im(self.task, g, u, self.u_train)

    def mean_for(self, view) -> float:
        """The predictor's ``u_v`` for one view (no rendering)."""
        with torch.inference_mode():
            return float(_mean_of(self.predictor, _view_tensor(view, self.device))[0])

    def _importance(self, view, timer: StageTimer, info: dict) -> torch.Tensor:
        v = _view_tensor(view, self.device)
        with timer.stage("mean"):
            u = _mean_of(self.predictor, v)
        info["mean"] = float(u[0])
        with timer.stage("importance"):
            return self._predict_im(v, u)[0, 0].bool()


class AdaptiveIMLPlusRecNN(IMLPlusRecNN):
    """IML + RecNN at a per-view mean value (importance from the rendered C-Image: the upper bound
    of the adaptive IML/S). Stages: ``selective_render`` (whole pattern), ``mean``, ``importance``,
    ``decoder``, ``recnn``; ``info["mean"]`` is the ``u_v`` used.

    Example:
        >>> m = AdaptiveIMLPlusRecNN(renderer, pattern, ims.iml, ims.recnn, predictor)   # doctest: +SKIP
    """

    name = "iml_adaptive"

    def __init__(self, renderer, pattern, iml: nn.Module, recnn: nn.Module, predictor: nn.Module,
                 opts: NetOptions | None = None):
        super().__init__(renderer, pattern, iml, recnn, opts)
        self.predictor = predictor.to(self.device).eval()

    def _importance(self, c: torch.Tensor, view, timer: StageTimer, info: dict) -> torch.Tensor:
        with timer.stage("mean"):
            u = _mean_of(self.predictor, _view_tensor(view, self.device))
        info["mean"] = float(u[0])
        with timer.stage("importance"), self.opts.autocast(self.device):
            return im_at_means(self.iml, iml_pim(getattr(self.iml, "_orig_mod", self.iml), c), u)


def mean_for_ipr(ipr_of: Callable[[float], float], target: float, steps: int = 30) -> float:
    """The fixed mean value ``u`` in ``[0.01, 1]`` whose average IPR ``ipr_of(u)`` is closest to ``target``.

    Bisection in ``log u`` (``ipr_of`` non-decreasing in ``u``); returns the closest ``u`` seen.

    Example:
        >>> round(mean_for_ipr(lambda u: 0.5 * u, 0.05), 4)
        0.1
    """
    lo, hi = MEAN_RANGE
    best, best_err = hi, abs(ipr_of(hi) - target)
    e = abs(ipr_of(lo) - target)
    if e < best_err:
        best, best_err = lo, e
    for _ in range(int(steps)):
        mid = math.exp(0.5 * (math.log(lo) + math.log(hi)))
        val = ipr_of(mid)
        if abs(val - target) < best_err:
            best, best_err = mid, abs(val - target)
        if val < target:
            lo = mid
        else:
            hi = mid
    return float(best)


# ------------------------------------------------------------------------------------------------
# 4. the CLI


@dataclass
class Settings:
    """Validated keys of ``conf/adaptive.yaml``."""

    ims: str
    recnn: str | None
    epsilon_db: float
    reference: str
    steps: int
    unreachable: str
    label_source: str
    tradeoff_means: int
    tradeoff_margins: tuple[float, ...]
    batch_size: int
    predictor: dict[str, Any]
    views: str
    max_views: int | None
    repeats: int
    timing_views: int
    device: str
    output_dir: str | None
    progress: bool

    def label_key(self) -> dict[str, Any]:
        return {"epsilon_db": self.epsilon_db, "reference": self.reference, "steps": self.steps,
                "unreachable": self.unreachable, "source": self.label_source}

    def hashed(self) -> dict[str, Any]:
        return {**self.label_key(), "predictor": self.predictor, "views": self.views, "max_views": self.max_views,
                "repeats": self.repeats, "timing_views": self.timing_views,
                "tradeoff_means": self.tradeoff_means, "tradeoff_margins": list(self.tradeoff_margins)}


PREDICTOR_DEFAULTS = {"hidden": 64, "layers": 2, "epochs": 600, "lr": 3e-3, "weight_decay": 1e-4, "seed": 0, "margin": 1.0}


def parse_settings(cfg) -> Settings:
    """Validate ``cfg`` (``conf/adaptive.yaml``); bad values raise a one-line :class:`InputError`."""
    from omegaconf import OmegaConf

    from .config import to_plain

    ims = OmegaConf.select(cfg, "ims_checkpoint", default=None) if not OmegaConf.is_missing(cfg, "ims_checkpoint") else None
    if not ims:
        raise InputError("ims_checkpoint: required, an IMS checkpoint trained with model.target=pim (python -m imls_lightning.train model=ims model.target=pim ...)")
    recnn = cfg.get("recnn_checkpoint") or None
    for key, p in (("ims_checkpoint", ims), ("recnn_checkpoint", recnn)):
        if p and not Path(str(p)).expanduser().is_file():
            raise InputError(f"{key}={p}: file not found")
    pred = dict(PREDICTOR_DEFAULTS)
    given = to_plain(cfg.get("predictor")) or {}
    unknown = set(given) - set(PREDICTOR_DEFAULTS)
    if unknown:
        raise InputError(f"predictor.{sorted(unknown)[0]}: unknown key; expected some of {sorted(PREDICTOR_DEFAULTS)}")
    pred.update(given)
    pred["hidden"] = _integer(pred["hidden"], "predictor.hidden", 1, 4096)
    pred["layers"] = _integer(pred["layers"], "predictor.layers", 0, 16)
    pred["epochs"] = _integer(pred["epochs"], "predictor.epochs", 1, 1_000_000)
    pred["seed"] = _integer(pred["seed"], "predictor.seed", 0)
    for k in ("lr", "weight_decay", "margin"):
        pred[k] = finite_number(pred[k], f"predictor.{k}", "a finite number")
    if pred["lr"] <= 0 or pred["weight_decay"] < 0 or not 0 < pred["margin"] <= 10:
        raise InputError(f"predictor: expected lr > 0, weight_decay >= 0 and margin in (0, 10] (got {pred['lr']}, {pred['weight_decay']}, {pred['margin']})")
    views = str(cfg.get("views", "test"))
    if views not in ("test", "val"):
        raise InputError(f"views={views}: expected 'test' (the trajectory) or 'val'")
    mv = cfg.get("max_views")
    reference = str(cfg.get("reference", "recnn"))
    if reference not in REFERENCES:
        raise InputError(f"reference={reference}: expected recnn (within epsilon of the RecNN alone) or iml (of IML + RecNN at the trained mean)")
    unreachable = str(cfg.get("unreachable", "best"))
    if unreachable not in UNREACHABLE:
        raise InputError(f"unreachable={unreachable}: expected best (within epsilon of the view's best gap) or hi (the bracket's top)")
    source = str(cfg.get("label_source", "ims"))
    if source not in SOURCES:
        raise InputError(f"label_source={source}: expected ims (labels on the IML/S path, the product) or iml (the IML on the rendered C-Image)")
    margins = to_plain(cfg.get("tradeoff_margins", [0.8, 1.0, 1.25, 1.5]))
    if isinstance(margins, (int, float)) and not isinstance(margins, bool):
        margins = [margins]
    if not isinstance(margins, list) or not margins:
        raise InputError(f"tradeoff_margins={margins}: expected a list of factors in (0, 10], e.g. [0.8,1,1.25]")
    margins = [finite_number(x, "tradeoff_margins", "factors in (0, 10]") for x in margins]
    if not all(0 < x <= 10 for x in margins):
        raise InputError(f"tradeoff_margins={margins}: expected factors in (0, 10]")
    device = str(cfg.get("device", "auto"))
    pick_device(device)
    return Settings(
        ims=str(ims), recnn=str(recnn) if recnn else None, epsilon_db=check_epsilon(cfg.get("epsilon_db", 1.0)), reference=reference,
        steps=_integer(cfg.get("steps", 8), "steps", 1, 30), unreachable=unreachable, label_source=source,
        tradeoff_means=_integer(cfg.get("tradeoff_means", 16), "tradeoff_means", 0, 200),
        tradeoff_margins=tuple(sorted(set(margins))), batch_size=_integer(cfg.get("batch_size", 16), "batch_size", 1),
        predictor=pred, views=views, max_views=None if mv is None else _integer(mv, "max_views", 1),
        repeats=_integer(cfg.get("repeats", 10), "repeats", 1), timing_views=_integer(cfg.get("timing_views", 20), "timing_views", 0),
        device=device, output_dir=cfg.get("output_dir") or None, progress=bool(cfg.get("progress", True)),
    )


def run_dir_of(checkpoint: str | Path) -> Path:
    """The training run directory of a checkpoint (``<run>/checkpoints/x.ckpt`` -> ``<run>``)."""
    p = Path(str(checkpoint)).expanduser().resolve()
    return p.parent.parent if p.parent.name == "checkpoints" else p.parent


def _ensure_labels(path: Path, make: Callable[[], MeanLabels], what: str) -> tuple[MeanLabels, bool]:
    if path.is_file():
        print(f"[adaptive] reusing {what} labels {path}", file=sys.stderr, flush=True)
        return MeanLabels.load(path), True
    labels = make()
    labels.save(path)
    return labels, False


def _fmt(x: Any, spec: str = ".3f") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, spec)


def run_adaptive(cfg, command: str | None = None) -> Path:
    """The CLI's body: labels -> predictor -> comparison on the test trajectory; returns ``adaptive.md``."""
    from omegaconf import OmegaConf

    from data_gen.cache import ViewImageCache, ensure_cache
    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene

    from . import report as rep
    from .config import file_hash, settings_hash, to_plain
    from .evaluate import measure, spaced
    from .orp import ORPSearch, evaluate_quality, batched
    from .pipeline import RecNNAlone

    s = parse_settings(cfg)
    t_start = time.perf_counter()
    ims, recnn = load_ims_and_recnn(s.ims, s.recnn)
    if ims.target != "pim":
        raise InputError(f"ims_checkpoint={s.ims}: its IMS was trained with model.target={ims.target}; the adaptive mean scales "
                         "the regressed PIM', which needs an IMS trained with model.target=pim")
    resolution = int(cfg.data.resolution)
    fr = int(ims.hparams["fr_size"])
    if fr != resolution:
        raise InputError(f"data.resolution={resolution}: the IMS checkpoint was trained at {fr}^2; pass the data group it was trained with")
    trained_scene = (ims.hparams.get("scene") or {}).get("name")
    if trained_scene and str(cfg.scene.get("name")) != str(trained_scene):
        raise InputError(f"scene={cfg.scene.get('name')}: the IMS checkpoint was trained on scene {trained_scene}; pass scene={trained_scene}")
    recnn = recnn if recnn is not None else ims.recnn
    if recnn is None:
        raise InputError(f"ims_checkpoint={s.ims}: carries no RecNN (its IML was trained standalone); pass recnn_checkpoint=<RecNN .ckpt>")
    device = pick_device(s.device)
    opts = NetOptions(device=str(device))
    iml = ims.iml
    u_train = float(iml.mean)
    pattern = ims.pattern
    m = resolution

    scene = build_scene(cfg.scene)
    cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=s.progress))
    if cache.resolution != resolution:
        raise InputError(f"data.resolution={resolution}: the cache {cache.path} holds {cache.resolution}^2 images")
    ck_hashes = {"ims": file_hash(Path(s.ims).expanduser()), "recnn": file_hash(Path(s.recnn).expanduser()) if s.recnn else None}
    run_dir = run_dir_of(s.ims)
    label_dir = run_dir / "adaptive" / "labels"
    label_hash = settings_hash(ck_hashes, cache.path.name, s.label_key())
    out = Path(s.output_dir) if s.output_dir else run_dir / "adaptive" / settings_hash(ck_hashes, cache.path.name, s.hashed())
    out.mkdir(parents=True, exist_ok=True)
    (out / "adaptive.md").unlink(missing_ok=True)
    timing: dict[str, Any] = {}

    # -- 1. labels ---------------------------------------------------------------------------------
    labels: dict[str, MeanLabels] = {}
    bracket = MEAN_RANGE if s.reference == "recnn" else (MEAN_RANGE[0], u_train)
    for split in ("train", "val", s.views):
        if split in labels:
            continue
        rows = cache.splits[split]
        if split == s.views:
            rows = rows[spaced(len(rows), s.max_views)]
        if len(rows) == 0:
            if split == "train":
                raise InputError(f"data: the cache {cache.path} has no training views to label")
            continue
        t0 = time.perf_counter()
        tag = split if split != s.views or s.max_views is None else f"{split}{len(rows)}"
        labels[split], reused = _ensure_labels(
            label_dir / f"{tag}-{label_hash}.npz",
            lambda rows=rows, split=split: compute_labels(cache, rows, pattern, iml, recnn, recnn, s.epsilon_db, s.steps,
                                                         s.batch_size, device, s.progress, desc=f"labels {split}",
                                                         reference=s.reference, bracket=bracket,
                                                         unreachable=s.unreachable, source=s.label_source, ims=ims),
            split)
        timing[f"labels_{split}_s"] = round(time.perf_counter() - t0, 2)
        timing[f"labels_{split}_reused"] = reused
    train_l = labels["train"]
    val_l = labels.get("val")

    # -- 2. predictor --------------------------------------------------------------------------------
    p = s.predictor
    predictor, hist = train_predictor(train_l.views, train_l.u, val=(val_l.views, val_l.u) if val_l is not None else None,
                                      hidden=p["hidden"], layers=p["layers"], epochs=p["epochs"], lr=p["lr"],
                                      weight_decay=p["weight_decay"], seed=p["seed"], margin=p["margin"])
    predictor.save(out / "mean_predictor.pt")
    timing["train_predictor_s"] = round(hist["seconds"], 2)

    # -- fixed-mean ORP on the validation views (the ORP's own evaluation at an inference-time u) ----
    t0 = time.perf_counter()
    from .data import ViewImageDataset

    orp_rows = cache.splits["val"] if len(cache.splits["val"]) else cache.splits["train"]
    orp_ds = ViewImageDataset(cache.path, orp_rows, pattern, fields=("view", "fr", "c"))

    def orp_quality(u: float) -> dict[str, float]:
        it = copy.deepcopy(iml)
        it.mean = _clamp_mean(u)
        return evaluate_quality(orp_ds, s.batch_size, SimpleNamespace(iml=it.to(device), pattern=pattern), recnn.to(device),
                         recnn.to(device), None, device)

    ref_q = orp_quality(u_train)["psnr_iml_recnn"] if s.reference == "iml" else None

    def orp_gap(u: float) -> float:
        q = orp_quality(u)
        return (q["psnr_recnn"] if ref_q is None else ref_q) - q["psnr_iml_recnn"]

    orp_res = ORPSearch(epsilon_db=s.epsilon_db, bracket=bracket, tolerance=0.05, k=1, max_rounds=12, scale="log").run(batched(orp_gap))
    u_orp = float(orp_res.mean) if orp_res.found else MEAN_RANGE[1]
    timing["orp_search_s"] = round(time.perf_counter() - t0, 2)

    # -- 3. evaluation on the trajectory -------------------------------------------------------------
    t_eval = time.perf_counter()
    ev = labels[s.views]
    rows = ev.rows
    renderer = make_renderer(scene, to_plain(cfg.renderer))
    ims.to(device).eval()
    views_t = torch.as_tensor(np.asarray(ev.views, np.float32)).to(device)
    with torch.inference_mode():
        g_all = ims.generator(views_t).float()
        u_pred = predictor.to(device)(views_t).double().cpu().numpy()

    def imls_ipr(u: float | np.ndarray) -> float:
        with torch.inference_mode():
            im = scaled_pim_im(ims, g_all, torch.as_tensor(u, dtype=torch.float32).expand(len(rows)), u_train)
        return float(im.flatten(1).sum(1).double().mean()) / m**2

    adaptive_ipr_est = imls_ipr(u_pred)
    u_match = mean_for_ipr(imls_ipr, adaptive_ipr_est)
    const = {"fixed": u_train, "orp": u_orp, "matched": u_match}
    methods: dict[str, Any] = {"recnn": RecNNAlone(renderer, pattern, recnn, opts),
                               "imls_fixed": IMLSRenderer.from_task(ims, renderer, recnn, opts)}
    for k in ("orp", "matched"):
        methods[f"imls_{k}"] = AdaptiveIMLSRenderer(renderer, ims, ConstantMean(_clamp_mean(const[k])), recnn, opts)
    methods["imls_adaptive"] = AdaptiveIMLSRenderer(renderer, ims, predictor, recnn, opts)
    oracle = _TableMean(ev.views, ev.u)
    methods["imls_oracle"] = AdaptiveIMLSRenderer(renderer, ims, oracle, recnn, opts)
    methods["iml_fixed"] = IMLPlusRecNN(renderer, pattern, iml, recnn, opts)
    methods["iml_orp"] = IMLPlusRecNN(renderer, pattern, iml, recnn, opts, mean=_clamp_mean(u_orp))
    methods["iml_adaptive"] = AdaptiveIMLPlusRecNN(renderer, pattern, iml, recnn, predictor, opts)
    methods["iml_oracle"] = AdaptiveIMLPlusRecNN(renderer, pattern, iml, recnn, oracle, opts)

    timed = {"recnn", "imls_fixed", "imls_adaptive"}
    timing_pos = set(spaced(len(rows), s.timing_views).tolist()) if s.timing_views else set()
    per_view: list[dict[str, Any]] = []
    lat: dict[str, list[dict[str, float]]] = {k: [] for k in timed}
    from tqdm import tqdm

    for i in tqdm(range(len(rows)), desc=f"evaluate {s.views}", unit="view", file=sys.stderr, disable=not s.progress,
                  dynamic_ncols=True):
        r = int(rows[i])
        view, truth = np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r])
        rec: dict[str, Any] = {"view": i, "row": r, "complexity": float(ev.complexity[i]), "u_label": float(ev.u[i]),
                               "label_met": bool(ev.met[i]), "u_pred": float(u_pred[i]), "u_fixed": u_train,
                               "u_orp": u_orp, "u_matched": u_match}
        for name, method in methods.items():
            reps = s.repeats if (name in timed and i in timing_pos) else 1
            fields_, _, _ = measure(method, view, truth, reps, 1 if reps > 1 else 0)
            rec[f"psnr_{name}"] = fields_["psnr"]
            rec[f"ipr_{name}"] = fields_["ipr"]
            if reps > 1:
                lat[name].append({k[:-3]: v for k, v in fields_.items() if k.endswith("_ms")})
        per_view.append(rec)
    timing["evaluate_s"] = round(time.perf_counter() - t_eval, 2)

    # -- 4. trade-off curve: fixed means vs the predictor at several margins, on the label source's path --
    trade = None
    if s.tradeoff_means:
        t0 = time.perf_counter()
        with torch.inference_mode():
            u_raw = predictor.log_mean(views_t).exp().double().cpu().numpy()
        fixed_us = np.exp(np.linspace(math.log(0.05), 0.0, s.tradeoff_means)) if s.tradeoff_means > 1 else np.array([u_train])
        means: dict[str, Any] = {f"fixed:{u:.6g}": float(u) for u in fixed_us}
        means.update({f"adaptive x{mg:g}": u_raw * mg for mg in s.tradeoff_margins})
        means["oracle (labels)"] = ev.u
        if s.reference == "iml":  # the reference is the path itself at the trained mean: measured in the same pass
            means["reference"] = u_train
        q = quality_at_means(cache, rows, pattern, iml, recnn, means, source=s.label_source, ims=ims,
                             batch_size=s.batch_size, device=device, progress=s.progress)
        ref_psnr = q.pop("reference" if s.reference == "iml" else "recnn")["psnr"]
        q.pop("recnn", None)
        curve, compared = tradeoff(ref_psnr, {float(k[6:]): v for k, v in q.items() if k.startswith("fixed:")},
                                   {k: v for k, v in q.items() if not k.startswith("fixed:")}, s.epsilon_db)
        trade = {"curve": curve, "points": compared, "seconds": round(time.perf_counter() - t0, 2)}
        _write_csv(out / "tradeoff.csv", [{"setting": f"fixed u={r['u']:.5g}", **r} for r in curve] +
                   [{"setting": p.name, "u": None, "ipr": p.ipr, "psnr": p.psnr, "within": p.within, "fixed_psnr": p.fixed_psnr,
                     "fixed_ipr": p.fixed_ipr, "fixed_within": p.fixed_within} for p in compared])
        _plot_tradeoff(out / "tradeoff.png", curve, compared, s.epsilon_db, rep, s.label_source)
        timing["tradeoff_s"] = trade["seconds"]
    timing["total_s"] = round(time.perf_counter() - t_start, 2)

    # -- report ----------------------------------------------------------------------------------------
    eps = s.epsilon_db
    names = list(methods)
    summ: dict[str, dict[str, Any]] = {}
    base = np.array([r["psnr_recnn"] for r in per_view])
    for name in names:
        ps = np.array([r[f"psnr_{name}"] for r in per_view])
        ip = np.array([r[f"ipr_{name}"] for r in per_view])
        gap = base - ps
        ref = np.array([r[f"psnr_{_ref_method(name, s.reference)}"] for r in per_view])
        gap_ref = ref - ps
        summ[name] = {"ipr": float(ip.mean()), "psnr": float(ps.mean()), "gap": float(gap.mean()),
                      "gap_ref": float(gap_ref.mean()), "max_gap_ref": float(gap_ref.max()),
                      "max_gap": float(gap.max()), "within": float((gap_ref <= eps + 1e-9).mean()),
                      "ipr_min": float(ip.min()), "ipr_max": float(ip.max())}
        if lat.get(name):
            summ[name]["latency_ms"] = {k: float(np.mean([d.get(k, 0.0) for d in lat[name]])) for k in lat[name][0]}
    csv_rows = per_view
    _write_csv(out / "adaptive.csv", csv_rows)
    _plot(out / "adaptive.png", per_view, eps, rep, s.reference)
    md = _markdown(s, cfg, ims, cache, summ, per_view, hist, timing, labels, u_train, u_orp, orp_res, u_match,
                   adaptive_ipr_est, out, command or _command(), trade)
    trade_json = None if trade is None else {"curve": trade["curve"], "points": [
        {**p.__dict__, "d_psnr": p.d_psnr, "d_ipr": p.d_ipr} for p in trade["points"]]}
    rep.atomic_write_text(out / "adaptive.json", json.dumps({"summary": summ, "tradeoff": trade_json, "timing": timing, "predictor": hist,
                                                             "u_train": u_train, "u_orp": u_orp, "u_matched": u_match,
                                                             "epsilon_db": eps}, indent=2, default=str))
    rep.atomic_write_text(out / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(
        {k: to_plain(cfg[k]) for k in ("scene", "data", "renderer") if k in cfg} | {"settings": s.hashed(), "ims_checkpoint": s.ims,
                                                                                    "recnn_checkpoint": s.recnn})))
    return rep.atomic_write_text(out / "adaptive.md", md)


def _ref_method(name: str, reference: str) -> str:
    """The method whose per-view PSNR ``name`` must stay within epsilon of."""
    if reference == "recnn" or name == "recnn":
        return "recnn"
    return "iml_fixed" if name.startswith("iml_") else "imls_fixed"


class _TableMean(nn.Module):
    """Looks a view's mean value up in a table (the per-view labels: the oracle predictor)."""

    def __init__(self, views: np.ndarray, u: np.ndarray):
        super().__init__()
        self.views = np.asarray(views, np.float32)
        self.u = np.asarray(u, np.float64)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        v = view.detach().float().cpu().numpy()
        idx = [int(np.argmin(np.abs(self.views - x[None]).sum(1))) for x in v]
        return torch.tensor([_clamp_mean(self.u[i]) for i in idx], dtype=torch.float32, device=view.device)


LABELS = {
    "recnn": "RecNN alone",
    "imls_fixed": "IML/S, fixed u (trained)",
    "imls_orp": "IML/S, fixed u (ORP)",
    "imls_matched": "IML/S, fixed u (IPR-matched)",
    "imls_adaptive": "IML/S, adaptive u",
    "imls_oracle": "IML/S, oracle u (labels)",
    "iml_fixed": "IML + RecNN, fixed u (trained)",
    "iml_orp": "IML + RecNN, fixed u (ORP)",
    "iml_adaptive": "IML + RecNN, adaptive u",
    "iml_oracle": "IML + RecNN, oracle u (labels)",
}


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    import csv
    import io

    buf = io.StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r)) or ["view"]  # union, in first-seen order
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    from .report import atomic_write_text

    atomic_write_text(path, buf.getvalue())


def _plot(path: Path, per_view: list[dict[str, Any]], eps: float, rep, reference: str = "recnn") -> None:
    fig = rep.new_figure(13.0, 4.0)
    cx = np.array([r["complexity"] for r in per_view])
    ax1, ax2, ax3 = fig.add_subplot(131), fig.add_subplot(132), fig.add_subplot(133)
    ax1.scatter(cx, [r["u_label"] for r in per_view], s=12, label="label u (oracle)", alpha=0.7)
    ax1.scatter(cx, [r["u_pred"] for r in per_view], s=12, marker="x", label="predicted u")
    ax1.axhline(per_view[0]["u_fixed"], color="gray", ls="--", lw=1, label="trained u")
    ax1.axhline(per_view[0]["u_orp"], color="k", ls=":", lw=1, label="ORP u")
    ax1.set_yscale("log")
    ax1.set_xlabel("view complexity (non-background share)")
    ax1.set_ylabel("mean value u")
    ax1.legend(fontsize=7)
    for name, mk in (("imls_fixed", "o"), ("imls_matched", "s"), ("imls_adaptive", "x")):
        ax2.scatter(cx, [r[f"ipr_{name}"] for r in per_view], s=12, marker=mk, label=LABELS[name], alpha=0.8)
    ax2.set_xlabel("view complexity (non-background share)")
    ax2.set_ylabel("IPR (rendered / FR pixels)")
    ax2.legend(fontsize=7)
    x = np.arange(len(per_view))
    for name in ("imls_fixed", "imls_matched", "imls_adaptive"):
        ax3.plot(x, [r[f"psnr_{_ref_method(name, reference)}"] - r[f"psnr_{name}"] for r in per_view], lw=1, label=LABELS[name])
    ax3.axhline(eps, color="k", ls=":", lw=1, label=f"epsilon {eps:g} dB")
    ax3.set_xlabel("view along the trajectory")
    ax3.set_ylabel("PSNR gap to the reference (dB)" if reference != "recnn" else "PSNR gap to RecNN alone (dB)")
    ax3.legend(fontsize=7)
    rep.save_figure(fig, path)


def _plot_tradeoff(path: Path, curve: list[dict[str, float]], points: list[TradeoffPoint], eps: float, rep, source: str) -> None:
    fig = rep.new_figure(10.0, 4.0)
    ax1, ax2 = fig.add_subplot(121), fig.add_subplot(122)
    path_name = "IML/S + RecNN" if source == "ims" else "IML + RecNN"
    for ax, key, label in ((ax1, "psnr", "average PSNR (dB)"), (ax2, "within", f"views within {eps:g} dB of the reference")):
        ax.plot([r["ipr"] for r in curve], [r[key] for r in curve], "o-", ms=3, color="gray", label="fixed u (sweep)")
        ad = [p for p in points if p.name.startswith("adaptive")]
        ax.plot([p.ipr for p in ad], [getattr(p, key) for p in ad], "x-", ms=6, color="C1", label="adaptive u (margins)")
        for p in ad:
            ax.annotate(p.name.split(" ", 1)[1], (p.ipr, getattr(p, key)), fontsize=7, xytext=(3, -9), textcoords="offset points")
        for p in points:
            if p.name.startswith("oracle"):
                ax.plot([p.ipr], [getattr(p, key)], "*", ms=10, color="C2", label="oracle u (labels)")
        ax.set_xlabel("average IPR (rendered / FR pixels)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{path_name}: per-view mean vs one fixed mean", fontsize=9)
    rep.save_figure(fig, path)


def _markdown(s: Settings, cfg, ims, cache, summ, per_view, hist, timing, labels, u_train, u_orp, orp_res, u_match,
              adaptive_ipr_est, out: Path, command: str, trade: dict[str, Any] | None = None) -> str:
    eps = s.epsilon_db
    n = len(per_view)
    L: list[str] = []
    bracket = (MEAN_RANGE[0], MEAN_RANGE[1] if s.reference == "recnn" else u_train)
    L.append(f"# Adaptive mean value vs fixed mean (scene {cfg.scene.get('name')}, {n} {s.views} views, epsilon {eps:g} dB)\n")
    L.append(f"Command: `{command}`\n")
    L.append(f"- IMS checkpoint: `{s.ims}` (target=pim; IML trained at u = {u_train:g}); RecNN: "
             f"`{s.recnn or 'the one in the IMS checkpoint'}`; cache `{cache.path}`; device {pick_device(s.device)}.")
    ref_text = "RecNN alone" if s.reference == "recnn" else f"IML + RecNN at the trained u = {u_train:g}"
    path_name = "IML/S + RecNN" if s.label_source == "ims" else "IML + RecNN"
    orp_ref_text = ref_text  # the ORP search always runs on the IML + RecNN path
    if s.reference != "recnn":
        ref_text = f"{path_name} at the trained u = {u_train:g}"
    L.append(f"- Labels: per view, smallest u in [{bracket[0]:g}, {bracket[1]:g}] with PSNR({path_name} at u) >= PSNR({ref_text}) - {eps:g} dB "
             f"(reference={s.reference}, label_source={s.label_source}), {s.steps} bisection steps in log u (+2 end checks); views that fail even at "
             f"u = {bracket[1]:g}: " + ("the smallest u within epsilon of their gap there (unreachable=best)." if s.unreachable == "best"
                                      else f"u = {bracket[1]:g} (unreachable=hi)."))
    for split, lab in labels.items():
        L.append(f"  - {split}: {len(lab)} views, u median {np.median(lab.u):.4f} (min {lab.u.min():.4f}, max {lab.u.max():.4f}), "
                 f"{int((~lab.met).sum())} views fail even at u = {bracket[1]:g}; "
                 f"{'reused' if timing.get(f'labels_{split}_reused') else 'computed'} in {timing.get(f'labels_{split}_s', 0):.1f} s"
                 f" (compute time recorded: {lab.meta.get('seconds', 0):.1f} s).")
    L.append(f"- Predictor: MLP {hist['views']} train views, {hist['epochs']} full-batch epochs in {hist['seconds']:.1f} s "
             f"(kept epoch {hist.get('best_epoch', hist['epochs'])}: lowest validation L1); "
             f"L1(log u) train {hist['train_l1']:.3f} / val {_fmt(hist['val_l1'])} vs constant (median) "
             f"{hist['constant_l1']:.3f} / {_fmt(hist['val_constant_l1'])}; margin x{s.predictor['margin']:g}.")
    ul = np.array([r["u_label"] for r in per_view])
    up = np.array([r["u_pred"] for r in per_view])
    cx = np.array([r["complexity"] for r in per_view])
    corr = float(np.corrcoef(np.log(ul), np.log(up))[0, 1]) if n > 2 and ul.std() > 0 and up.std() > 0 else float("nan")
    ccx = float(np.corrcoef(cx, np.log(ul))[0, 1]) if n > 2 and ul.std() > 0 and cx.std() > 0 else float("nan")
    L.append(f"- On the {s.views} views: corr(log label u, log predicted u) = {_fmt(corr, '.3f')}; "
             f"corr(complexity, log label u) = {_fmt(ccx, '.3f')}; L1(log u) = {float(np.abs(np.log(ul) - np.log(up)).mean()):.3f}.")
    L.append(f"- Fixed means compared: trained u = {u_train:g}; ORP u = {u_orp:.5g} (ORP search on the validation views against the "
             f"{orp_ref_text}, inference-time u, {orp_res.jobs} evaluations, {'found' if orp_res.found else 'NOT found: u = 1 used'}); "
             f"IPR-matched u = {u_match:.5g} (IML/S average IPR {adaptive_ipr_est:.4f} of the adaptive one).")
    L.append(f"- Time: labels {sum(v for k, v in timing.items() if k.startswith('labels_') and k.endswith('_s')):.1f} s, "
             f"predictor {timing['train_predictor_s']:.1f} s, ORP search {timing['orp_search_s']:.1f} s, "
             f"evaluation {timing['evaluate_s']:.1f} s, total {timing['total_s']:.1f} s.\n")

    L.append("## Summary\n")
    if s.reference != "recnn":
        L.append(f"Reference of each method (gap to reference, within epsilon): its own family at the trained mean "
                 f"(IML/S rows: IML/S fixed u = {u_train:g}; IML + RecNN rows: IML + RecNN fixed u = {u_train:g}).\n")
    L.append("| method | avg IPR | IPR min–max | avg PSNR (dB) | avg gap to RecNN (dB) | avg gap to reference (dB) | max gap to reference | views within epsilon of reference | latency (ms) |")
    L.append("|---|---|---|---|---|---|---|---|---|")
    for name, v in summ.items():
        lat = v.get("latency_ms", {}).get("total")
        L.append(f"| {LABELS.get(name, name)} | {v['ipr']:.4f} | {v['ipr_min']:.4f}–{v['ipr_max']:.4f} | {v['psnr']:.2f} | "
                 f"{v['gap']:.3f} | {v['gap_ref']:.3f} | {v['max_gap_ref']:.3f} | {100 * v['within']:.0f} % | {_fmt(lat, '.1f')} |")
    a, f_m, f_o, f_t = summ["imls_adaptive"], summ["imls_matched"], summ["imls_orp"], summ["imls_fixed"]
    L.append("")
    L.append("## Adaptive vs fixed (IML/S, the product)\n")
    L.append(f"- At the same average IPR ({f_m['ipr']:.4f} fixed vs {a['ipr']:.4f} adaptive): average PSNR "
             f"{f_m['psnr']:.2f} vs {a['psnr']:.2f} dB, i.e. the fixed mean is {f_m['psnr'] - a['psnr']:+.3f} dB vs adaptive; "
             f"views within epsilon {100 * f_m['within']:.0f} % vs {100 * a['within']:.0f} %.")
    L.append(f"- Against the fixed-mean ORP (u = {u_orp:.4g}): average IPR {f_o['ipr']:.4f} vs {a['ipr']:.4f} adaptive "
             f"({100 * (a['ipr'] / f_o['ipr'] - 1) if f_o['ipr'] > 0 else float('nan'):+.1f} %), PSNR gap to the reference "
             f"{f_o['gap_ref']:.3f} vs {a['gap_ref']:.3f} dB, within epsilon {100 * f_o['within']:.0f} % vs {100 * a['within']:.0f} %.")
    L.append(f"- Against the trained mean (u = {u_train:g}): average IPR {f_t['ipr']:.4f} vs {a['ipr']:.4f}, PSNR "
             f"{f_t['psnr']:.2f} vs {a['psnr']:.2f} dB.")
    i_a, i_o = summ["iml_adaptive"], summ["iml_orp"]
    L.append(f"- Upper bound (IML + RecNN, importance from the rendered C-Image): ORP IPR {i_o['ipr']:.4f} / gap {i_o['gap_ref']:.3f} dB / "
             f"within {100 * i_o['within']:.0f} %; adaptive IPR {i_a['ipr']:.4f} / gap {i_a['gap_ref']:.3f} dB / within "
             f"{100 * i_a['within']:.0f} %; oracle (labels) IPR {summ['iml_oracle']['ipr']:.4f} / within {100 * summ['iml_oracle']['within']:.0f} %.")
    if trade is not None:
        L.extend(_tradeoff_markdown(trade, s, path_name, len(per_view)))
    lat_a, lat_f = a.get("latency_ms"), f_t.get("latency_ms")
    if lat_a and lat_f:
        stages = [k for k in ("mean", "importance", "selective_render", "decoder", "recnn", "total") if k in lat_a or k in lat_f]
        L.append("")
        L.append(f"## Latency (ms, median of {s.repeats} runs per view, mean over {min(s.timing_views, n)} views)\n")
        L.append("| method | " + " | ".join(stages) + " |")
        L.append("|---|" + "---|" * len(stages))
        for name in ("recnn", "imls_fixed", "imls_adaptive"):
            la = summ[name].get("latency_ms", {})
            L.append(f"| {LABELS[name]} | " + " | ".join(_fmt(la.get(k), ".2f") for k in stages) + " |")
        if s.repeats < 10:
            L.append(f"\n(repeats={s.repeats} < 10: indicative timings only.)")
    L.append("")
    L.append("## Notes\n")
    L.append("- The adaptive IML/S scales the IMS's PIM' (normalized to the trained mean) by u_v / u_train before "
             "thresholding against P: exact for pixels below saturation; pixels the IMS saturated (g = 1, PIM' >= 1) are "
             "kept for u_v >= u_train and compared at their lower bound below it.")
    L.append("- Labels assume the gap falls as u grows; the paper notes that means far above the trained one need not "
             "improve quality, so a view can fail at u = 1 although it passed at a smaller u (bisection then returns one "
             "crossing). PSNRs here are on the uint8 images of the real selective renderer; labels use the float images.")
    L.append("- Files: `adaptive.csv` (per view), `adaptive.png` (u and IPR vs complexity, gap per view), "
             "`tradeoff.csv` / `tradeoff.png` (the curve), `mean_predictor.pt`, `adaptive.json`.\n")
    L.append("![adaptive](adaptive.png)\n")
    return "\n".join(L) + "\n"


def _tradeoff_markdown(trade: dict[str, Any], s: Settings, path_name: str, n: int) -> list[str]:
    eps = s.epsilon_db
    curve, points = trade["curve"], trade["points"]
    ref = "the RecNN alone" if s.reference == "recnn" else f"{path_name} at the trained mean"
    L = ["", f"## Trade-off: adaptive vs the whole fixed-mean curve ({path_name})\n",
         f"One fixed mean is one point; a fair comparison is against the curve of all of them. {len(curve)} fixed means "
         f"(log-spaced in [0.05, 1]) and the predictor at margins {', '.join(f'x{m:g}' for m in s.tradeoff_margins)} "
         f"on the {n} {s.views} views, float pipeline (cached images, no uint8 rounding), computed in {trade['seconds']:.1f} s. "
         f"'fixed at same IPR': the curve's average PSNR / within-epsilon share at the setting's average IPR; "
         f"'fixed IPR for same PSNR': the fewest pixels with which some fixed mean reaches the setting's average PSNR. "
         f"Within epsilon: PSNR at most {eps:g} dB below {ref}.\n",
         "| setting | avg IPR | avg PSNR (dB) | within epsilon | fixed at same IPR: PSNR / within | ΔPSNR (dB) | fixed IPR for same PSNR | Δ pixels |",
         "|---|---|---|---|---|---|---|---|"]
    for p in points:
        fixed = "–" if p.fixed_psnr is None else f"{p.fixed_psnr:.2f} / {100 * p.fixed_within:.0f} %"
        L.append(f"| {p.name} | {p.ipr:.4f} | {p.psnr:.2f} | {100 * p.within:.0f} % | {fixed} | {_fmt(p.d_psnr, '+.2f')} | "
                 f"{_fmt(p.fixed_ipr, '.4f')} | {'–' if p.d_ipr is None else f'{100 * p.d_ipr:+.1f} %'} |")
    ad = [p for p in points if p.name.startswith("adaptive") and p.d_psnr is not None]
    if ad:
        best = max(ad, key=lambda p: p.d_psnr)
        L.append("")
        L.append(f"- Adaptive beats the fixed-mean curve at {sum(p.d_psnr > 0 for p in ad)} of {len(ad)} margins inside its range; "
                 f"largest gain {best.d_psnr:+.2f} dB at IPR {best.ipr:.4f} ({best.name}); "
                 + ", ".join(f"{p.name}: {'–' if p.d_ipr is None else f'{100 * p.d_ipr:+.1f} %'} pixels for the same PSNR" for p in ad) + ".")
    top = max(curve, key=lambda r: r["psnr"])
    L.append(f"- The fixed-mean curve tops out at {top['psnr']:.2f} dB (u = {top['u']:.3g}, IPR {top['ipr']:.4f}); a setting "
             f"above it has '–' as fixed IPR. See `tradeoff.png`, `tradeoff.csv`.\n")
    L.append("![trade-off](tradeoff.png)")
    return L


def _command() -> str:
    from .report import hydra_command

    return hydra_command("imls_lightning.adaptive", "run_adaptive(cfg) through the Python API")

@checked_command_line(Path(__file__).resolve().parents[1] / "conf")
@hydra.main(version_base="1.3", config_path="../conf", config_name="adaptive")
@cli_errors
def main(cfg: DictConfig) -> None:
    """``python -m imls_lightning.adaptive ...``: prints the report's path last."""
    path = run_adaptive(cfg)
    print(path, flush=True)


if __name__ == "__main__":
    main()
