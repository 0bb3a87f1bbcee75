"""The evaluation: speed/accuracy of IML/S + RecNN against every baseline, on the same views in one run.

``python -m imls_lightning.evaluate scene=NAME checkpoints.ims=<IMS .ckpt> [checkpoints.las=<LAS .ckpt>]``
parses its config and calls :func:`evaluate` (:mod:`imls_lightning.evaluation.run`).

For each view of the cache's test trajectory (``views=test``; rendered if missing, with the
scene/data/renderer groups the networks were trained with) and each method - full ray cast, RecNN
alone, LAS (with a LAS checkpoint), IML + RecNN, IML/S + RecNN - every stage is timed (median of
``repeats`` runs after ``warmup``; see :func:`imls_lightning.evaluation.timing.time_method`) and the image is
scored against the cache's ground truth (PSNR, SSIM). Selective rendering is real: the renderer
ray-casts only the chosen pixels.

Sweeps on ``sweep_views`` views feed the latency/PSNR plot and the speed-quality front:

* IML + RecNN at each inference mean ``u`` in ``mean_values`` (the IML normalization target set at
  inference), and "IML IM, selectively rendered": the IML/S pipeline run with the IML's mask of
  that view in place of the IMS output (the IMS network still runs and is timed). It is the latency
  an IML/S would have if its IMS reproduced the IML's mask at that ``u``; its image equals
  IML + RecNN's (the numba renderer's selective render is exact).
* LAS at each IPR of ``las_iprs``;
* for the speed-quality front, IML/S + RecNN at each share of C of ``front_shares`` and blue noise +
  decoder at the same shares (:class:`Sweeps`).

The sweeps run on each sweep view right after that view's methods. The report's "Speed-quality front"
puts every method (the RecNN alone on a sparser pattern too, with ``checkpoints.recnn_sparser``) on the
sweep views, several points per method, and marks the Pareto front (:mod:`imls_lightning.report.front`).
The ORP is searched on held-out views no network was trained on (``orp_views``) and judged by an upper
bound on the mean gap the evaluated views will show (``orp_confidence``); the report shows its gap there
beside its gap on the evaluated views.

With ``options_sweep=true`` the IML/S network stages are also timed with each inference option
alone (``options_sweep_options``: half, channels_last, compile) on ``options_sweep_views`` views.

Output (``output_dir``): ``metrics.csv`` (view x method), ``sweep.csv``, ``options.csv``,
``config.yaml``, PNG plots, ``image_grid.png`` and ``report.md`` (written last, atomically; a run
deletes a previous report.md first, so a directory without one holds no finished evaluation). The
report's path is the last line of stdout. After the report, the ORP IML/S ran at (mean value, lift,
share of C and IPR on the validation views, epsilon) is recorded beside the IMS checkpoint,
``<ims.ckpt>.orp.json``, naming the checkpoint's SHA-256: renderers and viewers built from the
checkpoint alone run there (:mod:`imls_lightning.inference.operating_point`).

Modules: :mod:`~imls_lightning.evaluation.settings` (the validated settings), :mod:`~imls_lightning.evaluation.networks`
(the checkpoints, cross-checked), :mod:`~imls_lightning.evaluation.measurement` (one method on one view),
:mod:`~imls_lightning.evaluation.operating_point` (the ORP), :mod:`~imls_lightning.evaluation.baselines`,
:mod:`~imls_lightning.evaluation.sweeps` and :mod:`~imls_lightning.evaluation.run` (:func:`evaluate`, in steps).

Python:
    >>> from hydra import compose, initialize_config_dir          # doctest: +SKIP
    >>> with initialize_config_dir("/path/to/conf", version_base="1.3"):  # doctest: +SKIP
    ...     cfg = compose("evaluate", overrides=["scene=tiny", "data=tiny", "checkpoints.ims=ims.ckpt"])
    >>> report = evaluate(cfg)                                      # doctest: +SKIP
    >>> summary(report.parent / "metrics.csv")["imls"]["latency_ms"]["total"]   # doctest: +SKIP
"""
from __future__ import annotations

from ..report import summary
from .baselines import blue_noise_method, equal_share, ims_mask_at_share, sparser_method
from .measurement import image_quality, measure, spaced, view_loader
from ..render.camera import view_tensor
from .networks import Networks, check_trained_on, load_networks, load_sparser_recnn
from .operating_point import gap_by_distance, orp_search_views, orp_with_lift, paired_gap, record_operating_point
from .run import evaluate
from .settings import FRONT_SHARES, MIN_REPEATS, ORP_VIEWS, Settings, parse_settings
from .sweeps import Sweeps, options_sweep

__all__ = [
    "evaluate", "summary", "Settings", "parse_settings", "MIN_REPEATS", "FRONT_SHARES", "ORP_VIEWS",
    "Networks", "load_networks", "load_sparser_recnn", "check_trained_on",
    "image_quality", "measure", "spaced", "view_tensor", "view_loader",
    "orp_search_views", "orp_with_lift", "paired_gap", "gap_by_distance", "record_operating_point",
    "sparser_method", "blue_noise_method", "ims_mask_at_share", "equal_share", "Sweeps", "options_sweep",
]
