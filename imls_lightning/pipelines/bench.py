"""The reference benchmark (``make bench``, ``python -m imls_lightning.bench``): for every scene x RecNN,
the RecNN, the ORP search, the IMS, LAS and the evaluation through the real CLIs
(:func:`~imls_lightning.pipelines.stages.run_stage`), then ``BENCHMARKS.md``: the paper's ORP and LAS
tables on this machine (:func:`bench`, :func:`render_markdown`)."""
from __future__ import annotations

import hashlib
import json
import math
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.base.overrides import quote_override_value

from ..report import atomic_write_text, fmt, md_table, write_markdown
from ..report import fmt_pct as pct
from ..report.tables import speedup as ratio
from ..base.paths import CONF_DIR, log
from .stages import StageFailed, check_scene_overrides, dry_stage, override_list, run_stage, stage_args

TIMES_FILE = "bench_times.json"
#: RecNN -> the paper's column (the rendering mode its sampling pattern stands for)
KIND = {"enhancenet": "Sup-Res", "fovolnet": "Foveated"}
STAGE_KEYS = ("recnn", "orp", "ims", "las", "evaluate")


# ------------------------------------------------------------------------------------------------
# small helpers


def args_hash(args: Sequence[str], length: int = 8) -> str:
    """Short stable hash of a command's arguments (names the ORP sweep directory)."""
    return hashlib.sha1("\x00".join(args).encode()).hexdigest()[:length]


def _finite(x: Any) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def hms(seconds: Any) -> str:
    if not _finite(seconds):
        return "–"
    s = int(round(float(seconds)))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


# ------------------------------------------------------------------------------------------------
# reading the results of the CLIs


def read_orp(path: Path) -> dict[str, Any]:
    """The ORP of a sweep's ``orp.yaml``, and the IML checkpoint the rest of the pipeline uses.

    Returns ``{"found", "mean", "c_share", "ipr", "gap_db", "psnr_db", "iml_checkpoint",
    "pattern_ipr", "rounds", "jobs", "stop_reason", "finished", "path"}``. Without an ORP in the
    bracket (``found: false``), the successful job with the smallest gap stands in (its numbers are
    reported, marked as not meeting epsilon). ``pattern_ipr`` (pattern pixels / FR pixels) is
    ``ipr / c_share`` of the jobs.

    Raises:
        InputError: no job of the sweep succeeded.
    """
    import yaml

    rep = yaml.safe_load(Path(path).read_text()) or {}
    jobs = [j for j in rep.get("jobs") or [] if j.get("status") == "ok"]
    search = rep.get("search") or {}
    out: dict[str, Any] = {
        "found": bool(rep.get("found")), "epsilon_db": rep.get("epsilon_db"), "path": str(path),
        "pattern_ipr": _pattern_ipr(jobs),
        "rounds": search.get("rounds"), "jobs": search.get("jobs"), "stop_reason": search.get("stop_reason"),
        "finished": bool((rep.get("context") or {}).get("finished")),
    }
    if out["found"]:
        orp = rep.get("orp") or {}
        out.update(mean=float(rep["mean"]), c_share=orp.get("c_share"), ipr=orp.get("ipr"), gap_db=rep.get("gap_db"),
                   psnr_db=rep.get("psnr_db") or {}, iml_checkpoint=str(rep["iml_checkpoint"]))
        return out
    if not jobs:
        raise InputError(f"{path}: no job of the ORP sweep succeeded (see the errors listed there)")
    best = min(jobs, key=lambda j: (float(j["gap_db"]) if _finite(j.get("gap_db")) else math.inf, -float(j["mean"])))
    out.update(mean=float(best["mean"]), c_share=best.get("c_share"), ipr=best.get("ipr"), gap_db=best.get("gap_db"),
               psnr_db=best.get("psnr_db") or {}, iml_checkpoint=str(best["iml_checkpoint"]))
    return out


