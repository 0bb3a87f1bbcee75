"""``python -m imls_lightning.cost_mask row=<name> [views=<n>] [seed=<int>]`` (``make cost-mask ROW=<name>``): how much
of the render cost must a mask keep within 1 dB on a committed row, with the fastest ray caster?
(:mod:`imls_lightning.pipelines.cost_mask`). The last line of stdout is the path of ``cost_mask.json``."""
from __future__ import annotations

import hydra
from omegaconf import DictConfig

import data_gen  # noqa: F401  (registers the scene config resolvers)
from imls_lightning.base.errors import checked_command_line, cli_errors

from .base.config import register_resolvers
from .pipelines.cost_mask import cost_masks
from .base.paths import CONF_DIR

__all__ = ["main", "cost_masks"]

register_resolvers()


@checked_command_line(CONF_DIR, "cost_mask")
@hydra.main(version_base="1.3", config_path="../conf", config_name="cost_mask")
@cli_errors()
def main(cfg: DictConfig) -> None:
    print(cost_masks(cfg), flush=True)


if __name__ == "__main__":
    main()
