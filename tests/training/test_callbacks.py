"""imls_lightning.training.callbacks: the image-grid callback in a real Trainer run, and the CSV
logger that keeps a resumed run's earlier rows."""
from __future__ import annotations

import lightning as L
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
