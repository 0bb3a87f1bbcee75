"""The paper-scale benchmark (``make bench-paper``, ``python -m imls_lightning.bench_paper``): the demo's
stages (:func:`~imls_lightning.pipelines.demo.demo`) for every scene x RecNN at the paper's scale, then
the CSVs, ``paper_scale.md``, the breakdown plot and the paper-scale section of ``BENCHMARKS.md``
(:func:`bench_paper`)."""
from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError

from ..estimate import estimate_interval, read_estimate, speedup_from_estimate
from ..orp.overrides import override_key
from ..report import (atomic_write_text, equal_share_markdown, fmt, fmt_pct, md_table, shared_cores_warning, speedup,
                      write_markdown)
from ..report import write_csv as report_csv
from .demo import demo
from ..base.paths import log
from .stages import dry_stage, override_list, read_summary, renderer_overrides, run_stage


#: the columns of ``benchmarks/paper_scale.csv``, in order (issue 18)
LEGACY_COLUMNS = ("scene", "recnn", "fr_size", "c_size", "sample_distance_voxels", "mean", "c_share", "ipr",
                  "psnr_recnn_db", "psnr_imls_db", "gap_db", "recnn_ms", "imls_ms", "speedup", "las_ms", "las_psnr_db", "full_ms")
#: issue 31 appends the before-training estimate's columns (python -m imls_lightning.estimate): the volume's size,
#: the ray cast of the whole C pattern, the networks IML/S adds, bilinear C->FR and the bound at the row's share
ESTIMATE_COLUMNS = ("volume_dims", "c_render_ms", "nets_ms", "bilinear_db", "estimated_speedup")
#: whether the ray caster skipped empty space where the row was timed (bench_paper's ``skip_empty``; rows before it: true)
RENDERER_COLUMNS = ("skip_empty",)
#: the margin of the object floor the evaluation chose on validation views (``orp_object_floor``; empty: no floor)
FLOOR_COLUMNS = ("object_floor_margin",)
#: the most cores other processes kept busy while one of the row's views was timed (the evaluation's ``timing_load``;
#: above :data:`~imls_lightning.report.machine.BUSY_LIMIT` its times read high; empty: not measured, rows before it)
LOAD_COLUMNS = ("timing_busy_cores",)
#: the speed-up's 95% bootstrap interval over the row's timed views (the evaluation's ``speedup_interval``; empty: rows
#: before it whose per-view times were not kept)
INTERVAL_COLUMNS = ("speedup_low", "speedup_high")
#: the estimate's 95% interval at the row's share over the estimate's views resampled (empty: an estimate without
#: per-view times, or made by an earlier method; ``estimate.estimate_interval``)
ESTIMATE_INTERVAL_COLUMNS = ("estimated_low", "estimated_high")
#: LAS at the product's promise (the evaluation's ``las_searched``): the IPR searched on validation views (its mean
#: over the bands), its total and PSNR; empty: not measured. ``las_ms`` / ``las_psnr_db`` stay LAS at IML/S's IPR
LAS_SEARCHED_COLUMNS = ("las_searched_ipr", "las_searched_ms", "las_searched_psnr_db")
#: the fastest baseline (the evaluation's ``both_ray_casters``): the RecNN alone and IML/S with empty-space skipping
#: on and off, timed in one run, and IML/S's faster configuration against the faster RecNN alone with its interval;
#: ``trajectory_seed``: the fresh test trajectory the row was measured on (empty: the cache's own, seed data.seed).
#: Empty where not measured (rows before it, or lost networks)
FASTEST_COLUMNS = ("recnn_skip_ms", "recnn_noskip_ms", "imls_skip_ms", "imls_noskip_ms", "speedup_vs_fastest",
                   "speedup_vs_fastest_low", "speedup_vs_fastest_high", "trajectory_seed",
                   # LAS at equal quality (within 0.1 dB of IML/S's validation gap; evaluation.las_point.equal_quality_point)
                   "las_equal_ipr", "las_equal_ms", "las_equal_psnr_db")
#: the groups of columns in the order they were appended to the table
COLUMN_GROUPS = (LEGACY_COLUMNS, ESTIMATE_COLUMNS, RENDERER_COLUMNS, FLOOR_COLUMNS, LOAD_COLUMNS, INTERVAL_COLUMNS,
                 ESTIMATE_INTERVAL_COLUMNS, LAS_SEARCHED_COLUMNS, FASTEST_COLUMNS)
CSV_COLUMNS = sum(COLUMN_GROUPS, ())
#: the tables written before each group of columns was appended, still read
EARLIER_COLUMNS = tuple(sum(COLUMN_GROUPS[:n], ()) for n in range(1, len(COLUMN_GROUPS)))
#: the columns of ``benchmarks/paper_scale_adaptive.csv``: the per-view adaptive mean of each pair
#: (``python -m imls_lightning.adaptive``), its RecNN alone and the fixed mean of the same IPR measured in the same run
ADAPTIVE_COLUMNS = ("scene", "recnn", "u_median", "c_share", "ipr", "psnr_recnn_db", "psnr_adaptive_db", "gap_db", "within_eps",
                    "psnr_fixed_same_ipr_db", "recnn_ms", "adaptive_ms", "speedup")
SECTION_BEGIN = "<!-- paper-scale:begin (written by python -m imls_lightning.bench_paper) -->"
SECTION_END = "<!-- paper-scale:end -->"
#: the paper's ORP table (Table "Detailed ORP", GPU): dataset -> (ORP, latency ms, speed-up) per RecNN
PAPER_ORP = {
    "Chameleon": {"enhancenet": (0.20, 89.4, 2.07), "fovolnet": (0.40, 106.1, 1.77)},
    "Beechnut": {"enhancenet": (0.18, 86.0, 2.02), "fovolnet": (0.17, 79.1, 2.24)},
    "Rayleigh-Taylor": {"enhancenet": (0.40, 142.4, 1.75), "fovolnet": (0.42, 151.1, 1.49)},
    "Flame": {"enhancenet": (0.11, 56.9, 2.98), "fovolnet": (0.10, 54.1, 3.20)},
}
#: the methods of the breakdown, in the paper's order
BREAKDOWN_METHODS = ("full", "recnn", "las", "iml", "imls")


