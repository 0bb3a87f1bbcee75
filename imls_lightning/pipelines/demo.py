"""The demo pipeline (``make demo``, ``python -m imls_lightning.demo``): every stage of the IML/S
pipeline on one scene at a small scale, through the real CLIs (:func:`demo`)."""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

from .pack_row import trained_networks
from .stages import (check_scene_overrides, dry_stage, evaluation_lift, ims_decoder_overrides, ims_finetune_overrides,
                     override_list, run_stage, sparser_overrides, stage_args, stage_overrides)


def demo(cfg: DictConfig, scene_overrides: Sequence[str] = (), results: dict | None = None) -> Path | None:
    """Run every stage; returns the evaluation report's path (None with ``dry_run`` or ``train_only``).

    ``scene_overrides`` (``scene.<key>=...``, see :func:`split_scene_overrides`) follow
    ``scene=<cfg.scene>`` in every stage's command. ``results``, when given, gets every stage's result
    by name (``cache``, ``recnn``, ``recnn_sparser``, ``iml``, ``ims``, ``blue_noise``, ``las``, ``report``, ``adaptive``)."""
    runs = str(cfg.runs_dir)
    dry = bool(cfg.get("dry_run", False))
    check_scene_overrides(str(cfg.scene), scene_overrides)
    stage = dry_stage if dry else run_stage
    common, train_common = stage_args(cfg, scene_overrides)
    t0 = time.perf_counter()

    cache = stage("cache", ["-m", "data_gen", *common, "contact_sheet=true", f"progress={bool(cfg.progress)}"])
    sheet = Path(cache) / "contact_sheet.png"
    if not dry:
        print(f"[demo] contact sheet of the cached views: {sheet}", file=sys.stderr, flush=True)

    # a row's committed networks (pack_row's trained.yaml) stand in for its training stages: evaluated, not trained again
    committed = trained_networks(Path(str(cfg.trained))) if cfg.get("trained") else {}

    def train(key: str, name: str, model: str, *refs: str, overrides: Sequence[str] | None = None) -> str:
        if key in committed:
            print(f"[demo] {name}: the committed {committed[key]} (trained={cfg.trained}), not trained again",
                  file=sys.stderr, flush=True)
            return str(committed[key])
        return stage(name, ["-m", "imls_lightning.train", f"model={model}", *train_common, *refs,
                            *(stage_overrides(cfg, key) if overrides is None else overrides)])

    recnn = train("recnn", "RecNN", "recnn")
    sparser = None
    if OmegaConf.select(cfg, "stages.recnn_sparser") is not None:
        # what a user would do instead of IML/S: the same RecNN, trained the same way, on a sparser pattern
        sparser = train("recnn_sparser", "RecNN, sparser pattern", "recnn", overrides=sparser_overrides(cfg))
    iml = train("iml", "IML", "iml", f"recnn.checkpoint={recnn}")
    ims = train("ims", "IMS", "ims", f"iml.checkpoint={iml}", f"recnn.checkpoint={recnn}")
    if "ims" not in committed:
        ims = _ims_later_stages(cfg, stage, train_common, iml, recnn, ims)
    blue = None
    if OmegaConf.select(cfg, "stages.blue_noise") is not None:
        # the untrained-mask baseline: the blue-noise mask u > P with a decoder trained for it
        blue = train("blue_noise", "blue-noise decoder", "iml", f"recnn.checkpoint={recnn}", "model.importance=uniform")
    las = None
    if OmegaConf.select(cfg, "stages.las") is not None:
        las = train("las", "LAS", "las")

    if bool(cfg.get("train_only", False)):
        if not dry:
            print(f"\n[demo] train_only: trained in {(time.perf_counter() - t0) / 60:.1f} min; the evaluation is "
                  "left for the same command without train_only", file=sys.stderr, flush=True)
        return None
    ev = ["-m", "imls_lightning.evaluate", *common, f"paths.runs_dir={runs}", f"checkpoints.ims={ims}",
          f"checkpoints.recnn={recnn}", f"checkpoints.iml={iml}", f"progress={bool(cfg.progress)}", "reuse=true",
          *override_list(cfg, "evaluate")]
    if las:
        ev.append(f"checkpoints.las={las}")
    if blue:
        ev.append(f"checkpoints.blue_noise={blue}")
    if sparser:
        ev.append(f"checkpoints.recnn_sparser={sparser}")
    report = Path(stage("evaluation", ev))
    adaptive = None
    if OmegaConf.select(cfg, "adaptive") is not None:
        # the per-view mean value (python -m imls_lightning.adaptive) on the same masks as the evaluation's ORP
        lift = "<the evaluation's orp.lift>" if dry else str(evaluation_lift(report)).lower()
        adaptive = stage("adaptive mean", ["-m", "imls_lightning.adaptive", *common, f"ims_checkpoint={ims}",
                                           f"recnn_checkpoint={recnn}", f"ims_lift={lift}", f"progress={bool(cfg.progress)}",
                                           "reuse=true", *override_list(cfg, "adaptive")])
    if results is not None:
        results.update(cache=cache, recnn=recnn, recnn_sparser=sparser, iml=iml, ims=ims, blue_noise=blue, las=las,
                       report=str(report), adaptive=adaptive)
    if dry:
        return None
    minutes = (time.perf_counter() - t0) / 60
    print(f"\n[demo] finished in {minutes:.1f} min. Contact sheet: {sheet}", file=sys.stderr, flush=True)
    print(f"[demo] report (tables, plots, image grid): {report}", file=sys.stderr, flush=True)
    return report


def _ims_later_stages(cfg: DictConfig, stage, train_common: Sequence[str], iml: str, recnn: str, ims: str) -> str:
    """The IMS's stages after its first (its fine-tune and its decoder, where the pipeline has them) from the IMS
    checkpoint ``ims``; the product's IMS checkpoint."""
    tr = ["-m", "imls_lightning.train", "model=ims", *train_common, f"iml.checkpoint={iml}", f"recnn.checkpoint={recnn}"]
    if OmegaConf.select(cfg, "stages.ims_finetune") is not None:
        # the generator trained on from the IMS stage's best, at a lower learning rate (a step decay): the stage before
        # it keeps its constant rate, so more epochs there still continue the same run
        ims = stage("IMS fine-tune", [*tr, *ims_finetune_overrides(cfg), f"model.init_checkpoint={ims}"])
    if OmegaConf.select(cfg, "stages.ims_decoder") is not None:
        # the IMS's decoder alone, trained further on the masks the evaluation runs (its sharpness, lifted); the
        # generator stays as trained, and the product is this checkpoint
        ims = stage("IMS decoder", [*tr, *ims_decoder_overrides(cfg), f"model.init_checkpoint={ims}"])
    return ims
