"""Inference: the IML/S + RecNN renderer users call, and the baselines it is measured against.

Every method renders a view into an ``(m, m, 3)`` uint8 image in named stages (:meth:`Method.steps`, a generator
that names each stage as it starts it) and times nothing itself; :mod:`imls_lightning.evaluation.timing` times any
method by those stages (CUDA-synchronized when the networks run on a GPU):

=====================  =====================================================================
method                 stages
=====================  =====================================================================
``full``               ``render`` (ray cast of the whole FR-Image: the renderer of record)
``recnn``              ``selective_render`` (the whole sampling pattern), ``recnn``
``iml``                ``selective_render`` (whole pattern), ``importance`` (IML encoder),
                       ``decoder``, ``recnn`` - importance from the rendered C-Image: an upper bound
``imls``               ``importance`` (IMS mask head, view only), ``selective_render`` (only the
                       important pixels), ``decoder``, ``recnn`` - the product
``las``                ``low_res_render``, ``importance``, ``selective_render`` (at FR), ``recnn``
``two_pass``           ``low_res_render`` (a blue-noise base of the pattern), ``importance`` (the base's
                       unpredictability), ``selective_render``, ``decoder`` (pull-push fill), ``recnn`` -
                       the classical alternative, nothing learned but the RecNN (:mod:`.two_pass`)
=====================  =====================================================================

Selective rendering is real: only the chosen pixels are ray-cast by the scene's renderer
(``renderer.render_pixels``), so its cost falls with their number. A render stage ends when its
pixels are on the networks' device (the host-to-device copy is part of delivering the pixels).

``info`` of a run: ``ipr`` (important / FR pixels), ``c_share`` (important / pattern pixels; IML
methods), ``rendered_pixels`` (rays cast at FR in the render stages), and ``im`` (the ``(n, n)``
bool IM on the CPU; IML methods).

Options (:class:`~imls_lightning.inference.options.NetOptions`, with the device, in :mod:`.options`) apply to every
network's ``forward``: ``torch.compile`` wraps the
modules called directly (IMS generator, IML decoder, RecNN, LAS nets); the IML encoder path of
``iml`` (``IMLNet.importance``) and LAS's importance/reconstruction methods run uncompiled.

The product is a composition of plain modules, in the manner of pytorch3d's ``ImplicitRenderer(raysampler,
raymarcher)``: :class:`IMLSRenderer` ``(ray caster, sampling pattern, mask head, decoder, RecNN, point)``, the mask
head an :class:`~imls_lightning.models.ims.IMSMaskHead` run at the one frozen
:class:`~imls_lightning.core.operating_point.OperatingPoint` given at construction. What a method returns depends on
its construction and its call's arguments only: the point, an oracle mask (:meth:`IMLSRenderer.run`'s ``im``) and
LAS's IPR (:meth:`LASMethod.run`'s ``ipr``). Reading the networks from checkpoints is
:mod:`~imls_lightning.inference.checkpoints`' (:func:`~imls_lightning.inference.checkpoints.load_product`).

Example:
    >>> r = IMLSRenderer.from_checkpoints("ims.ckpt", scene=scene, renderer_cfg={"name": "numba"})  # doctest: +SKIP
    >>> image = r.render([0, 0, 3.5, 0, 0, 0, 0, 1, 0])                                                # doctest: +SKIP
    >>> from imls_lightning.evaluation.timing import timed                                               # doctest: +SKIP
    >>> image, timings = timed(r).render([0, 0, 3.5, 0, 0, 0, 0, 1, 0])  # seconds per stage            # doctest: +SKIP
    >>> timings                                                                                          # doctest: +SKIP
    {'importance': 0.004, 'selective_render': 0.021, 'decoder': 0.006, 'recnn': 0.011, 'total': 0.042}
"""
from __future__ import annotations

import abc
import copy
from dataclasses import dataclass, field
from typing import Any, Generator

import numpy as np
import torch

from imls_lightning.render.camera import validate_view, view_tensor
from imls_lightning.base.errors import InputError

from .checkpoints import IMSNets, load_product, renderer_for, require_recnn
from .options import NetOptions, compile_available, half_is_faster, pick_device, prepare_net  # noqa: F401 (re-exported)
from ..core.importance import check_ipr
from ..core.operating_point import OperatingPoint
from ..core.patterns import SamplingPattern, c_pixels_to_fr
from ..models.iml import decoder_at
from ..models.ims import DistanceMeans, IMSMaskHead

