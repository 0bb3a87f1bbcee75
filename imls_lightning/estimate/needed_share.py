"""The share of C a scene needs, before training: the quality half of the estimate.

The speed-up bound (:mod:`.bound`) says what IML/S gains at each share of the C-Image; which share the
product will need (its ORP) was known only after training. This measures it on the estimate's own views
with nothing learned but the quick RecNN (``recnn_lead``):

1. **An untrained importance from the C-Image**, each C-pixel's unpredictability from its neighbours, made
   into the product's kind of mask at each share, with a floor that keeps every region sampled
   (:mod:`imls_lightning.core.unpredictability`).
2. **The untrained fill and the RecNN.** The masked C-Image is filled by pull-push and passed through the
   RecNN; its PSNR against the full frame is compared with the RecNN on the whole C-Image. The needed
   share is the smallest share whose mean gap stays within ``epsilon_db`` (the ORP criterion).
3. **The render of exactly those pixels,** timed: an importance mask keeps the costly rays (edges and
   thin structure march through translucent material), so the bound's uniform cost per object pixel
   can be optimistic. Each view's times are fractions of its own whole pattern timed in the same pass, as
   the bound's render curve takes them (:func:`~.measure.on_own_patterns`).

It is an estimate, not a bound: the oracle sees the C-Image (as the IML does, not the IMS), and the fill
is untrained (the learned decoder beats it by several dB at low shares). BENCHMARKS.md compares it with
the ORPs the trained pairs reached.

Example:
    >>> first_share_within([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0)   # the gap reaches 1 dB half-way to 0.6
    0.5
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_number

from ..core.compaction import compact
from ..core.metrics import psnr_per_image
from ..core.patterns import SamplingPattern
from ..core.unpredictability import base_unpredictability, importance_mask, two_pass_mask, unpredictability
from ..core.pull_push import fill_c_image
from ..core.smallest_within import interpolated_within, smallest_within
from .measure import PassTimer, frame_tensor, median_ms, on_own_patterns

#: the shares of C at which the needed share is searched (a finer grid than the bound's)
NEEDED_SHARES = tuple(round(0.05 * i, 2) for i in range(1, 21))


@dataclass
class NeededShare:
    """The gap and the render of the untrained importance mask at each share, and the share it needs."""
    epsilon_db: float
    reference: str                 # what rebuilds the full frame: "recnn" (the quick RecNN) or the upsampler's name
    shares: list[float]            # the target shares
    kept: list[float]              # the shares the masks kept (mean over the views)
    gap_db: list[float]            # mean PSNR gap to the reference on the whole C-Image
    render_ms: list[float | None]  # render of exactly the masks' pixels (mean over views, on each view's pattern);
                                   # None at the shares not timed (:func:`timed_shares`)
    needed_share: float | None     # the smallest share within epsilon_db (interpolated); None: none is
    seconds: float

    def render_at(self, share: float) -> float:
        """The measured render at any share (linear between the timed ones)."""
        timed = [(k, r) for k, r in zip(self.kept, self.render_ms) if r is not None]
        return float(np.interp(share, [k for k, _ in timed], [r for _, r in timed]))

    def to_dict(self) -> dict[str, Any]:
        return {"epsilon_db": self.epsilon_db, "reference": self.reference, "needed_share": self.needed_share,
                "rows": [{"share": s, "kept": k, "gap_db": g, "render_ms": r}
                         for s, k, g, r in zip(self.shares, self.kept, self.gap_db, self.render_ms)],
                "seconds": self.seconds}


def first_share_within(kept: Sequence[float], gaps: Sequence[float], epsilon_db: float) -> float | None:
    """The smallest share whose gap is within ``epsilon_db``, linear between the first share within and the
    one before it; None when no share is (:func:`~imls_lightning.core.smallest_within.interpolated_within`).

    Example:
        >>> first_share_within([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0)
        0.5
    """
    return interpolated_within(kept, gaps, epsilon_db)


def share_gaps(rebuild: Callable[[torch.Tensor], torch.Tensor], pattern: SamplingPattern, frames: Sequence,
               shares: Sequence[float] = NEEDED_SHARES, floor: float = 0.25, seed: int = 0,
               on_mask: Callable[[int, int, np.ndarray], None] | None = None,
               base: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per frame and share, the share the untrained mask kept and its PSNR gap to ``rebuild`` on the whole C-Image:
    two ``(frames, shares)`` arrays. ``on_mask(frame, share index, FR pixels)`` sees each mask's pixels (the render
    timing of :func:`needed_share`). ``base``: the importance a two-pass sampler knows after rendering that
    blue-noise share (:func:`base_unpredictability`), the base always kept; None: from the whole C-Image."""
    idx = pattern.indices
    k = idx.shape[0]
    gaps = np.zeros((len(frames), len(shares)))
    kept = np.zeros_like(gaps)
    with torch.inference_mode():
        for v, fr in enumerate(frames):
            target = frame_tensor(fr)
            c = compact(target, idx, pattern.c_size)
            ref = float(psnr_per_image(rebuild(c).clamp(0, 1), target)[0])
            if base is None:
                score, first = unpredictability(c, pattern, seed=seed), None
            else:
                score, first = base_unpredictability(c, pattern, base, seed=seed)
            for j, s in enumerate(shares):
                mask = importance_mask(score, s, pattern, floor) if first is None else \
                    two_pass_mask(score, first, s, pattern, floor)
                m = mask.float()
                out = rebuild(fill_c_image(c * m, m, pattern)).clamp(0, 1)
                gaps[v, j] = ref - float(psnr_per_image(out, target)[0])
                pix = idx[mask.flatten()[:k]].numpy()
                kept[v, j] = pix.shape[0] / k
                if on_mask is not None:
                    on_mask(v, j, pix)
    return kept, gaps


def needed_share(rebuild: Callable[[torch.Tensor], torch.Tensor], reference: str, pattern: SamplingPattern,
                 renderer, views: Sequence, frames: Sequence[np.ndarray], epsilon_db: float = 1.0,
                 shares: Sequence[float] = NEEDED_SHARES, floor: float = 0.25, repeats: int = 3, warmup: int = 1,
                 seed: int = 0, progress: Callable[[str], None] | None = None,
                 c_render_ms: Sequence[float] | None = None, time_all: bool = False) -> NeededShare:
    """Measure the untrained importance mask's gap at each share on ``views`` / ``frames``, and the render of
    exactly its pixels at the shares around the needed one (:func:`timed_shares`; at every share with ``time_all``).

    Args:
        rebuild: C-Image ``(1, 3, n, n)`` -> FR ``(1, 3, m, m)`` in [0, 1]: the quick RecNN, or the
            classical upsampling when there is none.
        reference: its name, for the record.
        renderer: the scene's renderer (``render_pixels``).
        views, frames: the estimate's views and their FR frames ``(m, m, 3)`` uint8.
        epsilon_db: the ORP's tolerance (1 dB in the paper).
        floor: the importance every pixel keeps, relative to the mean (:func:`masks_at_share`).
        progress: called with a line after each view's masks are measured (long on paper-size volumes).
        c_render_ms: each view's whole-pattern render as the estimate measured it (the bound's RecNN alone):
            each view's mask times are put on it as fractions of the whole pattern timed in this pass (the
            mask of share 1 when it is timed, else one more render). None: on this pass's own.
        time_all: ray-cast the masks of every share, not just the two around the needed share.
    """
    eps = check_number(epsilon_db, "epsilon_db", 0.0, lo_open=True, what="a positive PSNR tolerance in dB")
    if len(views) != len(frames) or len(views) == 0:
        raise InputError("needed_share: expected one FR frame per view, and at least one view")
    if c_render_ms is not None and len(c_render_ms) != len(views):
        raise InputError(f"needed_share: expected one c_render_ms per view ({len(views)}), got {len(c_render_ms)}")
    t0 = time.perf_counter()
    masks: dict[tuple[int, int], np.ndarray] = {}

    def keep(v: int, j: int, pix: np.ndarray) -> None:
        masks[v, j] = pix

    # the gaps need no ray cast (each mask's pixels are the FR frame's); the renders come after, where they count
    kept, gaps = share_gaps(rebuild, pattern, frames, shares, floor, seed, on_mask=keep)
    gap, share_kept = gaps.mean(0).tolist(), kept.mean(0).tolist()
    need = first_share_within(share_kept, gap, eps)
    timed = list(range(len(shares))) if time_all else timed_shares(share_kept, gap, eps)
    ms = np.zeros((len(views), len(shares)))
    all_pix = pattern.indices.numpy()
    own = np.zeros(len(views))
    for v in range(len(views)):
        cast = PassTimer(renderer, views[v], pattern.fr_size, repeats, warmup, timing=median_ms)
        for j in timed:
            ms[v, j] = cast(masks[v, j])
        own[v] = cast(all_pix)   # the whole pattern of this view's own pass: share 1's mask when it kept every pixel
        if progress is not None:
            progress(f"needed share: view {v + 1}/{len(views)}, {len(shares)} masks, {len(timed)} of them ray-cast "
                     f"({time.perf_counter() - t0:.0f} s)")
    render = on_own_patterns(ms, own, own if c_render_ms is None else c_render_ms).tolist()
    return NeededShare(eps, reference, [float(s) for s in shares], share_kept, gap,
                       [float(r) if j in timed else None for j, r in enumerate(render)], need, time.perf_counter() - t0)


def timed_shares(kept: Sequence[float], gaps: Sequence[float], epsilon_db: float) -> list[int]:
    """The indices of the shares whose masks :func:`needed_share` ray-casts: the two around the needed share
    (:func:`first_share_within` interpolates between them; the first alone when it is already within), none when
    no share is. The speed-up at the needed share reads only these, and the 20 masks a view timed in full cost 10
    whole patterns (seed_whole: 145 of an estimate's 533 s).

    Example:
        >>> timed_shares([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0), timed_shares([0.2, 0.4], [0.5, 0.1], 1.0)
        ([1, 2], [0])
        >>> timed_shares([0.2, 0.4], [3.0, 2.0], 1.0)
        []
    """
    i = smallest_within(gaps, epsilon_db).index
    return [] if i is None else [i] if i == 0 else [i - 1, i]


__all__ = ["NEEDED_SHARES", "NeededShare", "first_share_within", "share_gaps", "needed_share", "timed_shares"]
