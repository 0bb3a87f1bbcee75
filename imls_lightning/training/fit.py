"""The body of ``python -m imls_lightning.train``: :func:`train` fits one configured model.

Build the task (``instantiate`` of the ``model`` node: :func:`build_task`) and the DataModule, run
the Trainer, test the best checkpoint on the test trajectory and write the run's ``result.json``.
Runs live in ``runs/<model>-<recnn>-<scene>-<settings hash>/``: running the same settings again
resumes from ``last.ckpt``, or returns at once when that run had finished; a larger
``trainer.max_epochs`` than a finished run trained to continues it from its ``last.ckpt``
(:func:`epochs_to_extend`).

The command line itself is :mod:`imls_lightning.train` (a thin entry point); this module is kept
apart from it so that the ORP job (:mod:`imls_lightning.orp`), which trains through :func:`train`
and is dispatched to by the entry point, does not make an import cycle.
"""
from __future__ import annotations

import json
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf

from data_gen.scenes import register_resolvers as register_scene_resolvers
from imls_lightning.base.errors import InputError

from .callbacks import ChunkTimer, ResumableCSVLogger, TrainingViews, set_aside_metrics
from ..base.config import checkpoint_problem, load_checkpoint, register_resolvers, to_plain

register_resolvers()
# the scene presets' resolvers too: Hydra resolves hydra.run.dir (the run's name holds the scene's, which scene=file
# takes from the file: ${imls_volume_name:...}) before the task runs, so `train scene=file` needs them at import
register_scene_resolvers()

RESULT_FILE = "result.json"
_UNSET = object()  # train(): the checkpoint to resume from is not chosen yet


class TrainingUnfinished(RuntimeError):
    """A fit stopped at the end of its chunk (``chunk_minutes``); the same command continues it."""

    #: the train CLI's exit status for it (pipelines stop there and say how to go on)
    EXIT_CODE = 3


def _callbacks(cfg: DictConfig) -> list[L.Callback]:
    return [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c is not None and "_target_" in c]


def chunk_minutes(cfg: DictConfig) -> float | None:
    """``chunk_minutes``: the wall time one invocation trains for (null: the whole schedule).

    Raises:
        InputError: not a positive number.
    """
    value = cfg.get("chunk_minutes")
    if value is None:
        return None
    try:
        minutes = float(value)
        if isinstance(value, bool) or not math.isfinite(minutes) or minutes <= 0:
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"chunk_minutes={value!r}: expected a positive number of minutes (null: train the whole schedule)") from None
    return minutes


def _loggers(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("logger") or {}).values() if c is not None and "_target_" in c]


def _warn(message: str) -> None:
    print("warning: " + " ".join(str(message).split()), file=sys.stderr, flush=True)


def _resume_path(cfg: DictConfig, run_dir: Path, task=None) -> str | None:
    """The checkpoint to resume from: ``resume=auto`` takes the run's ``last.ckpt`` when it is
    intact, else the newest intact checkpoint of the run (or none: training starts over), with a
    one-line warning; ``resume=<path>`` must be an intact checkpoint file and, given the ``task``,
    one of the model being trained (:func:`check_resume_checkpoint`)."""
    resume = str(cfg.get("resume", "auto"))
    if resume == "never":
        return None
    if resume == "auto":
        ckdir = run_dir / "checkpoints"
        last = ckdir / "last.ckpt"
        if not last.is_file():
            return None
        problem = checkpoint_problem(last)
        if problem is None:
            return str(last)
        others = sorted((p for p in ckdir.glob("*.ckpt") if p != last), key=lambda p: p.stat().st_mtime_ns, reverse=True)
        good = next((p for p in others if checkpoint_problem(p) is None), None)
        if good is not None:
            _warn(f"{last}: {problem}; resuming from the newest intact checkpoint {good}")
            return str(good)
        _warn(f"{last}: {problem}; no intact checkpoint in {ckdir}, training starts over")
        return None
    if not Path(resume).expanduser().is_file():
        raise InputError(f"resume={resume}: checkpoint not found (use 'auto', 'never' or a .ckpt path)")
    problem = checkpoint_problem(resume)
    if problem is not None:
        raise InputError(f"resume={resume}: {problem}")
    if task is not None:
        check_resume_checkpoint(resume, task)
    return str(Path(resume).expanduser())


