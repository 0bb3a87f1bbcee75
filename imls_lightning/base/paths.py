"""Where the commands find the repository (:data:`ROOT`, its Hydra configs :data:`CONF_DIR`) and how a
long one prints a progress line (:func:`log`): the entry points, the pipelines and the adaptive command share them."""
from __future__ import annotations

import sys
from pathlib import Path

#: the repository's root (the folder holding ``conf/``, ``imls_lightning/`` and ``data_gen/``)
ROOT = Path(__file__).resolve().parents[2]
#: the Hydra config folder of every CLI
CONF_DIR = str(ROOT / "conf")


def log(msg: str) -> None:
    """A pipeline's progress line, on stderr (stdout carries the stage results)."""
    print(msg, file=sys.stderr, flush=True)
