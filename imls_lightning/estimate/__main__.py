"""``python -m imls_lightning.estimate scene=NAME [recnn=fovolnet] [scene.* overrides]``: the
before-training estimate (:mod:`imls_lightning.estimate`); the last stdout line is ``estimate.json``'s path."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from data_gen.errors import checked_command_line, cli_errors

from .run import run_estimate

CONF = Path(__file__).resolve().parents[2] / "conf"


@checked_command_line(CONF)
@hydra.main(version_base="1.3", config_path="../../conf", config_name="estimate")
@cli_errors
def main(cfg: DictConfig) -> None:
    print(run_estimate(cfg), flush=True)


if __name__ == "__main__":
    main()
