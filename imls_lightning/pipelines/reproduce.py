"""``python -m imls_lightning.reproduce row=<name>``: re-measure a committed row from a fresh clone, choosing nothing.

A row (``conf/row/<name>.yaml``) names its scene, its data and evaluation settings, its networks (files under
``benchmarks/rows/<name>/`` with their SHA-256) and the evaluation that chose its operating point (``point``: that
evaluation's ``summary.json`` and ``config.yaml``, committed beside the networks). :func:`reproduce`:

1. checks every network file against its recorded SHA-256 and the trajectory seed against the seeds a choice read
   (a missing or altered file, or a seed some choice read, is one line and writes nothing);
2. builds the volume and renders the ground truth of a fresh test trajectory (``trajectory_seed``; default: the row's
   own, the one the README cites) with the fastest ray caster (empty-space skipping: the pixels are the same);
3. runs the evaluation with the committed networks at the committed operating point (``orp_from``), every baseline
   by the row's protocol, both ray casters timed in one run;
4. writes ``reproduce.json`` beside the evaluation's report and prints its path as the last line of stdout.

By default it measures ``views`` (the row's default, 60) of the trajectory's 120 views for PSNR and times
``timed_views`` (6) of them, 10 interleaved runs each: about 15-20 minutes on 2 cores, the caches included.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer

from ..base.paths import CONF_DIR, ROOT, log

#: the keys of ``reproduce.json`` (issue 85), all from the evaluation's summary (:func:`result`)
RESULT_KEYS = ("row", "trajectory_seed", "views", "timed_views", "c_share", "gap_db", "psnr_recnn_db", "psnr_imls_db",
               "recnn_ms", "imls_ms", "speedup", "recnn_skip_ms", "recnn_noskip_ms", "imls_skip_ms", "imls_noskip_ms",
               "speedup_vs_fastest", "speedup_vs_fastest_low", "speedup_vs_fastest_high", "report")


def row_spec(cfg: DictConfig) -> dict[str, Any]:
    """The row ``cfg.row`` composes (``conf/row/<name>.yaml``) as a plain mapping.

    Raises:
        InputError: no row, or one without a name.
    """
    row = OmegaConf.to_container(cfg.row, resolve=True) if cfg.get("row") is not None else None
    if not isinstance(row, dict) or not row.get("name"):
        raise InputError("row: required, a row of conf/row/ (e.g. row=seed_whole)")
    return row


def row_files(row: Mapping[str, Any]) -> tuple[Path, dict[str, Path], Path]:
    """``(folder, {checkpoint key: file}, point folder)`` of a row, each network checked against its SHA-256.

    Raises:
        InputError: a missing network file, or one whose bytes are not the recorded ones.
    """
    from ..base.config import file_hash
    from .pack_row import checked_networks

    name = row.get("name", "?")
    folder = Path(str(row["dir"]))
    folder = folder if folder.is_absolute() else ROOT / folder
    files = checked_networks(name, folder, row.get("networks") or {})
    if "ims" not in files:
        raise InputError(f"row={name}: lists no ims network (the IMS checkpoint carries the decoder and the RecNN)")
    point = folder / str(row.get("point", "point"))
    for f in ("summary.json", "config.yaml"):
        if not (point / f).is_file():
            raise InputError(f"row={name}: its operating point's {point / f} is missing")
    want = row.get("point_sha256")
    if want and file_hash(point / "summary.json", length=64) != str(want):
        raise InputError(f"row={name}: {point / 'summary.json'} is not the record the row committed (SHA-256 differs): "
                         "the operating point was edited")
    return folder, files, point


def evaluation_overrides(row: Mapping[str, Any], files: Mapping[str, Path], point: Path, *, seed: int, views: int | None,
                         timed_views: int, cache_dir: str, out: Path) -> list[str]:
    """The ``python -m imls_lightning.evaluate`` overrides of a reproduction: the row's scene, data and settings, the
    committed networks at the committed point, the fresh trajectory, the views asked for."""
    return [f"scene={row['scene']}", f"data={row.get('data', 'paper_cpu')}", "renderer=numba", "renderer.skip_empty=true",
            f"data.cache_dir={cache_dir}", *(f"checkpoints.{k}={p}" for k, p in files.items()), f"orp_from={point}",
            *[str(o) for o in (row.get("settings") or [])], f"trajectory_seed={seed}",
            f"max_views={'null' if views is None else views}", f"timed_views={timed_views}", "both_ray_casters=true",
            f"output_dir={out}", "reuse=true", "progress=false"]


def result(row_name: str, seed: int, report: Path) -> dict[str, Any]:
    """``reproduce.json``'s content from the evaluation's summary (the same cells as ``paper_scale.csv``'s row)."""
    from .bench_paper import csv_row
    from .stages import read_summary

    summary = read_summary(report)
    cells = csv_row(summary)
    out = {k: cells.get(k) for k in RESULT_KEYS if k in cells}
    out.update(row=row_name, trajectory_seed=int(seed), views=int(summary["views"]), timed_views=int(summary["timed_views"]),
               report=str(report))
    return {k: out.get(k) for k in RESULT_KEYS}


def reproduce(cfg: DictConfig) -> Path:
    """Re-measure ``cfg.row`` (module docstring); returns ``reproduce.json``'s path."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from ..evaluation import evaluate
    from ..evaluation.protocol import check_view_seeds, training_data_seed
    from ..evaluation.settings import parse_settings

    row = row_spec(cfg)
    name = str(row["name"])
    folder, files, point = row_files(row)
    seed = cfg.get("trajectory_seed")
    seed = check_integer(row.get("trajectory_seed") if seed is None else seed, "trajectory_seed", 0)
    views = cfg.get("views")
    views = check_integer(row.get("views", 60) if views is None else views, "views", 1)
    timed = cfg.get("timed_views")
    timed = check_integer(row.get("timed_views", 6) if timed is None else timed, "timed_views", 1)
    if timed > views:
        raise InputError(f"timed_views={timed}: at most the {views} views measured (views)")
    out = Path(str(cfg.output_dir)) if cfg.get("output_dir") else \
        Path(str(cfg.runs_dir)) / "reproduce" / f"{name}-seed{seed}-views{views}-timed{timed}"
    overrides = evaluation_overrides(row, files, point, seed=seed, views=views, timed_views=timed,
                                     cache_dir=str(cfg.cache_dir), out=out)
    GlobalHydra.instance().clear()
    with initialize_config_dir(CONF_DIR, version_base="1.3", job_name="reproduce"):
        ecfg = compose("evaluate", overrides=overrides)
    # every check before anything is written: the seeds (the evaluation checks them again)
    check_view_seeds(parse_settings(ecfg), ecfg, training_data_seed(files["ims"]))
    log(f"[reproduce] row {name}: networks checked ({len(files)} files, SHA-256), trajectory seed {seed}, {views} views "
        f"({timed} timed), evaluation in {out}")
    report = evaluate(ecfg)
    res = result(name, seed, report)
    path = report.parent / "reproduce.json"
    from ..report import atomic_write_text

    atomic_write_text(path, json.dumps(res, indent=1, default=float))
    vs = res["speedup_vs_fastest"]
    log(f"[reproduce] {name}: gap {res['gap_db']:.2f} dB; {res['speedup']:.2f}x the RecNN alone on the same ray caster; "
        + (f"{float(vs):.2f}x the fastest RecNN alone" if vs not in (None, "") else "one ray caster timed"))
    return path
