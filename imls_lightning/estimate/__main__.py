"""``python -m imls_lightning.estimate scene=NAME [recnn=fovolnet] [scene.* overrides]``: the
before-training estimate (:mod:`imls_lightning.estimate`); the last stdout line is ``estimate.json``'s path.

The resolution is checked before the scene is built or anything allocated (:func:`check_resolution`), and Ctrl-C
stops it with one line (exit status 130): an estimate is measured in one sitting, so nothing of it is kept."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import InputError, checked_command_line, cli_errors
from imls_lightning.base.validate import check_frame_memory, check_integer

from .run import run_estimate

CONF = Path(__file__).resolve().parents[2] / "conf"

#: the least memory the estimate takes per FR pixel: its full frames, the C-Image's masks at every share and the
#: networks' activations at paper sizes (a lower bound: it takes more at any size)
BYTES_PER_PIXEL = 256

#: what Ctrl-C leaves of an estimate
KEPT = ("nothing of this estimate is kept (it is measured in one sitting; a partial one is deleted, a finished one of the "
        "same settings is reused); run the same command again to measure it")


def check_resolution(cfg: DictConfig) -> int:
    """``resolution``, named as the user types it, before anything is allocated: an integer >= 1 whose frames fit in
    this machine's memory (:func:`~imls_lightning.base.validate.check_frame_memory`) and, on a super-resolution pattern, a
    multiple of its factor (the message names both settings).

    Raises:
        InputError: one line naming ``resolution``.
    """
    m = check_integer(cfg.get("resolution"), "resolution", 1)
    check_frame_memory(m, "resolution", BYTES_PER_PIXEL, "the estimate's frames, masks and network activations")
    pattern = cfg.get("pattern") or {}
    factor = pattern.get("factor")
    if pattern.get("kind") == "downsample" and isinstance(factor, int) and factor >= 1 and m % factor:
        below, above = m // factor * factor, (m // factor + 1) * factor
        recnn = (cfg.get("recnn") or {}).get("name", "the RecNN")
        raise InputError(f"resolution={m}: expected a multiple of {factor} (pattern.factor={factor}: {recnn} renders one "
                         f"pixel of every {factor}x{factor} block), e.g. " + (f"{below} or {above}" if below else f"{above}"))
    return m


@checked_command_line(CONF, "estimate")
@hydra.main(version_base="1.3", config_path="../../conf", config_name="estimate")
@cli_errors(interrupted=KEPT)
def main(cfg: DictConfig) -> None:
    check_resolution(cfg)
    print(run_estimate(cfg), flush=True)


if __name__ == "__main__":
    main()
