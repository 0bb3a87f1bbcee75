"""The Importance Mask Synthesis network (paper, "Importance Mask Synthesis Network"): a DCGAN
generator from the 9 view floats to the ``n x n`` importance mask, and its discriminator.

Generator layout (``layers`` transposed convolutions in all, paper: 8):

1. projection: the (normalized) view as a ``(B, 9, 1, 1)`` map -> ``ConvTranspose2d(kernel=s0)`` ->
   ``s0 x s0``;
2. ``k`` stride-2 ``ConvTranspose2d(4, 2, 1)``, each doubling the side: ``s0 * 2**k = c_size``;
3. the remaining ``layers - 1 - k`` layers are stride-1 ``ConvTranspose2d(3, 1, 1)`` at the final
   resolution.

BatchNorm + ReLU after every layer but the last, which has 1 channel and ``tanh``. ``s0`` is chosen
as the smallest side ``>= 4`` with ``c_size = s0 * 2**k`` and ``k <= layers - 1`` (more doublings
are preferred: fewer, cheaper layers at full size), e.g. 256 @ 8 layers: ``s0 = 4``, 6 doublings,
1 stride-1 layer; 64 @ 8: ``s0 = 4``, 4 doublings, 3 stride-1 layers; 48: ``s0 = 6``; 7: ``s0 = 7``.
Channels at side ``s0 * 2**j`` are ``min(base_channels * 2**(k - j), max_channels)`` (DCGAN: halving
as the side doubles).

View normalization. eye (at camera distance, up to a few units), lookAt (near the origin) and up
(unit vector) have different scales; the generator standardizes the view with per-component
``view_mean`` / ``view_std`` buffers (saved in checkpoints). They default to 0 / 1 (no-op); call
:meth:`IMSGenerator.fit_view_normalization` with the training views (the task does) so every input
component is ~N(0, 1). Components that never vary (std < 1e-6, e.g. a fixed up vector) keep std 1.

Targets. The IM ``{0, 1}`` is trained as ``{-1, 1}`` (:func:`im_to_target`); the generated IM is
``output > 0`` (:func:`output_to_im`).

The mask. :class:`IMSMaskHead` is the generator with its thresholding: view -> IM at the trained mean,
or at a mean value ``u`` given to each call (``target="pim"``: the regressed PIM' rescaled, optionally
lifted to the share ``u``). It is the one home of that arithmetic: training
(:class:`~imls_lightning.tasks.ims.IMSTask`), the product pipeline
(:class:`~imls_lightning.inference.pipeline.IMLSRenderer`) and the exported ``im`` network
(:mod:`imls_lightning.inference.export`) all call it.
"""
from __future__ import annotations

from typing import Optional

import torch
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import renamed_keyword
from imls_lightning.render.camera import view_tensor

from ..core.importance import (check_object_floor, check_sharpness, floored_mean, lift_to_share, lifted_mask, object_fraction,
                               sharpen_importance)
from ..core.operating_point import OperatingPoint

__all__ = ["IMSGenerator", "IMSDiscriminator", "IMSMaskHead", "MaskAt", "DistanceMeans", "TARGETS", "im_to_target", "output_to_im",
           "generator_plan"]

#: what an IMS generator regresses: the binary IM (paper) or the continuous PIM'
TARGETS = ("im", "pim")


def im_to_target(im: torch.Tensor) -> torch.Tensor:
    """IM ``{0, 1}`` (or soft ``[0, 1]``) -> generator target in ``{-1, 1}``: ``2 im - 1``.

    Example:
        >>> im_to_target(torch.tensor([0.0, 1.0])).tolist()
        [-1.0, 1.0]
    """
    return im.float() * 2 - 1


def output_to_im(g_out: torch.Tensor) -> torch.Tensor:
    """Generator output in ``(-1, 1)`` -> hard IM ``{0, 1}`` (float32): ``[g_out > 0]``.

    Example:
        >>> output_to_im(torch.tensor([-0.3, 0.0, 0.2])).tolist()
        [0.0, 0.0, 1.0]
    """
    return (g_out > 0).float()


