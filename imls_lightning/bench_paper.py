"""``make bench-paper``: the paper's protocol at the paper's scale, on this machine.

512² FR-Images, 256² C-Images, half-voxel sampling (``scene.sample_distance: auto``), the numba
renderer. For every scene of ``scenes`` and RecNN of ``recnns`` (``conf/pipelines/bench_paper.yaml``)
it runs the demo's stages through the real CLIs (:func:`imls_lightning.demo.demo`): cache, RecNN,
IML, IMS, blue-noise decoder, LAS, then the evaluation, which searches the ORP on the product path
(IMS mask from the view, exactly those pixels ray-cast, IML decoder, RecNN) on the validation views
and measures every method on the 120-view test trajectory. It then writes, after every pair:

* ``benchmarks/paper_scale.csv``: one row per (scene, recnn), :data:`CSV_COLUMNS` (rows of pairs not
  run this time are kept);
* ``benchmarks/paper_scale.md``: that table, the per-stage latency of every method with the physical
  limit (ray-casting the ORP's pixels alone), the equal-share baselines and the paper's figures;
* ``benchmarks/paper_scale_breakdown.png``: stacked bars per method (the paper's time-breakdown figure);
* the paper-scale section of ``BENCHMARKS.md`` (between :data:`SECTION_BEGIN` and :data:`SECTION_END`).

Resuming: every stage reuses finished work (each CLI reuses its finished run, the evaluation runs with
``reuse=true``), so the same command continues after an interruption.

Example:
    python -m imls_lightning.bench_paper                                         # make bench-paper
    python -m imls_lightning.bench_paper scenes=[ct_head] recnns=[enhancenet]    # one pair
    python -m imls_lightning.bench_paper scene=file scene.volume.path=/data/my_head.nii.gz
"""
from __future__ import annotations

import csv
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.errors import InputError, cli_errors

from .demo import demo, override_list, run_pipeline, split_scene_overrides
from .report import atomic_write_text, md_table
from .report.tables import equal_share_markdown, fmt, fmt_pct, speedup

ROOT = Path(__file__).resolve().parents[1]

#: the columns of ``benchmarks/paper_scale.csv``, in order (issue 18)
CSV_COLUMNS = ("scene", "recnn", "fr_size", "c_size", "sample_distance_voxels", "mean", "c_share", "ipr",
               "psnr_recnn_db", "psnr_imls_db", "gap_db", "recnn_ms", "imls_ms", "speedup", "las_ms", "las_psnr_db", "full_ms")
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


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def pair_config(cfg: DictConfig, scene: str, recnn: str) -> DictConfig:
    """The demo pipeline's config for one (scene, RecNN) pair: the paper-scale stage overrides, the
    RecNN's network size in every training stage and its patch crop where it applies."""
    net = override_list(cfg, f"recnn_net.{recnn}")
    crop = OmegaConf.select(cfg, f"crop.{recnn}")
    crop_args = [f"data.crop={int(crop)}"] if crop else []
    stages: dict[str, Any] = {}
    for name in ("recnn", "iml", "blue_noise", "ims", "las"):
        skip = name == "las" and recnn not in [str(r) for r in (cfg.get("las_with") or [])]
        if skip or (OmegaConf.select(cfg, f"stages.{name}") is None and name in ("blue_noise", "las")):
            stages[name] = None  # skipped, as in the demo
            continue
        extra = crop_args if name in ("recnn", "iml", "blue_noise") else []
        stages[name] = [*net, *extra, *override_list(cfg, f"stages.{name}")]
    return OmegaConf.create({
        "scene": scene, "data": str(cfg.data), "recnn": recnn, "renderer": str(cfg.renderer),
        "runs_dir": str(cfg.runs_dir), "cache_dir": str(cfg.cache_dir), "seed": int(cfg.seed),
        "progress": bool(cfg.progress), "dry_run": bool(cfg.dry_run),
        "train_only": bool(cfg.get("train_only", False)), "stages": stages,
        "evaluate": override_list(cfg, "evaluate"),
    })


# ------------------------------------------------------------------------------------------------
# one row per pair, from the evaluation's summary.json