def _pattern_ipr(jobs: Sequence[Mapping[str, Any]]) -> float:
    """Pattern pixels / FR pixels: exact from a job's ``orp_job.json``, else ``ipr / c_share`` of the
    job with the largest C-Image share (orp.yaml rounds both to 4 decimals)."""
    for j in jobs:
        try:
            v = json.loads((Path(str(j.get("job_dir"))) / "orp_job.json").read_text()).get("pattern_ipr")
        except (OSError, ValueError, TypeError):
            continue
        if _finite(v) and float(v) > 0:
            return float(v)
    ok = [j for j in jobs if _finite(j.get("ipr")) and _finite(j.get("c_share")) and float(j["c_share"]) > 0]
    if not ok:
        return math.nan
    j = max(ok, key=lambda j: float(j["c_share"]))
    return float(j["ipr"]) / float(j["c_share"])


def sweep_means(las_iprs: Sequence[float], pattern_ipr: float) -> list[float]:
    """Inference means ``u`` at which the IML keeps about ``ipr`` of the FR pixels: its C-Image share
    follows ``u`` (normalized importance + rejection sampling), so ``u = ipr / pattern_ipr``,
    rounded to 3 significant digits and clipped to the paper's range [0.01, 1].

    Example:
        >>> sweep_means([0.05, 0.1, 0.15], 0.25)
        [0.2, 0.4, 0.6]
    """
    share = pattern_ipr if _finite(pattern_ipr) and pattern_ipr > 0 else 0.25
    return [min(1.0, max(0.01, float(f"{float(ipr) / share:.3g}"))) for ipr in las_iprs]


def _sweep_points(sweep_csv: Path) -> dict[tuple[str, float], dict[str, Any]]:
    """Mean over views of each (method, setting value) of an evaluation's ``sweep.csv``
    (:func:`imls_lightning.report.tables.sweep_points`), keyed by the value rounded to 6 decimals."""
    from ..report import read_csv, sweep_points

    if not sweep_csv.is_file():
        return {}
    return {(method, round(value, 6)): {"total_ms": p["latency_ms"].get("total", math.nan), "ipr": p["ipr"],
                                        "c_share": p["c_share"], "psnr": p["psnr"], "ssim": p["ssim"], "views": p["views"]}
            for (method, value), p in sweep_points(read_csv(sweep_csv)).items()}


def collect_pair(scene: str, recnn: str, orp: Mapping[str, Any], eval_dir: Path, las_iprs: Sequence[float],
                 means: Sequence[float], with_las: bool) -> dict[str, Any]:
    """One scene x RecNN record for the tables, from ``orp.yaml`` (:func:`read_orp`) and the
    evaluation's ``metrics.csv`` / ``sweep.csv``.

    Returns ``{"scene", "recnn", "orp", "methods": summary(metrics.csv), "points": [{"ipr", "mean",
    "las": {...} | None, "imls": {...} | None}, ...], "with_las", "eval_dir"}``; a point's method entry
    has ``total_ms``, ``ipr`` (measured), ``psnr``, ``ssim``, ``views``.
    """
    from ..report import summary

    eval_dir = Path(eval_dir)
    methods = summary(eval_dir / "metrics.csv")
    sweep = _sweep_points(eval_dir / "sweep.csv")
    points = []
    for ipr, u in zip(las_iprs, means):
        points.append({"ipr": float(ipr), "mean": float(u),
                       "las": sweep.get(("las", round(float(ipr), 6))) if with_las else None,
                       "imls": sweep.get(("iml_selective", round(float(u), 6)))})
    return {"scene": scene, "recnn": recnn, "orp": dict(orp), "methods": methods, "points": points,
            "with_las": bool(with_las), "eval_dir": str(eval_dir)}


# ------------------------------------------------------------------------------------------------
# BENCHMARKS.md


def _total(rec: Mapping[str, Any] | None, method: str) -> float:
    if not rec or method not in rec["methods"]:
        return math.nan
    return rec["methods"][method]["latency_ms"].get("total", math.nan)


def _metric(rec: Mapping[str, Any] | None, method: str, key: str) -> float:
    if not rec or method not in rec["methods"]:
        return math.nan
    return rec["methods"][method].get(key, math.nan)


def _quality(psnr: Any, ssim: Any) -> str:
    return f"{fmt(psnr, 2)} / {fmt(ssim, 3)}" if _finite(psnr) else "–"


