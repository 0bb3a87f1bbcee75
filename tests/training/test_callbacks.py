"""imls_lightning.training.callbacks: the image-grid callback in a real Trainer run, and the CSV
logger that keeps a resumed run's earlier rows, the checkpoint whose last.ckpt follows every epoch."""
from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader, TensorDataset

from imls_lightning.training.callbacks import ImageGridCallback


class _Tiny(L.LightningModule):
    """A 1x1 convolution with the ``visuals`` hook the callback draws."""

    def __init__(self):
        super().__init__()
        self.net = torch.nn.Conv2d(3, 3, 1)

    def training_step(self, batch, _):
        (x,) = batch
        return torch.nn.functional.mse_loss(self.net(x), x)

    def validation_step(self, batch, _):
        (x,) = batch
        self.log("val/loss", torch.nn.functional.mse_loss(self.net(x), x))

    def visuals(self, batch):
        (x,) = batch
        return ["input", "output"], [x, self.net(x).clamp(0, 1)]

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


def test_smoke_image_grid_callback_writes_one_grid_per_epoch(tmp_path):
    data = DataLoader(TensorDataset(torch.rand(4, 3, 8, 8)), batch_size=2)
    trainer = L.Trainer(max_epochs=2, default_root_dir=tmp_path, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
                        callbacks=[ImageGridCallback(every_n_epochs=1, max_images=2, tile=16)])
    trainer.fit(_Tiny(), data, data)
    names = sorted(p.name for p in (tmp_path / "images").glob("*.png"))
    assert names == ["epoch000.png", "epoch001.png", "latest.png"]


def test_set_aside_metrics_keeps_every_earlier_log(tmp_path):
    from imls_lightning.training.callbacks import set_aside_metrics

    assert set_aside_metrics(tmp_path) is None
    for text in ("first", "second"):
        (tmp_path / "metrics.csv").write_text(text)
        set_aside_metrics(tmp_path)
    assert not (tmp_path / "metrics.csv").exists()
    assert (tmp_path / "metrics.previous1.csv").read_text() == "first"
    assert (tmp_path / "metrics.previous2.csv").read_text() == "second"


def test_resumable_csv_logger_appends_under_the_old_header(tmp_path):
    import csv

    from imls_lightning.training.callbacks import ResumableCSVLogger

    first = ResumableCSVLogger(tmp_path, name="csv", version="")
    first.log_metrics({"a": 1.0, "b": 2.0}, step=0)
    first.save()
    again = ResumableCSVLogger(tmp_path, name="csv", version="")  # a resumed run
    again.log_metrics({"b": 3.0}, step=1)
    again.log_metrics({"c": 4.0}, step=2)  # a column the first part never logged
    again.save()
    rows = list(csv.DictReader((tmp_path / "csv" / "metrics.csv").open(newline="")))
    assert [(r["step"], r["a"], r["b"], r["c"]) for r in rows] == [("0", "1.0", "2.0", ""), ("1", "", "3.0", ""), ("2", "", "", "4.0")]


def _fit(tmp_path, module, checkpoint_class, max_epochs, ckpt_path=None, **trainer_kw):
    """A real fit of ``module`` on 2 steps an epoch, checkpointed into ``tmp_path`` the way the default config does."""
    data = DataLoader(TensorDataset(torch.rand(4, 3, 8, 8)), batch_size=2)
    cb = checkpoint_class(dirpath=tmp_path, filename="epoch{epoch:03d}", auto_insert_metric_name=False, monitor="val/score",
                          mode="max", save_top_k=1, save_last=True, enable_version_counter=False)
    trainer = L.Trainer(max_epochs=max_epochs, default_root_dir=tmp_path, logger=False, enable_progress_bar=False,
                        enable_model_summary=False, num_sanity_val_steps=0, callbacks=[cb], **trainer_kw)
    trainer.fit(module, data, data, ckpt_path=ckpt_path, weights_only=True)
    return trainer, cb


class _Worsening(_Tiny):
    """Its monitored score gets worse every validation: only the first is ever the best."""

    def validation_step(self, batch, _):
        self.log("val/score", -float(self.global_step))


@pytest.mark.parametrize("val_check_interval", [1.0, 0.5])  # saved at the epoch's end / after a validation
def test_last_checkpoint_follows_every_epoch_when_the_best_does_not_improve(tmp_path, val_check_interval):
    """Lightning 2.6's ModelCheckpoint left last.ckpt at the best epoch, so a resumed chunk trained the epochs
    since the best again. A rerun with more epochs continues from the last one, not from the best."""
    from imls_lightning.training.callbacks import LastEveryEpochCheckpoint

    trainer, cb = _fit(tmp_path, _Worsening(), LastEveryEpochCheckpoint, 3, val_check_interval=val_check_interval)
    last = torch.load(tmp_path / "last.ckpt", weights_only=True)
    assert (last["epoch"], last["global_step"]) == (2, 6)
    assert Path(cb.best_model_path).name == "epoch000.ckpt"  # the top-k checkpoint is still the best one
    assert sorted(p.name for p in tmp_path.glob("*.ckpt")) == ["epoch000.ckpt", "last.ckpt"]
    trainer, _ = _fit(tmp_path, _Worsening(), LastEveryEpochCheckpoint, 4, tmp_path / "last.ckpt",
                      val_check_interval=val_check_interval)
    assert trainer.global_step == 8  # one more epoch of 2 steps, not three


def test_default_callbacks_use_the_every_epoch_last_checkpoint():
    from hydra import compose, initialize_config_dir
    from hydra.utils import get_class

    from imls_lightning.training.callbacks import LastEveryEpochCheckpoint

    with initialize_config_dir(str(Path(__file__).resolve().parents[2] / "conf"), version_base=None):
        cfg = compose("train")
    assert get_class(cfg.callbacks.model_checkpoint._target_) is LastEveryEpochCheckpoint
    assert cfg.callbacks.model_checkpoint.save_last


class _Improving(_Tiny):
    """Its monitored score improves at every validation but the third."""

    def validation_step(self, batch, _):
        self.log("val/score", -1.0 if self.global_step == 6 else float(self.global_step))


def test_a_run_checkpointed_by_lightnings_class_resumes_with_its_best_and_one_last_file(tmp_path):
    """The state sits under ModelCheckpoint's key: a run started before the switch keeps its best score and its
    paths, the superseded best is removed, and last.ckpt is the one file resume reads (no last-v1.ckpt beside it)."""
    from imls_lightning.training.callbacks import LastEveryEpochCheckpoint

    _fit(tmp_path, _Improving(), L.pytorch.callbacks.ModelCheckpoint, 2)  # epochs 0-1: epoch001 is the best (score 4)
    _, cb = _fit(tmp_path, _Improving(), LastEveryEpochCheckpoint, 3, tmp_path / "last.ckpt")  # epoch 2 scores -1
    assert float(cb.best_model_score) == 4.0 and Path(cb.best_model_path).name == "epoch001.ckpt"
    assert torch.load(tmp_path / "last.ckpt", weights_only=True)["epoch"] == 2
    _, cb = _fit(tmp_path, _Improving(), LastEveryEpochCheckpoint, 4, tmp_path / "last.ckpt")  # epoch 3 scores 8: the new best
    assert sorted(p.name for p in tmp_path.glob("*.ckpt")) == ["epoch003.ckpt", "last.ckpt"]
    assert cb.state_key == L.pytorch.callbacks.ModelCheckpoint(monitor="val/score", mode="max").state_key
