"""Train any model of the project: ``python -m imls_lightning.train model=... recnn=... scene=...``.

Thin on purpose: compose the config, build the DataModule and the task (``model._target_``), run
the Trainer, test the best checkpoint on the test trajectory, and print the best checkpoint's path
as the last line. Runs live in ``runs/<model>-<recnn>-<scene>-<settings hash>/``: running the same
settings again resumes from ``last.ckpt``, or returns at once when that run had finished.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf

from data_gen.errors import InputError, cli_errors

from .config import register_resolvers, to_plain

register_resolvers()

RESULT_FILE = "result.json"


def _callbacks(cfg: DictConfig) -> list[L.Callback]:
    return [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c is not None and "_target_" in c]


def _loggers(cfg: DictConfig) -> list:
    return [instantiate(c) for c in (cfg.get("logger") or {}).values() if c is not None and "_target_" in c]


def _resume_path(cfg: DictConfig, run_dir: Path) -> str | None:
    resume = str(cfg.get("resume", "auto"))
    if resume == "never":
        return None
    if resume == "auto":
        last = run_dir / "checkpoints" / "last.ckpt"
        return str(last) if last.is_file() else None
    if not Path(resume).is_file():
        raise InputError(f"resume={resume}: checkpoint not found (use 'auto', 'never' or a .ckpt path)")
    return resume


def build_datamodule(cfg: DictConfig, task_cls) -> L.LightningDataModule:
    from .data import ImlsDataModule

    extra = task_cls.datamodule_kwargs(cfg) if hasattr(task_cls, "datamodule_kwargs") else {}
    return ImlsDataModule(scene=cfg.scene, data=cfg.data, renderer=cfg.renderer, pattern=cfg.pattern, **extra)


def train(cfg: DictConfig) -> dict[str, Any]:
    """Fit (or resume, or reuse) the configured model; returns the run's result record."""
    run_dir = Path(cfg.paths.output_dir)
    result_file = run_dir / RESULT_FILE
    fast = bool(cfg.trainer.get("fast_dev_run", False))
    if str(cfg.get("resume", "auto")) == "auto" and result_file.is_file() and not fast:
        result = json.loads(result_file.read_text())
        if Path(result.get("best_checkpoint", "")).is_file():
            print(f"[train] {run_dir} already finished; reusing it (resume=never retrains)", flush=True)
            return result

    L.seed_everything(int(cfg.seed), workers=True)
    task_cls = get_class(cfg.model._target_)
    task = task_cls.from_config(cfg) if hasattr(task_cls, "from_config") else instantiate(cfg.model)
    datamodule = build_datamodule(cfg, task_cls)
    trainer: L.Trainer = instantiate(cfg.trainer, callbacks=_callbacks(cfg), logger=_loggers(cfg) or False)

    ckpt_path = None if fast else _resume_path(cfg, run_dir)
    if ckpt_path:
        print(f"[train] resuming from {ckpt_path}", flush=True)
    t0 = time.perf_counter()
    trainer.fit(task, datamodule=datamodule, ckpt_path=ckpt_path)
    minutes = (time.perf_counter() - t0) / 60.0
    if trainer.interrupted:
        raise InputError(f"training interrupted; run the same command again to resume from {run_dir / 'checkpoints' / 'last.ckpt'}")

    ckpt_cb = trainer.checkpoint_callback
    best = getattr(ckpt_cb, "best_model_path", "") if ckpt_cb is not None else ""
    if not best:
        # fast_dev_run (or checkpointing off): keep the weights anyway, so stages can be chained
        best = str(run_dir / "checkpoints" / ("fast_dev_run.ckpt" if fast else "final.ckpt"))
        trainer.save_checkpoint(best)
    score = getattr(ckpt_cb, "best_model_score", None) if ckpt_cb is not None else None
    test_metrics: dict[str, float] = {}
    if cfg.get("test", True):
        ckpt_for_test = None if fast or not getattr(ckpt_cb, "best_model_path", "") else "best"
        out = trainer.test(task, datamodule=datamodule, ckpt_path=ckpt_for_test, verbose=False)
        test_metrics = {k: float(v) for k, v in (out[0] if out else {}).items()}

    result = {
        "best_checkpoint": str(Path(best).resolve()),
        "best_score": float(score) if score is not None and math.isfinite(float(score)) else None,
        "monitor": str(cfg.model.get("monitor", "")),
        "epochs": int(trainer.current_epoch),
        "train_minutes": round(minutes, 3),
        "test": test_metrics,
        "config": to_plain(OmegaConf.masked_copy(cfg, ["scene", "data", "renderer", "pattern", "recnn", "model", "iml", "seed"])),
    }
    if trainer.is_global_zero and not fast:
        tmp = result_file.with_suffix(".tmp")
        run_dir.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(result, indent=2, default=str))
        tmp.replace(result_file)
    return result


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
@cli_errors
def main(cfg: DictConfig) -> float | dict | None:
    if cfg.get("orp_job") is not None:
        # a job of the ORP sweeper (hydra/sweeper=orp, docs/ORP.md): its record goes back to the sweeper
        from .orp import orp_main

        return orp_main(cfg)
    result = train(cfg)
    print(result["best_checkpoint"], flush=True)
    return result.get("best_score")


if __name__ == "__main__":
    torch.set_float32_matmul_precision("high")
    main()
