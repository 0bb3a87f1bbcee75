"""The adaptive renderers: IML/S + RecNN (:class:`AdaptiveIMLSRenderer`, the product path) and
IML + RecNN (:class:`AdaptiveIMLPlusRecNN`, the upper bound) at the mean value a predictor gives
each view.
"""
from __future__ import annotations

import torch
from torch import nn

from ..inference.checkpoints import load_ims_nets, renderer_for, require_pim_target, require_recnn
from ..inference.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions
from ..render.camera import view_tensor
from ..models.ims import IMSMaskHead
from .labels import im_at_means, iml_pim
from .predictor import MeanPredictor


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
        pattern: the sampling pattern.
        head: the IMS's :class:`~imls_lightning.models.ims.IMSMaskHead`, ``target="pim"`` (its generator
            moved to the options' device and prepared, as :class:`IMLSRenderer` does).
        decoder, recnn: the IML decoder and the RecNN.
        predictor: ``view (1, 9) -> u (1,)``, e.g. :class:`MeanPredictor` or :class:`ConstantMean`.
        opts: :class:`NetOptions`.
        lift: lift the masks to the share ``u_v`` (the evaluation's ``ims_lift``).

    Raises:
        InputError: the IMS was trained with ``target="im"`` (a binary mask cannot be rescaled), or
            no RecNN.

    Example:
        >>> r = AdaptiveIMLSRenderer.from_checkpoints("ims.ckpt", "mean_predictor.pt")   # doctest: +SKIP
        >>> image, t = r.render(view); sorted(t)                                          # doctest: +SKIP
        ['decoder', 'importance', 'mean', 'recnn', 'selective_render', 'total']
    """

    name = "imls_adaptive"

    def __init__(self, renderer, pattern, head: IMSMaskHead, decoder: nn.Module, recnn: nn.Module | None,
                 predictor: nn.Module, opts: NetOptions | None = None, *, lift: bool = False):
        require_pim_target({"target": head.target}, what="the adaptive renderer, which scales the regressed PIM',")
        recnn = require_recnn(recnn, key="ims_checkpoint")
        # the head's own sharpness and floor, the predictor's share per view, lifted with ``lift``
        super().__init__(renderer, pattern, head, decoder, recnn, opts, point=head.point(lift=lift))
        self.u_train = float(head.trained_mean)
        self.predictor = predictor.to(self.device).eval()

    @classmethod
    def from_checkpoints(cls, ims_checkpoint: str, predictor: str | nn.Module, *, scene=None, renderer=None,
                         renderer_cfg=None, recnn_checkpoint: str | None = None, opts: NetOptions | None = None,
                         margin: float | None = None) -> "AdaptiveIMLSRenderer":
        """Build from an IMS checkpoint and a predictor (module or a :meth:`MeanPredictor.save` file).

        Scene and renderer default to those stored in the IMS checkpoint (as
        :meth:`IMLSRenderer.from_checkpoints`); ``margin`` overrides the predictor file's margin.
        """
        nets = load_ims_nets(ims_checkpoint, recnn_checkpoint)
        if not isinstance(predictor, nn.Module):
            predictor = MeanPredictor.load(predictor, margin=margin)
        elif margin is not None:
            predictor.margin = margin
        recnn = require_recnn(nets.recnn, key="ims_checkpoint", path=ims_checkpoint)
        return cls(renderer_for(nets.hparams, scene, renderer, renderer_cfg), nets.pattern, nets.head, nets.decoder, recnn,
                   predictor, opts)

    def predict_im(self, view: torch.Tensor, u: torch.Tensor | float | None = None) -> torch.Tensor:
        """IM ``(B, 1, n, n)`` of views ``(B, 9)`` at mean ``u`` (``None``: the predictor's)."""
        if u is None:
            u = _mean_of(self.predictor, view)
        with self.opts.autocast(self.device):
            return self.mask_head(view, u, self.lift)

    def mean_for(self, view) -> float:
        """The predictor's ``u_v`` for one view (no rendering)."""
        with torch.inference_mode():
            return float(_mean_of(self.predictor, view_tensor(view, self.device))[0])

    def _importance(self, view, info: dict):
        v = view_tensor(view, self.device)
        yield "mean"
        u = _mean_of(self.predictor, v)
        yield None
        info["mean"] = float(u[0])
        yield "importance"
        return self.predict_im(v, u)[0, 0].bool()


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

    def _importance(self, c: torch.Tensor, view, info: dict):
        yield "mean"
        u = _mean_of(self.predictor, view_tensor(view, self.device))
        yield None
        info["mean"] = float(u[0])
        yield "importance"
        with self.opts.autocast(self.device):
            return im_at_means(self.iml, iml_pim(getattr(self.iml, "_orig_mod", self.iml), c), u)
