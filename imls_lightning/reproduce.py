"""``python -m imls_lightning.reproduce row=<name> [trajectory_seed=<int>] [views=<n>] [timed_views=<n>]``
(``make reproduce ROW=<name>``): re-measure a committed row from a fresh clone on a fresh test trajectory, with the
committed networks at the committed operating point, choosing nothing again
(:mod:`imls_lightning.pipelines.reproduce`). The last line of stdout is the path of ``reproduce.json``."""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

import data_gen  # noqa: F401  (registers the scene config resolvers)
from imls_lightning.base.errors import checked_command_line, cli_errors

from imls_lightning.base.config import register_resolvers
from .base.paths import CONF_DIR
from .pipelines.reproduce import reproduce

__all__ = ["main", "reproduce"]

register_resolvers()


def kept_when_interrupted(cfg: DictConfig) -> str:
    """What a reproduction stopped by Ctrl-C keeps (its evaluation runs with reuse=true in a folder of its settings)."""
    where = cfg.get("output_dir") or f"{cfg.get('runs_dir')}/reproduce/"
    return (f"the caches rendered and the views measured so far are kept (the evaluation's partial/ under {where}); "
            "run the same command again to continue from them")


@checked_command_line(CONF_DIR, "reproduce")
@hydra.main(version_base="1.3", config_path="../conf", config_name="reproduce")
@cli_errors(interrupted=kept_when_interrupted)
def main(cfg: DictConfig) -> None:
    print(reproduce(cfg), flush=True)


if __name__ == "__main__":
    main()
