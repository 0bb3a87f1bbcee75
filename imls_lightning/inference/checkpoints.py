"""Loading checkpoints: :func:`load_task` rebuilds the task a checkpoint names (training, evaluation);
inference loads bare networks instead (:func:`load_nets`: the weights of a state-dict prefix into the
network the task class builds from the saved hyperparameters, no task built), the product's networks
(:func:`load_ims_nets`: the IMS mask head, the IML decoder, the RecNN) and the product as it runs
(:func:`load_product`: those networks at the operating point recorded for the checkpoint, which
:meth:`IMLSRenderer.from_checkpoints <imls_lightning.inference.pipeline.IMLSRenderer.from_checkpoints>`
composes with a ray caster). Every checkpoint is read with ``weights_only=True``. The cross-checks of
:mod:`~imls_lightning.tasks.checkpoint_checks` ("does this checkpoint fit what it is used with")
are re-exported here.

This module sits above the tasks: it loads them by name (:data:`TASKS`), and no task imports it. A
task that loads another one from a checkpoint names its class
(:meth:`~imls_lightning.tasks.base.ImlsTask.from_checkpoint`).

Example:
    >>> task_class("LASTask").__name__
    'LASTask'
    >>> task_class("Net")
    Traceback (most recent call last):
    ...
    imls_lightning.base.errors.InputError: checkpoint names task 'Net': expected one of ['IMLTask', 'IMSTask', 'LASTask', 'RecNNTask']
"""
from __future__ import annotations


import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from torch import nn

from imls_lightning.base.errors import InputError

from ..base.config import load_checkpoint, to_plain
from ..core.importance import check_mean
from ..core.patterns import SamplingPattern, build_pattern
from ..models.ims import IMSMaskHead
from ..tasks.base import checkpoint_task_name
from ..tasks.checkpoint_checks import (
    check_resolution,
    check_same_pattern,
    check_trained_on,
    config_diff,
    require_pim_target,
    require_recnn,
    same_pattern,
)

__all__ = ["TASKS", "task_class", "task_path", "load_task", "load_nets", "load_recnn", "IMSNets", "load_ims_nets",
           "Product", "load_product", "renderer_for", "load_ims_and_recnn", "same_pattern", "check_same_pattern",
           "check_resolution", "check_trained_on", "require_recnn", "require_pim_target", "config_diff"]

# tasks that checkpoints may name (never import an arbitrary class from a file); imported by name on
# use, so that loading one task does not import them all
TASKS = {
    "RecNNTask": "imls_lightning.tasks.recnn",
    "IMLTask": "imls_lightning.tasks.iml",
    "IMSTask": "imls_lightning.tasks.ims",
    "LASTask": "imls_lightning.tasks.las",
}


def task_path(task) -> str | None:
    """The checkpoint file a task was loaded from (:func:`load_task`), None for one built in memory."""
    return getattr(task, "checkpoint_path", None)


def task_class(name: str) -> type:
    """The task class a checkpoint names (``"IMLTask"`` -> :class:`~imls_lightning.tasks.iml.IMLTask`).

    Raises:
        InputError: not one of :data:`TASKS`.
    """
    if name not in TASKS:
        raise InputError(f"checkpoint names task {name!r}: expected one of {sorted(TASKS)}")
    return getattr(importlib.import_module(TASKS[name]), name)


def load_task(path: str | Path, *, expect: str | None = None, what: str = "checkpoint"):
    """Rebuild a task from its checkpoint (``weights_only=True``), in eval mode on the CPU.

    Args:
        path: a ``.ckpt`` written by this project's training.
        expect: the task class name it must be (e.g. ``"RecNNTask"``).
        what: the config key the path came from, for error messages.

    Returns:
        The task (an :class:`~imls_lightning.tasks.base.ImlsTask`), ``checkpoint_path`` set.

    Raises:
        InputError: the file is missing or damaged, is not a checkpoint of this project, is another
            task than ``expect``, or its weights do not fit the network it describes.

    Example:
        >>> task = load_task("runs/recnn/checkpoints/last.ckpt", expect="RecNNTask")  # doctest: +SKIP
    """
    ckpt = load_checkpoint(path, what=what)
    name = checkpoint_task_name(ckpt, path, expect=expect, what=what)
    return task_class(name).from_checkpoint(path, what=what, ckpt=ckpt)


# ------------------------------------------------------------------------------------------------
# bare networks


