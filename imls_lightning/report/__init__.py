"""Evaluation report: the metrics CSV, its per-method summary, paper-style Markdown tables and plots.

:mod:`imls_lightning.evaluation` measures; this package only formats. Every file is written atomically
(temporary name + rename), so an interrupted run never leaves a half-written CSV, PNG or report.

Plots use matplotlib's object-oriented API on the Agg canvas (no pyplot global state, no display).

Example:
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> rows = [{"view": 0, "row": 40, "method": "recnn", "total_ms": 2.0, "recnn_ms": 1.0,
    ...          "selective_render_ms": 1.0, "ipr": 0.25, "psnr": 30.0, "ssim": 0.9}]
    >>> p = write_metrics_csv(rows, d / "metrics.csv")
    >>> summary(p)["recnn"]["latency_ms"]["total"]
    2.0

One idea per module, every public name re-exported here: :mod:`~imls_lightning.report.writer`
(the one report writer: the Markdown table, the number in a cell, the Markdown, CSV and YAML files),
:mod:`~imls_lightning.report.names` (labels, colours, CSV columns), :mod:`~imls_lightning.report.metrics_csv`
(the metrics CSV and the per-method summary), :mod:`~imls_lightning.report.machine` (command line, machine),
:mod:`~imls_lightning.report.tables` (Markdown tables), :mod:`~imls_lightning.report.front` (the
speed-quality front: its points, the Pareto front, where IML/S lies), :mod:`~imls_lightning.report.plots` and
:mod:`~imls_lightning.report.document` (``report.md``).
"""
from __future__ import annotations

from .document import ReportContext, render_markdown, write_report
from .front import front_markdown, front_point, front_points, front_verdict, pareto_front
from .machine import BUSY_LIMIT, OtherLoad, busy_cores, hydra_command, machine_info, shared_cores_warning
from .metrics_csv import number, read_csv, summarize_rows, summary, write_metrics_csv
from .names import (
    MASK_LABELS,
    METHOD_COLORS,
    METHOD_LABELS,
    METHOD_ORDER,
    METRIC_COLUMNS,
    OPTION_COLUMNS,
    STAGE_COLORS,
    STAGE_LABELS,
    SWEEP_COLUMNS,
)
from .plots import (
    error_map,
    im_to_fr_mask,
    new_figure,
    plot_image_grid,
    plot_latency_vs_psnr,
    plot_front,
    plot_options,
    plot_psnr_per_view,
    plot_stage_breakdown,
    save_figure,
)
from .tables import (equal_share_markdown, latency_table, options_table, quality_table, speedup, speedup_table, sweep_label,
                     sweep_points, sweep_table)
from .writer import (atomic_write_text, csv_text, fmt, fmt_pct, markdown_text, md_table, write_config, write_csv,
                     write_markdown, write_yaml)

__all__ = [
    "METHOD_LABELS", "METHOD_ORDER", "METRIC_COLUMNS", "SWEEP_COLUMNS", "OPTION_COLUMNS", "STAGE_LABELS",
    "atomic_write_text", "write_metrics_csv", "read_csv", "summarize_rows", "summary", "machine_info", "busy_cores", "OtherLoad", "BUSY_LIMIT", "shared_cores_warning", "md_table",
    "fmt", "fmt_pct", "speedup", "latency_table", "speedup_table", "quality_table", "sweep_table", "options_table",
    "sweep_points", "error_map", "im_to_fr_mask", "plot_stage_breakdown", "plot_psnr_per_view",
    "plot_latency_vs_psnr", "plot_options", "plot_image_grid", "new_figure", "save_figure", "ReportContext", "write_report",
    "render_markdown",
    "STAGE_COLORS", "METHOD_COLORS", "MASK_LABELS", "hydra_command", "equal_share_markdown", "number", "sweep_label",
    "pareto_front", "front_point", "front_points", "front_markdown", "front_verdict", "plot_front",
    "csv_text", "write_csv", "markdown_text", "write_markdown", "write_yaml", "write_config",
]
