"""``python -m imls_lightning.viewer ims_checkpoint=PATH [recnn_checkpoint=PATH] [screenshot=out.png]``:
the interactive viewer (:mod:`imls_lightning.viewer`, settings in ``conf/viewer.yaml``); with
``screenshot=`` the last stdout line is the PNG's path."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import checked_command_line, cli_errors

from .run import viewer

CONF = Path(__file__).resolve().parents[2] / "conf"


@checked_command_line(CONF, "viewer")
@hydra.main(version_base="1.3", config_path="../../conf", config_name="viewer")
@cli_errors
def main(cfg: DictConfig) -> None:
    out = viewer(cfg)
    if out is not None:
        print(out, flush=True)


if __name__ == "__main__":
    main()