def load_nets(path: str | Path, *, expect: str, what: str = "checkpoint",
              ckpt: Mapping[str, Any] | None = None) -> tuple[dict[str, nn.Module], dict[str, Any], Mapping[str, Any]]:
    """The networks inference runs from a checkpoint of task ``expect``, without building the task.

    The task class builds them from the saved hyperparameters
    (:meth:`~imls_lightning.tasks.base.ImlsTask.inference_nets`); each gets the weights under its
    state-dict prefix, all of them (strict), in eval mode on the CPU.

    Returns:
        ``(nets by state-dict prefix, hyperparameters, state dict)``.

    Raises:
        InputError: the file is missing or damaged, is not a checkpoint of ``expect``, or its weights
            do not fit the networks it describes.

    Example:
        >>> nets, hp, _ = load_nets("recnn.ckpt", expect="RecNNTask")  # doctest: +SKIP
        >>> nets["net"]                                                 # doctest: +SKIP
    """
    ckpt = load_checkpoint(path, what=what) if ckpt is None else ckpt
    checkpoint_task_name(ckpt, path, expect=expect, what=what)
    hp = dict(ckpt["hyper_parameters"])
    try:
        nets = task_class(expect).inference_nets(hp)
    except KeyError as err:
        raise InputError(f"{what}={path}: its hyperparameters lack {err}; not a complete {expect} checkpoint") from None
    state = ckpt["state_dict"]
    for prefix, net in nets.items():
        sub = {k[len(prefix) + 1:]: v for k, v in state.items() if k.startswith(prefix + ".")}
        missing, unexpected = net.load_state_dict(sub, strict=False)
        if missing or unexpected:
            raise InputError(f"{what}={path}: weights do not fit the network it describes ({prefix}: missing "
                             f"{missing[:3]}, unexpected {unexpected[:3]})")
        net.eval()
    return nets, hp, state


def load_recnn(path: str | Path, *, what: str = "recnn_checkpoint") -> tuple[nn.Module, dict[str, Any]]:
    """``(the RecNN, its task's hyperparameters)`` of a RecNN checkpoint (:func:`load_nets`; no task built).

    Example:
        >>> recnn, hp = load_recnn("runs/recnn/checkpoints/last.ckpt")  # doctest: +SKIP
    """
    nets, hp, _ = load_nets(path, expect="RecNNTask", what=what)
    return nets["net"], hp


# ------------------------------------------------------------------------------------------------
# the product's checkpoints


@dataclass
class IMSNets:
    """The product's networks from an IMS checkpoint (:func:`load_ims_nets`), no training task built.

    Attributes:
        head: the :class:`~imls_lightning.models.ims.IMSMaskHead` (generator, ``P``, ``valid``, target,
            trained mean): view -> IM at a mean value.
        decoder: the IML decoder ``(pr_c_image, im) -> C-Image`` (fine-tuned on the IMS's masks when
            the IMS was trained with ``decoder_lr > 0``).
        recnn: the RecNN ``C-Image -> FR-Image`` (the checkpoint's or a replacement), or None.
        pattern: the sampling pattern; hparams: the IMS checkpoint's hyperparameters (scene, renderer,
            provenance); path: the checkpoint file.
    """

    head: IMSMaskHead
    decoder: nn.Module
    recnn: nn.Module | None
    pattern: SamplingPattern
    hparams: dict[str, Any]
    path: str | None = None

    @property
    def target(self) -> str:
        return self.head.target

    @property
    def trained_mean(self) -> float:
        return float(self.head.trained_mean)


def load_ims_nets(ims_checkpoint: str | Path, recnn_checkpoint: str | Path | None = None, *,
                  keys: tuple[str, str] = ("ims_checkpoint", "recnn_checkpoint")) -> IMSNets:
    """The product's networks of an IMS checkpoint (:class:`IMSNets`), and when given a RecNN checkpoint
    that replaces the RecNN stored in it (checked to use the same sampling pattern and resolution).
    Only the generator, the IML decoder and the RecNN are built (:func:`load_nets`).

    Raises:
        InputError: a missing or wrong checkpoint, or a RecNN of another sampling pattern.

    Example:
        >>> nets = load_ims_nets("ims.ckpt")        # doctest: +SKIP
        >>> nets.head(view, share=0.4).shape          # doctest: +SKIP
        torch.Size([1, 1, 128, 128])
    """
    nets, hp, state = load_nets(ims_checkpoint, expect="IMSTask", what=keys[0])
    pattern = build_pattern(to_plain(hp["pattern"]), int(hp["fr_size"]))
    iml = hp["iml_hparams"]
    if "iml.sampling.P" not in state:
        raise InputError(f"{keys[0]}={ims_checkpoint}: holds no rank pattern (iml.sampling.P); not an IMS checkpoint of this project")
    # the IML's normalization settings, as its IMLNet validates them
    head = IMSMaskHead(nets["generator"], state["iml.sampling.P"].float(), pattern.valid, str(hp.get("target", "im")),
                       trained_mean=check_mean(iml.get("mean", 0.1)), lower=float(iml.get("lower", 0.0))).eval()
    recnn = nets.get("recnn")
    if recnn_checkpoint:
        recnn, rh = load_recnn(recnn_checkpoint, what=keys[1])
        check_same_pattern(rh, pattern, key=keys[1], path=recnn_checkpoint, network="RecNN",
                           against="the IMS/IML", hint="use a RecNN trained on the IMS's pattern and data.resolution")
    return IMSNets(head, nets["iml.decoder"], recnn, pattern, hp, str(ims_checkpoint))


