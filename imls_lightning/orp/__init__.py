"""Optimal rendering percentage (ORP): search the IML mean value by bisection / k-section.

The ORP (paper, "Hyperparameter Tuning: Mean Value" and "Free Rendering Latency Improvement") is the
fewest important pixels whose IML + RecNN reconstruction stays within ``epsilon`` (1 dB) PSNR of the
RecNN alone. The share of important C-Image pixels follows the mean value ``u`` of the importance
normalization, so the search runs over ``u`` in ``[0.01, 1]``, assuming that the gap

    gap(u) = PSNR_RecNN - PSNR_IML+RecNN(u)                       (dB, on the validation views)

decreases as ``u`` grows. This package holds, one idea per module (every public name is
re-exported here):

* :mod:`~imls_lightning.orp.search`: the search itself, pure, torch-free and independent of Hydra:
  :class:`ORPSettings`, :class:`ORPSearch` (ask/tell: ``next_batch()`` -> ``tell(...)``, or
  ``run(objective)``) and its result :class:`ORPResult`;
* :mod:`~imls_lightning.orp.overrides`: Hydra override lines (quoting, keys, the IMS job's overrides);
* :mod:`~imls_lightning.orp.job`: the work of one sweep job, :func:`orp_job`: train the IML at one
  ``u`` (reusing a finished run), evaluate IML + RecNN (and IML/S + RecNN) against the RecNN alone
  on the validation views, time the stages, and return the record (also written as
  ``orp_job.json`` in the job directory); :func:`orp_recnn_job`, the sweep's preparatory job when
  ``recnn.checkpoint`` is not set: train (or reuse) the RecNN of the same scene/data;
  :func:`orp_main` dispatches between them (called by ``imls_lightning.train`` when the config has
  an ``orp_job`` node);
* :mod:`~imls_lightning.orp.report`: :func:`orp_report` (the ``orp.yaml`` data) and :func:`format_table`.

Importing the package loads no torch (the sweeper plugin imports it while Hydra scans plugins).

The Hydra side (``hydra/sweeper=orp``) is ``hydra_plugins/orp_sweeper``; see ``docs/ORP.md``.

Search rule. Each round evaluates ``k`` interior points that split the bracket ``[lo, hi]`` into
``k + 1`` equal parts (``k = 1``: bisection), evenly in ``log u`` by default (``scale="log"``: the
IPR is roughly proportional to ``u`` and the bracket spans two decades, so equal *relative* steps
give the same precision to a small and a large ORP; ``scale="linear"`` is available). The smallest
``u`` meeting epsilon becomes ``hi``, the largest failing ``u`` below it becomes ``lo``. The search
stops when ``hi <= lo * (1 + tolerance)`` (``tolerance`` is *relative*: 0.1 = the mean value is
known to 10 %) or after ``max_rounds`` rounds. The upper end itself is evaluated only when no
evaluated point met epsilon (one extra round): if it fails too, there is no ORP in the bracket and
the result says so. A failed evaluation (exception, NaN, missing result) is recorded and counts as
not meeting epsilon.

Example:
    >>> search = ORPSearch(epsilon_db=1.0, tolerance=0.1)
    >>> res = search.run(batched(lambda u: 10 * (0.2 - u) if u < 0.2 else 0.0))  # gap <= 1 dB from u = 0.1
    >>> res.found, 0.1 <= res.mean <= 0.11, res.rounds
    (True, True, 6)
"""
from __future__ import annotations

from .job import JOB_FILE, STAGES, evaluate_quality, orp_job, orp_main, orp_recnn_job
from .overrides import ims_overrides_for, override_key, quote_override_value
from .report import REPORT_FILE, format_table, orp_report
from .search import (
    DEFAULTS,
    GAP_OF,
    JOB_KEYS,
    MEAN_RANGE,
    SCALES,
    Evaluation,
    GapBound,
    ORPJobError,
    ORPResult,
    ORPSearch,
    ORPSettings,
    batched,
    describe_error,
    evaluation_from,
    future_path_passes,
    gap_upper_bound,
    pass_gap_bound,
    path_passes,
    round_mean,
    strata_by_rank,
    stratified_gap_bound,
    protocol_gap_record,
)

__all__ = [
    "DEFAULTS",
    "MEAN_RANGE",
    "SCALES",
    "GAP_OF",
    "ORPSettings",
    "Evaluation",
    "ORPResult",
    "ORPSearch",
    "batched",
    "evaluation_from",
    "gap_upper_bound",
    "pass_gap_bound",
    "path_passes",
    "future_path_passes",
    "stratified_gap_bound",
    "protocol_gap_record",
    "strata_by_rank",
    "GapBound",
    "round_mean",
    "quote_override_value",
    "ORPJobError",
    "orp_main",
    "orp_job",
    "orp_recnn_job",
    "evaluate_quality",
    "orp_report",
    "format_table",
    "JOB_FILE",
    "REPORT_FILE",
    "JOB_KEYS",
    "STAGES",
    "override_key",
    "ims_overrides_for",
    "describe_error",
]