def generator_plan(c_size: int, layers: int, min_start: int = 4) -> tuple[int, int, int]:
    """``(s0, doublings k, stride-1 layers)`` for an output side ``c_size`` with ``layers`` layers."""
    n, L = int(c_size), int(layers)
    if n < 1:
        raise InputError(f"c_size={c_size}: expected a positive integer")
    if L < 1:
        raise InputError(f"layers={layers}: expected an integer >= 1")
    k = 0
    while k + 1 <= L - 1 and n % 2 ** (k + 1) == 0 and n // 2 ** (k + 1) >= min_start:
        k += 1
    return n // 2**k, k, L - 1 - k


class IMSGenerator(nn.Module):
    """DCGAN generator ``view (B, 9) -> (B, 1, n, n)`` in ``(-1, 1)``.

    Args:
        c_size: output side ``n`` (the C-Image side).
        layers: number of transposed convolutions, ``>= 1``. Default 8 (paper).
        base_channels: channels at full resolution (doubling toward the start). Default 32.
        max_channels: channel cap. Default 512.
        view_dim: length of the view vector. Default 9.
        view_mean, view_std: optional ``(view_dim,)`` input standardization (default 0 / 1).

    Example:
        >>> g = IMSGenerator(32, layers=5, base_channels=4)
        >>> g(torch.rand(3, 9)).shape
        torch.Size([3, 1, 32, 32])
    """

    def __init__(
        self,
        c_size: int,
        layers: int = 8,
        base_channels: int = 32,
        max_channels: int = 512,
        view_dim: int = 9,
        view_mean: Optional[torch.Tensor] = None,
        view_std: Optional[torch.Tensor] = None,
    ):
        super().__init__()
        if int(base_channels) < 1 or int(max_channels) < 1 or int(view_dim) < 1:
            raise InputError(
                f"base_channels={base_channels}, max_channels={max_channels}, view_dim={view_dim}: expected positive integers"
            )
        self.c_size, self.layers, self.view_dim = int(c_size), int(layers), int(view_dim)
        s0, k, extra = generator_plan(self.c_size, self.layers)
        self.start_size, self.doublings, self.extra_layers = s0, k, extra

        def ch(j: int) -> int:
            return min(int(base_channels) * 2 ** (k - j), int(max_channels))

        # (in, out, kernel, stride, padding) per layer; last layer -> 1 channel
        specs = [(self.view_dim, ch(0), s0, 1, 0)]
        specs += [(ch(j - 1), ch(j), 4, 2, 1) for j in range(1, k + 1)]
        specs += [(ch(k), ch(k), 3, 1, 1) for _ in range(extra)]
        cin, _, kern, stride, pad = specs[-1]
        specs[-1] = (cin, 1, kern, stride, pad)
        mods: list[nn.Module] = []
        for i, (ci, co, kern, stride, pad) in enumerate(specs):
            last = i == len(specs) - 1
            mods.append(nn.ConvTranspose2d(ci, co, kern, stride, pad, bias=last))
            mods += [nn.Tanh()] if last else [nn.BatchNorm2d(co), nn.ReLU(inplace=True)]
        self.net = nn.Sequential(*mods)
        _init_dcgan(self)
        mean = torch.zeros(self.view_dim) if view_mean is None else torch.as_tensor(view_mean, dtype=torch.float32)
        std = torch.ones(self.view_dim) if view_std is None else torch.as_tensor(view_std, dtype=torch.float32)
        if mean.shape != (self.view_dim,) or std.shape != (self.view_dim,) or bool((std <= 0).any()):
            raise InputError(f"view_mean/view_std: expected ({self.view_dim},) tensors with std > 0")
        self.register_buffer("view_mean", mean.clone())
        self.register_buffer("view_std", std.clone())

    @torch.no_grad()
    def fit_view_normalization(self, views: torch.Tensor) -> None:
        """Set ``view_mean``/``view_std`` from training views ``(N, view_dim)``."""
        v = torch.as_tensor(views, dtype=torch.float32)
        if v.dim() != 2 or v.shape[1] != self.view_dim or v.shape[0] < 1:
            raise InputError(f"views: expected an (N, {self.view_dim}) array with N >= 1, got shape {tuple(v.shape)}")
        mean = v.mean(0)
        std = v.std(0, unbiased=False) if v.shape[0] > 1 else torch.ones(self.view_dim)
        std = torch.where(std < 1e-6, torch.ones_like(std), std)
        self.view_mean.copy_(mean)
        self.view_std.copy_(std)

    def forward(self, view: torch.Tensor, return_pre_tanh: bool = False):
        """``(B, 1, n, n)`` in ``(-1, 1)``; with ``return_pre_tanh=True`` also the activation before
        the tanh, ``(out, pre)`` with ``out = tanh(pre)`` (an exact BCE needs it: through a
        saturated tanh the gradient vanishes)."""
        if view.dim() != 2 or view.shape[1] != self.view_dim:
            raise ValueError(f"IMSGenerator: expected views (B, {self.view_dim}), got {tuple(view.shape)}")
        z = (view.to(self.view_mean.dtype) - self.view_mean) / self.view_std
        if not return_pre_tanh:
            return self.net(z[:, :, None, None])
        pre = self.net[:-1](z[:, :, None, None])  # the last module is the nn.Tanh
        return self.net[-1](pre), pre

    def extra_repr(self) -> str:
        return (
            f"c_size={self.c_size}, layers={self.layers}, start_size={self.start_size}, "
            f"doublings={self.doublings}, extra_layers={self.extra_layers}"
        )


