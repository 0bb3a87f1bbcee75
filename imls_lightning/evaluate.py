"""Speed/accuracy evaluation of IML/S + RecNN against every baseline, on the same views in one run.

``python -m imls_lightning.evaluate scene=NAME checkpoints.ims=<IMS .ckpt> [checkpoints.las=<LAS .ckpt>]``

For each view of the cache's test trajectory and each method - full ray cast, RecNN alone, LAS (with a
LAS checkpoint), IML + RecNN, IML/S + RecNN - every stage is timed and the image is scored against the
cache's ground truth; sweeps feed the latency/PSNR plot and the speed-quality front, and the ORP is
searched on held-out views (settings: ``conf/evaluate.yaml``).

This entry point composes its Hydra config and calls :func:`imls_lightning.evaluation.evaluate` (the
evaluation, its settings, methods, sweeps and baselines live in :mod:`imls_lightning.evaluation`).

Output (``output_dir``): ``metrics.csv`` (view x method), ``sweep.csv``, ``options.csv``,
``config.yaml``, PNG plots, ``image_grid.png`` and ``report.md`` (written last, atomically). The
report's path is the last line of stdout. After the report, the ORP IML/S ran at is recorded beside
the IMS checkpoint, ``<ims.ckpt>.orp.json`` (:mod:`imls_lightning.inference.operating_point`).

Python: ``imls_lightning.evaluation.evaluate(cfg)`` returns ``report.md``'s path (example there).
"""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

import data_gen  # noqa: F401  (registers the scene config resolvers)
from imls_lightning.base.errors import checked_command_line, cli_errors

from imls_lightning.base.config import register_resolvers
from .evaluation import evaluate, summary  # noqa: F401  (public: evaluate(cfg) -> report.md, summary(metrics_csv) -> dict)
from .base.paths import CONF_DIR

__all__ = ["evaluate", "summary", "main"]

register_resolvers()


def kept_when_interrupted(cfg: DictConfig) -> str:
    """What an evaluation stopped by Ctrl-C keeps, and how to resume (:mod:`imls_lightning.evaluation.resume`)."""
    again = "run the same command again" if cfg.get("resume", True) is not False else "run it again with resume=true"
    return ("the caches rendered, the operating point once searched and every view measured are kept (partial/ in "
            f"the evaluation's output folder); {again} to continue from them")


@checked_command_line(CONF_DIR, "evaluate")
@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
@cli_errors(interrupted=kept_when_interrupted)
def main(cfg: DictConfig) -> None:
    path = evaluate(cfg)
    print(path, flush=True)


if __name__ == "__main__":
    main()
