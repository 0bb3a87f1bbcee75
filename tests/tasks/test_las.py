"""LAS training task (imls_lightning.tasks.las.LASTask) and its config (conf/model/las.yaml).

Unit tests run the real task and networks on synthetic (fr, low) batches; the CLI smoke test runs
``python -m imls_lightning.train model=las`` on the tiny procedural scene."""
from __future__ import annotations

import inspect
import math
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
import torch.nn.functional as F
from omegaconf import OmegaConf
from torch.utils.data import DataLoader

from imls_lightning.base.errors import InputError
from imls_lightning.models.las import las_loss
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.tasks.base import psnr_per_image
from imls_lightning.tasks.las import LASTask, check_low_res
from imls_lightning.base.images import image_grid

ROOT = Path(__file__).resolve().parents[2]
LOW, FR = 8, 32
TINY = dict(importance_channels=8, importance_blocks=1, importance_border=2, recon_channels=8, recon_blocks=1)

# self.log outside a Trainer only warns; direct step calls are the point of some tests
pytestmark = pytest.mark.filterwarnings("ignore:You are trying to `self.log\\(\\)`")


def tiny_task(**kw) -> LASTask:
    args = dict(fr_size=FR, low_res=LOW, mean=0.2, **TINY)
    args.update(kw)
    return LASTask(**args)


def synthetic_batch(b: int = 2, seed: int = 0) -> dict[str, torch.Tensor]:
    """Soft coloured blobs on black, ``fr`` (B, 3, FR, FR) and an area-downsampled ``low``.

    (The real data module renders ``low`` separately; for the task any (B, 3, LOW, LOW) image works.)"""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, FR), torch.linspace(-1, 1, FR), indexing="ij")
    imgs = []
    for _ in range(b):
        cx, cy, r = torch.rand(3, generator=g) * torch.tensor([0.8, 0.8, 0.3]) + torch.tensor([-0.4, -0.4, 0.3])
        blob = torch.sigmoid(12 * (r - ((xx - cx) ** 2 + (yy - cy) ** 2).sqrt()))
        imgs.append(blob * (torch.rand(3, 1, 1, generator=g) * 0.7 + 0.3))
    fr = torch.stack(imgs)
    return {"view": torch.zeros(b, 9), "fr": fr, "low": F.interpolate(fr, size=(LOW, LOW), mode="area")}


def batch_loader(n_batches: int = 2, b: int = 2) -> DataLoader:
    """A DataLoader over per-sample dicts, collated like ImlsDataModule's."""
    items = []
    for i in range(n_batches):
        batch = synthetic_batch(b, seed=i)
        items += [{k: v[j] for k, v in batch.items()} for j in range(b)]
    return DataLoader(items, batch_size=b, shuffle=False)


def quiet_trainer(**kw) -> L.Trainer:
    args = dict(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                enable_model_summary=False)
    args.update(kw)
    return L.Trainer(**args)


# ------------------------------------------------------------------------------------------
# smoke
# ------------------------------------------------------------------------------------------


def test_smoke_training_step_is_soft_and_differentiable():
    torch.manual_seed(0)
    task = tiny_task().train()
    loss = task.training_step(synthetic_batch(), 0)
    assert loss.dim() == 0 and torch.isfinite(loss)
    loss.backward()
    grads = [p.grad for p in task.parameters() if p.requires_grad]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    # both nets learn end to end: the importance net gets gradient through the soft mask
    assert task.net.importance_net.body.pre[0].weight.grad.abs().sum() > 0
    assert task.net.reconstruction_net.net is not None
    out = task.run(synthetic_batch(), hard=None)
    assert ((out.mask > 0) & (out.mask < 1)).any(), "training must sample softly"


def test_smoke_validation_step_uses_the_hard_mask():
    task = tiny_task().eval()
    with torch.no_grad():
        loss = task.validation_step(synthetic_batch(), 0)
        out = task.run(synthetic_batch(), hard=None)
    assert torch.isfinite(loss)
    assert set(out.mask.unique().tolist()) <= {0.0, 1.0}