def orp_table(records: Sequence[Mapping[str, Any]], scenes: Sequence[str], recnns: Sequence[str]) -> str:
    """The paper's ORP table: per scene, for each RecNN: ORP (share of the C-Image), the average
    rendering latency of IML/S + RecNN at the ORP, and its speed-up over the RecNN alone."""
    by = {(r["scene"], r["recnn"]): r for r in records}
    kinds = [KIND.get(n, n) for n in recnns]
    header = (["Dataset"] + [f"ORP {k} ↓" for k in kinds] + [f"Avg rendering latency (ms) {k} ↓" for k in kinds]
              + [f"Avg speed-up {k} ↑" for k in kinds])
    rows = []
    for s in scenes:
        recs = [by.get((s, n)) for n in recnns]
        if not any(recs):
            continue
        orp = [("–" if r is None else pct(r["orp"]["c_share"], 1) + ("" if r["orp"]["found"] else " (none)")) for r in recs]
        lat = [fmt(_total(r, "imls"), 1) for r in recs]
        spd = [ratio(_total(r, "recnn"), _total(r, "imls")) for r in recs]
        rows.append([s] + orp + lat + spd)
    return md_table(header, rows)


def orp_details(records: Sequence[Mapping[str, Any]]) -> str:
    header = ["Dataset", "RecNN", "mean u", "C-Image share (val)", "IPR (val)", "gap (dB, val)", "RecNN alone (ms)",
              "IML/S + RecNN (ms)", "speed-up", "PSNR RecNN / IML/S (dB)", "SSIM RecNN / IML/S", "IML/S IPR (test)",
              "search"]
    rows = []
    for r in records:
        o = r["orp"]
        search = f"{o.get('jobs')} jobs, {o.get('rounds')} rounds, {o.get('stop_reason')}"
        rows.append([r["scene"], r["recnn"], f"{o['mean']:g}" + ("" if o["found"] else " *"), pct(o["c_share"]),
                     pct(o["ipr"], 2), fmt(o["gap_db"], 2), fmt(_total(r, "recnn"), 2), fmt(_total(r, "imls"), 2),
                     ratio(_total(r, "recnn"), _total(r, "imls")),
                     f"{fmt(_metric(r, 'recnn', 'psnr'))} / {fmt(_metric(r, 'imls', 'psnr'))}",
                     f"{fmt(_metric(r, 'recnn', 'ssim'), 3)} / {fmt(_metric(r, 'imls', 'ssim'), 3)}",
                     pct(_metric(r, "imls", "ipr"), 2), search])
    return md_table(header, rows)


