"""``make bench-paper``: the paper's protocol at the paper's scale, on this machine.

512² FR-Images, 256² C-Images, half-voxel sampling (``scene.sample_distance: auto``), the numba
renderer. For every scene of ``scenes`` and RecNN of ``recnns`` (``conf/pipelines/bench_paper.yaml``)
it runs the demo's stages through the real CLIs (:func:`imls_lightning.pipelines.demo.demo`): cache, RecNN,
IML, IMS, blue-noise decoder, LAS, then the evaluation, which searches the ORP on the product path
(IMS mask from the view, exactly those pixels ray-cast, IML decoder, RecNN) on the validation views
and measures every method on the 120-view test trajectory. It then writes, after every pair:

* ``benchmarks/paper_scale.csv``: one row per (scene, recnn), :data:`~imls_lightning.pipelines.bench_paper.CSV_COLUMNS` (rows of pairs not
  run this time are kept);
* ``benchmarks/paper_scale.md``: that table, the per-stage latency of every method with the physical
  limit (ray-casting the ORP's pixels alone), the equal-share baselines and the paper's figures;
* ``benchmarks/paper_scale_breakdown.png``: stacked bars per method (the paper's time-breakdown figure);
* the paper-scale section of ``BENCHMARKS.md`` (between :data:`~imls_lightning.pipelines.bench_paper.SECTION_BEGIN` and :data:`~imls_lightning.pipelines.bench_paper.SECTION_END`).

Resuming: every stage reuses finished work (each CLI reuses its finished run, the evaluation runs with
``reuse=true``), so the same command continues after an interruption.

Example:
    python -m imls_lightning.bench_paper                                         # make bench-paper
    python -m imls_lightning.bench_paper scenes=[ct_head] recnns=[enhancenet]    # one pair
    python -m imls_lightning.bench_paper scene=file scene.volume.path=/data/my_head.nii.gz
"""
from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import checked_command_line, cli_errors

from .pipelines.bench_paper import bench_paper
from .base.paths import CONF_DIR
from .pipelines.stages import run_pipeline, split_scene_overrides

__all__ = ["main"]


def main() -> None:
    """``python -m imls_lightning.bench_paper``: scene overrides leave the command line first
    (:func:`imls_lightning.pipelines.stages.split_scene_overrides`); the Hydra entry point gets them through its
    closure (no module state)."""
    sys.argv[1:], scene_overrides = split_scene_overrides(sys.argv[1:])

    @checked_command_line(f"{CONF_DIR}/pipelines", "bench_paper")
    @hydra.main(version_base="1.3", config_path=f"{CONF_DIR}/pipelines", config_name="bench_paper")
    @cli_errors
    def _main(cfg: DictConfig) -> None:
        command = "python -m imls_lightning.bench_paper " + " ".join(sys.argv[1:] + scene_overrides)
        run_pipeline(lambda: bench_paper(cfg, scene_overrides, command.strip()))

    _main()


if __name__ == "__main__":
    main()