def check_resume_checkpoint(path: str, task) -> None:
    """``resume=<path>``: an intact Lightning checkpoint of the same task whose weights fit ``task``.

    Raises:
        InputError: one line naming ``resume=`` and what is wrong.
    """
    ckpt = load_checkpoint(path, what="resume")
    name = ckpt.get("imls_task")
    if name != type(task).__name__:
        raise InputError(f"resume={path}: is a {name or 'foreign'} checkpoint, this run trains a {type(task).__name__} (model={cfg_model_name(task)})")
    own = task.state_dict()
    theirs = ckpt["state_dict"]
    optional = task.optional_state_prefixes() if hasattr(task, "optional_state_prefixes") else ()
    missing = [k for k in own if k not in theirs and not k.startswith(optional)]
    unexpected = [k for k in theirs if k not in own]
    shapes = [k for k in own if k in theirs and hasattr(theirs[k], "shape") and tuple(theirs[k].shape) != tuple(own[k].shape)]
    if missing or unexpected or shapes:
        raise InputError(
            f"resume={path}: its weights do not fit the network configured here (another recnn/model setting?"
            f" missing {missing[:2]}, unexpected {unexpected[:2]}, other shapes {shapes[:2]})"
        )
    if "optimizer_states" not in ckpt or "loops" not in ckpt:
        raise InputError(f"resume={path}: holds weights only (no optimizer or loop state) and cannot resume training")


def cfg_model_name(task) -> str:
    return {"RecNNTask": "recnn", "IMLTask": "iml", "IMSTask": "ims", "LASTask": "las"}.get(type(task).__name__, "?")


def _max_epochs(cfg: DictConfig) -> int | None:
    value = cfg.trainer.get("max_epochs")
    return int(value) if value is not None and int(value) >= 0 else None


def trained_epochs(result: dict[str, Any]) -> int | None:
    """The epoch limit a finished run trained to: its ``max_epochs`` (runs before it was recorded: ``epochs``)."""
    value = result.get("max_epochs", result.get("epochs"))
    return int(value) if isinstance(value, (int, float)) else None


def epochs_to_extend(result: dict[str, Any], cfg: DictConfig) -> int | None:
    """``trainer.max_epochs`` when it asks a finished run for more epochs than it trained, else None.

    A run that stopped before its limit (early stopping, or ``trainer.max_time``: see :func:`stop_reason`)
    is finished at any limit: it would stop again, and a time-boxed run trained on a GPU machine must not
    go on training on the CPU that evaluates it. Fewer epochs than trained reuse the run as it is: its
    best checkpoint was chosen over all of them.

    Example:
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"trainer": {"max_epochs": 10}})
        >>> epochs_to_extend({"epochs": 3, "max_epochs": 3}, cfg), epochs_to_extend({"epochs": 10}, cfg)
        (10, None)
    """
    wanted, done = _max_epochs(cfg), trained_epochs(result)
    if wanted is None or done is None or result.get("stopped_early"):
        return None
    return wanted if wanted > done else None


def stop_reason(trainer: L.Trainer) -> str | None:
    """Why a fit ended before ``trainer.max_epochs``: ``"early_stopping"``, ``"max_time"`` or None.

    ``trainer.max_time`` (Lightning's :class:`~lightning.pytorch.callbacks.Timer`) time-boxes a stage,
    e.g. the training of a paper-scale pair on a lent GPU machine.
    """
    if getattr(trainer.early_stopping_callback, "stopped_epoch", 0) > 0:
        return "early_stopping"
    for cb in trainer.callbacks:
        if isinstance(cb, L.pytorch.callbacks.Timer):
            remaining = cb.time_remaining()
            if remaining is not None and remaining <= 0:
                return "max_time"
    return None


def cache_problem(recorded, cfg: DictConfig) -> str | None:
    """Why a finished run must not be reused for ``cfg``, or None: the caches it recorded against the keys these
    settings give now. A run's directory is the hash of its settings, not of the volume's voxels, so a volume
    replaced at the same path or a procedural generator that changed would otherwise be served the old networks.
    Building the scene to compute the keys reads the volume (its fingerprint), never renders."""
    now = build_datamodule(cfg, get_class(cfg.model._target_)).cache_keys()
    if list(recorded) == now:
        return None
    return f"it trained on cache {', '.join(map(str, recorded))}, these settings now give {', '.join(now)} (the volume or its rendering changed)"