class IMSDiscriminator(nn.Module):
    """DCGAN discriminator ``(B, 1, n, n) -> (B,)`` logits (real IM vs generated; no sigmoid: the
    losses take logits).

    ``Conv2d(4, 2, 1)`` steps halve the side (first without BatchNorm, as in DCGAN; then BatchNorm),
    each with LeakyReLU(0.2), while the side is ``> 4``; a final conv over the remaining
    ``s x s`` map gives one logit. Channels ``min(base_channels * 2**i, max_channels)``.

    Args:
        c_size: input side ``n``.
        base_channels: channels of the first conv. Default 32.
        max_channels: cap. Default 256.
        in_channels: input channels. Default 1.

    Example:
        >>> IMSDiscriminator(32, base_channels=4)(torch.rand(2, 1, 32, 32)).shape
        torch.Size([2])
    """

    def __init__(self, c_size: int, base_channels: int = 32, max_channels: int = 256, in_channels: int = 1):
        super().__init__()
        for name, v in (("c_size", c_size), ("base_channels", base_channels), ("max_channels", max_channels)):
            if int(v) < 1:  # one key per message: the task renames it to the user's key
                raise InputError(f"{name}={v}: expected a positive integer")
        self.c_size, self.in_channels = int(c_size), int(in_channels)
        mods: list[nn.Module] = []
        side, cin, i = self.c_size, self.in_channels, 0
        while side > 4:
            co = min(int(base_channels) * 2**i, int(max_channels))
            mods.append(nn.Conv2d(cin, co, 4, 2, 1, bias=i == 0))
            if i > 0:
                mods.append(nn.BatchNorm2d(co))
            mods.append(nn.LeakyReLU(0.2, inplace=True))
            side, cin, i = side // 2, co, i + 1
        mods.append(nn.Conv2d(cin, 1, side))
        self.net = nn.Sequential(*mods)
        _init_dcgan(self)

    def forward(self, im: torch.Tensor) -> torch.Tensor:
        n = self.c_size
        if im.dim() != 4 or tuple(im.shape[1:]) != (self.in_channels, n, n):
            raise ValueError(f"IMSDiscriminator: expected (B, {self.in_channels}, {n}, {n}), got {tuple(im.shape)}")
        return self.net(im).flatten(1).squeeze(1)