def read_summary(report: Path) -> dict[str, Any]:
    """The evaluation's ``summary.json`` beside ``report``; a missing or damaged one is refused in one line."""
    path = Path(report).parent / "summary.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: cannot read the evaluation's summary ({err}); run the evaluation again (reuse=false)") from None
    if not isinstance(data, dict) or "methods" not in data:
        raise InputError(f"{path}: not an evaluation summary (no 'methods'); run the evaluation again (reuse=false)")
    return data


def _total(methods: Mapping[str, Any], name: str) -> float:
    return float(methods.get(name, {}).get("latency_ms", {}).get("total", math.nan))


def csv_row(summary: Mapping[str, Any]) -> dict[str, Any]:
    """One ``paper_scale.csv`` row (:data:`CSV_COLUMNS`) from an evaluation summary."""
    m = summary["methods"]
    imls, recnn, las = m.get("imls", {}), m.get("recnn", {}), m.get("las", {})
    orp = summary.get("orp") or {}
    recnn_ms, imls_ms = _total(m, "recnn"), _total(m, "imls")
    psnr_r, psnr_i = float(recnn.get("psnr", math.nan)), float(imls.get("psnr", math.nan))
    return {
        "scene": summary["scene"], "recnn": summary["recnn"], "fr_size": summary["fr_size"], "c_size": summary["c_size"],
        "sample_distance_voxels": summary.get("sample_distance_voxels"),
        "mean": orp.get("mean") if orp.get("found") else summary.get("imls_mean"),
        "c_share": imls.get("c_share"), "ipr": imls.get("ipr"), "psnr_recnn_db": psnr_r, "psnr_imls_db": psnr_i,
        "gap_db": psnr_r - psnr_i, "recnn_ms": recnn_ms, "imls_ms": imls_ms,
        "speedup": recnn_ms / imls_ms if imls_ms > 0 else math.nan,
        "las_ms": _total(m, "las"), "las_psnr_db": las.get("psnr", math.nan), "full_ms": _total(m, "full"),
    }


def _cell(v: Any) -> str:
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
        if tuple(reader.fieldnames or ()) != CSV_COLUMNS:
            raise InputError(f"{path}: its columns {reader.fieldnames} are not {list(CSV_COLUMNS)}; move it away to start a new table")
        return [dict(r) for r in reader]


def write_csv(rows: Sequence[Mapping[str, Any]], path: Path) -> Path:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in CSV_COLUMNS])
    return atomic_write_text(path, buf.getvalue())


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
    from .inference.pipeline import STAGES
    from .report.names import METHOD_LABELS

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