def test_validation_equals_inference_and_never_sees_unsampled_truth():
    """What val/test score is what inference produces from really rendered pixels only."""
    torch.manual_seed(1)
    task = tiny_task().eval()
    batch = synthetic_batch(3)
    with torch.no_grad():
        out = task.run(batch, hard=True)
        mask = task.net.importance_mask(batch["low"])
        # unrendered pixels hold garbage at inference: the result must not depend on them
        garbage = torch.where(mask[:, None], batch["fr"], torch.rand_like(batch["fr"]))
        rec = task.net.reconstruct(garbage, mask)
        pred, pmask = task.predict(batch)
    assert torch.equal(out.mask[:, 0].bool(), mask)
    assert 0 < mask.float().mean() < 1
    torch.testing.assert_close(rec, out.fr_pred.clamp(0, 1), rtol=0, atol=1e-6)
    torch.testing.assert_close(pred, rec, rtol=0, atol=1e-6)
    assert torch.equal(pmask, mask)


def test_losses_finite_and_decrease_over_optimizer_steps():
    torch.manual_seed(0)
    task = tiny_task(lr=3e-3).train()
    opt = task.configure_optimizers()
    batch = synthetic_batch(4)
    losses = []
    for i in range(25):
        opt.zero_grad()
        loss = task.training_step(batch, i)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert all(math.isfinite(v) for v in losses)
    # soft sampling and the pattern augmentation are random: compare averages of 5 steps
    assert sum(losses[-5:]) / 5 < 0.7 * sum(losses[:5]) / 5, losses


def test_trainer_logs_every_metric_under_its_prefix():
    torch.manual_seed(0)
    task = tiny_task()
    trainer = quiet_trainer(max_steps=2, limit_val_batches=1, num_sanity_val_steps=0)
    trainer.fit(task, train_dataloaders=batch_loader(2), val_dataloaders=batch_loader(1))
    keys = set(trainer.callback_metrics)
    for k in ("train/loss", "train/ipr", "val/loss", "val/ipr", "val/fr_psnr", "val/fr_ssim", "val/l1", "val/heatmap"):
        assert k in keys, (k, sorted(keys))
        assert math.isfinite(float(trainer.callback_metrics[k]))
    assert 0 < float(trainer.callback_metrics["val/ipr"]) < 1
    test = trainer.test(task, dataloaders=batch_loader(1), verbose=False)[0]
    assert {"test/loss", "test/ipr", "test/fr_psnr", "test/fr_ssim"} <= set(test)
    # the scores are those of the hard (inference) mask, not of the soft training mask
    batch = next(iter(batch_loader(1)))
    task.eval()
    with torch.no_grad():
        hard, soft = task.run(batch, hard=True), task.run(batch, hard=False)
    hard_loss = las_loss(hard, batch["fr"])[0].item()
    assert test["test/loss"] == pytest.approx(hard_loss, rel=1e-5)
    assert test["test/loss"] != pytest.approx(las_loss(soft, batch["fr"])[0].item(), rel=1e-3)
    assert test["test/ipr"] == pytest.approx(hard.mask.mean().item(), rel=1e-6)
    assert test["test/fr_psnr"] == pytest.approx(psnr_per_image(hard.fr_pred, batch["fr"]).mean().item(), rel=1e-5)


def test_ipr_follows_the_mean_at_init():
    """The logged IPR is the hard mask's share of FR pixels; normalization makes it track u."""
    torch.manual_seed(0)
    for u in (0.05, 0.3):
        task = tiny_task(mean=u).eval()
        with torch.no_grad():
            out = task.run(synthetic_batch(2), hard=True)
        assert abs(out.mask.mean().item() - u) < 0.1, (u, out.mask.mean().item())


def test_visuals_columns_shapes_and_grid():
    task = tiny_task().eval()
    batch = synthetic_batch(2)
    with torch.no_grad():
        titles, tensors = task.visuals(batch)
    assert titles == ["low-res", "importance", "mask", "samples", "LAS", "truth"]
    assert [tuple(t.shape) for t in tensors] == [(2, 3, LOW, LOW), (2, 1, FR, FR), (2, 1, FR, FR), (2, 3, FR, FR),
                                                 (2, 3, FR, FR), (2, 3, FR, FR)]
    assert all(t.min() >= 0 and t.max() <= 1 for t in tensors)
    assert torch.equal(tensors[0], batch["low"]) and torch.equal(tensors[-1], batch["fr"])
    grid = image_grid([[t[i] for t in tensors] for i in range(2)], col_titles=titles, tile=32)
    assert grid.size[0] > 6 * 32