def pair_config(cfg: DictConfig, scene: str, recnn: str) -> DictConfig:
    """The demo pipeline's config for one (scene, RecNN) pair: the paper-scale stage overrides, the
    RecNN's network size in every training stage and its patch crop where it applies."""
    net = override_list(cfg, f"recnn_net.{recnn}")
    crop = OmegaConf.select(cfg, f"crop.{recnn}")
    crop_args = [f"data.crop={int(crop)}"] if crop else []
    stages: dict[str, Any] = {}
    for name in ("recnn", "iml", "blue_noise", "ims", "ims_finetune", "ims_decoder", "las"):
        skip = name == "las" and recnn not in [str(r) for r in (cfg.get("las_with") or [])]
        if skip or (OmegaConf.select(cfg, f"stages.{name}") is None and name in ("blue_noise", "ims_finetune", "ims_decoder", "las")):
            stages[name] = None  # skipped, as in the demo
            continue
        extra = crop_args if name in ("recnn", "iml", "blue_noise") else []
        chunk = [f"chunk_minutes={cfg.chunk_minutes}"] if cfg.get("chunk_minutes") is not None else []
        # the decoder stage is fine-tuned on the masks the evaluation will run: its candidate sharpnesses
        masks = [f"model.decoder_sharpness={v}" for v in _ims_sharpness(cfg)] if name == "ims_decoder" else []
        stages[name] = [*net, *extra, *masks, *override_list(cfg, f"stages.{name}"), *chunk]
    # the RecNN on a sparser pattern: the demo trains it as the recnn stage above plus the sparser pattern
    # (demo.sparser_overrides) and stages.recnn_sparser's overrides; only `stages.recnn_sparser: null` skips it
    explicit = cfg.get("stages") is not None and "recnn_sparser" in cfg.stages
    stages["recnn_sparser"] = override_list(cfg, "stages.recnn_sparser") if not explicit or cfg.stages.recnn_sparser is not None else None
    return OmegaConf.create({
        "scene": scene, "data": str(cfg.data), "recnn": recnn, "renderer": str(cfg.renderer),
        "renderer_overrides": renderer_overrides(cfg),
        "runs_dir": str(cfg.runs_dir), "cache_dir": str(cfg.cache_dir), "seed": int(cfg.seed),
        "progress": bool(cfg.progress), "dry_run": bool(cfg.dry_run),
        "train_only": bool(cfg.get("train_only", False)), "trained": cfg.get("trained"), "stages": stages,
        "evaluate": [*override_list(cfg, "evaluate"), *timing_overrides(cfg)],
        "adaptive": ([*override_list(cfg, "adaptive"), *timing_overrides(cfg)]
                     if OmegaConf.select(cfg, "adaptive") is not None else None),
    })


def timing_overrides(cfg: DictConfig) -> list[str]:
    """The renderer's overrides of every stage that times (the estimate, the evaluation, the adaptive mean), never of
    the cache or training: ``skip_empty: false`` changes no pixel, only what a ray costs (``renderer.skip_empty``)."""
    skip = cfg.get("skip_empty", True)
    if not isinstance(skip, bool):
        raise InputError(f"skip_empty={skip!r}: expected true or false")
    return [] if skip else ["renderer.skip_empty=false"]


# ------------------------------------------------------------------------------------------------
# one row per pair, from the evaluation's summary.json


def _total(methods: Mapping[str, Any], name: str) -> float:
    return float(methods.get(name, {}).get("latency_ms", {}).get("total", math.nan))


def estimate_cells(estimate: Mapping[str, Any] | None, c_share: Any, sharpness: Any = 1.0) -> dict[str, Any]:
    """The :data:`ESTIMATE_COLUMNS` and :data:`ESTIMATE_INTERVAL_COLUMNS` of a row from its pair's ``estimate.json``
    content (empty without one); ``estimated_speedup`` is the estimate's bound at the share the row measured, on the
    render curve of the mask sharpness its ORP kept (where the estimate has one), ``estimated_low`` / ``_high`` its
    interval over the estimate's views."""
    if not estimate:
        return {k: "" for k in ESTIMATE_COLUMNS + ESTIMATE_INTERVAL_COLUMNS}
    try:
        est_speedup = speedup_from_estimate(estimate, float(c_share), float(sharpness))
        iv = estimate_interval(estimate, float(c_share), float(sharpness))
    except (TypeError, ValueError):
        est_speedup, iv = math.nan, None
    return {"volume_dims": estimate.get("volume_dims", ""), "c_render_ms": estimate["c_render_ms"],
            "nets_ms": estimate["nets_ms"], "bilinear_db": estimate["bilinear_db"], "estimated_speedup": est_speedup,
            "estimated_low": iv.low if iv else "", "estimated_high": iv.high if iv else ""}