def plot_breakdown(summaries: Sequence[Mapping[str, Any]], path: Path) -> Path:
    """Stacked bars per method and pair, plus the limit (the paper's time-breakdown figure)."""
    import numpy as np

    from .inference.pipeline import STAGES
    from .report.names import METHOD_LABELS, STAGE_COLORS, STAGE_LABELS
    from .report.plots import new_figure, save_figure

    fig = new_figure(max(6.0, 4.2 * len(summaries)), 4.4)
    for k, s in enumerate(summaries):
        ax = fig.add_subplot(1, len(summaries), k + 1)
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
        for xi, tot in zip(x, bottom):
            ax.text(xi, tot, f"{tot:.0f}", ha="center", va="bottom", fontsize=7)
        ax.set_xticks(x)
        ax.set_xticklabels([METHOD_LABELS.get(n, "limit: ORP pixels") for n in names], rotation=25, ha="right", fontsize=7)
        ax.set_title(f"{s['scene']}, {s['recnn']} ({s['fr_size']}² FR)", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if k == 0:
            ax.set_ylabel("average latency (ms)")
    fig.axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return save_figure(fig, path)


def report_markdown(rows: Sequence[Mapping[str, Any]], summaries: Sequence[Mapping[str, Any]], *, partial: bool,
                    stage_minutes: Mapping[str, float], command: str, machine: Mapping[str, str],
                    settings: Mapping[str, Mapping[str, Sequence[str]]] | None = None) -> str:
    """``paper_scale.md``: the CSV as a table, each pair's breakdown and baselines, the paper's figures."""
    from .inference.pipeline import STAGES
    from .report.names import STAGE_LABELS

    out = ["# Paper-scale benchmark" + (" (partial: still running or interrupted)" if partial else ""), ""]
    out += ["The paper's protocol at the paper's scale on this CPU: 512² FR-Images, 256² C-Images, half-voxel sampling, "
            "the numba renderer. The ORP is searched on the product path (IMS mask from the view, exactly those pixels "
            "ray-cast, IML decoder, RecNN) on the validation views, within ε = 1 dB of the RecNN alone; PSNR is measured "
            "on the 120-view test trajectory. One IMS regresses PIM' and is rescaled to the ORP's mean. "
            "`speedup` = RecNN alone / IML/S + RecNN; `las_*` is LAS at IML/S's IPR.", ""]
    head = ["scene", "RecNN", "FR / C", "step (voxels)", "ORP mean", "C-share", "IPR", "RecNN PSNR", "IML/S PSNR", "gap (dB)",
            "RecNN (ms)", "IML/S (ms)", "speed-up", "LAS (ms)", "LAS PSNR", "full ray cast (ms)"]
    body = [[r["scene"], r["recnn"], f"{r['fr_size']}² / {r['c_size']}²", fmt(r.get("sample_distance_voxels")), fmt(r.get("mean"), 3),
             fmt_pct(_num(r.get("c_share"))), fmt_pct(_num(r.get("ipr"))), fmt(r.get("psnr_recnn_db")), fmt(r.get("psnr_imls_db")),
             fmt(r.get("gap_db")), fmt(r.get("recnn_ms"), 1), fmt(r.get("imls_ms"), 1), speedup(_num(r.get("recnn_ms")), _num(r.get("imls_ms"))),
             fmt(r.get("las_ms"), 1), fmt(r.get("las_psnr_db")), fmt(r.get("full_ms"), 1)] for r in rows]
    out += [md_table(head, body), "", "Files: `paper_scale.csv` (these rows), `paper_scale_breakdown.png`.", ""]
    for s in summaries:
        orp = s.get("orp") or {}
        out += [f"## {s['scene']}, {s['recnn']}", ""]
        if orp.get("found"):
            out += [f"ORP on the product path (validation views): mean u = {fmt(orp.get('mean'), 4)}, C-share {fmt_pct(orp.get('c_share'))}, "
                    f"IPR {fmt_pct(orp.get('ipr'))}, gap {fmt(orp.get('gap_db'))} dB ({orp.get('evaluations')} means tried).", ""]
        elif orp:
            out += ["ORP: no mean in [0.01, 1] brought IML/S within ε of the RecNN alone on the validation views; IML/S ran at its trained mean.", ""]
        out += [f"Average latency per stage (ms): stage medians on {s.get('timed_views')} of the {s.get('views')} trajectory views; "
                "PSNR on all of them.", ""]
        out += [md_table(["method", "IPR", *(STAGE_LABELS[x] for x in STAGES), "total", "speed-up vs RecNN alone", "PSNR (dB)"],
                         breakdown_rows(s)), ""]
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
                md_table(["RecNN", "stage", "overrides"], [[r, st, f"`{' '.join(a)}`" if a is not None else "skipped"]
                                                           for r, stages in settings.items() for st, a in stages.items()]), ""]
    if stage_minutes:
        out += ["## Time this run took", "", md_table(["pair", "minutes"], [[k, fmt(v, 1)] for k, v in stage_minutes.items()]), ""]
    out += ["## Machine and command", "", md_table(["", ""], [[k, v] for k, v in machine.items()]), "", f"`{command}`", ""]
    return "\n".join(out)


def update_section(benchmarks_md: Path, text: str) -> Path:
    """Put ``text`` between :data:`SECTION_BEGIN` and :data:`SECTION_END` of ``benchmarks_md`` (appended
    when the markers are missing; the rest of the file is kept)."""
    old = benchmarks_md.read_text(encoding="utf-8") if benchmarks_md.is_file() else ""
    block = f"{SECTION_BEGIN}\n{text.rstrip()}\n{SECTION_END}"
    if SECTION_BEGIN in old and SECTION_END in old:
        head, rest = old.split(SECTION_BEGIN, 1)
        new = head + block + rest.split(SECTION_END, 1)[1]
    else:
        new = old.rstrip() + ("\n\n" if old else "") + block + "\n"
    return atomic_write_text(benchmarks_md, new)


def orp_cell(row: Mapping[str, Any]) -> str:
    """The ORP's C-share, or "none" with the share IML/S ran at when no mean met ε."""
    found = math.isfinite(_num(row.get("mean")))
    return fmt_pct(_num(row.get("c_share"))) if found else f"none (ran at {fmt_pct(_num(row.get('c_share')))})"


