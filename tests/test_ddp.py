"""Distributed data parallel through the train CLI: ``trainer=ddp trainer.accelerator=cpu
trainer.devices=2`` (two processes, gloo) trains every model for one epoch on the tiny scene and
leaves a loadable checkpoint. The training test is slow: each run starts two interpreters (about
20-60 s on 2 cores)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]


def _train(args: list[str], tmp: Path) -> tuple[Path, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    cmd = [sys.executable, "-m", "imls_lightning.train", "scene=tiny", "data=tiny", "renderer=numba", "logger=none",
           "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2", "trainer.max_epochs=1",
           "trainer.enable_progress_bar=false", f"paths.runs_dir={tmp / 'runs'}", f"data.cache_dir={tmp / 'cache'}",
           "recnn=enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2", *args]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    out = p.stdout + p.stderr
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    assert "GLOBAL_RANK: 1, MEMBER: 2/2" in out and "distributed_backend=gloo" in out  # really two processes
    ckpt = Path(p.stdout.strip().splitlines()[-1])
    assert ckpt.suffix == ".ckpt" and ckpt.is_file(), p.stdout[-2000:]
    return ckpt, out


def test_ddp_config_is_sane():
    cfg = OmegaConf.load(ROOT / "conf" / "trainer" / "ddp.yaml")
    assert cfg.strategy == "ddp" and cfg.devices == 2 and cfg.num_nodes == 1
    assert cfg.sync_batchnorm is False  # SyncBatchNorm is CUDA-only; the IMS GAN has BatchNorm


@pytest.mark.slow
def test_ddp_trains_every_model_one_epoch(tmp_path):
    from imls_lightning.inference.checkpoints import load_task

    results = {}
    rec, _ = _train(["model=recnn"], tmp_path)
    iml, _ = _train(["model=iml", "model.mode=end_to_end", f"recnn.checkpoint={rec}", "model.depth=2", "model.base_channels=8"], tmp_path)
    ims, _ = _train(["model=ims", f"iml.checkpoint={iml}", "model.layers=5", "model.base_channels=8",
                     "model.loss.perceptual.weight=0", "model.loss.bce=1"], tmp_path)
    las, _ = _train(["model=las", "model.low_res=16"], tmp_path)
    for name, ckpt, task in (("recnn", rec, "RecNNTask"), ("iml", iml, "IMLTask"), ("ims", ims, "IMSTask"), ("las", las, "LASTask")):
        load_task(ckpt, expect=task)
        results[name] = json.loads((ckpt.parent.parent / "result.json").read_text())  # written once, by rank 0
        assert results[name]["epochs"] == 1 and results[name]["best_checkpoint"] == str(ckpt.resolve())
        assert results[name]["test"], name  # the test trajectory was evaluated too
    assert load_task(ims, expect="IMSTask").recnn is not None
