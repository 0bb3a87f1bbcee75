"""``make demo``: the whole IML/S pipeline on a built-in procedural scene, at a small scale.

Runs, one after the other, the commands a user would type (``conf/pipelines/demo.yaml`` lists their
overrides), so the demo exercises exactly the product's CLIs:

1. ``python -m data_gen ... contact_sheet=true``       the (view, image) cache and a contact sheet
2. ``python -m imls_lightning.train model=recnn``      the RecNN on its sampling pattern
   ... ``model=recnn pattern.factor=4``                the same RecNN on a sparser pattern of its own
   (:data:`~imls_lightning.pipelines.stages.SPARSER_PATTERN`; ``stages.recnn_sparser=null`` skips it): what a user would do instead of IML/S
3. ``python -m imls_lightning.train model=iml``        the IML network, end to end through the RecNN
4. ``python -m imls_lightning.train model=ims``        the IMS network on the IML's labels
5. ``python -m imls_lightning.train model=iml model.importance=uniform``  the blue-noise mask
   baseline's decoder (``stages.blue_noise=null`` skips it)
6. ``python -m imls_lightning.train model=las``        the LAS baseline (``stages.las=null`` skips it)
7. ``python -m imls_lightning.evaluate``               the ORP on the product path (validation
   views), then every method and the untrained baselines on the 120-view test trajectory, and the
   speed-quality front

Each CLI prints its result (cache directory, best checkpoint, report) as its last stdout line and
reuses a finished run of the same settings, so running the demo again costs seconds. The report's
path is the last line this command prints.

Any scene: every scene override that ``python -m data_gen`` accepts (``scene.volume.path=...``,
``scene.transfer_function.colormap=...``, ``scene.sample_distance_voxels=...``, also with ``+``,
``++`` or ``~``) is taken out of the command line before Hydra composes the pipeline's own config
(where ``scene`` is a plain name, :func:`~imls_lightning.pipelines.stages.split_scene_overrides`), checked against
``data_gen``'s config (:func:`~imls_lightning.pipelines.stages.check_scene_overrides`) and passed, verbatim, right after ``scene=<name>`` to every stage's
command. ``dry_run=true`` prints the stage commands (stdout) instead of running them.
``train_only=true`` stops after the training stages: train on a GPU machine, then run the same
command without it on the machine whose speed you want to measure (the evaluation reuses the runs
when the paths and settings are the same).

Example:
    python -m imls_lightning.demo                                   # flame, EnhanceNet
    python -m imls_lightning.demo scene=marschner_lobb recnn=fovolnet
    python -m imls_lightning.demo scene=file scene.volume.path=/data/my_head.nii.gz   # your own volume
"""
from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import checked_command_line, cli_errors

from .pipelines.demo import demo
from .base.paths import CONF_DIR
from .pipelines.stages import run_pipeline, split_scene_overrides

__all__ = ["main"]


def main() -> None:
    """``python -m imls_lightning.demo``: the scene overrides leave the command line before Hydra
    composes the pipeline's config (:func:`~imls_lightning.pipelines.stages.split_scene_overrides`); the
    Hydra entry point gets them through its closure (no module state)."""
    sys.argv[1:], scene_overrides = split_scene_overrides(sys.argv[1:])

    @checked_command_line(f"{CONF_DIR}/pipelines", "demo")
    @hydra.main(version_base="1.3", config_path=f"{CONF_DIR}/pipelines", config_name="demo")
    @cli_errors
    def _main(cfg: DictConfig) -> None:
        run_pipeline(lambda: demo(cfg, scene_overrides))

    _main()


if __name__ == "__main__":
    main()
