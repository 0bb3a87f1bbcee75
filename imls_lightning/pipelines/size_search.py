"""The network-size search (``python -m imls_lightning.size_search``): one Hydra sweep job per candidate
network size runs the demo's stages (:func:`size_job`), then the speed-quality front over the scene's
candidates, its table, plot and the experiment file of the chosen sizes (:func:`summarize`,
:class:`SizeFront`, the sweep's callback)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.atomic import atomic_write_text
from imls_lightning.base.errors import InputError

from ..orp.overrides import override_key
from .bench_paper import csv_row
from .demo import demo
from ..base.paths import ROOT, log
from .stages import dry_stage, override_list, read_summary, run_stage, stage_args, stage_overrides


#: size key -> (the stages it applies to, the override key there)
SIZE_KEYS: dict[str, tuple[tuple[str, ...], str]] = {
    "recnn_channels": (("recnn",), "recnn.net.channels"),
    "recnn_blocks": (("recnn",), "recnn.net.blocks"),
    "decoder_depth": (("iml", "blue_noise"), "model.depth"),
    "decoder_width": (("iml", "blue_noise"), "model.base_channels"),
    "ims_layers": (("ims",), "model.layers"),
    "ims_width": (("ims",), "model.base_channels"),
}
#: the columns of ``pareto.csv``
FRONT_COLUMNS = (*SIZE_KEYS, "recnn_test_psnr_db", "reference_test_psnr_db", "recnn_ok", "orp_found", "mean", "c_share",
                 "psnr_recnn_db", "psnr_imls_db", "gap_db", "recnn_ms", "imls_ms", "speedup", "feasible", "pareto", "report")
#: second line of a config this tool wrote, after the package line (it never overwrites a file without it)
EXPERIMENT_MARK = "# written by python -m imls_lightning.size_search"


def check_sizes(size: Mapping[str, Any] | None) -> dict[str, int]:
    """The ``size`` node as positive integers; an unknown key or a bad value is one line.

    Example:
        >>> check_sizes({"recnn_channels": 16, "recnn_blocks": 4, "decoder_depth": 4, "decoder_width": 8,
        ...              "ims_layers": 5, "ims_width": 16})["recnn_channels"]
        16
    """
    size = dict(size or {})
    unknown = sorted(set(size) - set(SIZE_KEYS))
    if unknown:
        raise InputError(f"size.{unknown[0]}: unknown size; expected some of {list(SIZE_KEYS)}")
    out = {}
    for k in SIZE_KEYS:
        v = size.get(k)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise InputError(f"size.{k}={v}: expected a positive integer")
        out[k] = int(v)
    return out


def candidate_name(sizes: Mapping[str, int]) -> str:
    """A candidate's file name, e.g. ``r32x4-d4w8-s5w16``."""
    s = sizes
    return (f"r{s['recnn_channels']}x{s['recnn_blocks']}-d{s['decoder_depth']}w{s['decoder_width']}"
            f"-s{s['ims_layers']}w{s['ims_width']}")


def size_overrides(sizes: Mapping[str, int]) -> dict[str, list[str]]:
    """Stage -> the overrides that give it these sizes."""
    out: dict[str, list[str]] = {}
    for k, (stages, key) in SIZE_KEYS.items():
        if k in sizes:
            for st in stages:
                out.setdefault(st, []).append(f"{key}={int(sizes[k])}")
    return out


def candidate_config(cfg: DictConfig, sizes: Mapping[str, int], skip: bool = True) -> DictConfig:
    """The demo pipeline's config for one candidate: its sizes override the stages' (and the scene's);
    with ``skip`` the stages of ``search_skips`` (the baselines the search does not need) are skipped."""
    # the pipeline's own keys (a multirun's callback also gets the hydra node, not resolvable there)
    job = OmegaConf.to_container(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True)
    scene_stages = job.setdefault("scene_stages", {}) or {}
    job["scene_stages"] = scene_stages
    mine = scene_stages.setdefault(str(cfg.scene), {}) or {}
    scene_stages[str(cfg.scene)] = mine
    for stage, ov in size_overrides(sizes).items():
        if job["stages"].get(stage) is None:
            continue  # a skipped stage stays skipped
        mine[stage] = [*(mine.get(stage) or []), *ov]
    for stage in (job.get("search_skips") or []) if skip else []:
        if stage not in job["stages"]:
            raise InputError(f"search_skips: unknown stage {stage!r}; expected some of {sorted(job['stages'])}")
        job["stages"][stage] = None
    return OmegaConf.create(job)


