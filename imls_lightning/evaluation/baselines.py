"""The baselines an evaluation measures beside IML/S + RecNN: the RecNN alone on a sparser pattern
(:func:`sparser_method`), blue noise + decoder (:func:`blue_noise_method`), the untrained masks at equal
share (:func:`equal_share`) and the IMS's mask brought to a share of C (:func:`ims_mask_at_share`)."""
from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..core.operating_point import OperatingPoint
from ..inference.baselines import equal_share_rows, mask_at_share, summarize_equal_share
from ..inference.pipeline import IMLSRenderer, NetOptions, RecNNAlone
from .measurement import view_loader
from ..render.camera import view_tensor
from .networks import Networks
from .settings import Settings


def equal_share(s: Settings, cache, rows_all, positions, nets: Networks, pattern, device,
                point: OperatingPoint | None = None) -> list[dict[str, Any]]:
    """The untrained baselines at equal share on the evaluated views (cache pixels = what the selective ray cast returns);
    the IMS's masks made as at ``point`` (its lift, sharpness and object floor; ``None``: the paper's)."""
    point = point if point is not None else OperatingPoint()
    ims = nets.ims_task.to(device)
    out = []
    with torch.inference_mode():
        for b in view_loader(cache, rows_all[positions], pattern):
            out.append(equal_share_rows(b["c"].to(device), b["fr"].to(device), b["view"].to(device), nets.recnn.to(device).eval(),
                                        iml=nets.iml.to(device).eval(), ims_task=ims, blue=None if nets.blue is None else nets.blue.to(device).eval(),
                                        shares=s.shares, pattern=pattern, ims_lift=point.lift, ims_head=ims.mask_head.for_point(point)))
    return summarize_equal_share(out)


def sparser_method(renderer, task, opts: NetOptions | None = None) -> RecNNAlone:
    """The RecNN alone on its own sparser pattern (a ``RecNNTask`` from :func:`load_sparser_recnn`): the
    whole sparser pattern ray-cast, then its RecNN."""
    method = RecNNAlone(renderer, task.pattern, task.net, opts)
    method.name = "recnn_sparser"
    return method


def blue_noise_method(renderer, pattern, blue_iml, recnn, share: float, opts: NetOptions | None = None) -> IMLSRenderer:
    """The blue-noise baseline on the product path: the plastic mask ``u > P`` at ``share`` of the
    pattern's pixels (the same for every view; no network picks it), exactly those pixels ray-cast,
    the decoder trained for blue-noise masks, the RecNN."""
    n = pattern.c_size
    valid = pattern.valid.bool()
    P = blue_iml.sampling.P.detach().cpu()
    mask = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P.view(1, 1, n, n), max(share, 1.0 / pattern.count), valid, 1)
    mask = mask.bool()

    def predict_im(view: torch.Tensor) -> torch.Tensor:
        return mask.to(view.device)

    method = IMLSRenderer(renderer, pattern, predict_im, blue_iml.decoder, recnn, opts)
    method.name = "blue_noise"
    return method


def ims_mask_at_share(head, view: np.ndarray, share: float, lift: bool = False) -> torch.Tensor:
    """The IMS's mask of ``view`` brought to ``share`` of the pattern's pixels: ``(n, n)`` bool.

    Bisection on the mean value (:func:`~imls_lightning.inference.baselines.mask_at_share`, the
    equal-share protocol) of the IMS output rescaled to each mean (lifted with ``lift``, as the evaluation's);
    ``share = 1`` is the whole pattern. ``head``: the IMS's :class:`~imls_lightning.models.ims.IMSMaskHead` (at the
    operating point's sharpness and floor, :meth:`~imls_lightning.models.ims.IMSMaskHead.for_point`). Needs an IMS
    trained with ``model.target=pim``.
    """
    valid = head.valid.bool().view(head.valid.shape[-2:])
    if share >= 1.0:
        return valid.clone().cpu()
    device = valid.device
    with torch.inference_mode():
        g = head.generator(view_tensor(view, device)).float()
        im = mask_at_share(lambda u: head.threshold(g, u.to(device), lift), share, valid, 1)
    return im[0, 0].bool().cpu()