def csv_row(summary: Mapping[str, Any], estimate: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One ``paper_scale.csv`` row (:data:`CSV_COLUMNS`) from an evaluation summary and its pair's estimate."""
    m = summary["methods"]
    imls, recnn, las = m.get("imls", {}), m.get("recnn", {}), m.get("las", {})
    orp = summary.get("orp") or {}
    recnn_ms, imls_ms = _total(m, "recnn"), _total(m, "imls")
    psnr_r, psnr_i = float(recnn.get("psnr", math.nan)), float(imls.get("psnr", math.nan))
    row = {
        "scene": summary["scene"], "recnn": summary["recnn"], "fr_size": summary["fr_size"], "c_size": summary["c_size"],
        "sample_distance_voxels": summary.get("sample_distance_voxels"),
        "mean": orp.get("mean") if orp.get("found") else summary.get("imls_mean"),
        "c_share": imls.get("c_share"), "ipr": imls.get("ipr"), "psnr_recnn_db": psnr_r, "psnr_imls_db": psnr_i,
        "gap_db": psnr_r - psnr_i, "recnn_ms": recnn_ms, "imls_ms": imls_ms,
        "speedup": recnn_ms / imls_ms if imls_ms > 0 else math.nan,
        "las_ms": _total(m, "las"), "las_psnr_db": las.get("psnr", math.nan), "full_ms": _total(m, "full"),
        **estimate_cells(estimate, imls.get("c_share"), orp.get("sharpness", 1.0)),
        "skip_empty": summary.get("skip_empty", True),
        "object_floor_margin": ((orp.get("object_floor") or {}).get("chosen") or {}).get("margin", "") if orp.get("found") else "",
        "timing_busy_cores": (summary.get("timing_load") or {}).get("max", ""),
        **interval_cells(summary), **las_searched_cells(summary), **fastest_cells(summary),
    }
    return {k: row[k] for k in CSV_COLUMNS}  # in the table's order (the estimate's interval comes last)


def las_searched_cells(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`LAS_SEARCHED_COLUMNS` of a row: LAS at the product's promise as the evaluation measured it (its IPR
    is the mean the test views ran at, one per band of camera distance); empty where it was not measured.

    Example:
        >>> las_searched_cells({"methods": {"las_searched": {"ipr": 0.12, "psnr": 33.1, "latency_ms": {"total": 900.0}}}})
        {'las_searched_ipr': 0.12, 'las_searched_ms': 900.0, 'las_searched_psnr_db': 33.1}
        >>> las_searched_cells({"methods": {}})
        {'las_searched_ipr': '', 'las_searched_ms': '', 'las_searched_psnr_db': ''}
    """
    las = summary["methods"].get("las_searched")
    if not las:
        return {k: "" for k in LAS_SEARCHED_COLUMNS}
    return {"las_searched_ipr": las.get("ipr", ""), "las_searched_ms": _total(summary["methods"], "las_searched"),
            "las_searched_psnr_db": las.get("psnr", "")}


def fastest_cells(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`FASTEST_COLUMNS` of a row from the summary's ``ray_casters`` and ``trajectory`` (empty where the
    evaluation did not time both ray casters or read the cache's own trajectory).

    Example:
        >>> fastest_cells({"ray_casters": {"recnn_skip_ms": 180.0, "recnn_noskip_ms": 1900.0, "imls_skip_ms": 200.0,
        ...     "imls_noskip_ms": 860.0, "speedup_vs_fastest": 0.9, "speedup_vs_fastest_low": 0.85,
        ...     "speedup_vs_fastest_high": 0.95}, "trajectory": {"seed": 7}})["speedup_vs_fastest"]
        0.9
        >>> set(fastest_cells({}).values())
        {''}
    """
    rc, traj = summary.get("ray_casters") or {}, summary.get("trajectory") or {}
    cells = {k: rc.get(k, "") for k in FASTEST_COLUMNS if not k.startswith(("trajectory", "las_equal"))}
    las = (summary.get("methods") or {}).get("las_equal") or {}
    return {**cells, "trajectory_seed": traj.get("seed", ""), "las_equal_ipr": las.get("ipr", ""),
            "las_equal_ms": _total(summary["methods"], "las_equal") if las else "", "las_equal_psnr_db": las.get("psnr", "")}


def interval_cells(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The :data:`INTERVAL_COLUMNS` of a row: IML/S's interval over the RecNN alone in the summary's
    ``speedup_interval`` (empty where the evaluation predates it)."""
    iv = (summary.get("speedup_interval") or {}).get("imls") or {}
    return {"speedup_low": iv.get("low", ""), "speedup_high": iv.get("high", "")}


def speedup_cell(row: Mapping[str, Any]) -> str:
    """A row's speed-up with its interval where it has one: ``2.02× (1.90–2.15)``.

    Example:
        >>> speedup_cell({"recnn_ms": "300", "imls_ms": "150", "speedup_low": "1.9", "speedup_high": "2.1"})
        '2.00× (1.90–2.10)'
        >>> speedup_cell({"recnn_ms": 300.0, "imls_ms": 150.0, "speedup_low": "", "speedup_high": ""})
        '2.00×'
    """
    text = speedup(_num(row.get("recnn_ms")), _num(row.get("imls_ms")))
    lo, hi = _num(row.get("speedup_low")), _num(row.get("speedup_high"))
    return f"{text} ({lo:.2f}–{hi:.2f})" if math.isfinite(lo) and math.isfinite(hi) else text


def read_adaptive(report: Path) -> dict[str, Any]:
    """The adaptive run's ``adaptive.json`` beside ``report`` (its summary per method and its means);
    a missing or damaged one is refused in one line."""
    from ..adaptive.report import read_results

    data, problem = read_results(Path(report).parent)
    if problem:
        raise InputError(f"{Path(report).parent / 'adaptive.json'}: {problem}; run it again (reuse=false)")
    return {"summary": data["summary"], "u_median": (data.get("u_adaptive") or {}).get("median"), "report": str(report)}


def adaptive_row(summary: Mapping[str, Any]) -> dict[str, Any] | None:
    """One ``paper_scale_adaptive.csv`` row (:data:`ADAPTIVE_COLUMNS`) from a pair's summary with its
    ``adaptive`` entry (:func:`read_adaptive`); None without one. The speed-up and the gap are against
    the RecNN alone timed in the adaptive run itself (ratios from one run)."""
    ad = summary.get("adaptive")
    if not ad:
        return None
    m = ad["summary"]
    a, r = m["imls_adaptive"], m.get("recnn", {})
    imls = summary["methods"].get("imls", {})
    share_per_ipr = _num(imls.get("c_share")) / _num(imls.get("ipr")) if _num(imls.get("ipr")) > 0 else math.nan
    recnn_ms, ad_ms = _total(m, "recnn"), _total(m, "imls_adaptive")
    return {"scene": summary["scene"], "recnn": summary["recnn"], "u_median": ad.get("u_median"),
            "c_share": _num(a.get("ipr")) * share_per_ipr, "ipr": a.get("ipr"), "psnr_recnn_db": r.get("psnr"),
            "psnr_adaptive_db": a.get("psnr"), "gap_db": a.get("gap"), "within_eps": a.get("within"),
            "psnr_fixed_same_ipr_db": m.get("imls_matched", {}).get("psnr"), "recnn_ms": recnn_ms, "adaptive_ms": ad_ms,
            "speedup": recnn_ms / ad_ms if ad_ms > 0 else math.nan}


def _cell(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return "" if v is None else str(v)


def merge_rows(old: Sequence[Mapping[str, Any]], new: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """``old`` rows with those of the pairs in ``new`` replaced (a run of one pair keeps the others)."""
    key = lambda r: (str(r["scene"]), str(r["recnn"]))  # noqa: E731
    fresh = {key(r): dict(r) for r in new}
    out = [fresh.pop(key(r), dict(r)) for r in old]
    return out + list(fresh.values())


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of an earlier ``paper_scale.csv``; one with other columns is refused in one line."""
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) not in (CSV_COLUMNS, *EARLIER_COLUMNS):
            raise InputError(f"{path}: its columns {reader.fieldnames} are not {list(CSV_COLUMNS)}; move it away to start a new table")
        # a table from before the estimate's columns: they stay empty until the pair is estimated; every row timed
        # before skip_empty existed was timed with empty-space skipping, and every row before the floor ran without one
        return [{**{k: "" for k in ESTIMATE_COLUMNS + INTERVAL_COLUMNS + ESTIMATE_INTERVAL_COLUMNS + LAS_SEARCHED_COLUMNS
                    + FASTEST_COLUMNS}, "skip_empty": True, "object_floor_margin": "",
                 "timing_busy_cores": "", **dict(r)} for r in reader]


def write_csv(rows: Sequence[Mapping[str, Any]], path: Path, columns: Sequence[str] = CSV_COLUMNS) -> Path:
    """``paper_scale.csv``: ``rows`` in ``columns``, each cell by :func:`_cell`; atomic."""
    return report_csv(path, rows, columns, _cell)


#: what ``paper_scale_pairs.json`` keeps per pair, so a run of one pair reports every pair run before
PAIR_RECORD_KEYS = ("summary", "minutes", "settings", "command")


def read_pairs(path: Path) -> dict[str, dict[str, Any]]:
    """Earlier pairs' records (``{"<scene>, <recnn>": {summary, minutes, settings, command}}``) from
    ``paper_scale_pairs.json``; a file that is not such a record set is refused in one line."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: cannot read it ({err}); move it away to start a new table") from None
    ok = isinstance(data, dict) and all(isinstance(v, dict) and set(PAIR_RECORD_KEYS) <= set(v)
                                        and isinstance(v["summary"], dict) and "methods" in v["summary"] for v in data.values())
    if not ok:
        raise InputError(f"{path}: not the benchmark's pair records (each needs {list(PAIR_RECORD_KEYS)}); move it away to start a new table")
    return data


# ------------------------------------------------------------------------------------------------
# the report


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def breakdown_rows(summary: Mapping[str, Any]) -> list[list[str]]:
    """Per-stage latency of every method of one pair, then the physical limit: ray-casting the
    ORP's pixels alone (IML/S's selective render with free networks)."""
    from ..inference.pipeline import STAGES
    from ..report.names import METHOD_LABELS

    m = summary["methods"]
    rows = []
    for name in BREAKDOWN_METHODS:
        if name not in m:
            continue
        lat = m[name]["latency_ms"]
        rows.append([METHOD_LABELS[name], fmt_pct(m[name].get("ipr")), *(fmt(lat.get(s)) for s in STAGES),
                     f"**{fmt(lat.get('total'))}**", speedup(_total(m, "recnn"), _total(m, name)), fmt(m[name].get("psnr"))])
    if "imls" in m:
        lim = m["imls"]["latency_ms"].get("selective_render")
        rows.append(["limit: the ORP's pixels alone", fmt_pct(m["imls"].get("ipr")), *("–" for _ in STAGES),
                     f"**{fmt(lim)}**", speedup(_total(m, "recnn"), _num(lim)), "–"])
    return rows


def plot_breakdown(summaries: Sequence[Mapping[str, Any]], path: Path, columns: int = 4) -> Path:
    """Stacked bars per method and pair, plus the limit (the paper's time-breakdown figure), ``columns`` pairs a row.

    Each panel's title gives IML/S + RecNN against the RecNN alone (speed-up, PSNR gap). The full ray cast, several
    times the rest, is cut at the panel's top with its total written there, so the other bars stay readable."""
    import math

    import numpy as np

    from ..inference.pipeline import STAGES
    from ..report.names import METHOD_LABELS, STAGE_COLORS, STAGE_LABELS
    from ..report.plots import new_figure, save_figure

    cols = max(1, min(columns, len(summaries)))
    rows = math.ceil(len(summaries) / cols)
    fig = new_figure(max(6.0, 4.0 * cols), 4.6 * rows)
    for k, s in enumerate(summaries):
        ax = fig.add_subplot(rows, cols, k + 1)
        names = [n for n in BREAKDOWN_METHODS if n in s["methods"]]
        lat = [s["methods"][n]["latency_ms"] for n in names]
        if "imls" in s["methods"]:
            names.append("limit")
            lat.append({"selective_render": s["methods"]["imls"]["latency_ms"].get("selective_render", 0.0)})
        x, bottom = np.arange(len(names)), np.zeros(len(names))
        for st in STAGES:
            vals = np.nan_to_num(np.array([float(d.get(st, 0.0)) for d in lat]))
            if vals.any():
                ax.bar(x, vals, 0.65, bottom=bottom, color=STAGE_COLORS[st], label=STAGE_LABELS[st])
                bottom += vals
        rest = [tot for n, tot in zip(names, bottom) if n != "full"]
        top = 1.3 * max(rest) if rest and max(rest) > 0 else None
        for xi, tot in zip(x, bottom):
            cut = top is not None and tot > top
            ax.text(xi, 0.97 * top if cut else tot, f"{tot:.0f}" + (" (cut)" if cut else ""), ha="center",
                    va="top" if cut else "bottom", fontsize=7, rotation=90 if cut else 0)
        if top is not None:
            ax.set_ylim(0, top)
        ax.set_xticks(x)
        ax.set_xticklabels([METHOD_LABELS.get(n, "limit: ORP pixels") for n in names], rotation=25, ha="right", fontsize=7)
        title = f"{s['scene']}, {s['recnn']} ({s['fr_size']}² FR)"
        row = csv_row(s)  # the table's speed-up and gap, so the panel and paper_scale.csv agree
        if math.isfinite(row["speedup"]):
            title += f"\nIML/S {row['speedup']:.2f}x the RecNN alone, {-row['gap_db']:+.2f} dB"
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if k % cols == 0:
            ax.set_ylabel("average latency (ms)")
    handles: dict[str, Any] = {}  # every stage that any pair shows (LAS's low-res render only where LAS ran)
    for ax in fig.axes:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles), fontsize=8, loc="lower center", ncol=len(handles),
               bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, 0.04 / rows, 1, 1))
    return save_figure(fig, path)