# ------------------------------------------------------------------------------------------
# checkpoints
# ------------------------------------------------------------------------------------------


def test_checkpoint_round_trip_through_trainer_and_load_task(tmp_path):
    torch.manual_seed(0)
    task = tiny_task(mean=0.25, recon_arch="enhancenet")
    fresh = {k: v.clone() for k, v in task.state_dict().items()}
    trainer = quiet_trainer(max_steps=2, limit_val_batches=0)
    trainer.fit(task, train_dataloaders=batch_loader(2))
    path = tmp_path / "las.ckpt"
    trainer.save_checkpoint(path)
    assert any(not torch.equal(fresh[k], v) for k, v in task.state_dict().items()), "training changed nothing"

    loaded = load_task(path, expect="LASTask")
    assert isinstance(loaded, LASTask) and not loaded.training
    assert dict(loaded.hparams) == dict(task.hparams)
    assert all(isinstance(v, (int, float, str, bool)) for v in loaded.hparams.values())
    task.eval()
    batch = synthetic_batch(2, seed=7)
    with torch.no_grad():
        a, b = task.run(batch, hard=True), loaded.run(batch, hard=True)
        assert torch.equal(a.fr_pred, b.fr_pred) and torch.equal(a.mask, b.mask)
        assert torch.equal(task.net.importance_mask(batch["low"], ipr=0.1), loaded.net.importance_mask(batch["low"], ipr=0.1))
    with pytest.raises(InputError, match="expected a RecNNTask checkpoint"):
        load_task(path, expect="RecNNTask")


# ------------------------------------------------------------------------------------------
# config
# ------------------------------------------------------------------------------------------


def las_yaml():
    return OmegaConf.load(ROOT / "conf" / "model" / "las.yaml")


def test_yaml_keys_are_all_task_arguments():
    """A typo in las.yaml would be swallowed by **_; every key must be a real argument."""
    model = las_yaml()
    params = set(inspect.signature(LASTask.__init__).parameters) - {"self", "_"}
    meta = {"name", "_target_", "patience", "monitor"}
    assert set(model) - meta <= params, sorted(set(model) - meta - params)
    assert model.name == "las" and model.monitor == "val/loss" and model.patience == 20
    assert model.low_res == 64 and model.alpha == 50
    assert model._target_ == f"{LASTask.__module__}.{LASTask.__qualname__}"


def test_build_task_and_datamodule_kwargs():
    from imls_lightning.training.fit import build_task

    cfg = OmegaConf.create({"model": las_yaml(), "data": {"resolution": 128}})
    task = build_task(cfg)
    assert task.hparams.fr_size == 128 and task.hparams.low_res == 64
    assert task.hparams.recon_channels == cfg.model.recon_channels
    assert task.net.importance_net.net_upscale == 2
    assert LASTask.datamodule_kwargs(cfg) == {"fields": ("view", "fr"), "low_res": 64}
    cfg.data.resolution = 32  # the CPU default 64 does not fit a 32^2 cache
    with pytest.raises(InputError, match=r"^model.low_res=64: .*data.resolution=32"):
        build_task(cfg)