def build_task(cfg: DictConfig) -> L.LightningModule:
    """The task of ``cfg.model``: ``hydra.utils.instantiate`` of that node (``_target_``: the task
    class; every model setting, with its one default, lives in ``conf/model/<name>.yaml``), called
    with the task's ``config_context(cfg)``: what comes from outside the node (the pattern,
    ``data.resolution``, the networks of input checkpoints, ...; see
    :class:`~imls_lightning.tasks.base.ImlsTask`).

    Raises:
        InputError: one line, from the context (a missing or mismatched checkpoint) or the task.
    """
    task_cls = get_class(cfg.model._target_)
    context = task_cls.config_context(cfg)
    # the context goes to the call, not into instantiate(): merged into the node, tensors would be
    # copied into OmegaConf and nested `_target_`s (recnn.net) built; and the task's InputError
    # reaches the user as it is, not wrapped in Hydra's InstantiationException
    return instantiate(cfg.model, _partial_=True, _convert_="all")(**context)


def build_datamodule(cfg: DictConfig, task_cls) -> L.LightningDataModule:
    from ..data.datamodule import ImlsDataModule

    extra = task_cls.datamodule_kwargs(cfg) if hasattr(task_cls, "datamodule_kwargs") else {}
    # one switch for the run's bars: without it a pipeline's log (trainer.enable_progress_bar=false) still got the
    # cache's and the labels' tqdm redraws, thousands of them for an IMS's 1,620 views
    progress = bool(OmegaConf.select(cfg, "trainer.enable_progress_bar", default=True))
    return ImlsDataModule(scene=cfg.scene, data=cfg.data, renderer=cfg.renderer, pattern=cfg.pattern,
                          progress=progress, **extra)