def report_markdown(rows: Sequence[Mapping[str, Any]], summaries: Sequence[Mapping[str, Any]], *, partial: bool,
                    stage_minutes: Mapping[str, float], command: str, machine: Mapping[str, str],
                    settings: Mapping[str, Mapping[str, Sequence[str]]] | None = None,
                    commands: Mapping[str, str] | None = None) -> str:
    """``paper_scale.md``: the CSV as a table (plus each pair's per-view adaptive row), each pair's
    breakdown and baselines, the paper's figures; ``settings``, ``stage_minutes`` and ``commands`` are
    keyed by pair (``"<scene>, <recnn>"``)."""
    from ..inference.pipeline import STAGES
    from ..report.names import STAGE_LABELS

    out = ["# Paper-scale benchmark" + (" (partial: still running or interrupted)" if partial else ""), ""]
    out += ["The paper's protocol at the paper's scale on this CPU: 512² FR-Images, 256² C-Images, half-voxel sampling, "
            "the numba renderer. The ORP is searched on the product path (IMS mask from the view, exactly those pixels "
            "ray-cast, IML decoder, RecNN) on the validation views, within ε = 1 dB of the RecNN alone; PSNR is measured "
            "on the 120-view test trajectory. One IMS regresses PIM' and is rescaled to the ORP's mean (the paper's "
            "rescale; where that finds no ORP, its masks are lifted to each mean's share of C, `ims_lift`, and the pair's section says so). "
            "`speedup` = RecNN alone / IML/S + RecNN, with its 95% bootstrap interval over the row's timed views in "
            "parentheses (`speedup_low`, `speedup_high`; how far the ratio moves with the views drawn, not between "
            "sittings); `las_*` is LAS at IML/S's IPR.", ""]
    head = ["scene", "RecNN", "FR / C", "step (voxels)", "ORP mean", "C-share", "IPR", "RecNN PSNR", "IML/S PSNR", "gap (dB)",
            "RecNN (ms)", "IML/S (ms)", "speed-up (95% interval)", "LAS (ms)", "LAS PSNR", "full ray cast (ms)"]
    main = [[scene_cell(r), r["recnn"], f"{r['fr_size']}² / {r['c_size']}²", fmt(r.get("sample_distance_voxels")), fmt(r.get("mean"), 3),
             fmt_pct(_num(r.get("c_share"))), fmt_pct(_num(r.get("ipr"))), fmt(r.get("psnr_recnn_db")), fmt(r.get("psnr_imls_db")),
             fmt(r.get("gap_db")), fmt(r.get("recnn_ms"), 1), fmt(r.get("imls_ms"), 1), speedup_cell(r),
             fmt(r.get("las_ms"), 1), fmt(r.get("las_psnr_db")), fmt(r.get("full_ms"), 1)] for r in rows]
    per_view = {}
    for s in summaries:
        a = adaptive_row(s)
        if a is not None:
            per_view[(a["scene"], a["recnn"])] = [
                a["scene"], f"{a['recnn']}, per-view u", f"{s['fr_size']}² / {s['c_size']}²", fmt(s.get("sample_distance_voxels")),
                f"per view (median {fmt(a.get('u_median'), 3)})", fmt_pct(a.get("c_share")), fmt_pct(_num(a.get("ipr"))),
                fmt(a.get("psnr_recnn_db")), fmt(a.get("psnr_adaptive_db")), fmt(a.get("gap_db")), fmt(a.get("recnn_ms"), 1),
                fmt(a.get("adaptive_ms"), 1), speedup(a.get("recnn_ms"), a.get("adaptive_ms")), "–", "–", "–"]
    body = rows_beside(main, per_view)
    out += [md_table(head, body), *skipping_note(rows), "", "Files: `paper_scale.csv` (these rows but the per-view ones), `paper_scale_adaptive.csv` "
            "(the per-view adaptive mean: `python -m imls_lightning.adaptive`, its RecNN alone timed in the same run), "
            "`paper_scale_breakdown.png`.", ""]
    for s in summaries:
        orp = s.get("orp") or {}
        out += [f"## {s['scene']}, {s['recnn']}", ""]
        if orp.get("found"):
            out += [f"ORP on the product path (validation views): mean u = {fmt(orp.get('mean'), 4)}, C-share {fmt_pct(orp.get('c_share'))}, "
                    f"IPR {fmt_pct(orp.get('ipr'))}, gap {fmt(orp.get('gap_db'))} dB ({orp.get('evaluations')} means tried)"
                    + ("; the IMS's masks lifted to each mean's share (the paper's rescale found no ORP)." if orp.get("lift") else "."), ""]
        elif orp:
            out += ["ORP: no mean in [0.01, 1] brought IML/S within ε of the RecNN alone on the validation views; IML/S ran at its trained mean.", ""]
        out += [f"Average latency per stage (ms): stage medians on {s.get('timed_views')} of the {s.get('views')} trajectory views; "
                "PSNR on all of them.", ""]
        out += [md_table(["method", "IPR", *(STAGE_LABELS[x] for x in STAGES), "total", "speed-up vs RecNN alone", "PSNR (dB)"],
                         breakdown_rows(s)), ""]
        a = adaptive_row(s)
        if a is not None:
            out += [f"Per-view adaptive mean (`python -m imls_lightning.adaptive`, the masks of the ORP above; report "
                    f"`{s['adaptive']['report']}`): the predictor's u per view (median {fmt(a.get('u_median'), 3)}) gives IPR "
                    f"{fmt_pct(_num(a.get('ipr')))} ({fmt_pct(a.get('c_share'))} of C) and {fmt(a.get('psnr_adaptive_db'))} dB, "
                    f"{fmt(a.get('gap_db'))} dB below the RecNN alone, {fmt_pct(a.get('within_eps'), 0)} of the views within ε; "
                    f"the fixed mean of the same IPR scores {fmt(a.get('psnr_fixed_same_ipr_db'))} dB. Timed in that run: "
                    f"{fmt(a.get('adaptive_ms'), 1)} ms against the RecNN alone's {fmt(a.get('recnn_ms'), 1)} ms "
                    f"({speedup(a.get('recnn_ms'), a.get('adaptive_ms'))}).", ""]
        if s.get("front"):
            from ..report.front import front_markdown, front_verdict

            op = (s.get("orp") or {})
            out += ["### Speed-quality front", "", f"Every method on the evaluation's {len(s.get('front_views') or [])} sweep view(s), "
                    "median latency against mean PSNR; ◆: on the Pareto front (the evaluation's report has the plot).", "",
                    front_markdown(s["front"]), "", "Where IML/S lies: " + front_verdict(s["front"], f"{s['scene']}, {s['recnn']}"), ""]
            if op.get("test"):
                out += [f"ORP gap: {fmt(op.get('gap_db'))} dB on the validation views (bound {fmt(op.get('gap_bound_db'))} dB), "
                        f"{fmt(op['test'].get('gap_db'))} dB on the {op['test'].get('views')} evaluated trajectory views.", ""]
        if s.get("equal_share"):
            out += ["Learned parts against the untrained baselines at equal share of C (PSNR after the RecNN, mean over the "
                    "evaluated trajectory views):", "", equal_share_markdown(s["equal_share"]), ""]
    out += ["## The paper's figures (GPU, 512² FR)", "",
            md_table(["dataset", "ORP Sup-Res", "ORP Foveated", "latency Sup-Res (ms)", "latency Foveated (ms)", "speed-up Sup-Res", "speed-up Foveated"],
                     [[k, fmt_pct(v["enhancenet"][0], 0), fmt_pct(v["fovolnet"][0], 0), fmt(v["enhancenet"][1], 1), fmt(v["fovolnet"][1], 1),
                       f"{v['enhancenet'][2]:.2f}×", f"{v['fovolnet'][2]:.2f}×"] for k, v in PAPER_ORP.items()]), ""]
    if settings:
        out += ["## Network sizes and training per stage", "",
                "Sized for 2 CPU cores: the paper's EnhanceNet (64 channels x 10 blocks) costs 1.8 s per 256² C-Image here, "
                "more than ray-casting the whole pattern, so no ORP could pay for it; 16 x 4 costs the breakdown's RecNN column. "
                "The overrides each stage ran with:", "",
                md_table(["pair", "stage", "overrides"], [[r, st, f"`{' '.join(a)}`" if a is not None else "skipped"]
                                                          for r, stages in settings.items() for st, a in stages.items()]), ""]
    if stage_minutes:
        cmds = commands or {}
        out += ["## Time each pair took", "", "The pair's last command, all its stages: the minutes count only what ran, so a pair "
                "whose training or evaluation was reused shows less than a first run.", "",
                md_table(["pair", "minutes", "command"], [[k, fmt(v, 1), f"`{cmds[k]}`" if cmds.get(k) else ""]
                                                          for k, v in stage_minutes.items()]), ""]
    out += ["## Machine and command", "", md_table(["", ""], [[k, v] for k, v in machine.items()]), "", f"`{command}`", ""]
    return "\n".join(out)


