"""The classical two-pass sampler: the simplest alternative to the IMS, with no network but the RecNN.

What a visualization engineer would do instead of learning a mask: ray-cast a blue-noise ``base`` share of
the RecNN's pattern, find where those pixels do not predict each other
(:func:`~imls_lightning.core.unpredictability.base_unpredictability`), ray-cast the most unpredictable
further pixels up to the ``share``, fill the rest by pull-push and run the RecNN. Its stages:

=====================  =====================================================================
``low_res_render``     the base pixels (one selective ray cast)
``importance``         the base's unpredictability and the mask at the share
``selective_render``   the further pixels (a second selective ray cast)
``decoder``            the pull-push fill of the C-Image (no weights)
``recnn``              the RecNN
=====================  =====================================================================

Example:
    >>> m = TwoPassFill(renderer, pattern, recnn, share=0.6, base=0.2)   # doctest: +SKIP
    >>> image, timings = m.render(view)                                  # doctest: +SKIP
"""
from __future__ import annotations

import torch

from imls_lightning.base.errors import InputError

from ..core.unpredictability import base_unpredictability, first_pass, two_pass_mask
from ..core.pull_push import fill_c_image, in_layout_of
from ..models.ims import DistanceMeans
from .pipeline import NetOptions, RenderResult, PatternMethod, prepare_net, to_uint8_image


class TwoPassFill(PatternMethod):
    """Two selective ray casts (a blue-noise base, then the base's most unpredictable neighbours), a pull-push
    fill, the RecNN. ``share``: of the pattern's pixels in all (the base included); ``base``: the first pass's
    share, below ``share``; ``floor``: the importance every pixel keeps, relative to the mean; ``by_distance``: a
    :class:`~imls_lightning.models.ims.DistanceMeans` of shares, each view then at its band of camera distance's
    share instead of ``share`` (the evaluation's ``orp_by_distance`` point), each above ``base``."""

    name = "two_pass"

    def __init__(self, renderer, pattern, recnn: torch.nn.Module, share: float, base: float = 0.2,
                 floor: float = 0.25, seed: int = 0, opts: NetOptions | None = None,
                 by_distance: DistanceMeans | None = None):
        super().__init__(renderer, pattern, opts)
        if not 0.0 < float(base) < float(share) <= 1.0:
            raise InputError(f"base={base}, share={share}: expected 0 < base < share <= 1 (the first pass is part "
                             "of the share)")
        self.by_distance = by_distance
        self.recnn = prepare_net(recnn, self.device, self.opts)
        self.share, self.base, self.floor, self.seed = float(share), float(base), float(floor), int(seed)
        if not all(self.base < x <= 1.0 for x in self.shares):
            raise InputError(f"by_distance: shares {self.shares}: expected each in (base={base}, 1] (the first pass is "
                             "part of the share)")
        # the base is the same for every view: its blue-noise pixels are fixed once
        self._first = first_pass(pattern, self.base, self.seed)

    def mask(self, c_first: torch.Tensor, share: float | None = None) -> torch.Tensor:
        """``(n, n)`` bool: the pixels to ray-cast in all at ``share`` (None: ``self.share``), from the first pass's
        C-Image ``(1, 3, n, n)`` (0 elsewhere)."""
        score, first = base_unpredictability(c_first, self.pattern, self.base, seed=self.seed)
        return two_pass_mask(score, first, self.share if share is None else share, self.pattern, self.floor)[0, 0]

    @property
    def shares(self) -> list[float]:
        """The shares of C it runs at: ``[share]``, or its bands' near to far (``by_distance``)."""
        return [self.share] if self.by_distance is None else self.by_distance.values()

    def share_for(self, view) -> float:
        """The share of C a validated view ``(9,)`` runs at: its band's with ``by_distance``, else ``share``."""
        if self.by_distance is None:
            return self.share
        return self.by_distance.value_for(view)

    def steps(self, view):
        first = self._first
        yield "low_res_render"
        c1, n1 = self._render_c_pixels(view, first)
        yield "importance"
        keep = self.mask(c1.float(), self.share_for(view))
        second = keep & ~first.to(keep.device)
        yield "selective_render"
        c2, n2 = self._render_c_pixels(view, second)
        yield "decoder"
        m = keep[None, None].to(c1.dtype)
        c = in_layout_of(fill_c_image(c1 + c2, m, self.pattern), c1)  # the RecNN runs up to 1.7x faster channels-last
        yield "recnn"
        with self.opts.autocast(self.device):
            fr = self.recnn(self._tensor(c))
        yield None
        count = n1 + n2
        return RenderResult(to_uint8_image(fr), {},
                            {"ipr": count / self.fr_size**2, "c_share": count / self.pattern.count,
                             "rendered_pixels": count, "im": keep.cpu()})


__all__ = ["TwoPassFill"]