STAGES = ("low_res_render", "render", "importance", "selective_render", "decoder", "recnn")


def run_steps(steps: Generator[str | None, None, "RenderResult"]) -> "RenderResult":
    """Run a method's forward pass (:meth:`Method.steps`) to its end, timing nothing: its :class:`RenderResult`
    (``timings`` empty). :func:`imls_lightning.evaluation.timing.timed_run` runs the same steps timing each stage."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


def to_uint8_image(x: torch.Tensor) -> np.ndarray:
    """``(1, 3, m, m)`` float in [0, 1] -> ``(m, m, 3)`` uint8 (NaN -> 0)."""
    t = torch.nan_to_num(x[0].float(), nan=0.0).clamp(0, 1).mul(255.0).round().to(torch.uint8)
    return t.permute(1, 2, 0).contiguous().cpu().numpy()


@dataclass
class RenderResult:
    image: np.ndarray
    timings: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)


class Method(abc.ABC):
    """Base class of an inference method: a forward pass (:meth:`steps`) in named stages, run by :meth:`run` or
    :meth:`render`, timing nothing (:func:`imls_lightning.evaluation.timing.timed` times any method by its stages)."""

    name = "method"

    def __init__(self, renderer, fr_size: int, opts: NetOptions | None = None):
        self.renderer = renderer
        self.fr_size = int(fr_size)
        self.opts = opts or NetOptions()
        self.device = pick_device(self.opts.device)

    def with_ray_caster(self, renderer) -> "Method":
        """The same method (its prepared networks shared) on another ray caster."""
        twin = copy.copy(self)
        twin.renderer = renderer
        return twin

    def _tensor(self, x: torch.Tensor) -> torch.Tensor:
        x = x.to(self.device, non_blocking=True)
        return x.contiguous(memory_format=torch.channels_last) if self.opts.channels_last else x

    @abc.abstractmethod
    def steps(self, view, **kwargs) -> Generator[str | None, None, RenderResult]:
        """The forward pass of a validated view as a generator: it yields the name of each stage (one of
        :data:`STAGES`, or ``"mean"``) just before running it, ``None`` before a step no stage counts, and returns the
        :class:`RenderResult` (``kwargs``: the method's per-call arguments). It reads no clock: a stage ends where the
        next begins, and a timer that runs the steps (:func:`imls_lightning.evaluation.timing.timed_run`) times them."""

    def run(self, view, **kwargs) -> RenderResult:
        """Render a validated view (``kwargs``: the method's per-call arguments); ``timings`` is empty."""
        return run_steps(self.steps(view, **kwargs))

    @torch.inference_mode()
    def render(self, view) -> np.ndarray:
        """Render one view: the ``(m, m, 3)`` uint8 image."""
        return self.run(validate_view(view)).image


class FullRayCast(Method):
    """Baseline 1: ray-cast every pixel of the FR-Image."""

    name = "full"

    def steps(self, view):
        yield "render"
        img = self.renderer.render(view, self.fr_size)
        return RenderResult(img, {}, {"ipr": 1.0, "rendered_pixels": self.fr_size**2})


class PatternMethod(Method):
    """A method on a RecNN's sampling pattern: ray-casts chosen C-Image pixels (:meth:`_render_c_pixels`), the
    base of every pattern method here and of :class:`~imls_lightning.inference.two_pass.TwoPassFill`."""

    def __init__(self, renderer, pattern: SamplingPattern, opts: NetOptions | None = None):
        super().__init__(renderer, pattern.fr_size, opts)
        self.pattern = pattern
        self._fr_idx = pattern.indices.numpy()

    def _render_c_pixels(self, view, c_mask: torch.Tensor | None) -> tuple[torch.Tensor, int]:
        """Ray-cast the C-Image pixels in ``c_mask`` ((n, n) bool; None = the whole pattern).

        Returns the PR-C-Image ``(1, 3, n, n)`` float on the device (0 where not rendered) and the
        number of pixels ray-cast.
        """
        n, k = self.pattern.c_size, self.pattern.count
        if c_mask is None:
            c_pos = np.arange(k)
            fr = self._fr_idx
        else:
            c_pos = np.flatnonzero(c_mask.reshape(-1)[:k].cpu().numpy())
            fr = self._fr_idx[c_pos]
        colours = self.renderer.render_pixels(view, self.fr_size, fr)  # (K, 3) uint8
        flat = np.zeros((n * n, 3), np.float32)
        flat[c_pos] = colours.astype(np.float32) / 255.0
        # (1, n, n, 3) -> (1, 3, n, n) is channels-last memory, which PyTorch recognizes only when the
        # batch dimension is permuted too; the networks run up to 2.2x faster on it on the CPU, and
        # every method's first network must get the same layout (the decoder's output already has it)
        c = torch.from_numpy(flat).view(1, n, n, 3).permute(0, 3, 1, 2)
        return self._tensor(c), int(len(fr))


class RecNNAlone(PatternMethod):
    """Baseline 2: render the RecNN's whole sampling pattern, reconstruct with the RecNN."""

    name = "recnn"

    def __init__(self, renderer, pattern, recnn: torch.nn.Module, opts: NetOptions | None = None):
        super().__init__(renderer, pattern, opts)
        self.recnn = prepare_net(recnn, self.device, self.opts)

    def steps(self, view):
        yield "selective_render"
        c, count = self._render_c_pixels(view, None)
        yield "recnn"
        with self.opts.autocast(self.device):
            fr = self.recnn(c)
        yield None
        return RenderResult(to_uint8_image(fr), {}, {"ipr": count / self.fr_size**2, "c_share": 1.0, "rendered_pixels": count})


class IMLPlusRecNN(PatternMethod):
    """Baseline 4: IML + RecNN, the importance taken from the rendered C-Image (an upper bound).

    Renders the whole pattern (the IML needs the C-Image), so it is never faster than the RecNN
    alone: it bounds the quality an IMS that reproduced the IML's mask exactly would reach.

    Args:
        iml: the :class:`~imls_lightning.models.iml.IMLNet` (encoder + decoder).
        recnn: the RecNN ``(1, 3, n, n) -> (1, 3, m, m)``.
        mean: normalization mean ``u`` at inference (the paper's normalization of the IML's importance); ``None``
            keeps the trained one. It is an argument of every normalization this method runs: the IML, shared with
            other methods, is never changed.
    """

    name = "iml"

    def __init__(self, renderer, pattern, iml: torch.nn.Module, recnn: torch.nn.Module, opts: NetOptions | None = None,
                 mean: float | None = None):
        super().__init__(renderer, pattern, opts)
        # the mean value of every normalization this method runs (None: the IML's own), validated by the IML's layer
        self._u = None if mean is None or float(mean) == float(iml.mean) else iml.normalization.checked(mean)
        self.mean = float(iml.mean) if self._u is None else self._u
        self.iml = prepare_net(iml, self.device, self.opts)
        self.recnn = prepare_net(recnn, self.device, self.opts)

    def _importance(self, c: torch.Tensor, view, info: dict) -> Generator[str | None, None, torch.Tensor]:
        """The steps to the hard IM of the rendered C-Image ``(1, 1, n, n)``; subclasses change how it is chosen."""
        yield "importance"
        with self.opts.autocast(self.device):
            return self.iml.importance(c, hard=True, mean=self._u)

    def steps(self, view):
        yield "selective_render"
        c, _ = self._render_c_pixels(view, None)
        info: dict = {}
        im = yield from self._importance(c, view, info)
        yield "decoder"
        with self.opts.autocast(self.device):
            m = im.to(c.dtype)
            c_rec = self.iml.decode(m * c, m)
        yield "recnn"
        with self.opts.autocast(self.device):
            fr = self.recnn(c_rec)
        yield None
        im_cpu = im[0, 0].bool().cpu()
        count = int(im_cpu.sum())
        return RenderResult(to_uint8_image(fr), {},
                            {"ipr": count / self.fr_size**2, "c_share": count / self.pattern.count,
                             "rendered_pixels": self.pattern.count, "im": im_cpu, **info})


def prepare_mask_head(head: IMSMaskHead, device: torch.device, opts: NetOptions) -> IMSMaskHead:
    """``head`` on ``device`` in eval mode, its generator prepared as ``opts`` asks (:func:`prepare_net`;
    the thresholding is never compiled). The generator module is moved in place, the head is a new one."""
    return head.with_generator(prepare_net(head.generator, device, opts)).to(device).eval()


class IMLSRenderer(PatternMethod):
    """The product: IML/S + RecNN. View -> mask head -> IM -> ray-cast only those pixels -> decoder -> RecNN.

    Built from its parts and one operating point, in the manner of pytorch3d's ``ImplicitRenderer(raysampler,
    raymarcher)``; its forward pass (:meth:`steps`) times nothing (:func:`imls_lightning.evaluation.timing.timed`
    times it from outside).

    Args:
        renderer: the ray caster, the scene's renderer (``render_pixels`` is used).
        pattern: the RecNN's sampling pattern.
        mask: the mask head: an :class:`~imls_lightning.models.ims.IMSMaskHead` (run at ``point``; its generator
            prepared as ``opts`` asks), or any module or callable view ``(1, 9)`` float32 on the device ->
            ``(1, 1, n, n)`` bool IM with its point bound (an exported ``im`` network, a fixed mask); padding already
            zero.
        decoder: the IML decoder ``(pr_c_image (1, 3, n, n), im (1, 1, n, n)) -> (1, 3, n, n)``.
        recnn: the RecNN ``(1, 3, n, n) -> (1, 3, m, m)``.
        opts: :class:`NetOptions`.
        point: the :class:`~imls_lightning.core.operating_point.OperatingPoint` the masks are made at (share, lift,
            bands of camera distance, sharpness, object floor; another share than the trained one needs
            ``target="pim"``), and its decoder (``"fill"``: the pull-push fill in place of ``decoder``).
            ``None``: an :class:`IMSMaskHead` at its trained share, as it is; for a bound mask, what it is bound to
            when said (an export's), else unknown.
        record: the evaluation's record the point came from
            (:class:`~imls_lightning.inference.operating_point.ORPRecord`, or an export's dict), or ``None``.

    Attributes:
        point (frozen), record, mask (``view -> IM``), mask_head (the prepared head, or None); mean (the
        share as the paper's mean value ``u`` the masks are made at: the trained one for ``share=None``; ``None``
        when a bound mask does not say; with bands the single recorded value, for display), lift, by_distance
        (the bands as a :class:`~imls_lightning.models.ims.DistanceMeans`, or None). ``info["mean"]`` of a run is
        the view's band's with bands.

    Example:
        >>> r = IMLSRenderer.from_checkpoints("ims.ckpt", scene=scene, renderer_cfg={"name": "numba"})  # doctest: +SKIP
        >>> image = r.render(view)                    # (m, m, 3) uint8                                  # doctest: +SKIP
        >>> r = IMLSRenderer(ray_caster, pattern, nets.head, nets.decoder, nets.recnn,
        ...                  point=OperatingPoint(share=0.4))                                              # doctest: +SKIP
    """

    name = "imls"

    def __init__(self, renderer, pattern, mask, decoder: torch.nn.Module, recnn: torch.nn.Module,
                 opts: NetOptions | None = None, *, point: OperatingPoint | None = None, record: Any = None):
        super().__init__(renderer, pattern, opts)
        if point is not None and not isinstance(point, OperatingPoint):
            raise InputError(f"point={point!r}: expected an OperatingPoint (imls_lightning.core.operating_point)")
        self.mask_head = None
        if isinstance(mask, IMSMaskHead):
            self.mask_head = prepare_mask_head(mask, self.device, self.opts)
            point = point if point is not None else self.mask_head.point()
            mask = self.mask_head.at(point)  # InputError for a share of a target=im head
        self.mask = mask
        self.point, self.record = point, record
        share = None if point is None else point.share
        self.mean = share if share is not None or self.mask_head is None else self.mask_head.trained_mean
        self.lift = point is not None and point.lift
        self.by_distance = getattr(mask, "by_distance", None) if self.mask_head is not None else None
        self.decoder = prepare_net(self._point_decoder(decoder, pattern, point), self.device, self.opts)
        self.recnn = prepare_net(recnn, self.device, self.opts)

    @staticmethod
    def _point_decoder(decoder: torch.nn.Module, pattern, point: OperatingPoint | None) -> torch.nn.Module:
        """The decoder the point runs: ``decoder`` (the IMS's own), or the untrained fill of the same pixels where the
        search kept it (:func:`~imls_lightning.models.iml.decoder_at`)."""
        return decoder_at("trained" if point is None else point.decoder, decoder, pattern)

    @classmethod
    def from_nets(cls, nets: IMSNets, renderer, opts: NetOptions | None = None, *, point: OperatingPoint | None = None,
                  record: Any = None) -> "IMLSRenderer":
        """The renderer of the product's networks (:class:`~imls_lightning.inference.checkpoints.IMSNets`:
        mask head, decoder, RecNN) and a ray caster, at ``point`` (``None``: the trained share)."""
        recnn = require_recnn(nets.recnn, key="ims_checkpoint", path=nets.path)
        return cls(renderer, nets.pattern, nets.head, nets.decoder, recnn, opts, point=point, record=record)

    @classmethod
    def from_checkpoints(cls, ims_checkpoint: str, *, scene=None, renderer=None, renderer_cfg=None,
                         recnn_checkpoint: str | None = None, opts: NetOptions | None = None,
                         share: float | str | None = None, mean: float | str | None = None) -> "IMLSRenderer":
        """Build the renderer from an IMS checkpoint (it carries the IML decoder and the RecNN):
        :func:`~imls_lightning.inference.checkpoints.load_product` composed with a ray caster.

        By default it runs at the operating point the evaluation recorded for this checkpoint
        (``<ims.ckpt>.orp.json``, checked against the checkpoint's bytes: the report's ORP, its
        masks lifted, sharpened and floored as the evaluation made them), else at the trained share; one line on
        stderr says which (:mod:`imls_lightning.inference.operating_point`). :attr:`point` is the point it runs at,
        :attr:`record` the record used (``None``: none).

        Args:
            ims_checkpoint: a ``.ckpt`` of ``model=ims``.
            scene / renderer / renderer_cfg: a built renderer, or a scene (+ renderer config) to make one;
                by default the scene and renderer the IMS was trained on (stored in its checkpoint).
            recnn_checkpoint: use this RecNN instead of the one stored in the IMS checkpoint.
            opts: :class:`NetOptions` (device, half, channels_last, compile).
            share: ``None``: the recorded operating point, else the trained share; a number in
                ``[0.01, 1]``: that share of the C-Image (the paper's rescale to that mean value; needs
                ``model.target=pim``); ``"trained"``: the trained share. Neither reads the record.
                ``mean``: the same (its older name).
        """
        product = load_product(ims_checkpoint, recnn_checkpoint, share=share if share is not None else mean,
                               share_key="share" if share is not None or mean is None else "mean")
        ray_caster = renderer_for(product.nets.hparams, scene, renderer, renderer_cfg)
        return cls.from_nets(product.nets, ray_caster, opts, point=product.point, record=product.record)

    def predict_im(self, view: torch.Tensor) -> torch.Tensor:
        """The IM ``(B, 1, n, n)`` bool of views ``(B, 9)`` (float32, on the device): the mask, the
        generator under the options' autocast, the thresholding in float32."""
        with self.opts.autocast(self.device):
            return self.mask(view)

    def _importance(self, view, info: dict) -> Generator[str | None, None, torch.Tensor]:
        """The steps to the IM ``(n, n)`` bool of one view; subclasses change how it is chosen."""
        v = view_tensor(view, self.device)
        yield "importance"
        im = self.predict_im(v)[0, 0].bool()
        if self.by_distance is not None:  # the view's band's mean value, for the caller (outside the importance stage)
            yield None
            info["mean"] = float(self.mask.by_distance(v)[0])
        return im

    def steps(self, view, im: torch.Tensor | None = None):
        """The forward pass of a validated view. ``im``: an ``(n, n)`` bool IM to render instead of the mask's (the
        mask still runs, in the importance stage: "the IML's IM, selectively rendered" of the evaluation)."""
        info: dict = {}
        mask = yield from self._importance(view, info)
        if im is not None:
            yield "importance"
            mask = torch.as_tensor(im).to(self.device).bool().reshape(mask.shape)
        yield "selective_render"
        pr_c, count = self._render_c_pixels(view, mask)
        yield "decoder"
        with self.opts.autocast(self.device):
            c_rec = self.decoder(pr_c, mask.to(pr_c.dtype).view(1, 1, *mask.shape[-2:]))
        yield "recnn"
        with self.opts.autocast(self.device):
            fr = self.recnn(c_rec)
        yield None
        return RenderResult(to_uint8_image(fr), {},
                            {"ipr": count / self.fr_size**2, "c_share": count / self.pattern.count,
                             "rendered_pixels": count, "im": mask.cpu(), **info})


def las_mean_for_ipr(las: torch.nn.Module, raw: torch.Tensor, ipr: float, steps: int = 30) -> torch.Tensor:
    """Per-image mean ``u`` ``(B, 1, 1, 1)`` at which LAS samples about ``ipr`` of the FR pixels:
    :meth:`LASNet.mean_for_ipr <imls_lightning.models.las.LASNet.mean_for_ipr>` (the bisection of
    ``LASNet.importance_mask(ipr=...)``); :func:`las_mask` with the result gives that method's mask.

    Args:
        las: a :class:`~imls_lightning.models.las.LASNet`.
        raw: ``(B, 1, m, m)`` the importance net's output.
        ipr: target share of sampled FR pixels in ``(0, 1]``.
    """
    return las.mean_for_ipr(raw, ipr, steps)


def las_mask(las: torch.nn.Module, raw: torch.Tensor, mean: torch.Tensor | float) -> torch.Tensor:
    """LAS's hard sampling mask ``(B, 1, m, m)`` bool at normalization mean ``mean`` (number or
    ``(B,1,1,1)``): :meth:`LASNet.mask_at <imls_lightning.models.las.LASNet.mask_at>`."""
    return las.mask_at(raw, mean)


class LASMethod(Method):
    """Baseline 3: LAS. Low-res render -> importance net -> normalized importance -> plastic
    sampling at full resolution -> ray-cast those pixels -> reconstruction with the mask channel.

    Args:
        las_net: a trained :class:`~imls_lightning.models.las.LASNet`.
        fr_size, low_res: FR side ``m`` and low-res side ``h`` it was trained with.
        ipr: sample this share of the FR pixels (LAS's evaluation protocol: the mean ``u`` is
            bisected per view). The bisection is a calibration, not part of LAS at inference (a
            deployed LAS uses a fixed ``u``): it runs outside the timed stages; the timed
            ``importance`` stage is the importance net + one normalization + sampling.
            ``None``: the trained mean. :meth:`run` takes another per call.
        by_distance: a :class:`~imls_lightning.models.ims.DistanceMeans` of IPRs: each view at its band of
            camera distance's IPR instead of ``ipr`` (the evaluation's LAS searched per band, ``las_searched``).
    """

    name = "las"

    def __init__(self, renderer, las_net: torch.nn.Module, fr_size: int, low_res: int,
                 ipr: float | None = None, opts: NetOptions | None = None, by_distance: DistanceMeans | None = None):
        super().__init__(renderer, fr_size, opts)
        self.las = prepare_net(las_net, self.device, self.opts)
        self.low_res = int(low_res)
        self.ipr = None if ipr is None else check_ipr(ipr)
        self.by_distance = by_distance
        if by_distance is not None:
            for x in self.iprs:
                check_ipr(x, "by_distance")

    @property
    def iprs(self) -> list[float | None]:
        """The IPRs it runs at: ``[ipr]``, or its bands' near to far (``by_distance``)."""
        return [self.ipr] if self.by_distance is None else self.by_distance.values()

    def ipr_for(self, view) -> float | None:
        """The IPR a validated view ``(9,)`` runs at: its band's with ``by_distance``, else ``ipr``."""
        if self.by_distance is None:
            return self.ipr
        return self.by_distance.value_for(view)

    def steps(self, view, ipr: float | None = None):
        """The forward pass of a validated view at this call's ``ipr`` (a share of the FR pixels in ``(0, 1]``;
        ``None``: the method's own, or its band's)."""
        ipr = self.ipr_for(view) if ipr is None else check_ipr(ipr)
        m = self.fr_size
        net = getattr(self.las, "_orig_mod", self.las)  # attributes of a compiled LASNet
        yield "low_res_render"
        low = self.renderer.render(view, self.low_res)
        low_t = self._tensor(torch.from_numpy(low).permute(2, 0, 1).float().div(255.0)[None])
        yield "importance"
        with self.opts.autocast(self.device):
            raw = net.importance_net(low_t)
        yield None
        u = net.mean if ipr is None else las_mean_for_ipr(net, raw, ipr)  # a calibration, in no stage
        yield "importance"
        mask = las_mask(net, raw, u)[0, 0]
        idx = np.flatnonzero(mask.cpu().numpy().reshape(-1))
        yield "selective_render"
        colours = self.renderer.render_pixels(view, m, idx)
        flat = np.zeros((m * m, 3), np.float32)
        flat[idx] = colours.astype(np.float32) / 255.0
        samples = self._tensor(torch.from_numpy(flat).view(1, m, m, 3).permute(0, 3, 1, 2))  # channels-last, as above
        yield "recnn"
        with self.opts.autocast(self.device):
            fr = net.reconstruct(samples, mask[None, None].float())
        yield None
        return RenderResult(to_uint8_image(fr), {},
                            {"ipr": len(idx) / m**2, "rendered_pixels": int(len(idx)), "mask": mask.bool().cpu()})


def c_mask_to_fr_pixels(pattern: SamplingPattern, c_mask: torch.Tensor) -> torch.Tensor:
    """FR raster indices of the set C-Image pixels (re-exported for users)."""
    return c_pixels_to_fr(pattern, c_mask)