class IMSMaskHead(nn.Module):
    """The IMS's importance mask: view ``(B, 9)`` -> IM ``(B, 1, n, n)`` bool, False on C-Image padding.

    The generator ``g = G(view)`` in ``(-1, 1)`` and its thresholding (:meth:`threshold`):

    * ``target="im"`` (paper): ``IM = g > 0``;
    * ``target="pim"``: the regressed ``PIM' = (g + 1) / 2``, normalized to the trained mean ``u_train``,
      dithered as the IML does against the plastic rank pattern ``P``: ``IM = PIM' > P  or  g >= 1``.
      At a share ``u`` of the C-Image (an argument of each call, ``share``: the IML normalizes to mean ``u``, the
      expected share sampled) the IML normalization, affine in ``u``, rescales it:
      ``PIM'(u) = l + (PIM' - l) (u - l) / (u_train - l)``, ``IM = PIM'(u) > P`` (a saturated ``g = 1``
      stays important when ``u >= u_train``). With ``lift``, above ``u_train``, PIM'(u) is lifted until
      the expected share is ``u`` (:func:`~imls_lightning.core.importance.lift_to_share`): the same masks
      as the rescale, reached at their share, then a blue-noise floor; ``u = 1`` takes every pixel.
    * ``sharpness`` ``gamma > 1`` (``target="pim"``): the PIM' is sharpened first, per image, keeping its mean
      (:func:`~imls_lightning.core.importance.sharpen_importance`): at the same mean value fewer pixels on
      the low floor, more where the importance is high. The evaluation searches it beside the mean value
      (``ims_sharpness``); at ``gamma = 1`` (default) every mask is the paper's, bit for bit.
    * ``object_floor`` ``(margin, tau)`` (``target="pim"``): each view's mean value is first raised to the share of
      its C-pixels whose unsharpened PIM' exceeds ``tau`` plus ``margin``,
      ``u' = max(u, min(1, object + margin))`` (:func:`~imls_lightning.core.importance.floored_mean`): a mask
      whose share falls near its own object's fraction leaves holes in the object (seed_whole's failing views).
      The evaluation chooses the margin on validation views (``orp_object_floor``); ``None`` (default): no floor.

    No state changes what a call returns: the share and the lift are arguments (:class:`MaskAt`
    binds them for a caller that passes views only, e.g. an export). Tensor operations only: traceable.

    Args:
        generator: the :class:`IMSGenerator` (any module ``(B, 9) -> (B, 1, n, n)``).
        P: ``(n, n)`` plastic rank pattern the IML's labels were dithered with (``target="pim"``).
        valid: ``(n, n)`` bool, the sampling pattern's C-Image pixels.
        target: ``"im"`` or ``"pim"``.
        trained_mean: the IML's mean value ``u_train`` the PIM' targets were normalized to.
        lower: the IML normalization's lower bound ``l``. Default 0 (paper).
        sharpness: ``gamma`` in ``[1, 8]``. Default 1 (paper). :meth:`with_sharpness` makes a head at another.
        object_floor: ``(margin, tau)``, ``margin`` in ``[0, 1]``, ``tau`` in ``(0, 1)``, or ``None`` (default).
            :meth:`with_object_floor` makes a head with another.

    Example:
        >>> n = 8
        >>> head = IMSMaskHead(IMSGenerator(n, layers=3, base_channels=4).eval(), torch.rand(n, n),
        ...                    torch.ones(n, n, dtype=torch.bool), "pim", trained_mean=0.2)
        >>> view = torch.tensor([[0.0, 0.0, 3.5, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
        >>> head(view).shape, head(view).dtype
        (torch.Size([1, 1, 8, 8]), torch.bool)
        >>> bool(head(view, share=1.0, lift=True).all())   # the whole C-Image, lifted: every pixel
        True
    """

    def __init__(self, generator: nn.Module, P: torch.Tensor, valid: torch.Tensor, target: str,
                 trained_mean: float | None = None, lower: float = 0.0, sharpness: float = 1.0,
                 object_floor: "tuple[float, float] | None" = None):
        super().__init__()
        if target not in TARGETS:
            raise InputError(f"model.target={target!r}: expected one of {list(TARGETS)}")
        n = int(valid.shape[-1])
        if tuple(P.shape[-2:]) != (n, n) or P.numel() != n * n or valid.numel() != n * n:
            raise InputError(f"P {tuple(P.shape)} and valid {tuple(valid.shape)}: expected two (n, n) maps of one size")
        if target == "pim" and trained_mean is None:
            raise InputError("trained_mean: an IMS with model.target=pim needs the IML's trained mean value")
        self.generator = generator
        self.target = target
        self.trained_mean = None if trained_mean is None else float(trained_mean)
        self.lower = float(lower)
        self.sharpness = check_sharpness(sharpness)
        if self.sharpness != 1.0 and target != "pim":
            raise InputError(f"sharpness={sharpness}: sharpening the IMS's mask needs model.target=pim (a binary IM has no importance to sharpen)")
        self.object_floor = None if object_floor is None else check_object_floor(*object_floor)
        if self.object_floor is not None and target != "pim":
            raise InputError(f"object_floor={object_floor}: a floor on the IMS's mean value needs model.target=pim "
                             "(a binary IM has no mean value to raise)")
        # (1, 1, n, n) views of the given tensors (not copies): a head made from a task's buffers follows them
        self.register_buffer("P", P.detach().reshape(1, 1, n, n))
        self.register_buffer("valid", valid.detach().to(torch.bool).reshape(1, 1, n, n))

    @property
    def c_size(self) -> int:
        return int(self.valid.shape[-1])

    def with_generator(self, generator: nn.Module) -> "IMSMaskHead":
        """The same head around another generator module (e.g. a compiled or channels-last one); the
        buffers are shared."""
        return IMSMaskHead(generator, self.P, self.valid, self.target, self.trained_mean, self.lower, self.sharpness,
                           self.object_floor)

    def with_sharpness(self, sharpness: float) -> "IMSMaskHead":
        """The same head (generator and buffers shared) at another ``sharpness``."""
        return IMSMaskHead(self.generator, self.P, self.valid, self.target, self.trained_mean, self.lower, sharpness,
                           self.object_floor)

    def with_object_floor(self, margin: float | None, tau: float = 0.2) -> "IMSMaskHead":
        """The same head (generator and buffers shared) with the object floor ``(margin, tau)``; ``margin=None``:
        without one."""
        return IMSMaskHead(self.generator, self.P, self.valid, self.target, self.trained_mean, self.lower, self.sharpness,
                           None if margin is None else (margin, tau))

    def forward(self, view: torch.Tensor, share: torch.Tensor | float | None = None, lift: bool = False,
                floor_margin: torch.Tensor | None = None, *, mean: torch.Tensor | float | None = None) -> torch.Tensor:
        """IM ``(B, 1, n, n)`` bool of views ``(B, 9)`` at the trained share (``share=None``) or at ``share`` of the
        C-Image (a number or ``(B,)``; ``target="pim"`` only), lifted to it with ``lift``; ``floor_margin`` see
        :meth:`threshold`; ``mean``: ``share``'s older name (the paper's mean value ``u``, the same number). Run the
        generator under autocast if wanted: the thresholding is float32 whatever its output."""
        return self.threshold(self.generator(view), renamed_keyword(share, mean, "share", "mean", "IMSMaskHead"), lift,
                              floor_margin)

    def threshold(self, g: torch.Tensor, share: torch.Tensor | float | None = None, lift: bool = False,
                  floor_margin: torch.Tensor | None = None, *, mean: torch.Tensor | float | None = None) -> torch.Tensor:
        """Generator output ``g`` ``(B, 1, n, n)`` -> IM ``(B, 1, n, n)`` bool (see the class doc).

        ``share=None``: the trained share. A number or ``(B,)`` tensor, the share of the C-Image (the IML's mean
        value ``u``: the same number): the PIM' rescaled to it (at ``u == u_train``, the same float32, bit for bit the
        trained-mean IM), lifted with ``lift``. ``mean``: ``share``'s older name.
        ``floor_margin`` ``(B,)``: each view's object-floor margin in place of the head's one (a floor per band of
        camera distance, :meth:`DistanceMeans.floor_margin`; -1: none for that view); the head's ``object_floor``
        gives ``tau``.

        Raises:
            InputError: a share for an IMS trained with ``target="im"`` (a binary IM cannot be rescaled);
                ``floor_margin`` for a head without an ``object_floor``; both ``share`` and ``mean``.
        """
        mean = renamed_keyword(share, mean, "share", "mean", "IMSMaskHead.threshold")  # u: the share, as normalized
        if floor_margin is not None and self.object_floor is None:
            raise InputError("floor_margin: margins per view need a head with an object_floor (its tau); "
                             "make one with with_object_floor(margin, tau)")
        with torch.autocast(device_type=g.device.type, enabled=False):
            g = g.float()
            P, valid = self.P.to(g.device), self.valid.to(g.device)
            if mean is None and (self.sharpness != 1.0 or self.object_floor is not None):
                mean = self.trained_mean  # the sharpened (or floored) PIM' at the trained mean: the rescale by 1
            if mean is None:
                if self.target == "im":
                    im = g > 0
                else:
                    # g = 1 is the target of every PIM' >= 1, which the IML always keeps, also where P = 1
                    im = ((g + 1.0) * 0.5 > P) | (g >= 1.0)
                return im & valid
            if self.target != "pim":
                raise InputError(f"share={mean if not torch.is_tensor(mean) else 'per view'}: its IMS was trained with "
                                 "model.target=im; rescaling the IMS's mask to another share needs an IMS trained "
                                 "with model.target=pim")
            return self._rescaled(g, mean, bool(lift), P, valid, floor_margin)

    def _rescaled(self, g: torch.Tensor, mean, lift: bool, P: torch.Tensor, valid: torch.Tensor,
                  floor_margin: torch.Tensor | None = None) -> torch.Tensor:
        lower = self.lower
        ut = torch.as_tensor(mean, dtype=torch.float32, device=g.device).reshape(-1, 1, 1, 1)
        pim = (g + 1.0) * 0.5
        if self.object_floor is not None:  # the object's own fraction, from the unsharpened PIM', plus the margin
            margin, tau = self.object_floor
            if floor_margin is not None:  # each view's band's margin
                margin = floor_margin.to(device=g.device, dtype=torch.float32).reshape(-1).expand(g.shape[0])
            ut = floored_mean(ut.flatten().expand(g.shape[0]), object_fraction(pim, valid, tau), margin).reshape(-1, 1, 1, 1)
        scale = (ut - lower) / torch.tensor(self.trained_mean - lower, dtype=torch.float32, device=g.device)
        pim = sharpen_importance(pim, self.sharpness, valid)
        pim_u = pim * scale if lower == 0.0 else (pim - lower) * scale + lower
        # a pixel at g = 1 had PIM' >= 1 (the target was clamped at 1): important at any u >= u_train
        saturated = (g >= 1.0) & (scale >= 1.0)
        im = (pim_u > P) | saturated
        if lift:
            # above the trained mean only (below it nothing saturates and the IM stays the paper's): m = 1,
            # f = 0 add nothing, so where the rescale reaches u the IM is bit-for-bit the rescaled one. A sharpened
            # PIM' saturates at any u (gamma = 3 on flame_whole: 14% of C at u = 0.2, then 20% at u = 0.201), so
            # its masks are lifted at every u: the share then follows u without a jump
            x = torch.where(saturated, pim_u.clamp_min(1.0), pim_u)
            m, f = lift_to_share(x, ut.flatten(), valid)
            above = (scale > 1.0) if self.sharpness == 1.0 else torch.ones_like(scale, dtype=torch.bool)
            above = above.to(m.device)
            m = torch.where(above, m, torch.ones_like(m))
            f = torch.where(above, f, torch.zeros_like(f))
            im = im | lifted_mask(x, m, f, P)
        return im & valid

    def at(self, point: "OperatingPoint | float | DistanceMeans | None" = None, lift: bool = False) -> "MaskAt":
        """This head at an :class:`~imls_lightning.core.operating_point.OperatingPoint` (its share, lift, bands,
        sharpness and floor), or at a mean value (or a :class:`DistanceMeans`) and ``lift``: ``view -> IM``
        (see :class:`MaskAt`)."""
        return MaskAt(self, point, lift)

    def for_point(self, point: OperatingPoint) -> "IMSMaskHead":
        """The head (generator and buffers shared) at ``point``'s sharpness and object floor: itself where they are
        its own, else a new head view; nothing of this one changes."""
        if point.sharpness == self.sharpness and point.object_floor == self.object_floor:
            return self
        return IMSMaskHead(self.generator, self.P, self.valid, self.target, self.trained_mean, self.lower, point.sharpness,
                           point.object_floor)

    def point(self, share: float | None = None, lift: bool = False) -> OperatingPoint:
        """The :class:`~imls_lightning.core.operating_point.OperatingPoint` this head's masks are made at with
        ``share`` (``None``: the trained one) and ``lift``: its own sharpness and floor."""
        return OperatingPoint(share=share, lift=lift, sharpness=self.sharpness, object_floor=self.object_floor)

    def extra_repr(self) -> str:
        return (f"target={self.target}, c_size={self.c_size}, trained_mean={self.trained_mean}, lower={self.lower}"
                + (f", sharpness={self.sharpness}" if self.sharpness != 1.0 else "")
                + (f", object_floor={self.object_floor}" if self.object_floor is not None else ""))


