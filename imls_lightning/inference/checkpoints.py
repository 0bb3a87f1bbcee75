"""Loading task checkpoints: :func:`load_task` rebuilds the task a checkpoint names, and
:func:`load_ims_and_recnn` the product's pair; the cross-checks of
:mod:`~imls_lightning.inference.checkpoint_checks` ("does this checkpoint fit what it is used with")
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
    data_gen.errors.InputError: checkpoint names task 'Net': expected one of ['IMLTask', 'IMSTask', 'LASTask', 'RecNNTask']
"""
from __future__ import annotations

import importlib
from pathlib import Path

from data_gen.errors import InputError

from ..config import load_checkpoint
from ..tasks.base import checkpoint_task_name
from .checkpoint_checks import (
    check_resolution,
    check_same_pattern,
    check_trained_on,
    config_diff,
    require_pim_target,
    require_recnn,
    same_pattern,
)

__all__ = ["TASKS", "task_class", "task_path", "load_task", "load_ims_and_recnn", "same_pattern", "check_same_pattern",
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
# the product's checkpoints


def load_ims_and_recnn(ims_checkpoint: str, recnn_checkpoint: str | None = None, *,
                       keys: tuple[str, str] = ("ims_checkpoint", "recnn_checkpoint")):
    """``(IMSTask, RecNN module or None)``: the IMS checkpoint and, when given, a RecNN checkpoint
    that replaces the RecNN stored in it (checked to use the same sampling pattern and resolution).

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
    rt = load_task(recnn_checkpoint, expect="RecNNTask", what=keys[1])
    check_same_pattern(rt.hparams, task.pattern, key=keys[1], path=recnn_checkpoint, network="RecNN",
                       against="the IMS/IML", hint="use a RecNN trained on the IMS's pattern and data.resolution")
    return task, rt.net