def update_section(benchmarks_md: Path, text: str) -> Path:
    """Put ``text`` between :data:`SECTION_BEGIN` and :data:`SECTION_END` of ``benchmarks_md`` (appended
    when the markers are missing; the rest of the file is kept)."""
    from ..report.results_table import update_between

    return update_between(benchmarks_md, SECTION_BEGIN, SECTION_END, text)


def rows_beside(main: Sequence[Sequence[str]], extra: Mapping[tuple[str, str], Sequence[str]]) -> list[list[str]]:
    """Table rows: each ``main`` row (scene and RecNN in its first two cells) followed by its pair's
    ``extra`` row when there is one; extra rows of pairs without a main row come last."""
    out, left = [], dict(extra)
    for r in main:
        out.append(list(r))
        key = (str(r[0]).split(" ")[0], r[1])  # the scene's name without a note such as "(no skipping)"
        if key in left:
            out.append(list(left.pop(key)))
    return out + [list(v) for v in left.values()]


def orp_cell(row: Mapping[str, Any]) -> str:
    """The ORP's C-share, or "none" with the share IML/S ran at when no mean met ε."""
    found = math.isfinite(_num(row.get("mean")))
    return fmt_pct(_num(row.get("c_share"))) if found else f"none (ran at {fmt_pct(_num(row.get('c_share')))})"