# ------------------------------------------------------------------------------------------
# exceptions
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, key",
    [
        (dict(low_res=12), "model.low_res"),          # does not divide 32
        (dict(low_res=64), "model.low_res"),          # larger than the FR-Image
        (dict(low_res=0), "model.low_res"),
        (dict(low_res=2.5), "model.low_res"),
        (dict(fr_size=0), "data.resolution"),
        (dict(post_upscale=3), "model.post_upscale"),  # 32 / 8 = 4 is not a multiple of 3
        (dict(mean=0.0), "model.mean"),
        (dict(mean=1.5), "model.mean"),
        (dict(mean="a lot"), "model.mean"),
        (dict(lower=0.3), "model.lower"),             # >= mean
        (dict(lower=-0.1), "model.lower"),
        (dict(delta=0.0), "model.delta"),
        (dict(alpha=0), "model.alpha"),
        (dict(alpha=float("inf")), "model.alpha"),
        (dict(recon_arch="resnet"), "model.recon_arch"),
        (dict(importance_channels=0), "model.importance_channels"),
        (dict(recon_blocks=-1), "model.recon_blocks"),
        (dict(importance_border=True), "model.importance_border"),
        (dict(l1_weight=0.0, mse_weight=0.0), "model.l1_weight"),
        (dict(heatmap_weight=-0.1), "model.heatmap_weight"),
        (dict(mse_weight=float("nan")), "model.mse_weight"),
        (dict(heatmap_center=float("inf")), "model.heatmap_center"),
        (dict(border=16), "model.border"),
        (dict(lr=0), "model.lr"),
        (dict(lr=-1e-3), "model.lr"),
    ],
)
def test_exception_bad_config_values(kw, key):
    with pytest.raises(InputError) as err:
        tiny_task(**kw)
    msg = str(err.value)
    assert msg.startswith(key + "=") and "\n" not in msg, msg


def test_exception_check_low_res():
    assert check_low_res(64, 512) == 64 and check_low_res(32, 32) == 32
    with pytest.raises(InputError, match="model.low_res"):
        check_low_res(48, 512)


def test_exception_bad_batches():
    task = tiny_task()
    batch = synthetic_batch()
    with pytest.raises(InputError, match="expected 'fr' and 'low'"):
        task.training_step({"fr": batch["fr"]}, 0)
    with pytest.raises(InputError, match="low_res"):
        task.training_step({"fr": batch["fr"], "low": F.interpolate(batch["fr"], size=(16, 16), mode="area")}, 0)
    with pytest.raises(InputError, match="fr_image"):
        task.validation_step({"fr": batch["fr"][:, :, :16, :16], "low": batch["low"]}, 0)


# ------------------------------------------------------------------------------------------
# end to end: the training CLI on the tiny procedural scene
# ------------------------------------------------------------------------------------------


def cli_low_res(resolution: int) -> int:
    """The paper's 64 when it fits (m >= 128), else the largest divisor of m that is <= m / 4."""
    if resolution >= 128 and resolution % 64 == 0:
        return 64
    return max(d for d in range(1, max(1, resolution // 4) + 1) if resolution % d == 0)


def run_train_cli(tmp_path: Path, resolution: int, *extra: str) -> tuple[subprocess.CompletedProcess, int]:
    """``python -m imls_lightning.train model=las scene=tiny data=tiny`` (fast_dev_run) in ``tmp_path``."""
    low = cli_low_res(resolution)
    # ++: fast_dev_run may or may not be in conf/trainer; set it either way
    cmd = [sys.executable, "-m", "imls_lightning.train", "model=las", "scene=tiny", "data=tiny",
           "++trainer.fast_dev_run=true", f"paths.runs_dir={tmp_path / 'runs'}",
           f"data.cache_dir={tmp_path / 'cache'}", f"model.low_res={low}", *extra]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    return proc, low


def test_cli_low_res_choice():
    assert [cli_low_res(m) for m in (512, 128, 64, 48, 32, 16)] == [64, 64, 16, 12, 8, 4]


def test_smoke_train_cli_fast_dev_run(tmp_path):
    for needed in ("conf/scene/tiny.yaml", "conf/data/tiny.yaml", "conf/renderer/vtk.yaml"):
        if not (ROOT / needed).is_file():
            pytest.skip(f"{needed} not written yet")
    proc, low = run_train_cli(tmp_path, int(OmegaConf.load(ROOT / "conf" / "data" / "tiny.yaml").resolution))
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    last = proc.stdout.strip().splitlines()[-1]
    ckpt = Path(last)
    assert ckpt.is_file() and ckpt.suffix == ".ckpt", last
    loaded = load_task(ckpt, expect="LASTask")
    assert loaded.hparams.low_res == low
    assert list((tmp_path / "cache").glob("*")), "the data module rendered no cache"
