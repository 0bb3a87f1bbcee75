"""Lightning callbacks of the project."""
from __future__ import annotations

from pathlib import Path

import lightning as L
import torch

from .viz import image_grid, save_image


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