def las_cell(row: Mapping[str, Any]) -> str:
    """``"<ms>, <PSNR> dB"`` of LAS at the row's IPR, or ``"–"`` for a pair without LAS (FoVolNet: ``las_with``).

    Example:
        >>> las_cell({"las_ms": 648.84, "las_psnr_db": 29.57}), las_cell({"las_ms": None})
        ('648.8, 29.57 dB', '–')
    """
    if not math.isfinite(_num(row.get("las_ms"))):
        return "–"
    return f"{fmt(row.get('las_ms'), 1)}, {fmt(row.get('las_psnr_db'))} dB"


def skips_empty(row: Mapping[str, Any]) -> bool:
    """Whether the row was timed with empty-space skipping (a bool from a summary, a string from the CSV)."""
    return str(row.get("skip_empty", True)).strip().lower() not in ("false", "0")


def scene_cell(row: Mapping[str, Any]) -> str:
    return str(row["scene"]) + ("" if skips_empty(row) else " (no skipping)")


def skipping_note(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    if all(skips_empty(r) for r in rows):
        return []
    return ["", "*(no skipping)*: timed on the ray caster without empty-space skipping (`make bench-paper skip_empty=false`, "
            "`renderer.skip_empty=false`): every ray marches the volume's box, as the paper's ray caster does. The same pixels; "
            "the other rows skip empty bricks."]


def section_text(rows: Sequence[Mapping[str, Any]], partial: bool, adaptive: Sequence[Mapping[str, Any]] = ()) -> str:
    lines = ["## Paper scale (512² FR, 256² C, half-voxel sampling)" + (" — partial" if partial else ""), "",
             "`make bench-paper`; details, per-stage breakdown and the paper's figures in "
             "[benchmarks/paper_scale.md](benchmarks/paper_scale.md), rows in `benchmarks/paper_scale.csv`.", ""]
    main = [[scene_cell(r), r["recnn"], orp_cell(r), f"{fmt(r.get('psnr_imls_db'))} ({fmt(r.get('gap_db'))} dB)",
             fmt(r.get("recnn_ms"), 1), fmt(r.get("imls_ms"), 1), speedup_cell(r), las_cell(r)] for r in rows]
    per_view = {(a["scene"], a["recnn"]): [a["scene"], f"{a['recnn']}, per-view u", f"per view: {fmt_pct(_num(a.get('c_share')))}",
                                           f"{fmt(a.get('psnr_adaptive_db'))} ({fmt(a.get('gap_db'))} dB)", fmt(a.get("recnn_ms"), 1),
                                           fmt(a.get("adaptive_ms"), 1), speedup(_num(a.get("recnn_ms")), _num(a.get("adaptive_ms"))), "–"]
                for a in adaptive}
    lines.append(md_table(["scene", "RecNN", "ORP C-share", "IML/S PSNR (gap)", "RecNN alone (ms)", "IML/S + RecNN (ms)", "speed-up (95% interval)",
                           "LAS (ms, PSNR)"], rows_beside(main, per_view)))
    lines += skipping_note(rows)
    if adaptive:
        lines += ["", "The per-view rows: `python -m imls_lightning.adaptive` on the same checkpoints and masks, its own RecNN "
                  "alone timed in the same run (`benchmarks/paper_scale_adaptive.csv`)."]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------


#: stage override key -> the estimate's key for the same network size
_ESTIMATE_SIZES = {"iml": {"model.depth": "iml.depth", "model.base_channels": "iml.base_channels", "model.decoder": "iml.decoder"},
                   "ims": {"model.layers": "ims.layers", "model.base_channels": "ims.base_channels",
                           "model.max_channels": "ims.max_channels"}}


def estimate_args(cfg: DictConfig, stages: DictConfig, scene_overrides: Sequence[str] = ()) -> list[str]:
    """The estimate's command for a pair, with the networks' sizes its stages train.

    Example:
        >>> st = OmegaConf.create({"scene": "ct_head", "recnn": "enhancenet", "renderer": "numba", "runs_dir": "runs",
        ...     "stages": {"recnn": ["recnn.net.channels=16", "trainer.max_epochs=20"], "iml": ["recnn.net.channels=16",
        ...     "model.depth=4"], "ims": ["model.layers=7", "trainer.max_epochs=5"]}})
        >>> estimate_args(OmegaConf.create({"estimate": ["views=3"]}), st)[1:]
        ['imls_lightning.estimate', 'scene=ct_head', 'recnn=enhancenet', 'renderer=numba', 'runs_dir=runs', 'recnn.net.channels=16', 'iml.depth=4', 'ims.layers=7', 'views=3']
    """
    net = [o for o in (stages.stages.get("recnn") or []) if override_key(str(o)).startswith("recnn.net.")]
    sizes = []
    for stage, keys in _ESTIMATE_SIZES.items():
        for o in stages.stages.get(stage) or []:
            key = override_key(str(o))
            if key in keys:
                sizes.append(f"{keys[key]}={str(o).split('=', 1)[1]}")
    return ["-m", "imls_lightning.estimate", f"scene={stages.scene}", *scene_overrides, f"recnn={stages.recnn}",
            f"renderer={stages.renderer}", *renderer_overrides(stages), f"runs_dir={stages.runs_dir}", *[str(o) for o in net], *sizes,
            *timing_overrides(cfg), *evaluated_sharpness(cfg), *evaluated_options(cfg), *override_list(cfg, "estimate")]


def _ims_sharpness(cfg: DictConfig) -> list[str]:
    """The value of the evaluation's ``ims_sharpness`` override, as written (``[]``: not set)."""
    found = [str(o).split("=", 1)[1] for o in override_list(cfg, "evaluate") if override_key(str(o)) == "ims_sharpness"]
    return found[-1:]


def evaluated_options(cfg: DictConfig) -> list[str]:
    """The evaluation's network options (``options.half``, ``options.compile``, ...) as the estimate's overrides, so a
    row's estimate times its networks as the row runs them (eager and compiled networks differ by 10-40%); none where
    ``estimate_evaluated_options`` is false (the estimate's own options, as the rows before them issued it).

    Example:
        >>> evaluated_options(OmegaConf.create({"evaluate": ["repeats=10", "options.half=auto", "options.compile=auto"]}))
        ['options.half=auto', 'options.compile=auto']
        >>> evaluated_options(OmegaConf.create({"evaluate": ["options.half=auto"], "estimate_evaluated_options": False}))
        []
    """
    if not cfg.get("estimate_evaluated_options", True):
        return []
    return [str(o) for o in override_list(cfg, "evaluate") if override_key(str(o)).startswith("options.")]


def evaluated_sharpness(cfg: DictConfig) -> list[str]:
    """The estimate's ``sharpness`` override from the evaluation's ``ims_sharpness`` (its candidates get a render curve
    each, so a row's estimate follows the sharpness its ORP keeps); ``[]`` for the paper's masks alone.

    Example:
        >>> evaluated_sharpness(OmegaConf.create({"evaluate": ["repeats=10", "ims_sharpness=[1.0,2.0]"]}))
        ['sharpness=[1.0,2.0]']
    """
    found = _ims_sharpness(cfg)
    return [] if not found or found[-1].strip() in ("[1.0]", "[1]", "1", "1.0") else [f"sharpness={found[-1]}"]


def pair_estimate(cfg: DictConfig, stages: DictConfig, scene_overrides: Sequence[str] = ()) -> dict[str, Any] | None:
    """Run (or reuse) the pair's before-training estimate; its ``estimate.json`` content (None on a dry run)."""
    args = estimate_args(cfg, stages, scene_overrides)
    if cfg.dry_run:
        dry_stage("estimate", args, tag="bench-paper")
        return None
    path = Path(run_stage("estimate", args, tag="bench-paper"))
    est = read_estimate(path)
    if est is None:
        raise InputError(f"{path}: not a whole estimate.json; delete its folder and run again")
    return est


def pairs(cfg: DictConfig) -> list[tuple[str, str]]:
    scenes = [str(cfg.scene)] if cfg.get("scene") else [str(s) for s in (cfg.get("scenes") or [])]
    recnns = [str(r) for r in (cfg.get("recnns") or [])]
    if not scenes or not recnns:
        raise InputError(f"scenes={scenes}, recnns={recnns}: expected at least one scene and one RecNN")
    bad = [r for r in recnns if r not in ("enhancenet", "fovolnet")]
    if bad:
        raise InputError(f"recnns: {bad[0]!r} is not a RecNN; expected enhancenet or fovolnet")
    # one RecNN after the other: the super-resolution rows of every scene come first
    return [(s, r) for r in recnns for s in scenes]


def write_results(cfg: DictConfig, records: Mapping[str, Mapping[str, Any]], old_rows: Sequence[Mapping[str, Any]], *,
                  partial: bool, command: str, machine: Mapping[str, str]) -> None:
    """Every output of the benchmark from the pairs' records: ``paper_scale_pairs.json``, the two CSVs,
    the breakdown plot, ``paper_scale.md`` and the BENCHMARKS.md section (``cfg.benchmarks_md``)."""
    out_dir = Path(str(cfg.output_dir))
    summaries = [r["summary"] for r in records.values()]
    # the machine the newest pair was measured on (summarize_only runs elsewhere must not relabel its times)
    machine = next((r["machine"] for r in reversed(list(records.values())) if r.get("machine")), machine)
    all_rows = merge_rows(old_rows, [csv_row(r["summary"], r.get("estimate")) for r in records.values()])
    ad_rows = [a for a in (adaptive_row(x) for x in summaries) if a is not None]
    atomic_write_text(out_dir / "paper_scale_pairs.json", json.dumps(records, indent=1, default=str))
    write_csv(all_rows, out_dir / "paper_scale.csv")
    write_csv(ad_rows, out_dir / "paper_scale_adaptive.csv", ADAPTIVE_COLUMNS)
    plot_breakdown(summaries, out_dir / "paper_scale_breakdown.png")
    write_markdown(out_dir / "paper_scale.md", report_markdown(
        all_rows, summaries, partial=partial, stage_minutes={n: r["minutes"] for n, r in records.items()}, command=command,
        machine=machine, settings={n: r["settings"] for n, r in records.items()},
        commands={n: r["command"] for n, r in records.items()}))
    if cfg.get("benchmarks_md"):
        update_section(Path(str(cfg.benchmarks_md)), section_text(all_rows, partial, ad_rows))
    write_current_results(cfg, all_rows, out_dir)


def write_current_results(cfg: DictConfig, rows: Sequence[Mapping[str, Any]], out_dir: Path) -> None:
    """The current result per row, where a reader looks first: the table at the top of the README and of BENCHMARKS.md
    (between the results markers) and its plot, ``paper_scale_results.png``."""
    from ..report.results_table import README_BEGIN, README_END, plot_results, results_table, update_between

    table = results_table(rows)
    plot_results(rows, out_dir / "paper_scale_results.png")
    if cfg.get("readme"):  # the rows a reader can re-measure (make reproduce); the others stay in BENCHMARKS.md
        update_between(Path(str(cfg.readme)), README_BEGIN, README_END, results_table(rows, current_only=True))
    if cfg.get("benchmarks_md"):
        update_between(Path(str(cfg.benchmarks_md)), README_BEGIN, README_END, table)


def bench_paper(cfg: DictConfig, scene_overrides: Sequence[str] = (), command: str = "") -> Path | None:
    """Run every pair and write the results; returns ``paper_scale.md`` (None with ``dry_run`` or ``train_only``).

    Pairs run before (``paper_scale_pairs.json``) stay in every table; a pair run again replaces its record."""
    from ..report import machine_info

    todo = pairs(cfg)
    out_dir = Path(str(cfg.output_dir))
    csv_path, md_path, pairs_path = out_dir / "paper_scale.csv", out_dir / "paper_scale.md", out_dir / "paper_scale_pairs.json"
    old_rows = read_rows(csv_path)  # refuse a foreign table before hours of work
    records = read_pairs(pairs_path)
    machine = machine_info("cpu")
    if bool(cfg.get("summarize_only", False)):
        if not records:
            raise InputError(f"summarize_only=true: {pairs_path} holds no pairs yet; run the benchmark first")
        for name, rec in records.items():  # pairs run before the estimate existed: estimate them now (minutes each)
            if not rec.get("estimate") and not cfg.dry_run:
                scene, recnn = rec["summary"]["scene"], rec["summary"]["recnn"]
                rec["estimate"] = pair_estimate(cfg, pair_config(cfg, scene, recnn), scene_overrides)
        write_results(cfg, records, old_rows, partial=False, command=command, machine=machine)
        return md_path
    for k, (scene, recnn) in enumerate(todo):
        log(f"\n[bench-paper] pair {k + 1}/{len(todo)}: {scene}, {recnn}")
        t0 = time.perf_counter()
        stages = pair_config(cfg, scene, recnn)
        # before any cache or training: the bound this pair can reach (it picks scenes and sizes; issue 31). Not on a
        # machine that only trains: the machine that evaluates measures the times the estimate predicts
        estimate = None if cfg.get("train_only", False) else pair_estimate(cfg, stages, scene_overrides)
        results: dict[str, Any] = {}
        report = demo(stages, scene_overrides, results)
        if report is None:  # dry run, or train_only
            continue
        name = f"{scene}, {recnn}"
        summary = read_summary(report)
        if results.get("adaptive"):
            summary["adaptive"] = read_adaptive(Path(results["adaptive"]))
        records.pop(name, None)  # a pair run again moves to the end, with its new record
        records[name] = {"summary": summary, "estimate": estimate, "machine": machine,
                         "minutes": (time.perf_counter() - t0) / 60, "command": command,
                         "settings": {st: (list(v) if v is not None else None) for st, v in stages.stages.items()}}
        write_results(cfg, records, old_rows, partial=k + 1 < len(todo), command=command, machine=machine)
        log(f"[bench-paper] {name} done in {records[name]['minutes']:.1f} min -> {csv_path}")
        if warning := shared_cores_warning((summary.get("timing_load") or {}).get("max"), f"the row of {name}"):
            log(f"[bench-paper] {warning} (its timing_busy_cores column)")
    return None if cfg.dry_run or cfg.get("train_only", False) else md_path
