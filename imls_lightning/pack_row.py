"""``python -m imls_lightning.pack_row evaluation=<finished evaluation folder> name=<row> trajectory_seed=<int>``:
pack a row's networks and operating point for the repository and write ``conf/row/<row>.yaml``
(:mod:`imls_lightning.pipelines.pack_row`); the last line of stdout is that file's path."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError, checked_command_line, cli_errors

from .pipelines.pack_row import pack_row, pack_trained
from .base.paths import CONF_DIR, ROOT

__all__ = ["main"]


@checked_command_line(CONF_DIR)
@hydra.main(version_base="1.3", config_path="../conf", config_name="pack_row")
@cli_errors
def main(cfg: DictConfig) -> None:
    dest = Path(str(cfg.dest)) if cfg.dest else ROOT / "benchmarks" / "rows" / str(cfg.name)
    if cfg.evaluation is None:  # a row trained, not yet evaluated: its networks only
        sources = {str(k): Path(str(v)) for k, v in (cfg.checkpoints or {}).items()}
        if not sources:
            raise InputError("evaluation=<finished evaluation folder> or checkpoints.<key>=<path> expected, got neither")
        print(pack_trained(sources, str(cfg.name), dest, experiment=cfg.trained_by), flush=True)
        return
    if cfg.trajectory_seed is None:
        raise InputError("trajectory_seed=<int> expected with evaluation=: the fresh trajectory the row's numbers come from")
    print(pack_row(Path(str(cfg.evaluation)), str(cfg.name), dest, data=str(cfg.data), trajectory_seed=int(cfg.trajectory_seed),
                   settings=[str(s) for s in OmegaConf.to_container(cfg.settings)], views=int(cfg.views),
                   timed_views=int(cfg.timed_views)), flush=True)


if __name__ == "__main__":
    main()
