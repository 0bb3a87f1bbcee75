"""The browser viewer's state, with no web code: a camera, the chosen method, the share of the C-Image, and
one frame at a time (image, mask, error against the ground truth, stage latencies, PSNR).

:class:`ViewerSession` is what :mod:`imls_lightning.web.app` drives; it is tested without a browser.

Example:
    >>> s = ViewerSession.from_checkpoints("ims.ckpt")      # doctest: +SKIP
    >>> s.orbit(15, 0); s.set_share(0.4); f = s.frame()      # doctest: +SKIP
    >>> f.psnr, f.stages_ms["total"], f.ipr, f.share         # doctest: +SKIP
"""
from __future__ import annotations

import base64
import io
import math
import warnings
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from PIL import Image

from imls_lightning.base.errors import InputError, finite_number

from ..core.patterns import c_pixels_to_fr
from ..evaluation.timing import timed_run  # each frame's stages, timed from outside the methods
from ..inference.camera import DEFAULT_DISTANCE_RANGE, OrbitCamera, frame_psnr, orbit_view
from ..inference.checkpoints import IMSNets, load_product, load_task, renderer_for
from ..core.operating_point import OperatingPoint
from ..inference.pipeline import FullRayCast, IMLSRenderer, LASMethod, NetOptions, RecNNAlone
from ..render.camera import view_tensor
from ..base.images import error_map, to_uint8
from ..models.ims import DistanceMeans

#: the methods a user can pick, with their labels
METHODS = {"imls": "IML/S + RecNN (the product)", "adaptive": "IML/S + RecNN, adaptive mean", "recnn": "RecNN alone",
           "las": "LAS", "truth": "Ground truth (full ray cast)"}
#: stage names shown, in pipeline order
STAGES = ("mean", "importance", "low_res_render", "selective_render", "decoder", "recnn", "render", "total")
HISTORY = 60  # latency / PSNR points kept for the small plot


@dataclass
class Frame:
    """One rendered frame of the session.

    Attributes:
        method: the method's key (:data:`METHODS`).
        image: ``(m, m, 3)`` uint8, the method's image.
        mask: ``(m, m)`` bool, the FR pixels ray-cast for it.
        error: ``(m, m, 3)`` uint8 heat map of the error against the ground truth (x4).
        stages_ms: stage -> milliseconds (``total`` included).
        ipr: the image-plane ratio, ray-cast FR pixels / FR pixels.
        psnr: dB against the ground truth (100 when identical).
        share: the share of the C-Image IML/S ran this view at (the paper's mean value ``u``, the same number).
        view_share: whether ``share`` is this view's own (the adaptive mean, a by-distance point).
    """

    method: str
    image: np.ndarray
    mask: np.ndarray
    error: np.ndarray
    stages_ms: dict[str, float]
    ipr: float
    psnr: float
    share: float
    view_share: bool = False


def png_data_url(image: np.ndarray) -> str:
    """``(h, w)`` bool / ``(h, w, 3)`` uint8 -> a ``data:image/png;base64,...`` URL for an ``<img>``."""
    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.uint8) * 255
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


