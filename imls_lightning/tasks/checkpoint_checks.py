"""Does a checkpoint fit what it is used with: the cross-checks on a checkpoint's hyperparameters,
their one home.

A network trained by this project is only meaningful with the sampling pattern, resolution, scene
and renderer it was trained on; a RecNN, IML, IMS or LAS checkpoint handed to another run, to the
evaluation, the exporter, the viewer or the ORP search is checked here, before anything is rendered
or trained. Every check raises a one-line :class:`~imls_lightning.base.errors.InputError` that names the
setting the checkpoint came from (``key``, and its path where known), what disagrees, and what to
pass instead.

Checks take the checkpoint's *hyperparameters* (``task.hparams`` or the ``hyper_parameters`` of
:func:`~imls_lightning.base.config.load_checkpoint`), so they also run where no network is built (a
task's constructor, a report that only reads the checkpoint). They import no task: the tasks and the data
module's labels use them, and :mod:`~imls_lightning.inference.checkpoints`, which loads the tasks, re-exports them.

Example:
    >>> from imls_lightning.core.patterns import build_pattern
    >>> p = build_pattern({"kind": "downsample", "factor": 2}, 8)
    >>> same_pattern({"pattern": {"kind": "downsample", "factor": 2}, "fr_size": 8}, p)
    True
    >>> check_resolution({"fr_size": 16}, 8, key="checkpoints.las", network="LAS")
    Traceback (most recent call last):
    ...
    imls_lightning.base.errors.InputError: checkpoints.las: the LAS was trained at data.resolution=16, this run uses 8; pass data.resolution=16 (and the data group it was trained with)
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from imls_lightning.base.errors import InputError
from imls_lightning.render import renderer_pixel_settings

from ..base.config import to_plain
from ..core.patterns import SamplingPattern, build_pattern

__all__ = ["same_pattern", "check_same_pattern", "check_resolution", "check_trained_on", "require_recnn",
           "require_pim_target", "config_diff"]


def _where(key: str, path: Any = None) -> str:
    return key if path is None else f"{key}={path}"


# ------------------------------------------------------------------------------------------------
# pattern and resolution


def _pattern_of(hp: Mapping) -> SamplingPattern | None:
    """The pattern ``hp`` was trained on, or None when it cannot be built (old or foreign hparams)."""
    try:
        return build_pattern(to_plain(hp["pattern"]), int(hp["fr_size"]))
    except (KeyError, TypeError, ValueError, InputError):
        return None


def same_pattern(hp: Mapping, pattern: SamplingPattern) -> bool:
    """Whether hyperparameters ``hp`` (``pattern`` node + ``fr_size``) describe ``pattern``: the
    same resolution and the same pixels (:meth:`SamplingPattern.fingerprint`).

    Example:
        >>> from imls_lightning.core.patterns import build_pattern
        >>> p = build_pattern({"kind": "downsample", "factor": 2}, 8)
        >>> same_pattern({"pattern": {"kind": "downsample", "factor": 2}, "fr_size": 16}, p)
        False
    """
    theirs = _pattern_of(hp)
    return theirs is not None and theirs.fr_size == pattern.fr_size and theirs.fingerprint() == pattern.fingerprint()


def check_same_pattern(hp: Mapping, pattern: SamplingPattern, *, key: str, path: Any = None, network: str = "network",
                       against: str = "this run", hint: str = "use one trained on the same pattern and data.resolution") -> None:
    """Raise unless ``hp`` was trained on ``pattern`` (:func:`same_pattern`).

    Args:
        hp: the checkpoint's hyperparameters (``pattern``, ``fr_size``).
        pattern: what it is used with.
        key, path: the setting the checkpoint came from (path: None where unknown).
        network: its name in the message (``"RecNN"``, ``"IML"``).
        against: who uses ``pattern`` (``"this run"``, ``"the IMS"``).
        hint: what to do instead.

    Raises:
        InputError: ``key=path: the RecNN was trained on another sampling pattern or resolution
            (A at 64^2; the IML: B at 64^2); hint``.
    """
    if same_pattern(hp, pattern):
        return
    theirs = _pattern_of(hp)
    told = theirs.summary() if theirs is not None else f"pattern={hp.get('pattern')}"
    raise InputError(
        f"{_where(key, path)}: the {network} was trained on another sampling pattern or resolution "
        f"({told} at {hp.get('fr_size')}^2; {against}: {pattern.summary()} at {pattern.fr_size}^2); {hint}"
    )


def check_resolution(hp: Mapping, fr_size: int, *, key: str, path: Any = None, network: str = "network",
                     against: str = "this run uses", hint: str | None = None) -> None:
    """Raise unless ``hp["fr_size"]`` (the trained ``data.resolution``) is ``fr_size``.

    Args:
        hp: the checkpoint's hyperparameters.
        fr_size: the resolution it is used at.
        key, path, network: as :func:`check_same_pattern`.
        against: the words before ``fr_size`` (``"the cache ... holds"``).
        hint: what to do instead; default: pass the trained resolution.

    Example:
        >>> check_resolution({"fr_size": 64}, 64, key="checkpoints.las")
    """
    its = int(hp["fr_size"])
    if its != int(fr_size):
        hint = hint or f"pass data.resolution={its} (and the data group it was trained with)"
        raise InputError(f"{_where(key, path)}: the {network} was trained at data.resolution={its}, {against} {fr_size}; {hint}")


# ------------------------------------------------------------------------------------------------
# what the IMS checkpoint carries


def require_recnn(recnn, *, key: str, path: Any = None, recnn_key: str = "recnn_checkpoint"):
    """``recnn`` itself; raises when it is None (an IMS on a standalone IML stores no RecNN).

    Raises:
        InputError: ``key=path: carries no RecNN (its IML was trained standalone); pass recnn_key=<RecNN .ckpt>``.
    """
    if recnn is None:
        raise InputError(f"{_where(key, path)}: carries no RecNN (its IML was trained standalone); pass {recnn_key}=<RecNN .ckpt>")
    return recnn


def require_pim_target(hp: Mapping, *, key: str = "ims_checkpoint", path: Any = None, what: str = "rescaling its mask") -> None:
    """Raise unless the IMS of ``hp`` regresses PIM' (``target="pim"``): only that mask can be
    rescaled to another mean value (a binary IM cannot).

    Example:
        >>> require_pim_target({"target": "im"}, what="the adaptive mean")
        Traceback (most recent call last):
        ...
        imls_lightning.base.errors.InputError: ims_checkpoint: its IMS was trained with model.target=im; the adaptive mean needs an IMS trained with model.target=pim
    """
    target = hp.get("target")
    if target != "pim":
        raise InputError(f"{_where(key, path)}: its IMS was trained with model.target={target}; {what} needs an IMS trained with model.target=pim")


# ------------------------------------------------------------------------------------------------
# scene and renderer


def config_diff(a: Any, b: Any, prefix: str = "") -> list[str]:
    """Dotted keys where two plain configs differ (paths to the same file count as equal).

    Example:
        >>> config_diff({"a": 1, "b": {"c": 2}}, {"a": 1, "b": {"c": 3}})
        ['b.c']
    """
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        out: list[str] = []
        for k in sorted(set(a) | set(b), key=str):
            out += config_diff(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else str(k))
        return out
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b):
        return [] if all(not config_diff(x, y) for x, y in zip(a, b)) else [prefix]
    if a == b:
        return []
    if isinstance(a, str) and isinstance(b, str) and prefix.endswith("path"):
        try:
            if Path(a).expanduser().resolve() == Path(b).expanduser().resolve():
                return []
        except OSError:
            pass
    return [prefix]


def check_trained_on(hp: Mapping, scene: Any, renderer: Any, *, key: str, path: Any = None,
                     against: str = "this run", escape: str = "") -> None:
    """Raise unless ``scene`` and ``renderer`` (configs) are those the checkpoint records in ``hp``
    (``scene``, ``renderer``); a checkpoint that records none passes. Renderers are compared on
    the settings that change pixels only.

    Args:
        hp: the checkpoint's hyperparameters (an IMS records its scene and renderer).
        scene, renderer: the configs of this run.
        key, path: the setting the checkpoint came from.
        against: who uses them (``"this evaluation"``).
        escape: appended to the hint, e.g. ``"or allow_mismatch=true to evaluate it anyway"``.

    Raises:
        InputError: ``key=path: trained on scene=A, this run uses scene=B (scene differs in ...); pass scene=A``.
    """
    tail = f", {escape}" if escape else ""
    trained_scene, trained_renderer = hp.get("scene"), hp.get("renderer")
    if trained_scene:
        diff = config_diff(trained_scene, to_plain(scene))
        if diff:
            name = trained_scene.get("name", "?")
            raise InputError(
                f"{_where(key, path)}: trained on scene={name}, {against} uses scene={(scene or {}).get('name')} "
                f"(scene differs in {', '.join(diff[:3])}{', ...' if len(diff) > 3 else ''}); pass scene={name} "
                f"(with the overrides it was trained with){tail}"
            )
    if trained_renderer:
        a, b = renderer_pixel_settings(trained_renderer), renderer_pixel_settings(to_plain(renderer))
        if a != b:
            raise InputError(
                f"{_where(key, path)}: trained with renderer={a.get('name')}, {against} uses renderer={b.get('name')} "
                f"(differs in {', '.join(config_diff(a, b)[:3])}); pass renderer={a.get('name')}{tail}"
            )
