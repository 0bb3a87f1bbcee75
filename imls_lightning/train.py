"""Train any model of the project: ``python -m imls_lightning.train model=... recnn=... scene=...``.

Thin on purpose: compose the config and call :func:`imls_lightning.training.fit.train` (or, for a job
of the ORP sweeper, :func:`imls_lightning.orp.orp_main`), then print the best checkpoint's path as
the last line. Runs live in ``runs/<model>-<recnn>-<scene>-<settings hash>/``: running the same
settings again resumes from ``last.ckpt``, or returns at once when that run had finished.
"""
from __future__ import annotations

import sys
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

from imls_lightning.base.errors import checked_command_line, cli_errors

from .orp import orp_main
from .training.fit import (  # noqa: F401  (re-exported: the train CLI's body, by its old names)
    RESULT_FILE,
    TrainingUnfinished,
    build_datamodule,
    cfg_model_name,
    check_resume_checkpoint,
    remove_if_only_hydra,
    train,
)


@checked_command_line(Path(__file__).resolve().parents[1] / "conf", "train")
@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
@cli_errors
def main(cfg: DictConfig) -> float | dict | None:
    if cfg.get("orp_job") is not None:
        # a job of the ORP sweeper (hydra/sweeper=orp, docs/ORP.md): its record goes back to the sweeper
        return orp_main(cfg)
    try:
        result = train(cfg)
    except TrainingUnfinished as chunk_done:  # not an error: the run continues when the command is run again
        print(f"[train] {chunk_done}", file=sys.stderr, flush=True)
        sys.exit(TrainingUnfinished.EXIT_CODE)
    except BaseException:
        remove_if_only_hydra(Path(str(cfg.paths.output_dir)))
        raise
    print(result["best_checkpoint"], flush=True)
    return result.get("best_score")


if __name__ == "__main__":
    torch.set_float32_matmul_precision("high")
    main()
