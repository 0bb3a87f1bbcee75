"""The pipelines: the product's CLIs run one after the other, as a user would type them.

Each pipeline is an entry point directly under ``imls_lightning/`` that composes its Hydra config
(``conf/pipelines/``) and calls a module of this package:

====================================  =====================================================  ==================
command                               what                                                   module
====================================  =====================================================  ==================
``python -m imls_lightning.demo``     every stage on one scene at a small scale              :mod:`.demo`
``python -m imls_lightning.bench``    the paper's ORP and LAS tables (``BENCHMARKS.md``)     :mod:`.bench`
``python -m imls_lightning.bench_paper``  the paper's protocol at the paper's scale           :mod:`.bench_paper`
``python -m imls_lightning.size_search``  the network sizes' speed-quality front             :mod:`.size_search`
====================================  =====================================================  ==================

What they share lives in :mod:`.stages` (running a stage's command, the arguments every stage
shares, the scene overrides, the evaluation's summary); the repository's root, its config folder and the
progress line are the foundation's (:mod:`imls_lightning.base.paths`). No pipeline imports an entry point, and no entry point another.
"""
from __future__ import annotations

from .stages import (SPARSER_PATTERN, StageFailed, StageUnfinished, check_scene_overrides, dry_stage, evaluation_lift,
                     ims_decoder_overrides, ims_finetune_overrides, override_list, read_summary, run_pipeline, run_stage, sparser_overrides,
                     renderer_overrides, split_scene_overrides, stage_args, stage_overrides)

__all__ = [
    "SPARSER_PATTERN", "StageFailed", "StageUnfinished", "check_scene_overrides", "dry_stage",
    "evaluation_lift", "ims_decoder_overrides", "ims_finetune_overrides", "override_list", "read_summary", "run_pipeline", "run_stage",
    "renderer_overrides", "sparser_overrides", "split_scene_overrides", "stage_args", "stage_overrides",
]
