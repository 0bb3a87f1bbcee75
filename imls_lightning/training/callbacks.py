"""Lightning callbacks and loggers of the project."""
from __future__ import annotations

import csv
import time
from pathlib import Path

import lightning as L
import torch
from lightning.fabric.loggers.logger import rank_zero_experiment
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger
from lightning.pytorch.loggers.csv_logs import ExperimentWriter

from ..base.images import image_grid, save_image


#: the checkpoint key of the views a network trained on (:class:`TrainingViews`)
TRAINING_VIEWS_KEY = "imls_training_views"


class TrainingViews(L.Callback):
    """Record, in every checkpoint, which views the network trained on: the cache's view ``seed`` and ``num_views``
    (``checkpoint["imls_training_views"]``). An evaluation checks with it that the views it chooses settings on are
    none the network trained on (:func:`imls_lightning.evaluation.protocol.check_view_seeds`), also for a checkpoint
    copied out of its run folder.

    Example:
        >>> ckpt = {}
        >>> TrainingViews(seed=100, num_views=1500).on_save_checkpoint(None, None, ckpt)
        >>> ckpt["imls_training_views"]
        {'seed': 100, 'num_views': 1500}
    """

    def __init__(self, seed: int, num_views: int):
        self.views = {"seed": int(seed), "num_views": int(num_views)}

    def on_save_checkpoint(self, trainer, pl_module, checkpoint) -> None:
        checkpoint[TRAINING_VIEWS_KEY] = dict(self.views)


class ChunkTimer(L.Callback):
    """Stop a fit at the end of the epoch after which the next one would overrun ``minutes`` of this
    process's wall time (training that outlives one sitting: ``chunk_minutes``).

    Unlike Lightning's ``Timer`` (``trainer.max_time``) it keeps no state in the checkpoint: every
    invocation that resumes the run gets a whole chunk again. ``stopped`` tells the caller that the
    chunk, not the schedule, ended the fit.

    Example:
        >>> t = ChunkTimer(30)
        >>> t.budget_s, t.stopped
        (1800.0, False)
    """

    def __init__(self, minutes: float):
        self.budget_s = float(minutes) * 60.0
        self.stopped = False
        self._t0 = self._epoch_t0 = 0.0

    def on_train_start(self, trainer, pl_module) -> None:
        self._t0 = time.perf_counter()

    def on_train_epoch_start(self, trainer, pl_module) -> None:
        self._epoch_t0 = time.perf_counter()

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        now = time.perf_counter()
        last = trainer.max_epochs is not None and trainer.max_epochs >= 0 and trainer.current_epoch + 1 >= trainer.max_epochs
        if not last and (now - self._t0) + (now - self._epoch_t0) > self.budget_s:
            trainer.should_stop = True
            self.stopped = True


class LastEveryEpochCheckpoint(ModelCheckpoint):
    """Lightning's :class:`~lightning.pytorch.callbacks.ModelCheckpoint` whose ``last.ckpt`` follows every
    epoch, improving or not.

    Lightning 2.6 writes ``last.ckpt`` only at a step where a top-k checkpoint was written, so with
    ``save_top_k=1`` an epoch that did not beat the best left ``last.ckpt`` at the best one. A chunked run
    (``chunk_minutes``) resumed from there and trained every epoch since the best again: rt_plumes's IMS
    ran its third epoch twice that way, about 20 minutes each on 2 cores. Here ``last.ckpt`` is written at
    the end of every epoch the parent's hooks did not already save, with the same ``save_last`` setting, and
    its state (the best score and paths) under the parent's key, so runs checkpointed before resume alike.

    Example:
        >>> cb = LastEveryEpochCheckpoint(monitor="val/loss", save_top_k=1, save_last=True)
        >>> cb.save_last
        True
    """

    @property
    def state_key(self) -> str:
        # the parent's key: a run checkpointed by Lightning's class resumes with its best score and paths (with the
        # subclass's own name they were dropped, the old best was never removed and last.ckpt went stale beside a
        # new last-v1.ckpt)
        return super().state_key.replace(type(self).__qualname__, ModelCheckpoint.__qualname__, 1)

    def on_train_epoch_end(self, trainer, pl_module) -> None:
        super().on_train_epoch_end(trainer, pl_module)
        if self._should_save_on_train_epoch_end(trainer):
            self._save_last_if_not_saved(trainer)

    def on_validation_end(self, trainer, pl_module) -> None:
        super().on_validation_end(trainer, pl_module)
        if not self._should_save_on_train_epoch_end(trainer):
            self._save_last_if_not_saved(trainer)

    def _save_last_if_not_saved(self, trainer) -> None:
        # _should_skip_saving_checkpoint is also true when this step was saved already (the top-k and last pair)
        if self.save_last and not self._should_skip_saving_checkpoint(trainer):
            self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))


