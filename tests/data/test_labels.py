"""IML labels for IMS training (imls_lightning.data.labels): made from a real VTK cache of the procedural
``tiny`` volume and a real (briefly trained) IML checkpoint; checked against a direct
re-implementation of the IML's inference path, for resumption after an interruption (raised and
``kill -9``), for re-runs doing nothing, and for refusing mismatched inputs."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import imls_lightning.data.labels as labels_mod
from data_gen.cache import ViewImageCache, ensure_cache
from imls_lightning.base.errors import InputError
from data_gen.scenes import build_scene
from imls_lightning.core.compaction import compact
from imls_lightning.data import ImlsDataModule
from imls_lightning.core.importance import normalize_importance
from imls_lightning.data.labels import ImportanceLabels, ensure_labels, labels_path_for
from imls_lightning.tasks.iml import IMLTask
from imls_lightning.tasks.recnn import RecNNTask

ROOT = Path(__file__).resolve().parents[2]
SCENE = {"name": "tiny", "volume": {"kind": "procedural", "generator": "tiny", "seed": 0}, "transfer_function": {"auto": True}}
RENDERER = {"name": "vtk"}
DOWN = {"kind": "downsample", "factor": 2}
FOVEAL = {"kind": "foveal", "c_size": 16, "sigma": 0.1}  # K = 132 of 256: a zero-padded C-Image


def data_cfg(cache_dir: Path, resolution: int = 32) -> dict:
    return {"num_views": 24, "test_views": 4, "resolution": resolution, "workers": 0, "cache_dir": str(cache_dir),
            "fsync": False, "batch_size": 4}


def save_task_checkpoint(task: L.LightningModule, path: Path, dm=None, steps: int = 2) -> Path:
    """A real checkpoint: a few Trainer steps (when a DataModule is given), then ``save_checkpoint``."""
    tr = L.Trainer(accelerator="cpu", max_steps=steps, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                   enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    if dm is not None:
        tr.fit(task, datamodule=dm)
    else:
        tr.strategy.connect(task)
    tr.save_checkpoint(path)
    return path


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A rendered cache (28 rows, 32^2) and IML checkpoints on the downsampling and foveal patterns."""
    root = tmp_path_factory.mktemp("labels")
    torch.manual_seed(0)
    dm = ImlsDataModule(SCENE, data_cfg(root / "cache"), RENDERER, DOWN, fields=("view", "fr", "c"), progress=False)
    dm.setup()
    down = save_task_checkpoint(IMLTask(DOWN, 32, depth=2, base_channels=4), root / "iml_down.ckpt", dm)
    dmf = ImlsDataModule(SCENE, data_cfg(root / "cache"), RENDERER, FOVEAL, fields=("view", "fr", "c"), progress=False)
    dmf.setup()
    fov = save_task_checkpoint(IMLTask(FOVEAL, 32, depth=2, base_channels=4, mean=0.3), root / "iml_fov.ckpt", dmf)
    return {"root": root, "cache": dm.cache_path, "down": down, "fov": fov}


def direct_labels(cache_path: Path, ckpt: Path) -> tuple[np.ndarray, np.ndarray]:
    """The IML's inference path written out: compact -> encoder -> softplus -> normalize -> PIM' > P, 0 on padding."""
    from imls_lightning.inference.checkpoints import load_task

    task = load_task(ckpt, expect="IMLTask")
    cache = ViewImageCache.open(cache_path)
    pat, net = task.pattern, task.iml
    x = torch.from_numpy(np.array(cache.images)).permute(0, 3, 1, 2).float() / 255.0
    c = compact(x, pat.indices, pat.c_size)
    with torch.no_grad():
        pim = F.softplus(net.encoder(c))
        pim_n = normalize_importance(pim, task.hparams.mean, valid=None if bool(pat.valid.all()) else pat.valid)
    im = (pim_n > net.sampling.P) & pat.valid
    return im[:, 0].numpy(), pim_n[:, 0].numpy()


