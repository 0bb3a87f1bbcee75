"""Adaptive importance: a per-view mean value instead of one fixed ``u`` (the paper's stated limitation).

The IML normalizes its importance map to a prescribed mean value ``u`` and keeps C-Image pixel ``i``
when ``PIM'_i > P_i``, so about a share ``u`` of the pattern's pixels is rendered, whatever the view.
The ORP (:mod:`imls_lightning.orp`) picks the smallest *fixed* ``u`` whose IML + RecNN stays within
``epsilon`` (1 dB) of the RecNN alone. A simple view (little of the volume on screen) needs fewer
pixels than a busy one for the same quality. This package makes ``u`` a function of the view:

1. **Per-view labels** (:func:`compute_labels`): for each view of a cache split, the smallest
   ``u_v`` in ``[0.01, 1]`` such that the path on that view is within ``epsilon_db`` PSNR of the
   RecNN alone (against the FR ground truth), by bisection in ``log u`` with a fixed number of steps
   (:func:`bisect_mean`), vectorized over a batch of views. The path is the product's, IML/S
   (``source="ims"``: the IMS's PIM' from the view, scaled to ``u_v``, decoder, RecNN), or the
   trained IML's own (``source="iml"``, :func:`iml_pim`, :func:`im_at_means`: encoder,
   normalization at ``u_v``, hard rejection sampling against ``P``, decoder, RecNN).
2. **A mean predictor** (:class:`MeanPredictor`): view ``(B, 9)`` -> ``u`` ``(B,)`` in ``[0.01, 1]``,
   a small MLP with a sigmoid in ``log u``, trained on the labels of the train split by
   :func:`train_predictor` (L1 on ``log u``, full batch, seeded); ``margin`` multiplies predictions.
3. **The adaptive renderer** (:class:`AdaptiveIMLSRenderer`): the IMS (``target="pim"``) regresses
   ``PIM'`` normalized to the IML's trained mean ``u_train``; with ``l = 0`` the normalization is
   linear in ``u``, so ``PIM'(u_v) = PIM'(u_train) * u_v / u_train`` exactly (:func:`scaled_pim_im`);
   the rest (selective render of those pixels, decoder, RecNN) is :class:`IMLSRenderer`'s. Its
   timings add the predictor's stage ``"mean"``. :class:`AdaptiveIMLPlusRecNN` is the upper bound
   (importance from the rendered C-Image at ``u_v``).
4. **The CLI** (:func:`run_adaptive`): labels (cached next to the IMS run and reused), predictor,
   and the comparison on the test trajectory with the fixed-mean alternatives (the trained mean, the
   fixed-mean ORP on the validation views, searched on the product path as the evaluation searches it
   when the labels are, the fixed mean whose average IPR matches the adaptive one),
   written as ``adaptive.md`` + ``adaptive.csv`` + ``adaptive.png``; and the trade-off
   (:func:`quality_at_means`, :func:`tradeoff`): the predictor at several margins against the whole
   curve of fixed means on the (average IPR, average PSNR) plane (``tradeoff.png`` / ``.csv``).

    python -m imls_lightning.adaptive scene=flame data=small ims_checkpoint=<IMS .ckpt> epsilon_db=1.0

One idea per module, every public name re-exported here: :mod:`~imls_lightning.adaptive.checks`
(validation helpers), :mod:`~imls_lightning.adaptive.labels` (1.),
:mod:`~imls_lightning.adaptive.predictor` (2.), :mod:`~imls_lightning.adaptive.renderer` (3.),
:mod:`~imls_lightning.adaptive.tradeoff` (the trade-off measurement),
:mod:`~imls_lightning.adaptive.settings`, :mod:`~imls_lightning.adaptive.report` (``adaptive.md``,
CSVs, plots) and :mod:`~imls_lightning.adaptive.cli` (4.; ``__main__.py`` runs it).

Example:
    >>> import torch
    >>> res = bisect_mean(lambda u: 10 * (0.2 - u).clamp(min=0), 3, epsilon_db=1.0, steps=12)
    >>> [round(x, 3) for x in res.u.tolist()], res.met.tolist()     # gap <= 1 dB from u = 0.1
    ([0.1, 0.1, 0.1], [True, True, True])
"""
from __future__ import annotations

from ..core.importance import MEAN_RANGE
from ..tasks.ims import scaled_pim_im
from .checks import check_epsilon, check_integer, clamp_mean
from .cli import CONF_DIR, main, run_adaptive, run_dir_of
from .labels import (
    REFERENCES,
    SOURCES,
    UNREACHABLE,
    BisectResult,
    MeanLabels,
    bisect_mean,
    check_source,
    compute_labels,
    im_at_means,
    iml_pim,
    mask_function,
    view_complexity,
)
from .predictor import ConstantMean, MeanPredictor, TableMean, train_predictor
from .renderer import AdaptiveIMLPlusRecNN, AdaptiveIMLSRenderer
from .report import LABELS
from .settings import PREDICTOR_DEFAULTS, Settings, parse_settings
from .tradeoff import TradeoffPoint, mean_for_ipr, quality_at_means, tradeoff

__all__ = [
    "MEAN_RANGE",
    "check_epsilon",
    "BisectResult",
    "bisect_mean",
    "iml_pim",
    "im_at_means",
    "MeanLabels",
    "compute_labels",
    "quality_at_means",
    "TradeoffPoint",
    "tradeoff",
    "view_complexity",
    "MeanPredictor",
    "ConstantMean",
    "train_predictor",
    "scaled_pim_im",
    "AdaptiveIMLSRenderer",
    "AdaptiveIMLPlusRecNN",
    "mean_for_ipr",
    "run_adaptive",
    "main",
    "REFERENCES",
    "SOURCES",
    "UNREACHABLE",
    "LABELS",
    "PREDICTOR_DEFAULTS",
    "Settings",
    "parse_settings",
    "run_dir_of",
    "CONF_DIR",
    "check_integer",
    "clamp_mean",
    "check_source",
    "mask_function",
    "TableMean",
]