def recnn_test_psnr(checkpoint: str | Path) -> float:
    """The FR PSNR of a RecNN run's test pass (``result.json`` of the run the checkpoint belongs to)."""
    run = Path(str(checkpoint)).resolve().parents[1]
    try:
        result = json.loads((run / "result.json").read_text())
        return float(result["test"]["test/fr_psnr"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise InputError(f"{run}/result.json: no test PSNR of the RecNN ({err!r}); train it with test=true") from None


def reference_recnn(cfg: DictConfig, scene_overrides: Sequence[str] = ()) -> str:
    """Train (or reuse) the reference RecNN: the stage ``recnn`` with the reference size; its checkpoint."""
    ref = OmegaConf.to_container(cfg.reference, resolve=True) or {}
    args = [f"{SIZE_KEYS['recnn_' + k][1]}={int(v)}" for k, v in ref.items()]
    common = stage_args(cfg, scene_overrides)[1]
    stage = dry_stage if bool(cfg.get("dry_run", False)) else run_stage
    merged = {override_key(o): o for o in [*override_list(cfg, "stages.recnn"), *args]}  # the reference's size wins
    return stage("reference RecNN", ["-m", "imls_lightning.train", "model=recnn", *common, *merged.values()])


def scene_dir(cfg: DictConfig) -> Path:
    return Path(str(cfg.output_dir)) / str(cfg.scene)


def size_job(cfg: DictConfig, scene_overrides: Sequence[str] = ()) -> dict[str, Any]:
    """One candidate: its pipeline, its evaluation, its record (also written to ``jobs/<name>.json``)."""
    sizes = check_sizes(OmegaConf.to_container(cfg.size, resolve=True))
    ref = OmegaConf.to_container(cfg.get("reference"), resolve=True) or {}
    bad = sorted(set(ref) - {"channels", "blocks"})
    if bad:
        raise InputError(f"reference.{bad[0]}: unknown key; expected channels and blocks (the reference RecNN's size)")
    name = candidate_name(sizes)
    t0 = time.perf_counter()
    log(f"[size_search] candidate {name}")
    dry = bool(cfg.get("dry_run", False))
    ref_ckpt = reference_recnn(cfg, scene_overrides) if ref else None
    report = demo(candidate_config(cfg, sizes), scene_overrides)
    if dry:
        return {}
    ref_psnr = recnn_test_psnr(ref_ckpt) if ref_ckpt else math.nan
    summary = read_summary(report)
    row = csv_row(summary)
    recnn_ckpt = str(OmegaConf.load(Path(report).parent / "config.yaml").checkpoints.recnn)
    own_psnr = recnn_test_psnr(recnn_ckpt)
    orp = summary.get("orp") or {}
    recnn_ok = not math.isfinite(ref_psnr) or own_psnr >= ref_psnr - float(cfg.recnn_bound_db)
    found = bool(orp.get("found"))
    record = {**sizes, "recnn_test_psnr_db": own_psnr, "reference_test_psnr_db": ref_psnr, "recnn_ok": recnn_ok,
              "orp_found": found, **{k: row[k] for k in ("mean", "c_share", "psnr_recnn_db", "psnr_imls_db", "gap_db",
                                                         "recnn_ms", "imls_ms", "speedup")},
              "feasible": bool(recnn_ok and found), "report": str(report), "minutes": (time.perf_counter() - t0) / 60}
    path = scene_dir(cfg) / "jobs" / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(record, indent=2))
    log(f"[size_search] {name}: IML/S {record['imls_ms']:.1f} ms, {record['psnr_imls_db']:.2f} dB, "
        f"feasible={record['feasible']} -> {path}")
    return record


# ------------------------------------------------------------------------------------------------
# the front


def pareto_flags(points: Sequence[tuple[float, float]]) -> list[bool]:
    """Which ``(latency, psnr)`` points no other point beats in both (lower latency, higher PSNR).

    Example:
        >>> pareto_flags([(10, 30.0), (20, 31.0), (25, 30.5), (10, 29.0)])
        [True, True, False, False]
    """
    flags = []
    for i, (t, q) in enumerate(points):
        dominated = any((t2 <= t and q2 >= q) and (t2 < t or q2 > q) for j, (t2, q2) in enumerate(points) if j != i)
        flags.append(not dominated and math.isfinite(t) and math.isfinite(q))
    return flags


def read_records(folder: Path) -> list[dict[str, Any]]:
    """Every job record of a scene; a damaged one is skipped with a one-line warning (run it again)."""
    records = []
    for path in sorted(Path(folder).glob("*.json")):
        try:
            rec = json.loads(path.read_text())
            check_sizes({k: rec[k] for k in SIZE_KEYS})
            float(rec["imls_ms"]), float(rec["psnr_imls_db"])
        except (OSError, ValueError, KeyError, TypeError, InputError) as err:
            log(f"[size_search] warning: {path} is not a job record ({err}); run that candidate again")
            continue
        records.append(rec)
    return records


def choose(records: Sequence[Mapping[str, Any]]) -> dict[str, Any] | None:
    """The fastest feasible record (None when none is)."""
    feasible = [r for r in records if r.get("feasible")]
    return dict(min(feasible, key=lambda r: float(r["imls_ms"]))) if feasible else None


def front_rows(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    rows = sorted((dict(r) for r in records), key=lambda r: float(r["imls_ms"]))
    for r, on in zip(rows, pareto_flags([(float(r["imls_ms"]), float(r["psnr_imls_db"])) for r in rows])):
        r["pareto"] = on
    return rows


def write_front(records: Sequence[Mapping[str, Any]], folder: Path, scene: str) -> dict[str, Path]:
    """``pareto.csv``, ``pareto.md`` and ``pareto.png`` of a scene's records."""
    from ..report import fmt, md_table, write_csv, write_markdown
    from ..report.plots import new_figure, save_figure

    rows = front_rows(records)
    paths = {"csv": write_csv(folder / "pareto.csv", rows, FRONT_COLUMNS,
                              lambda v: f"{v:.6g}" if isinstance(v, float) and math.isfinite(v) else v)}
    chosen = choose(rows)
    table = md_table(
        ["candidate", "RecNN test (dB)", "ORP u", "C-share", "RecNN alone (ms)", "IML/S (ms)", "speed-up",
         "IML/S (dB)", "gap (dB)", "feasible", "Pareto"],
        [[candidate_name(r), fmt(r["recnn_test_psnr_db"]), fmt(r["mean"], 3) if r["orp_found"] else "none",
          fmt(100 * float(r["c_share"]), 1) + "%", fmt(r["recnn_ms"], 1), fmt(r["imls_ms"], 1), fmt(r["speedup"]) + "x",
          fmt(r["psnr_imls_db"]), fmt(r["gap_db"]), "yes" if r["feasible"] else "no", "yes" if r["pareto"] else ""]
         for r in rows])
    ref = next((float(r["reference_test_psnr_db"]) for r in rows if math.isfinite(float(r["reference_test_psnr_db"]))), math.nan)
    md = [f"# Size search: {scene}", "",
          "Candidate `rCxB-dDwW-sLwS`: RecNN C channels x B blocks, IML decoder depth D width W, IMS L layers "
          "width S. Latencies and PSNR on the product path at each candidate's ORP (test trajectory).", "",
          f"Reference RecNN (the paper's size) test PSNR: {fmt(ref)} dB; a candidate's RecNN must stay within "
          "0.5 dB of it, and its IML/S within ε of its RecNN alone (an ORP exists).", "", table, ""]
    md.append(f"Chosen: **{candidate_name(chosen)}** ({fmt(chosen['imls_ms'], 1)} ms, {fmt(chosen['psnr_imls_db'])} dB)."
              if chosen else "No candidate meets both bounds; no experiment config was written.")
    paths["md"] = write_markdown(folder / "pareto.md", md)

    fig = new_figure(5.6, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    for r in rows:
        color = "tab:green" if r["feasible"] else "tab:gray"
        ax.scatter(float(r["imls_ms"]), float(r["psnr_imls_db"]), color=color, marker="o" if r["pareto"] else "x")
        ax.annotate(candidate_name(r), (float(r["imls_ms"]), float(r["psnr_imls_db"])), fontsize=6,
                    xytext=(3, 3), textcoords="offset points")
    front = [r for r in rows if r["pareto"]]
    ax.plot([float(r["imls_ms"]) for r in front], [float(r["psnr_imls_db"]) for r in front], color="tab:blue", lw=1,
            label="Pareto front")
    ax.set_xlabel("IML/S + RecNN latency at the ORP (ms)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f"size search: {scene} (green: meets both bounds)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    paths["png"] = save_figure(fig, folder / "pareto.png")
    return paths


def experiment_text(cfg: DictConfig, chosen: Mapping[str, Any]) -> str:
    """The ``<scene>_fast`` experiment of the demo / bench_paper pipelines: the chosen candidate's whole
    stage lists (the pipeline's, its scene's entries, the sizes; baselines included) and no scene
    entries left to change them."""
    sizes = {k: int(chosen[k]) for k in SIZE_KEYS}
    job = candidate_config(cfg, sizes, skip=False)
    scene = str(cfg.scene)
    stages = {st: (None if job.stages[st] is None else stage_overrides(job, st)) for st in job.stages}
    body = OmegaConf.to_yaml(OmegaConf.create({"scene": scene, "recnn": str(cfg.recnn), "stages": stages,
                                               "scene_stages": None}))
    head = ["# @package _global_",  # Hydra reads the package from the first line
            EXPERIMENT_MARK + f" ({time.strftime('%Y-%m-%d')}); do not edit: the next search rewrites it.",
            f"# The fastest sizes for {scene} with {cfg.recnn} that keep the RecNN within {cfg.recnn_bound_db} dB of the",
            f"# reference and IML/S within epsilon of that RecNN: {candidate_name(sizes)}, IML/S {float(chosen['imls_ms']):.1f} ms",
            f"# at the ORP u = {chosen['mean']}, {float(chosen['psnr_imls_db']):.2f} dB (benchmarks/size_search/{scene}/pareto.md).",
            f"#   python -m imls_lightning.demo +experiment={scene}_fast"]
    return "\n".join(head) + "\n" + body


def written_by_search(text: str) -> bool:
    """Whether a config's header says this tool wrote it (its second line)."""
    lines = text.splitlines()
    return len(lines) > 1 and lines[1].startswith(EXPERIMENT_MARK)


def write_experiment(folder: Path, cfg: DictConfig, chosen: Mapping[str, Any]) -> Path:
    """Write ``<folder>/<scene>_fast.yaml``; a file there this tool did not write is refused in one line."""
    path = Path(folder) / f"{cfg.scene}_fast.yaml"
    if path.exists() and not written_by_search(path.read_text(errors="replace")):
        raise InputError(f"{path}: exists and was not written by the size search; move it away or set experiment_dir")
    return atomic_write_text(path, experiment_text(cfg, chosen))


def summarize(cfg: DictConfig) -> dict[str, Path]:
    """The scene's front and, when a candidate is feasible, its experiment config."""
    folder = scene_dir(cfg)
    records = read_records(folder / "jobs")
    if not records:
        log(f"[size_search] no job records in {folder / 'jobs'}; nothing to summarize")
        return {}
    paths = write_front(records, folder, str(cfg.scene))
    chosen = choose(records)
    exp_dir = cfg.get("experiment_dir")
    if chosen is not None and exp_dir:
        exp_dir = ROOT / "conf" / "pipelines" / "experiment" if str(exp_dir) == "auto" else Path(str(exp_dir))
        if not exp_dir.is_dir():
            raise InputError(f"experiment_dir={exp_dir}: not a folder (the size search writes into folders that exist)")
        paths["experiment"] = write_experiment(exp_dir, cfg, chosen)
    for k, p in paths.items():
        log(f"[size_search] {k}: {p}")
    return paths


class SizeFront(Callback):
    """Hydra callback: after the sweep, :func:`summarize` the scene's records."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        summarize(config)