# ------------------------------------------------------------------------------------------
# against a direct re-implementation
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["down", "fov"])
def test_labels_match_direct_iml_inference(world, which):
    out = ensure_labels(world["cache"], world[which], progress=False, chunk_size=8, batch_size=5)
    assert out == labels_path_for(world["cache"], world[which])
    assert out.parent == Path(world["cache"]) / "labels" and out.name.startswith("iml-") and len(out.name) == 4 + 16
    lab = ImportanceLabels.open(out)
    im_ref, pim_ref = direct_labels(world["cache"], world[which])
    assert len(lab) == 28
    ims = np.stack([lab.im(i) for i in range(len(lab))])
    assert ims.dtype == np.uint8 and set(np.unique(ims)) <= {0, 1}
    np.testing.assert_array_equal(ims.astype(bool), im_ref)
    np.testing.assert_allclose(np.stack([lab.pim(i) for i in range(len(lab))]), pim_ref, rtol=1e-5, atol=1e-6)
    # one bit per pixel on disk
    assert lab.packed_im.shape == (28, 16, 2)
    meta = lab.meta
    assert meta["complete"] and meta["c_size"] == 16 and meta["fr_size"] == 32
    assert meta["checkpoint_sha256"] == out.name[4:] and Path(meta["checkpoint"]) == Path(world[which]).resolve()
    assert sum(meta["counts"].values()) == 28 and meta["counts"]["test"] == 4
    ipr = im_ref.reshape(28, -1).sum(1) / 32.0**2
    assert meta["stats"]["all"]["ipr"]["mean"] == pytest.approx(ipr.mean())
    np.testing.assert_allclose(lab.ipr(), ipr)
    assert lab.verify() == []
    if which == "fov":  # padding is never important
        assert not ims[:, ~lab_valid(FOVEAL)].any()


def lab_valid(pattern_cfg) -> np.ndarray:
    from imls_lightning.core.patterns import build_pattern

    return build_pattern(pattern_cfg, 32).valid.numpy()


def test_labels_flow_into_the_datamodule(world):
    out = ensure_labels(world["cache"], world["down"], progress=False)
    dm = ImlsDataModule(SCENE, data_cfg(world["root"] / "cache"), RENDERER, DOWN, fields=("view", "c"), labels=out, progress=False)
    batch = next(iter(dm.train_dataloader()))
    assert batch["im"].shape == (4, 1, 16, 16) and batch["pim"].shape == (4, 1, 16, 16)
    lab = ImportanceLabels.open(out)
    row = int(batch["index"][0])
    np.testing.assert_array_equal(batch["im"][0, 0].numpy(), lab.im(row))


# ------------------------------------------------------------------------------------------
# resumable, idempotent
# ------------------------------------------------------------------------------------------


def test_rerun_does_nothing(world, monkeypatch):
    out = ensure_labels(world["cache"], world["down"], progress=False)
    stamp = {p.name: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file() and p.name != ".lock"}

    def boom(*a, **k):
        raise AssertionError("a complete label set was recomputed")

    monkeypatch.setattr(labels_mod, "label_iml", boom)
    monkeypatch.setattr(labels_mod, "_initialise", boom)
    assert ensure_labels(world["cache"], world["down"], progress=False) == out
    assert stamp == {p.name: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file() and p.name != ".lock"}


def _fresh_cache(tmp_path: Path) -> Path:
    return ensure_cache(build_scene(SCENE), data_cfg(tmp_path / "cache"), RENDERER, progress=False)


def test_resume_after_an_interrupted_run(world, tmp_path, monkeypatch):
    cache = _fresh_cache(tmp_path)
    real_marker, real_label = labels_mod._write_marker, labels_mod.label_iml
    calls = {"markers": 0, "rows": 0}

    def marker_then_die(*a, **k):
        if calls["markers"] == 2:
            raise KeyboardInterrupt("simulated interruption")
        calls["markers"] += 1
        real_marker(*a, **k)

    monkeypatch.setattr(labels_mod, "_write_marker", marker_then_die)
    with pytest.raises(KeyboardInterrupt):
        ensure_labels(cache, world["down"], progress=False, chunk_size=8)
    out = labels_path_for(cache, world["down"])
    assert len(list((out / "chunks").glob("*.json"))) == 2
    with pytest.raises(InputError, match="incomplete"):
        ImportanceLabels.open(out)

    # a torn marker (crash while writing it would leave only a .tmp; a foreign/garbled file) is not trusted
    (out / "chunks" / "00000000-00000008.json").write_text('{"rows": [0')

    def counting(iml, pattern, images, device):
        calls["rows"] += len(images)
        return real_label(iml, pattern, images, device)

    monkeypatch.setattr(labels_mod, "_write_marker", real_marker)
    monkeypatch.setattr(labels_mod, "label_iml", counting)
    # a different chunk_size on resume keeps the chunking the set was started with
    assert ensure_labels(cache, world["down"], progress=False, chunk_size=5) == out
    assert calls["rows"] == 28 - 8  # chunk 8..16 was trusted, the torn 0..8 and 16..28 were redone
    lab = ImportanceLabels.open(out)
    im_ref, pim_ref = direct_labels(cache, world["down"])
    np.testing.assert_array_equal(np.stack([lab.im(i) for i in range(28)]).astype(bool), im_ref)
    assert lab.verify() == []


