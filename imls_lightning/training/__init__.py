"""Training one configured model: fit, resume or reuse a run, and the Lightning plumbing it uses.

* :mod:`.fit`: :func:`train` (fit / resume / reuse one model, test it, write ``result.json``),
  :func:`build_task` and :func:`build_datamodule`.
* :mod:`.callbacks`: :class:`ImageGridCallback` and :class:`ResumableCSVLogger`.
"""
from .callbacks import ImageGridCallback, ResumableCSVLogger
from .fit import build_datamodule, build_task, train

__all__ = ["train", "build_task", "build_datamodule", "ImageGridCallback", "ResumableCSVLogger"]