class ImageGridCallback(L.Callback):
    """Save a grid of the task's :meth:`visuals` for the first validation batch.

    Writes ``<run>/images/epoch{E:03d}.png`` (and ``latest.png``) and, with a TensorBoard logger,
    adds the grid as an image. Rows are samples, columns the task's named images.

    Args:
        every_n_epochs: how often.
        max_images: samples per grid.
    """

    def __init__(self, every_n_epochs: int = 1, max_images: int = 4, tile: int = 128):
        self.every_n_epochs = max(1, int(every_n_epochs))
        self.max_images = max(1, int(max_images))
        self.tile = int(tile)

    def on_validation_batch_end(self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0):
        if batch_idx != 0 or trainer.sanity_checking or not trainer.is_global_zero:
            return
        if trainer.current_epoch % self.every_n_epochs:
            return
        visuals = getattr(pl_module, "visuals", None)
        if visuals is None:
            return
        with torch.no_grad():
            titles, tensors = visuals(batch)
        if not tensors:
            return
        n = min(self.max_images, tensors[0].shape[0])
        rows = [[t[i] for t in tensors] for i in range(n)]
        grid = image_grid(rows, col_titles=titles, tile=self.tile)
        out = Path(trainer.default_root_dir) / "images"
        save_image(grid, out / f"epoch{trainer.current_epoch:03d}.png")
        save_image(grid, out / "latest.png")
        for logger in trainer.loggers:
            exp = getattr(logger, "experiment", None)
            if hasattr(exp, "add_image"):
                import numpy as np

                exp.add_image("val/grid", np.asarray(grid), trainer.current_epoch, dataformats="HWC")


class _AppendingWriter(ExperimentWriter):
    """Lightning's CSV writer, except that an existing ``metrics.csv`` is continued, not deleted."""

    def _check_log_dir_exists(self) -> None:
        # Lightning deletes metrics.csv here, so a resumed run lost the epochs before the resume;
        # continue the file instead, with its header as the known columns
        path = Path(self.metrics_file_path)
        if path.is_file():
            with path.open(newline="") as f:
                header = next(csv.reader(f), [])
            self.metrics_keys = list(header)


class ResumableCSVLogger(CSVLogger):
    """``CSVLogger`` whose ``metrics.csv`` survives a resumed run: the rows logged after the
    resume are appended to those logged before it (Lightning's own logger deletes the file).

    A run that starts over instead moves the old file aside first (:func:`set_aside_metrics`).

    Example:
        >>> logger = ResumableCSVLogger("runs/x", name="csv", version="")  # doctest: +SKIP
    """

    @property
    @rank_zero_experiment
    def experiment(self) -> ExperimentWriter:
        if self._experiment is None:
            self._fs.makedirs(self.root_dir, exist_ok=True)
            self._experiment = _AppendingWriter(log_dir=self.log_dir)
        return self._experiment


def set_aside_metrics(log_dir: Path) -> Path | None:
    """Rename ``<log_dir>/metrics.csv`` to the first free ``metrics.previous<N>.csv`` (a run that
    trains again from the start keeps its old log beside the new one); returns the new name."""
    path = Path(log_dir) / ExperimentWriter.NAME_METRICS_FILE
    if not path.is_file():
        return None
    n = 1
    while (target := path.with_name(f"metrics.previous{n}.csv")).exists():
        n += 1
    path.rename(target)
    return target