KILL_SCRIPT = r"""
import sys, time
import imls_lightning.data.labels as L
real = L.label_iml
def slow(*a, **k):
    out = real(*a, **k)
    print("batch", flush=True)
    time.sleep(0.4)
    return out
L.label_iml = slow
L.ensure_labels(sys.argv[1], sys.argv[2], batch_size=2, chunk_size=4, progress=False)
print("finished", flush=True)
"""


def test_resume_after_kill_9(world, tmp_path):
    cache = _fresh_cache(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", KILL_SCRIPT, str(cache), str(world["down"])], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        seen = 0
        for line in proc.stdout:  # kill in the middle of a chunk: after 5 batches (2.5 chunks)
            seen += line.startswith("batch")
            if seen == 5:
                os.kill(proc.pid, signal.SIGKILL)
                break
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    out = labels_path_for(cache, world["down"])
    assert 1 <= len(list((out / "chunks").glob("*.json"))) < 7
    with pytest.raises(InputError, match="incomplete"):
        ImportanceLabels.open(out)
    ensure_labels(cache, world["down"], progress=False)
    lab = ImportanceLabels.open(out)
    im_ref, pim_ref = direct_labels(cache, world["down"])
    np.testing.assert_array_equal(np.stack([lab.im(i) for i in range(28)]).astype(bool), im_ref)
    np.testing.assert_allclose(np.stack([lab.pim(i) for i in range(28)]), pim_ref, rtol=1e-5, atol=1e-6)
    assert lab.verify() == []


def test_verify_finds_changed_bytes(world, tmp_path):
    cache = _fresh_cache(tmp_path)
    out = ensure_labels(cache, world["down"], progress=False, chunk_size=8)
    pim = np.load(out / "pim.npy", mmap_mode="r+")
    pim[9, 0, 0] += 1.0
    pim.flush()
    del pim
    assert ImportanceLabels.open(out).verify() == [(8, 16)]


# ------------------------------------------------------------------------------------------
# exceptions
# ------------------------------------------------------------------------------------------


def test_exception_resolution_mismatch(world, tmp_path):
    ck = save_task_checkpoint(IMLTask(DOWN, 64, depth=2, base_channels=4), tmp_path / "iml64.ckpt")
    with pytest.raises(InputError, match=r"data\.resolution=64") as err:
        ensure_labels(world["cache"], ck, progress=False)
    assert "\n" not in str(err.value)


def test_exception_not_an_iml_checkpoint(world, tmp_path):
    net = {"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4, "blocks": 1}
    ck = save_task_checkpoint(RecNNTask(net, DOWN, 32), tmp_path / "recnn.ckpt")
    with pytest.raises(InputError, match="RecNNTask checkpoint, expected a IMLTask"):
        ensure_labels(world["cache"], ck, progress=False)
    with pytest.raises(InputError, match="iml.checkpoint=.*file not found"):
        ensure_labels(world["cache"], tmp_path / "missing.ckpt", progress=False)


def test_exception_bad_arguments_and_directories(world, tmp_path):
    with pytest.raises(InputError, match="batch_size"):
        ensure_labels(world["cache"], world["down"], batch_size=0)
    with pytest.raises(InputError, match="device="):
        ensure_labels(_fresh_cache(tmp_path), world["down"], device="gpu7", progress=False)
    with pytest.raises(InputError, match="not an IML label directory"):
        ImportanceLabels.open(tmp_path)
    with pytest.raises(InputError, match="not a view/image cache"):
        ensure_labels(tmp_path, world["down"], progress=False)


def test_packbits_for_sizes_not_multiple_of_8(world, tmp_path):
    cfg = data_cfg(tmp_path / "cache", resolution=24)  # downsample 2 -> n = 12
    dm = ImlsDataModule(SCENE, cfg, RENDERER, DOWN, fields=("view", "fr", "c"), progress=False)
    dm.setup()
    ck = save_task_checkpoint(IMLTask(DOWN, 24, depth=2, base_channels=4), tmp_path / "iml24.ckpt", dm)
    out = ensure_labels(dm.cache_path, ck, progress=False)
    lab = ImportanceLabels.open(out)
    assert lab.packed_im.shape == (28, 12, 2) and lab.im(0).shape == (12, 12)
    im_ref, _ = direct_labels(dm.cache_path, ck)
    np.testing.assert_array_equal(np.stack([lab.im(i) for i in range(28)]).astype(bool), im_ref)
    assert json.loads((out / "meta.json").read_text())["stats"]["all"]["ipr"]["mean"] == pytest.approx(im_ref.sum() / 28 / 24**2)