def las_table(records: Sequence[Mapping[str, Any]], scenes: Sequence[str], recnns: Sequence[str]) -> str:
    """The paper's LAS comparison table: per scene the full ray-cast latency and, at each IPR, the
    latency of LAS and IML/S (+ speed-up) and their PSNR / SSIM, for each RecNN (LAS: super-resolution
    only, "NS" otherwise). The last row per scene compares at the IPR IML/S reaches at its ORP (the
    trained IML/S + RecNN; LAS matched to that IPR)."""
    by = {(r["scene"], r["recnn"]): r for r in records}
    kinds = [KIND.get(n, n) for n in recnns]
    header = ["Dataset", "Full ray cast (ms)", "IPR"]
    for k in kinds:
        header += [f"{k}: LAS (ms)", f"{k}: IML/S (ms)", f"{k}: speed-up"]
    for k in kinds:
        header += [f"{k}: LAS PSNR / SSIM", f"{k}: IML/S PSNR / SSIM"]
    rows = []
    for s in scenes:
        recs = [by.get((s, n)) for n in recnns]
        present = [r for r in recs if r]
        if not present:
            continue
        fulls = [_total(r, "full") for r in present if _finite(_total(r, "full"))]
        full = fmt(sum(fulls) / len(fulls), 1) if fulls else "–"
        n_points = max(len(r["points"]) for r in present)
        for i in range(n_points + 1):
            lat_cells, q_cells = [], []
            if i < n_points:
                ipr = next(r["points"][i]["ipr"] for r in present if i < len(r["points"]))
                label = pct(ipr, 1)
            else:
                label = "at ORP: " + ", ".join(f"{pct(_metric(r, 'imls', 'ipr'), 1)}" for r in present)
            for r in recs:
                if r is None:
                    lat_cells += ["–"] * 3
                    q_cells += ["–"] * 2
                    continue
                if i < n_points:
                    p = r["points"][i] if i < len(r["points"]) else {"las": None, "imls": None}
                    las, imls = p.get("las"), p.get("imls")
                    las_ms, imls_ms = (las or {}).get("total_ms"), (imls or {}).get("total_ms")
                    las_q = _quality((las or {}).get("psnr"), (las or {}).get("ssim"))
                    imls_q = _quality((imls or {}).get("psnr"), (imls or {}).get("ssim"))
                else:
                    las_ms, imls_ms = _total(r, "las"), _total(r, "imls")
                    las_q = _quality(_metric(r, "las", "psnr"), _metric(r, "las", "ssim"))
                    imls_q = _quality(_metric(r, "imls", "psnr"), _metric(r, "imls", "ssim"))
                if r["with_las"]:
                    lat_cells += [fmt(las_ms, 1), f"**{fmt(imls_ms, 1)}**", ratio(las_ms, imls_ms)]
                    q_cells += [las_q, imls_q]
                else:
                    lat_cells += ["NS", f"**{fmt(imls_ms, 1)}**", "–"]
                    q_cells += ["NS", imls_q]
            rows.append([s if i == 0 else "", full if i == 0 else "", label] + lat_cells + q_cells)
    return md_table(header, rows)


def las_details(records: Sequence[Mapping[str, Any]]) -> str:
    header = ["Dataset", "RecNN", "target IPR", "method", "setting", "measured IPR", "latency (ms)", "PSNR (dB)", "SSIM", "views"]
    rows = []
    for r in records:
        for p in r["points"]:
            for name, label, setting in (("las", "LAS", f"IPR {p['ipr']:g}"),
                                         ("imls", "IML/S (IML IM, selectively rendered)", f"u {p['mean']:g}")):
                v = p.get(name)
                if v is None:
                    continue
                rows.append([r["scene"], r["recnn"], pct(p["ipr"], 1), label, setting, pct(v["ipr"], 2), fmt(v["total_ms"], 2),
                             fmt(v["psnr"], 2), fmt(v["ssim"], 4), int(v["views"])])
        for name, label in (("las", "LAS (matched to IML/S)"), ("imls", "IML/S + RecNN (trained, ORP)")):
            if name in r["methods"]:
                m = r["methods"][name]
                rows.append([r["scene"], r["recnn"], "at ORP", label, "", pct(m.get("ipr"), 2),
                             fmt(m["latency_ms"].get("total"), 2), fmt(m.get("psnr"), 2), fmt(m.get("ssim"), 4), m.get("views")])
    return md_table(header, rows)


def stage_table(records: Sequence[Mapping[str, Any]], times: Mapping[str, Mapping[str, float]]) -> str:
    """Minutes each stage took when its result was made (``times``: ``"scene/recnn" -> {stage: s}``)."""
    header = ["Dataset", "RecNN", "RecNN training", "ORP search", "IMS", "LAS (per scene)", "evaluation", "total"]
    rows = []
    for r in records:
        t = times.get(f"{r['scene']}/{r['recnn']}", {})
        vals = [t.get(k) for k in STAGE_KEYS]
        known = [float(v) for v in vals if _finite(v)]
        rows.append([r["scene"], r["recnn"]] + [hms(v) for v in vals] + [hms(sum(known)) if known else "–"])
    return md_table(header, rows)


def paper_table_section(title: str, table: str, note: str, details_title: str, details: str) -> list[str]:
    """The lines of one paper table's section of BENCHMARKS.md: ``## title``, the table, the note on how it was
    measured, then ``### details_title`` and the details."""
    return [f"## {title}", "", table, "", note, "", f"### {details_title}", "", details, ""]


