"""Per-view mean-value labels: for each view, the smallest ``u`` whose IML (or IML/S) + RecNN stays
within ``epsilon_db`` of the reference, by bisection in ``log u`` (:func:`bisect_mean`,
:func:`compute_labels`, saved as :class:`MeanLabels`); and the IML's importance at per-image means
(:func:`iml_pim`, :func:`im_at_means`), which the labels and the adaptive renderers share.
"""
from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from imls_lightning.base.errors import InputError, finite_number

from ..core.importance import MEAN_RANGE, normalize_importance
from ..core.metrics import psnr_per_image
from ..core.smallest_within import bisect_monotone, within
from ..inference.pipeline import pick_device
from .checks import check_epsilon, check_integer, clamp_mean

REFERENCES = ("recnn", "iml")
SOURCES = ("ims", "iml")  # whose importance the labels bisect: the IMS (IML/S, the product) or the IML (upper bound)
UNREACHABLE = ("hi", "best")  # the label of a view that no mean in the bracket brings within epsilon


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
    every view at once (:func:`~imls_lightning.core.smallest_within.bisect_monotone`: ``hi`` always meets epsilon,
    ``lo`` never does), and ``hi`` is the answer:
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
    steps = check_integer(steps, "steps", 1, 60)
    batch = check_integer(batch, "batch", 1)
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
    met = within(g_hi, eps) | within(g_lo, eps)
    # per-view threshold: epsilon, or (unreachable="best", finite gap at hi) epsilon above the gap at hi
    thr = torch.full_like(g_hi, eps)
    if unreachable == "best":
        thr = torch.where((g_hi > eps) & torch.isfinite(g_hi), g_hi + eps, thr)
    ok_hi, ok_lo = within(g_hi, thr), within(g_lo, thr)
    b = bisect_monotone(gap, thr, lo, hi, steps, rising=False, value_hi=g_hi)
    u = torch.where(ok_lo, torch.full_like(hi, lo0), torch.where(ok_hi, b.hi, torch.full_like(hi, hi0)))
    g = torch.where(ok_lo, g_lo, b.value_hi)
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
    padding): each image is normalized by :func:`~imls_lightning.core.importance.normalize_importance`
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
    pim_norm = torch.cat([normalize_importance(pim[b:b + 1], clamp_mean(u), norm.lower, norm.delta, valid)
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
        from imls_lightning.base.atomic import atomic_write

        return atomic_write(path, lambda f: np.savez(
            f, rows=self.rows, views=self.views, u=self.u, met=self.met, gap_db=self.gap_db, psnr_ref=self.psnr_ref,
            complexity=self.complexity, meta=np.asarray(json.dumps(self.meta))), unique=True)

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


def check_source(source: str, ims) -> None:
    """``source`` is ``"ims"`` (then ``ims`` must be an IMS with ``target="pim"``: its mask head or its
    task) or ``"iml"``."""
    if source not in SOURCES:
        raise InputError(f"label_source={source!r}: expected one of {list(SOURCES)}")
    if source == "ims" and (ims is None or getattr(ims, "target", None) != "pim"):
        raise InputError("label_source=ims: needs the IMS task (an IMS trained with model.target=pim)")


def mask_function(source: str, iml: nn.Module, ims, c: torch.Tensor, view: torch.Tensor,
                  lift: bool = False) -> Callable[[Any], torch.Tensor]:
    """``u (B,) -> IM (B, 1, n, n)`` in ``c``'s dtype for one batch: the IML's mask at ``u`` from the
    rendered C-Image ``c`` (``source="iml"``) or the IMS's PIM' for ``view`` scaled to ``u``
    (``source="ims"``, the IML/S path: ``ims``'s :class:`~imls_lightning.models.ims.IMSMaskHead`, or an
    IMS task's ``mask_head``; lifted to the share ``u`` with ``lift``). The network runs once here, not
    per ``u``."""
    if source == "iml":
        pim = iml_pim(iml, c)
        return lambda u: im_at_means(iml, pim, u).to(c.dtype)
    head = getattr(ims, "mask_head", ims)
    g = head.generator(view.float()).float()
    return lambda u: head.threshold(g, torch.as_tensor(u, dtype=torch.float32).reshape(-1).expand(c.shape[0]),
                                    lift).to(c.dtype)


def compute_labels(cache, rows: np.ndarray, pattern, iml: nn.Module, recnn_iml: nn.Module, recnn_alone: nn.Module,
                   epsilon_db: float = 1.0, steps: int = 8, batch_size: int = 16, device: str | torch.device = "cpu",
                   progress: bool = True, desc: str = "labels", reference: str = "recnn",
                   bracket: Sequence[float] = MEAN_RANGE, unreachable: str = "hi", source: str = "iml",
                   ims=None, lift: bool = False) -> MeanLabels:
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
            scaled to ``u`` (its mask head's thresholding, lifted with ``lift``); needs ``ims``, an IMS
            with ``target="pim"``). With ``"ims"`` and ``reference="iml"`` the reference is IML/S at the
            trained mean.
    """
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from ..data.datamodule import ViewImageDataset

    eps = check_epsilon(epsilon_db)
    steps = check_integer(steps, "steps", 1, 60)
    bs = check_integer(batch_size, "batch_size", 1)
    if reference not in REFERENCES:
        raise InputError(f"reference={reference!r}: expected one of {list(REFERENCES)}")
    check_source(source, ims)
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
            mask_at = mask_function(source, iml, ims, c, batch["view"].to(dev), lift)
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