class DistanceMeans(nn.Module):
    """A mean value per band of camera distance: view ``(B, 9)`` -> ``u`` ``(B,)`` float32.

    Band ``k`` holds the views whose eye lies at a distance ``d`` from the volume's centre with
    ``edges[k-1] <= d < edges[k]`` (the first band is open below, the last above); its views run at
    ``means[k]``. The evaluation's by-distance operating point (``orp_by_distance``) is one: close-ups,
    where the object fills the C-Image, need more pixels than views from afar. The band is found by
    comparisons and a gather, so tracing and ONNX export see no branch.

    With ``floor_margins`` each band also has its own object floor's margin (the evaluation's
    ``orp_object_floor_by_band``: close-ups need a larger one than views from afar), which
    :meth:`floor_margin` gives per view and :class:`MaskAt` hands to the head (its ``object_floor`` gives the
    ``tau``); ``None`` in a band: no floor there.

    Args:
        edges: ``K - 1`` increasing finite distances (``K >= 1``).
        means: ``K`` mean values in ``[0.01, 1]``.
        floor_margins: ``K`` margins in ``[0, 1]`` or ``None`` (no floor in that band), or ``None`` (default): the
            head's one margin for every view.

    Raises:
        InputError: edges not increasing or not finite, a mean outside ``[0.01, 1]``, ``len(means) != len(edges) + 1``,
            floor margins not one per band or outside ``[0, 1]``.

    Example:
        >>> sched = DistanceMeans([2.7, 3.0], [0.9, 0.7, 0.5])
        >>> views = torch.tensor([[2.5, 0, 0, 0, 0, 0, 0, 1, 0], [0, 2.8, 0, 0, 0, 0, 0, 1, 0], [0, 0, 3.3, 0, 0, 0, 0, 1, 0]])
        >>> [round(u, 2) for u in sched(views).tolist()]
        [0.9, 0.7, 0.5]
        >>> [round(m, 2) for m in DistanceMeans([2.7, 3.0], [0.9, 0.7, 0.5], [0.1, 0.02, None]).floor_margin(views).tolist()]
        [0.1, 0.02, -1.0]
    """

    def __init__(self, edges, means, floor_margins=None):
        super().__init__()
        import math

        e = [float(x) for x in edges]
        u = [float(x) for x in means]
        if len(u) != len(e) + 1:
            raise InputError(f"by_distance: {len(u)} mean values for {len(e)} band edges; expected one more mean than edges")
        if not all(math.isfinite(x) for x in e) or any(b <= a for a, b in zip(e, e[1:])):
            raise InputError(f"by_distance: band edges {e}: expected increasing finite distances")
        if not all(math.isfinite(x) and 0.01 <= x <= 1.0 for x in u):
            raise InputError(f"by_distance: mean values {u}: expected numbers in [0.01, 1]")
        self.register_buffer("edges", torch.tensor(e, dtype=torch.float32))
        self.register_buffer("means", torch.tensor(u, dtype=torch.float32))
        self.floor_margins = None if floor_margins is None else check_band_margins(floor_margins, len(u))
        if self.floor_margins is not None:  # -1: no floor in that band (floored_mean then keeps the band's u)
            self.register_buffer("margins", torch.tensor([NO_FLOOR if m is None else m for m in self.floor_margins],
                                                         dtype=torch.float32))

    def values(self) -> list[float]:
        """The bands' mean values near to far, as given: the float32 buffer rounded back to 6 digits (0.4, not
        0.4000000059). The methods that run a knob per band (LAS's IPR, the two-pass sampler's share) read theirs here."""
        return [round(float(x), 6) for x in self.means.tolist()]

    def value_for(self, view) -> float:
        """The value one view ``(9,)`` runs at (its band's), rounded as :meth:`values`."""
        return round(float(self(view_tensor(view))[0]), 6)

    def band(self, view: torch.Tensor) -> torch.Tensor:
        """The band index ``(B,)`` int64 of each view ``(B, 9)``, near to far."""
        d = view[:, :3].float().norm(dim=1)
        return (d.unsqueeze(1) >= self.edges.to(d.device)).sum(1)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        return self.means.to(view.device)[self.band(view)]

    def floor_margin(self, view: torch.Tensor) -> torch.Tensor | None:
        """Each view's band's object-floor margin ``(B,)`` (-1: no floor in its band), or ``None``: no floor
        margins per band (the head's one margin holds)."""
        if self.floor_margins is None:
            return None
        return self.margins.to(view.device)[self.band(view)]

    def extra_repr(self) -> str:
        return (f"edges={[round(x, 4) for x in self.edges.tolist()]}, means={[round(x, 4) for x in self.means.tolist()]}"
                + ("" if self.floor_margins is None else f", floor_margins={list(self.floor_margins)}"))