def render_markdown(records: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> str:
    """The text of BENCHMARKS.md (see the module docstring); ``meta`` holds ``scenes``, ``recnns``,
    ``command``, ``machine``, ``scale`` (lines), ``notes``, ``times``, ``elapsed_s``, ``done``, ``total``."""
    scenes, recnns = list(meta["scenes"]), list(meta["recnns"])
    done, total = int(meta.get("done", len(records))), int(meta.get("total", len(records)))
    L = ["# IML/S benchmark", ""]
    status = "complete" if done >= total else f"**partial**: {done} of {total} scene × RecNN pairs done (run the command again to resume)"
    L += [f"Status: {status}. Written {meta.get('date', time.strftime('%Y-%m-%d %H:%M'))}.", ""]
    L += ["Command:", "", "```bash", str(meta.get("command", "python -m imls_lightning.bench")), "```", ""]
    times = meta.get("times") or {}
    pair_s = [sum(float(v) for v in (times.get(f"{r['scene']}/{r['recnn']}") or {}).values() if _finite(v)) for r in records]
    L += [f"Wall time of this invocation: {hms(meta.get('elapsed_s'))} (h:mm:ss; reused stages take seconds). "
          f"Time the results in the tables cost when they were made: {hms(sum(pair_s))} (see Stage times).", ""]
    L += ["## Machine", "", md_table(["", ""], [(k, v) for k, v in (meta.get("machine") or {}).items()]), ""]
    L += ["## Scale", ""] + [f"- {line}" for line in meta.get("scale", [])] + [""]

    L += paper_table_section("ORP for free rendering latency improvement (paper: Table \"Detailed ORP\")",
                             orp_table(records, scenes, recnns),
                             "ORP: share of the C-Image's pattern pixels the IML keeps at the smallest mean value whose IML + RecNN "
                             "stays within epsilon (1 dB) PSNR of the RecNN alone on the validation views (\"(none)\": no mean value "
                             "in the bracket met epsilon; the job with the smallest gap stands in). Latency: IML/S + RecNN at the ORP "
                             "(IMS network, selective rendering of its important pixels, IML decoder, RecNN), mean over the test "
                             "trajectory of per-view medians. Speed-up: RecNN alone (ray-casting its whole pattern + RecNN) / IML/S + RecNN.",
                             "ORP details", orp_details(records))
    L += paper_table_section("Comparison with LAS (paper: Table \"LAS comparison\")", las_table(records, scenes, recnns),
                             "Full ray cast: every FR pixel ray-cast by this machine's renderer (the paper's GPU ray-caster column). "
                             "LAS runs at exactly each IPR (its mean bisected per view, outside the timed stages). IML/S at the IPR rows: "
                             "the IML/S pipeline (IMS network timed) selectively rendering the mask of the ORP's IML at the inference "
                             "mean u = IPR / pattern share, whose quality is that of IML + RecNN at u (an IMS reproducing the IML's mask); "
                             "the measured IPRs are in the details. \"at ORP\": the trained IML/S + RecNN at its own IPR, LAS matched to "
                             "that IPR (super-resolution). Speed-up: LAS / IML/S. NS: not supported (LAS is a super-resolution method).",
                             "LAS comparison details", las_details(records))
    L += ["## Stage times", "", stage_table(records, times), ""]
    L += ["Minutes:seconds each stage took when its result was made (the RecNN stage includes rendering the cache; "
          "a stage cut off and resumed shows the resumed part only).", ""]
    if meta.get("notes"):
        L += ["## Notes", ""] + [f"- {n}" for n in meta["notes"]] + [""]
    L += ["## Files", ""]
    for r in records:
        L.append(f"- {r['scene']} / {r['recnn']}: ORP `{r['orp']['path']}`, evaluation report `{Path(r['eval_dir']) / 'report.md'}`")
    L.append("")
    return "\n".join(L)


# ------------------------------------------------------------------------------------------------
# the benchmark


class Times:
    """Stage seconds keyed by the stage's result (``<runs_dir>/bench_times.json``), kept on the first
    run that made the result, so a resumed benchmark still reports what each result cost."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data: dict[str, float] = json.loads(path.read_text()) if path.is_file() else {}
        except ValueError:
            self.data = {}

    def record(self, result: str, seconds: float) -> float:
        if result not in self.data:
            self.data[result] = round(float(seconds), 2)
            atomic_write_text(self.path, json.dumps(self.data, indent=1, sort_keys=True))
        return self.data[result]


def _floats(cfg: DictConfig, key: str, lo: float, hi: float) -> list[float]:
    v = OmegaConf.select(cfg, key)
    vals = OmegaConf.to_container(v) if OmegaConf.is_list(v) else None
    try:
        out = [float(x) for x in vals] if vals else []
    except (TypeError, ValueError):
        out = []
    if not out or not all(lo < x <= hi for x in out):
        raise InputError(f"{key}={v}: expected a non-empty list of numbers in ({lo}, {hi}]")
    return out


def _names(cfg: DictConfig, key: str) -> list[str]:
    v = OmegaConf.select(cfg, key)
    if not OmegaConf.is_list(v) or not len(v) or not all(isinstance(x, str) and x for x in v):
        raise InputError(f"{key}={v}: expected a non-empty list of names, e.g. [mri_head, ct_head]")
    return [str(x) for x in v]


def _command(scene_overrides: Sequence[str] = ()) -> str:
    from shlex import quote as shell_quote

    from ..report import hydra_command

    cmd = hydra_command("imls_lightning.bench", "python -m imls_lightning.bench")
    return " ".join([cmd, *(shell_quote(a) for a in scene_overrides)])


def scene_label(scene: str, scene_overrides: Sequence[str]) -> str:
    """A benchmarked scene's name in the tables: ``scene.name=`` when overridden, the volume's name
    for ``scene=file`` (``scene.volume.name=``, else from ``scene.volume.path=``), else the preset's.

    Example:
        >>> scene_label("file", ["scene.volume.path=/d/engine_256x256x128_uint8.raw"]), scene_label("ct_head", [])
        ('engine', 'ct_head')
    """
    from data_gen.scenes import volume_name

    given = {}
    for o in scene_overrides:
        key, eq, value = o.lstrip("+").partition("=")
        if eq:
            given[key] = value.strip().strip("'\"")
    if given.get("scene.name"):
        return given["scene.name"]
    if scene == "file":
        return volume_name(given.get("scene.volume.name"), given.get("scene.volume.path"))
    return scene

def _scale_lines(cfg: DictConfig, scenes, recnns, las_iprs, scene_overrides: Sequence[str] = ()) -> list[str]:
    """The scale of the run, for the report: scenes, data group, every stage's overrides."""
    lines = [f"scenes: {', '.join(scenes)}; RecNNs: {', '.join(f'{r} ({KIND.get(r, r)})' for r in recnns)}; renderer: {cfg.renderer}"]
    if scene_overrides:
        lines.append(f"scene overrides (every scene): `{' '.join(scene_overrides)}`")
    try:  # the data group's numbers (informative; `common` overrides are listed below)
        d = OmegaConf.merge(OmegaConf.load(Path(CONF_DIR) / "data" / "default.yaml"),
                            OmegaConf.load(Path(CONF_DIR) / "data" / f"{cfg.data}.yaml"))
        n, m = int(d.num_views), int(d.resolution)
        val = int(round(n * float(d.val_fraction)))
        lines.append(f"data={cfg.data}: FR-Images {m}² (C-Images {m // 2}²), {n} random views ({n - val} train / {val} val), "
                     f"test trajectory of {d.test_views} views")
    except Exception:
        lines.append(f"data={cfg.data}")
    for key in ("common", "train", "stages.recnn", "stages.iml", "stages.orp", "stages.ims", "stages.las", "evaluate"):
        lines.append(f"{key}: `{' '.join(override_list(cfg, key)) or '–'}`")
    for r in recnns:
        lines.append(f"recnn_net.{r}: `{' '.join(override_list(cfg, f'recnn_net.{r}')) or '(defaults)'}`")
    lines.append(f"LAS comparison IPRs: {', '.join(pct(x, 1) for x in las_iprs)}; LAS with: {', '.join(override_list(cfg, 'las_with')) or '–'}")
    return lines


def bench(cfg: DictConfig, scene_overrides: Sequence[str] = ()) -> Path | None:
    """Run (or resume) the benchmark; returns the path of the BENCHMARKS.md written (None with
    ``dry_run``). ``scene_overrides`` (``scene.<key>=...``) follow ``scene=<name>`` in every stage's
    command, for every scene."""
    from ..report import machine_info

    one = cfg.get("scene")
    scenes, recnns = ([str(one)] if one else _names(cfg, "scenes")), _names(cfg, "recnns")
    for s in scenes:
        if not (Path(CONF_DIR) / "scene" / f"{s}.yaml").is_file():
            known = sorted(p.stem for p in (Path(CONF_DIR) / "scene").glob("*.yaml"))
            raise InputError(f"{'scene' if one else 'scenes'}: unknown scene {s!r}; expected names of conf/scene presets: {', '.join(known)}")
        check_scene_overrides(s, scene_overrides)
    label = {s: scene_label(s, scene_overrides) for s in scenes}
    if len(set(label.values())) < len(scenes):
        raise InputError(f"scenes={scenes} with {' '.join(scene_overrides)}: the scenes get the same name {sorted(label.values())}; "
                         "benchmark them one at a time")
    dry = bool(cfg.get("dry_run", False))
    for r in [*recnns, str(cfg.las_recnn)]:
        if r not in KIND:
            raise InputError(f"recnns/las_recnn: unknown RecNN {r!r}; expected one of {', '.join(KIND)}")
    las_iprs = _floats(cfg, "las_iprs", 0.0, 1.0)
    las_with = set(override_list(cfg, "las_with"))
    runs = Path(str(cfg.runs_dir))
    out_path = Path(str(cfg.output))
    progress = bool(cfg.progress)
    times = Times(runs / TIMES_FILE)
    pair_times: dict[str, dict[str, float]] = {}
    t0 = time.perf_counter()
    n_pairs = len(scenes) * len(recnns)
    meta: dict[str, Any] = {
        "scenes": [label[s] for s in scenes], "recnns": recnns, "command": _command(scene_overrides), "machine": machine_info("cpu"),
        "scale": _scale_lines(cfg, [label[s] for s in scenes], recnns, las_iprs, scene_overrides), "times": pair_times, "total": n_pairs,
        "notes": [
            "Timings are medians of the evaluation's repeats per view (after a warm-up run), averaged over the views; "
            "the networks run on the CPU next to the renderer, as everything else on this machine.",
            f"Reduced scale for a 2-core CPU (see Scale); the paper uses 512² FR-Images, 2000 views and a GPU. "
            "Absolute latencies and PSNRs are not comparable with the paper's; the ratios are the point.",
        ],
    }
    records: list[dict[str, Any]] = []

    def elapsed() -> str:
        return hms(time.perf_counter() - t0)

    def stage(pair: str, key: str, name: str, args: list[str], result_key=lambda line: line) -> str:
        if dry:
            return dry_stage(name, args, tag="bench")
        log(f"\n[bench] {pair}: {name} (elapsed {elapsed()})")
        s0 = time.perf_counter()
        result = run_stage(f"{pair} {name}", args, tag="bench")
        pair_times.setdefault(pair, {})[key] = times.record(result_key(result), time.perf_counter() - s0)
        return result

    def write() -> Path:
        meta.update(done=len(records), elapsed_s=time.perf_counter() - t0, date=time.strftime("%Y-%m-%d %H:%M"))
        return write_markdown(out_path, render_markdown(records, meta))

    las_ckpt: dict[str, str] = {}
    train = ["-m", "imls_lightning.train"]
    for scene in scenes:
        common, base_train = stage_args(cfg, scene_overrides, scene=scene, recnn=False, quote=True,
                                        common=override_list(cfg, "common"), train=override_list(cfg, "train"))
        for recnn in recnns:
            pair = f"{label[scene]}/{recnn}"
            net = [f"recnn={recnn}", *override_list(cfg, f"recnn_net.{recnn}")]
            tc = [*base_train, *net]
            recnn_ckpt = stage(pair, "recnn", "RecNN", [*train, "model=recnn", *tc, *override_list(cfg, "stages.recnn")])

            sweep = [*train, "-m", "model=iml", *tc, *override_list(cfg, "stages.iml"), "hydra/sweeper=orp",
                     f"recnn.checkpoint={quote_override_value(recnn_ckpt)}", *override_list(cfg, "stages.orp")]
            sweep_dir = runs / "orp" / f"{label[scene]}-{recnn}-{args_hash(sweep)}"
            orp_yaml = sweep_dir / "orp.yaml"
            if dry:
                stage(pair, "orp", "ORP search", [*sweep, f"hydra.sweep.dir={quote_override_value(str(sweep_dir))}"])
            elif orp_yaml.is_file() and read_orp_finished(orp_yaml):
                log(f"\n[bench] {pair}: ORP search already finished; reusing {orp_yaml}")
                pair_times.setdefault(pair, {})["orp"] = times.data.get(str(orp_yaml), math.nan)
            else:
                line = stage(pair, "orp", "ORP search", [*sweep, f"hydra.sweep.dir={quote_override_value(str(sweep_dir))}"],
                             result_key=lambda _: str(orp_yaml))
                if not line.startswith("[orp] ") or not orp_yaml.is_file():
                    raise StageFailed(f"{pair} ORP search: expected '[orp] {orp_yaml}' as its last line, got {line!r}")
            if dry:
                orp = {"iml_checkpoint": "<ORP-IML>", "pattern_ipr": math.nan}
            else:
                orp = read_orp(orp_yaml)
                log(f"[bench] {pair}: ORP {'found' if orp['found'] else 'NOT found'}: u={orp['mean']:g}, "
                    f"C-share {pct(orp['c_share'])}, gap {fmt(orp['gap_db'])} dB")

            ims_ckpt = stage(pair, "ims", "IMS", [*train, "model=ims", *tc, f"iml.checkpoint={quote_override_value(orp['iml_checkpoint'])}",
                                                  f"recnn.checkpoint={quote_override_value(recnn_ckpt)}", *override_list(cfg, "stages.ims")])
            with_las = recnn in las_with
            if with_las and scene not in las_ckpt:
                las_ckpt[scene] = stage(pair, "las", "LAS", [*train, "model=las", *base_train, f"recnn={cfg.las_recnn}",
                                                             *override_list(cfg, "stages.las")])
            elif with_las:
                pair_times.setdefault(pair, {})["las"] = times.data.get(las_ckpt[scene], math.nan)
            means = sweep_means(las_iprs, orp["pattern_ipr"])
            ev = ["-m", "imls_lightning.evaluate", *common, f"paths.runs_dir={quote_override_value(str(runs))}",
                  f"checkpoints.ims={quote_override_value(ims_ckpt)}", f"checkpoints.recnn={quote_override_value(recnn_ckpt)}",
                  f"las_iprs=[{','.join(repr(x) for x in las_iprs)}]", f"mean_values=[{','.join(repr(u) for u in means)}]",
                  f"progress={progress}", "reuse=true", *override_list(cfg, "evaluate")]
            if with_las:
                ev.append(f"checkpoints.las={quote_override_value(las_ckpt[scene])}")
            report = Path(stage(pair, "evaluate", "evaluation", ev))
            if dry:
                continue
            if report.name != "report.md" or not (report.parent / "metrics.csv").is_file():
                raise StageFailed(f"{pair} evaluation: expected the path of its report.md as its last line, got {str(report)!r}")
            records.append(collect_pair(label[scene], recnn, orp, report.parent, las_iprs, means, with_las))
            path = write()
            log(f"[bench] {pair} done (elapsed {elapsed()}); tables so far: {path}")
    return None if dry else write()


def read_orp_finished(path: Path) -> bool:
    """True when ``orp.yaml`` is a finished sweep's (its context has ``finished``)."""
    import yaml

    try:
        rep = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, ValueError, yaml.YAMLError):
        return False
    return bool((rep.get("context") or {}).get("finished"))