@dataclass(frozen=True)
class Product:
    """The product as it runs from an IMS checkpoint (:func:`load_product`): its networks and the
    :class:`~imls_lightning.core.operating_point.OperatingPoint` they run at (``None``: the trained share), from
    ``record`` (the evaluation's, :mod:`~imls_lightning.inference.operating_point`) or as asked."""

    nets: IMSNets
    point: Any = None
    record: Any = None

    @property
    def mean(self) -> float | None:
        """The point's share as the paper's mean value ``u`` (``None``: the trained one)."""
        return None if self.point is None else self.point.u

    @property
    def lift(self) -> bool:
        return self.point is not None and self.point.lift


def load_product(ims_checkpoint: str | Path, recnn_checkpoint: str | Path | None = None, *,
                 share: float | str | None = None, share_key: str = "share",
                 keys: tuple[str, str] = ("ims_checkpoint", "recnn_checkpoint")) -> Product:
    """:func:`load_ims_nets` and the operating point to run at: by default the one the evaluation recorded for this
    checkpoint (its share, bands, lift, sharpness and object floor), else the trained share (one line on stderr says
    which); ``share`` (a number in ``[0.01, 1]``, or ``"trained"``) overrides it
    (:func:`~imls_lightning.inference.operating_point.point_to_run`; ``share_key``: the setting it came from, for
    messages). The networks are the checkpoint's as they
    are: the point is applied by whoever renders with them (:class:`~imls_lightning.inference.pipeline.IMLSRenderer`,
    the export's ``im`` network).

    Example:
        >>> p = load_product("ims.ckpt")                   # doctest: +SKIP
        >>> p.point, p.record                              # doctest: +SKIP
        (OperatingPoint(share=0.52, ...), ORPRecord(...))
    """
    from .operating_point import point_to_run

    nets = load_ims_nets(ims_checkpoint, recnn_checkpoint, keys=keys)
    point, record = point_to_run(ims_checkpoint, share, target=nets.target, trained_mean=nets.trained_mean, key=share_key)
    return Product(nets, point, record)


def renderer_for(hparams: Mapping[str, Any], scene=None, renderer=None, renderer_cfg=None):
    """``renderer`` if given, else one made for ``scene`` (+ ``renderer_cfg``), by default the scene and
    renderer config an IMS checkpoint with hyperparameters ``hparams`` was trained on (stored in it).

    Raises:
        InputError: no renderer or scene given and the checkpoint stores no scene.
    """
    if renderer is not None:
        return renderer
    if scene is None and hparams.get("scene"):
        from data_gen.scenes import build_scene

        scene = build_scene(hparams["scene"])
        if renderer_cfg is None:
            renderer_cfg = hparams.get("renderer")
    if scene is None:
        raise InputError("ims_checkpoint stores no scene (trained before scenes were recorded): pass scene= or renderer=")
    from imls_lightning.render import make_renderer

    return make_renderer(scene, renderer_cfg)


def load_ims_and_recnn(ims_checkpoint: str, recnn_checkpoint: str | None = None, *,
                       keys: tuple[str, str] = ("ims_checkpoint", "recnn_checkpoint")):
    """``(IMSTask, RecNN module or None)``: the IMS checkpoint's whole task (for evaluations that need
    its IML encoder too; the product needs only :func:`load_ims_nets`) and, when given, a RecNN
    checkpoint that replaces the RecNN stored in it (checked to use the same sampling pattern and
    resolution; the bare RecNN, :func:`load_recnn`).

    Args:
        ims_checkpoint: a ``.ckpt`` of ``model=ims``.
        recnn_checkpoint: a ``.ckpt`` of ``model=recnn``, or None.
        keys: the settings the two paths came from, for messages.

    Raises:
        InputError: a missing or wrong checkpoint, or a RecNN of another sampling pattern.

    Example:
        >>> task, recnn = load_ims_and_recnn("ims.ckpt")  # doctest: +SKIP
    """
    task = load_task(ims_checkpoint, expect="IMSTask", what=keys[0])
    if not recnn_checkpoint:
        return task, None
    recnn, rh = load_recnn(recnn_checkpoint, what=keys[1])
    check_same_pattern(rh, task.pattern, key=keys[1], path=recnn_checkpoint, network="RecNN",
                       against="the IMS/IML", hint="use a RecNN trained on the IMS's pattern and data.resolution")
    return task, recnn