@dataclass
class ViewerSession(OrbitCamera):
    """Camera, method and share of the C-Image of one viewer, and the methods built from the checkpoints.

    Args:
        nets: the product's networks (:class:`~imls_lightning.inference.checkpoints.IMSNets`: the IMS
            mask head, the IML decoder, the pattern).
        recnn: the RecNN module (the checkpoint's, or another of the same pattern).
        renderer: the scene's renderer.
        las: an optional LAS network and its low-res side ``(net, low_res)``.
        predictor: an optional per-view mean predictor (``python -m imls_lightning.adaptive``'s
            ``mean_predictor.pt``): adds the adaptive-mean method.
        opts: inference options of every network.
        azimuth, elevation, distance: start camera (degrees, degrees, normalized units; ``None``:
            the middle of the scene's camera distance range).
        method: the start method (:data:`METHODS`).
        point: the :class:`~imls_lightning.core.operating_point.OperatingPoint` IML/S opens at (``None``: the trained
            share); :meth:`from_checkpoints` passes the one the evaluation recorded for the IMS. Its share is the start
            share (:attr:`share`); at it each view runs at its band's share (``bands``); a share set with the slider
            (:meth:`set_share`) holds for every view, with the point's lift, sharpness and object floor.
        record: the evaluation's record the point came from (``None``: none).
    """

    nets: IMSNets
    recnn: torch.nn.Module
    renderer: Any
    las: tuple[torch.nn.Module, int] | None = None
    predictor: torch.nn.Module | None = None
    opts: NetOptions = field(default_factory=NetOptions)
    azimuth: float = 30.0
    elevation: float = 20.0
    distance: float | None = None
    method: str = "imls"
    point: OperatingPoint | None = None
    record: Any = None

    def __post_init__(self):
        scene = getattr(self.renderer, "scene", None)
        self.distance_range = tuple(float(c) for c in getattr(scene, "camera_distance", DEFAULT_DISTANCE_RANGE))
        lo, hi = self.distance_range
        self.distance = 0.5 * (lo + hi) if self.distance is None else finite_number(self.distance, "distance", "a finite number")
        if not lo - 1e-9 <= self.distance <= hi + 1e-9:
            raise InputError(f"distance={self.distance}: expected a camera distance in scene.camera_distance=[{lo:g}, {hi:g}]")
        orbit_view(self.azimuth, self.elevation, self.distance)  # one-line InputError on bad angles
        self.home = (float(self.azimuth), float(self.elevation), float(self.distance))
        self.scene_name = getattr(scene, "name", "?")
        self.trained_mean = self.nets.trained_mean
        # the start point as the viewer shows it, made once here: its share, lift, bands, the record
        self.start_share = None if self.point is None else self.point.share
        self.lift = self.point is not None and self.point.lift
        b = None if self.point is None else self.point.bands
        self.by_distance = None if b is None else DistanceMeans(b.edges, b.shares, b.floor_margins)
        self.operating_point = self.record
        self.share = self.trained_mean  # the share of C in force: the trained one until set
        self.rescalable = self.nets.target == "pim"
        if self.start_share is not None:
            self.set_share(self.start_share)  # checked there
            self.share = float(self.start_share)  # exactly the recorded point, not rounded like a slider value
        self._imls: dict[float, IMLSRenderer] = {}
        self.truth_method = FullRayCast(self.renderer, self.pattern.fr_size, self.opts)
        self.recnn_method = RecNNAlone(self.renderer, self.pattern, self.recnn, self.opts)
        # LAS is built once; each frame runs it at IML/S's IPR at that view (an argument of its run)
        self.las_method = None if self.las is None else LASMethod(self.renderer, self.las[0], self.pattern.fr_size,
                                                                   self.las[1], ipr=1.0, opts=self.opts)
        self.adaptive_method = None
        if self.predictor is not None:
            from ..adaptive.renderer import AdaptiveIMLSRenderer

            head = self.nets.head if self.point is None else self.nets.head.for_point(self.point)  # its sharpness and floor
            self.adaptive_method = AdaptiveIMLSRenderer(self.renderer, self.pattern, head, self.nets.decoder,
                                                        self.recnn, self.predictor, self.opts, lift=self.lift)

        self.history: deque[tuple[str, float, float]] = deque(maxlen=HISTORY)
        self._truth_cache: tuple[bytes, np.ndarray] | None = None
        self.set_method(self.method)

    @classmethod
    def from_checkpoints(cls, ims_checkpoint: str, recnn_checkpoint: str | None = None, las_checkpoint: str | None = None,
                         predictor: str | None = None, *, opts: NetOptions | None = None, share: float | str | None = None,
                         mean: float | str | None = None, **camera) -> "ViewerSession":
        """Load the IMS (and optionally another RecNN, a LAS checkpoint and a mean predictor); the
        scene and renderer are those the IMS was trained on. Bad or mismatched files fail in one line.

        The session opens at the operating point the evaluation recorded for the IMS checkpoint
        (its masks lifted if the evaluation lifted them), else at the trained mean, as
        :meth:`IMLSRenderer.from_checkpoints` does; ``share`` (a number or ``"trained"``; ``mean``: its older name)
        overrides it.
        """
        value, key = (share, "share") if share is not None else (mean, "mean")
        product = load_product(ims_checkpoint, recnn_checkpoint, share=value, share_key=key)
        nets, recnn = product.nets, product.nets.recnn
        if recnn is None:
            raise InputError(f"ims_checkpoint={ims_checkpoint}: holds no RecNN; pass recnn_checkpoint=<RecNN .ckpt>")
        las = None
        if las_checkpoint:
            lt = load_task(las_checkpoint, expect="LASTask", what="las_checkpoint")
            if int(lt.hparams["fr_size"]) != int(nets.pattern.fr_size):
                raise InputError(f"las_checkpoint={las_checkpoint}: trained at {lt.hparams['fr_size']}^2, the IMS at "
                                 f"{nets.pattern.fr_size}^2; use a LAS of the same resolution")
            las = (lt.net, int(lt.hparams["low_res"]))
        mean_predictor = None
        if predictor:
            from ..adaptive.predictor import MeanPredictor

            mean_predictor = MeanPredictor.load(predictor)
        session = cls(nets, recnn, renderer_for(nets.hparams), las=las, predictor=mean_predictor, opts=opts or NetOptions(),
                      point=product.point, record=product.record, **camera)
        return session

    @property
    def pattern(self):
        """The sampling pattern of the IMS (and of the RecNN)."""
        return self.nets.pattern

    # -- controls ----------------------------------------------------------------------------------
    @property
    def methods(self) -> dict[str, str]:
        """The methods this session can show (LAS only with a LAS checkpoint, the adaptive mean only
        with a predictor)."""
        return {k: v for k, v in METHODS.items()
                if (k != "las" or self.las is not None) and (k != "adaptive" or self.predictor is not None)}

    def set_method(self, name: str) -> None:
        if name not in self.methods:
            raise InputError(f"method={name!r}: expected one of {', '.join(self.methods)}")
        self.method = name

    def set_share(self, share: float) -> None:
        """The share of the C-Image IML/S runs at (the IMS's PIM' rescaled to it); ``[0.01, 1]``."""
        u = finite_number(share, "share", "a number in [0.01, 1]")
        if not 0.01 <= u <= 1.0:
            raise InputError(f"share={u}: expected a number in [0.01, 1]")
        if not self.rescalable and abs(u - self.trained_mean) > 1e-9:
            raise InputError(f"share={u}: this IMS was trained with model.target={self.nets.target}; only its "
                             f"trained share {self.trained_mean:g} can be shown (train it with model.target=pim)")
        self.share = round(u, 4)

    def set_mean(self, u: float) -> None:
        """:meth:`set_share`'s older name (the paper's mean value ``u`` is the share): still works, with a
        ``DeprecationWarning``."""
        warnings.warn("ViewerSession.set_mean is set_share's older name; call set_share", DeprecationWarning, stacklevel=2)
        self.set_share(u)

    @property
    def mean(self) -> float:
        """:attr:`share`'s older name (the paper's mean value ``u``, the same number)."""
        return self.share

    # -- rendering ---------------------------------------------------------------------------------
    def _imls_at(self, u: float) -> IMLSRenderer:
        if u not in self._imls:
            share = None if abs(u - self.trained_mean) < 1e-9 else u
            at_start = self.start_share is not None and abs(u - float(self.start_share)) < 1e-9
            start = self.point if self.point is not None else self.nets.head.point()
            point = start.replace(share=share, bands=start.bands if at_start else None)
            self._imls[u] = IMLSRenderer(self.renderer, self.pattern, self.nets.head, self.nets.decoder, self.recnn, self.opts,
                                         point=point)
        return self._imls[u]

    def _truth(self, view: np.ndarray):
        key = np.asarray(view, np.float64).tobytes()
        if self._truth_cache is None or self._truth_cache[0] != key:
            res = timed_run(self.truth_method, view)
            self._truth_cache = (key, res.image)
            self._truth_ms = {k: 1e3 * v for k, v in res.timings.items()}
        return self._truth_cache[1]

    def _fr_mask(self, c_mask: torch.Tensor | None) -> np.ndarray:
        """``(m, m)`` bool: the FR pixels of the set C-Image pixels (None: the whole pattern)."""
        p = self.pattern
        mask = np.zeros(p.fr_size * p.fr_size, bool)
        mask[p.indices.numpy() if c_mask is None else c_pixels_to_fr(p, torch.as_tensor(c_mask)).numpy()] = True
        return mask.reshape(p.fr_size, p.fr_size)

    def frame(self) -> Frame:
        """Render the current view with the current method (and the ground truth it is scored against)."""
        view = self.view()
        m = self.pattern.fr_size
        with torch.inference_mode():
            truth = self._truth(view)
            imls = self._imls_at(self.share)
            if self.method == "truth":
                image, stages, mask = truth, dict(self._truth_ms), np.ones((m, m), bool)
            else:
                if self.method in ("imls", "adaptive"):
                    res = timed_run(imls if self.method == "imls" else self.adaptive_method, view)
                    mask = self._fr_mask(res.info["im"])
                elif self.method == "recnn":
                    res = timed_run(self.recnn_method, view)
                    mask = self._fr_mask(None)
                else:  # LAS at the IPR IML/S has at this view and share (the IMS alone decides it, no rendering)
                    im = imls.predict_im(view_tensor(view, imls.device))
                    res = timed_run(self.las_method, view, ipr=max(float(im.sum()) / m**2, 1.0 / m**2))
                    mask = res.info["mask"].numpy().reshape(m, m)
                image, stages = res.image, {k: 1e3 * v for k, v in res.timings.items()}
        psnr = frame_psnr(image, truth)
        err = to_uint8(error_map(torch.from_numpy(np.array(image)).permute(2, 0, 1).float() / 255,
                                 torch.from_numpy(np.array(truth)).permute(2, 0, 1).float() / 255))
        ipr = float(mask.mean())
        self.history.append((self.method, stages.get("total", math.nan), psnr))
        # the adaptive mean's and a by-distance point's share (u) are the view's own
        view_share = self.method in ("imls", "adaptive") and "mean" in res.info
        share = float(res.info["mean"]) if view_share else self.share
        return Frame(self.method, image, mask, err, stages, ipr, psnr, share, view_share)