NO_FLOOR = -1.0  # a band's margin that leaves its views' u as it is (floored_mean: max(u, f - 1) = u)


def check_band_margins(margins, bands: int | None = None, name: str = "floor_margins") -> list[float | None]:
    """One object-floor margin in ``[0, 1]`` or ``None`` (no floor) per band of camera distance (``bands`` of them;
    ``None``: any number, at least one).

    Example:
        >>> check_band_margins([0.1, None, "0"], 3)
        [0.1, None, 0.0]
    """
    from imls_lightning.base.validate import check_number

    items = list(margins) if isinstance(margins, (list, tuple)) else None
    if not items or (bands is not None and len(items) != bands):
        want = f"{bands} margins" if bands is not None else "a list of margins"
        raise InputError(f"{name}={margins!r}: expected {want} (one per band of camera distance), each in [0, 1] or null")
    return [None if m is None else check_number(m, f"{name}[{i}]", 0.0, 1.0, what="a share of the C-Image in [0, 1] or null")
            for i, m in enumerate(items)]


class MaskAt(nn.Module):
    """An :class:`IMSMaskHead` at a fixed operating point: ``forward(view (B, 9)) -> IM (B, 1, n, n)`` bool. What a
    caller that passes views only needs (the product, the exported ``im`` network; tracing then sees one branch). The
    binding is made once, at construction, and never changes.

    ``point``: an :class:`~imls_lightning.core.operating_point.OperatingPoint` (its share, lift, bands, and the head
    at its sharpness and floor, :meth:`IMSMaskHead.for_point`); or, with ``lift``, a mean value (``None``: the
    trained one) or a :class:`DistanceMeans` (each view at its band's mean value) for the head as it is.

    Example:
        >>> n = 8
        >>> head = IMSMaskHead(IMSGenerator(n, layers=3, base_channels=4).eval(), torch.rand(n, n),
        ...                    torch.ones(n, n, dtype=torch.bool), "pim", trained_mean=0.2)
        >>> view = torch.rand(2, 9)
        >>> torch.equal(head.at(0.5, lift=True)(view), head(view, 0.5, lift=True))
        True
        >>> torch.equal(head.at(DistanceMeans([], [0.5]), lift=True)(view), head(view, 0.5, lift=True))
        True
    """

    def __init__(self, head: IMSMaskHead, point: "OperatingPoint | float | DistanceMeans | None" = None, lift: bool = False):
        super().__init__()
        if isinstance(point, OperatingPoint):
            head = head.for_point(point)  # InputError: a sharpness or floor for a target=im head
            b = point.bands
            mean = point.share if b is None else DistanceMeans(b.edges, b.shares, b.floor_margins)
            lift = point.lift
        else:
            mean = point
        if mean is not None and head.target != "pim":
            shown = "per band" if isinstance(mean, DistanceMeans) else mean
            raise InputError(f"mean={shown}: rescaling the IMS's mask needs model.target=pim and the trained mean")
        self.head = head
        self.by_distance = mean if isinstance(mean, DistanceMeans) else None
        self.mean = None if mean is None or self.by_distance is not None else float(mean)
        self.lift = bool(lift) and mean is not None

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        if self.by_distance is None:
            return self.head(view, self.mean, self.lift)
        return self.head(view, self.by_distance(view), self.lift, floor_margin=self.by_distance.floor_margin(view))

    def extra_repr(self) -> str:
        return f"mean={'by distance' if self.by_distance is not None else self.mean}, lift={self.lift}"


def _init_dcgan(module: nn.Module) -> None:
    """DCGAN init: conv weights ~ N(0, 0.02), BatchNorm weights ~ N(1, 0.02), biases 0."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            nn.init.normal_(m.weight, 0.0, 0.02)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.normal_(m.weight, 1.0, 0.02)
            nn.init.zeros_(m.bias)
