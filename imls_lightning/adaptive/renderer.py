"""The adaptive renderers: IML/S + RecNN (:class:`AdaptiveIMLSRenderer`, the product path) and
IML + RecNN (:class:`AdaptiveIMLPlusRecNN`, the upper bound) at the mean value a predictor gives
each view.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..inference.checkpoints import load_ims_and_recnn, require_pim_target, require_recnn, task_path
from ..inference.pipeline import (
    IMLPlusRecNN,
    IMLSRenderer,
    NetOptions,
    StageTimer,
    pick_device,
    prepare_net,
    renderer_for_task,
)
from ..tasks.ims import scaled_pim_im
from .labels import im_at_means, iml_pim
from .predictor import MeanPredictor


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
        require_pim_target(task.hparams, path=task_path(task), what="the adaptive renderer, which scales the regressed PIM',")
        opts = opts or NetOptions()
        recnn = require_recnn(task.recnn if recnn is None else recnn, key="ims_checkpoint", path=task_path(task))
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
