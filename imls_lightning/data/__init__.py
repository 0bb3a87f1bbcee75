"""Data for training: the DataModule over a (view, image) cache, and the IML labels the IMS learns.

* :mod:`.datamodule`: :class:`ImlsDataModule` (splits, crops, loaders) and :class:`ViewImageDataset`;
  for ``model=ims`` it makes the IML labels of its cache (the task never renders or labels).
* :mod:`.labels`: :class:`ImportanceLabels` and :func:`ensure_labels` (made once per cache and IML,
  checked by content before reuse).
"""
from .datamodule import ImlsDataModule, ViewImageDataset
from .labels import ImportanceLabels, ensure_labels, labels_path_for

__all__ = ["ImlsDataModule", "ViewImageDataset", "ImportanceLabels", "ensure_labels", "labels_path_for"]