def train(cfg: DictConfig) -> dict[str, Any]:
    """Fit (or resume, or reuse) the configured model; returns the run's result record."""
    run_dir = Path(cfg.paths.output_dir)
    result_file = run_dir / RESULT_FILE
    chunk = chunk_minutes(cfg)
    fast = bool(cfg.trainer.get("fast_dev_run", False))
    restart, resume_from = False, _UNSET
    if str(cfg.get("resume", "auto")) == "auto" and result_file.is_file() and not fast:
        try:
            result = json.loads(result_file.read_text())
            best = str(result.get("best_checkpoint", ""))
        except (OSError, ValueError, AttributeError):
            result, best = None, ""
        if isinstance(result, dict) and result.get("unfinished"):
            # a chunk's record, or a continuation's (interrupted or not): the run goes on from its last.ckpt, and
            # the best checkpoint it names may since have given way to a better epoch's (the top-k keeps one)
            resume_from = _resume_path(cfg, run_dir)
            problem = None if resume_from else f"no intact checkpoint to continue from in {run_dir / 'checkpoints'}"
        else:
            problem = checkpoint_problem(best) if best else f"{RESULT_FILE} is damaged"
        if problem is None and result.get("caches") is not None:
            problem = cache_problem(result["caches"], cfg)
        more = epochs_to_extend(result, cfg) if result is not None and problem is None else None
        if result is not None and problem is None and result.get("unfinished"):
            more = _max_epochs(cfg) if _max_epochs(cfg) is not None else -1  # the chunks go on to the schedule's end
        if result is not None and problem is None and more is None:
            print(f"[train] {run_dir} already finished; reusing it (resume=never retrains)", flush=True)
            return result
        if more is not None:
            # trainer limits are not part of the run's identity, so a longer schedule continues the
            # finished run from its last.ckpt instead of returning the shorter one as if it were asked for
            done = (f"was continuing after {result.get('epochs')} epochs" if result.get("stopped_by") == "continuing" else
                    f"trained a chunk ({result.get('epochs')} epochs)" if result.get("unfinished") else f"finished {trained_epochs(result)} epochs")
            print(f"[train] {run_dir} {done}; continuing to trainer.max_epochs={more}", flush=True)
            if not result.get("unfinished"):
                # from here the record is a run in progress: interrupted, it must continue from last.ckpt, not be
                # judged by a best checkpoint the continuation may replace (it was trained again from the start)
                from imls_lightning.base.atomic import atomic_json

                atomic_json(result_file, {**result, "unfinished": True, "stopped_by": "continuing"}, indent=2, sort_keys=False)
        else:
            # never trust a finished run whose best checkpoint is gone or damaged, or that trained on other pixels
            state = "had trained part of its schedule" if isinstance(result, dict) and result.get("unfinished") else "had finished"
            culprit = "" if isinstance(result, dict) and result.get("unfinished") else f"{best or RESULT_FILE}: "
            _warn(f"{run_dir} {state}, but {culprit}{problem}; training it again from the start")
            result_file.unlink(missing_ok=True)
            restart = True

    # resume=<not a checkpoint> is refused before Lightning's first line (the seed, the devices);
    # whether it fits the model needs the task, built after seeding, still before the Trainer
    ckpt_path = None if fast or restart else (_resume_path(cfg, run_dir) if resume_from is _UNSET else resume_from)
    L.seed_everything(int(cfg.seed), workers=True)
    task = build_task(cfg)
    resume = str(cfg.get("resume", "auto"))
    if ckpt_path and resume not in ("auto", "never"):
        check_resume_checkpoint(resume, task)
    datamodule = build_datamodule(cfg, type(task))
    timer = ChunkTimer(chunk) if chunk is not None and not fast else None
    views = TrainingViews(OmegaConf.select(cfg, "data.seed", default=0) or 0,
                          OmegaConf.select(cfg, "data.num_views", default=0) or 0)  # which views it trained on
    trainer: L.Trainer = instantiate(cfg.trainer, callbacks=_callbacks(cfg) + [views] + ([timer] if timer else []),
                                     logger=_loggers(cfg) or False)

    if ckpt_path:
        print(f"[train] resuming from {ckpt_path}", flush=True)
    else:
        # a run that starts (over) keeps the log of an earlier attempt beside its own
        for lg in trainer.loggers:
            if isinstance(lg, ResumableCSVLogger):
                set_aside_metrics(Path(lg.log_dir))
    t0 = time.perf_counter()
    trainer.fit(task, datamodule=datamodule, ckpt_path=ckpt_path, weights_only=True)  # tensors and plain types only
    minutes = (time.perf_counter() - t0) / 60.0
    if trainer.interrupted:
        raise InputError(f"training interrupted; run the same command again to resume from {run_dir / 'checkpoints' / 'last.ckpt'}")

    ckpt_cb = trainer.checkpoint_callback
    best = getattr(ckpt_cb, "best_model_path", "") if ckpt_cb is not None else ""
    if not best:
        # fast_dev_run (or checkpointing off): keep the weights anyway, so stages can be chained
        best = str(run_dir / "checkpoints" / ("fast_dev_run.ckpt" if fast else "final.ckpt"))
        trainer.save_checkpoint(best, weights_only=False)  # the whole state: it may be resumed
    score = getattr(ckpt_cb, "best_model_score", None) if ckpt_cb is not None else None
    unfinished = timer is not None and timer.stopped
    test_metrics: dict[str, float] = {}
    if cfg.get("test", True) and not unfinished:
        ckpt_for_test = None if fast or not getattr(ckpt_cb, "best_model_path", "") else "best"
        out = trainer.test(task, datamodule=datamodule, ckpt_path=ckpt_for_test, verbose=False, weights_only=True)
        test_metrics = {k: float(v) for k, v in (out[0] if out else {}).items()}

    stopped_by = "chunk" if unfinished else stop_reason(trainer)
    result = {
        "best_checkpoint": str(Path(best).resolve()),
        "best_score": float(score) if score is not None and math.isfinite(float(score)) else None,
        "monitor": str(cfg.model.monitor),
        "epochs": int(trainer.current_epoch),
        "max_epochs": _max_epochs(cfg),
        "stopped_early": stopped_by not in (None, "chunk"),
        "stopped_by": stopped_by,
        "unfinished": unfinished,
        "train_minutes": round(minutes, 3),
        "test": test_metrics,
        "config": to_plain(OmegaConf.masked_copy(cfg, ["scene", "data", "renderer", "pattern", "recnn", "model", "iml", "seed"])),
        # the caches it trained on, by content: a later reuse is checked against them (cache_problem)
        "caches": datamodule.cache_keys(),
    }
    if trainer.is_global_zero and not fast:
        from imls_lightning.base.atomic import atomic_json

        atomic_json(result_file, result, indent=2, sort_keys=False)
    if unfinished:
        raise TrainingUnfinished(f"{run_dir}: trained a chunk of chunk_minutes={chunk:g} ({result['epochs']} of "
                                 f"{result['max_epochs']} epochs); run the same command again to continue")
    return result


def remove_if_only_hydra(run_dir: Path) -> bool:
    """Remove a run folder that holds nothing but what Hydra put there when the job started
    (``.hydra/`` and the job's empty log): a failed run leaves no empty run folder behind."""
    try:
        names = {p.name for p in run_dir.iterdir()}
    except OSError:
        return False
    logs = {p.name for p in run_dir.glob("*.log") if p.is_file() and p.stat().st_size == 0}
    if not names or names - logs - {".hydra"}:
        return False
    shutil.rmtree(run_dir, ignore_errors=True)
    return True