def section_text(rows: Sequence[Mapping[str, Any]], partial: bool) -> str:
    lines = ["## Paper scale (512² FR, 256² C, half-voxel sampling)" + (" — partial" if partial else ""), "",
             "`make bench-paper`; details, per-stage breakdown and the paper's figures in "
             "[benchmarks/paper_scale.md](benchmarks/paper_scale.md), rows in `benchmarks/paper_scale.csv`.", ""]
    lines.append(md_table(["scene", "RecNN", "ORP C-share", "IML/S PSNR (gap)", "RecNN alone (ms)", "IML/S + RecNN (ms)", "speed-up", "LAS (ms, PSNR)"],
                          [[r["scene"], r["recnn"], orp_cell(r), f"{fmt(r.get('psnr_imls_db'))} ({fmt(r.get('gap_db'))} dB)",
                            fmt(r.get("recnn_ms"), 1), fmt(r.get("imls_ms"), 1), speedup(_num(r.get("recnn_ms")), _num(r.get("imls_ms"))),
                            f"{fmt(r.get('las_ms'), 1)}, {fmt(r.get('las_psnr_db'))} dB"] for r in rows]))
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------


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


def bench_paper(cfg: DictConfig, scene_overrides: Sequence[str] = (), command: str = "") -> Path | None:
    """Run every pair and write the results; returns ``paper_scale.md`` (None with ``dry_run`` or ``train_only``)."""
    from .report import machine_info

    todo = pairs(cfg)
    out_dir = Path(str(cfg.output_dir))
    csv_path, md_path, png_path = out_dir / "paper_scale.csv", out_dir / "paper_scale.md", out_dir / "paper_scale_breakdown.png"
    old_rows = read_rows(csv_path)  # refuse a foreign table before hours of work
    rows: list[dict[str, Any]] = []
    summaries: list[dict[str, Any]] = []
    minutes: dict[str, float] = {}
    machine = machine_info("cpu")
    for k, (scene, recnn) in enumerate(todo):
        log(f"\n[bench-paper] pair {k + 1}/{len(todo)}: {scene}, {recnn}")
        t0 = time.perf_counter()
        report = demo(pair_config(cfg, scene, recnn), scene_overrides)
        if report is None:  # dry run, or train_only
            continue
        minutes[f"{scene}, {recnn}"] = (time.perf_counter() - t0) / 60
        summary = read_summary(report)
        summaries.append(summary)
        rows.append(csv_row(summary))
        partial = k + 1 < len(todo)
        all_rows = merge_rows(old_rows, rows)
        write_csv(all_rows, csv_path)
        plot_breakdown(summaries, png_path)
        settings = {r: {k: (list(v) if v is not None else None) for k, v in pair_config(cfg, scene, r).stages.items()}
                    for r in dict.fromkeys(rr for _, rr in todo)}
        atomic_write_text(md_path, report_markdown(all_rows, summaries, partial=partial, stage_minutes=minutes,
                                                   command=command, machine=machine, settings=settings))
        if cfg.get("benchmarks_md"):
            update_section(Path(str(cfg.benchmarks_md)), section_text(all_rows, partial))
        log(f"[bench-paper] {scene}, {recnn} done in {minutes[f'{scene}, {recnn}']:.1f} min -> {csv_path}")
    return None if cfg.dry_run or cfg.get("train_only", False) else md_path


_SCENE_OVERRIDES: list[str] = []


@hydra.main(version_base="1.3", config_path=str(ROOT / "conf" / "pipelines"), config_name="bench_paper")
@cli_errors
def _main(cfg: DictConfig) -> None:
    command = "python -m imls_lightning.bench_paper " + " ".join(sys.argv[1:] + _SCENE_OVERRIDES)
    run_pipeline(lambda: bench_paper(cfg, _SCENE_OVERRIDES, command.strip()))


def main() -> None:
    """``python -m imls_lightning.bench_paper``: scene overrides leave the command line first
    (:func:`imls_lightning.demo.split_scene_overrides`)."""
    sys.argv[1:], _SCENE_OVERRIDES[:] = split_scene_overrides(sys.argv[1:])
    _main()


if __name__ == "__main__":
    main()
