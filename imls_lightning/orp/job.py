"""The work of one ORP sweep job (run inside ``python -m imls_lightning.train`` when the config has
an ``orp_job`` node): :func:`orp_main` dispatches to :func:`orp_job` (train the IML at one mean value,
reusing a finished run, evaluate IML + RecNN (and IML/S + RecNN) against the RecNN alone on the
validation views, time the stages) or :func:`orp_recnn_job` (the sweep's preparatory RecNN). Each
writes its record, or its error, as ``orp_job.json`` (:data:`JOB_FILE`) in the job directory.

Torch, Lightning and the networks are imported inside the functions, so importing this module stays
cheap (the sweeper plugin imports :data:`JOB_FILE`).
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from imls_lightning.base.atomic import atomic_json
from imls_lightning.base.errors import InputError

from .overrides import ims_overrides_for
from .search import DEFAULTS, ORPJobError, ORPSettings, describe_error

JOB_FILE = "orp_job.json"
STAGES = ("iml", "recnn")  # orp_job.stage: the IML job (default) or the sweep's preparatory RecNN job


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    atomic_json(path, data, indent=2, sort_keys=False)


def _hydra_job() -> tuple[Path | None, list[str] | None]:
    """The running Hydra job's output directory and task overrides (``None`` outside Hydra)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        if not HydraConfig.initialized():
            return None, None
        hc = HydraConfig.get()
        return Path(hc.runtime.output_dir), list(hc.overrides.task)
    except Exception:
        return None, None


def orp_main(cfg) -> dict[str, Any]:
    """Run the sweep job that ``cfg.orp_job`` asks for: ``stage: iml`` (default) or ``stage: recnn``.

    Raises:
        ORPJobError: the job failed (its ``orp_job.json`` says why).
    """
    flag = _plain(cfg.get("orp_job"))
    stage = str(flag.get("stage", "iml")) if isinstance(flag, Mapping) else "iml"
    if stage == "recnn":
        return orp_recnn_job(cfg)
    if stage != "iml":
        return _run_job(lambda job_dir, overrides: _bad_stage(stage), cfg)
    return orp_job(cfg)


def _bad_stage(stage: str) -> dict[str, Any]:
    raise InputError(f"orp_job.stage={stage!r}: expected one of {list(STAGES)}")


def _run_job(work: Callable[[Path, list[str]], dict[str, Any]], cfg, task_overrides: Sequence[str] | None = None) -> dict[str, Any]:
    """Run ``work(job_dir, overrides)``; write its record (or the error) as ``orp_job.json``."""
    job_dir, hydra_overrides = _hydra_job()
    if task_overrides is None:
        task_overrides = hydra_overrides
    if job_dir is None:
        job_dir = Path(str(cfg.paths.get("runs_dir", "runs"))) / "orp_job"
    t0 = time.perf_counter()
    try:
        record = work(job_dir, list(task_overrides or []))
    except Exception as err:
        msg = describe_error(err)
        _write_json(job_dir / JOB_FILE, {"status": "failed", "error": msg, "job_dir": str(job_dir),
                                          "minutes": round((time.perf_counter() - t0) / 60, 3)})
        raise ORPJobError(msg) from (None if isinstance(err, InputError) else err)
    record["minutes"] = round((time.perf_counter() - t0) / 60, 3)
    _write_json(job_dir / JOB_FILE, record)
    return record


def orp_recnn_job(cfg) -> dict[str, Any]:
    """The sweep's preparatory job: train (or reuse) the RecNN the IML jobs are compared with.

    ``cfg`` is the ``train`` config composed with ``model=recnn`` and the sweep's other overrides.
    The run goes to the settings-hashed ``<paths.runs_dir>/<run_name>-<run_hash>``, the directory a
    plain ``python -m imls_lightning.train model=recnn ...`` with the same settings uses, so an
    earlier RecNN run is reused and a later sweep reuses this one.

    Returns:
        ``{"status": "ok", "stage": "recnn", "recnn_checkpoint", "run_dir", "train_minutes", ...}``.
    """

    def work(job_dir: Path, overrides: list[str]) -> dict[str, Any]:
        from ..training.fit import train

        if not str(cfg.model.get("_target_", "")).endswith("RecNNTask"):
            raise InputError(f"model={cfg.model.get('name')}: the ORP's RecNN stage trains model=recnn")
        run_cfg = _with_run_dir(cfg)
        result = train(run_cfg)
        return {"status": "ok", "stage": "recnn", "recnn_checkpoint": result["best_checkpoint"],
                "run_dir": str(run_cfg.paths.output_dir), "train_minutes": result.get("train_minutes"),
                "best_score": result.get("best_score"), "job_dir": str(job_dir)}

    return _run_job(work, cfg)


def orp_job(cfg, task_overrides: Sequence[str] | None = None) -> dict[str, Any]:
    """One ORP sweep job: train the IML at the configured mean value and evaluate it.

    Runs inside ``python -m imls_lightning.train`` when the config has an ``orp_job`` node (the
    ORP sweeper adds ``++orp_job={...}`` with the knobs in :data:`JOB_KEYS`). Steps:

    1. train the IML with :func:`imls_lightning.training.fit.train` in its own settings-hashed run
       directory ``<paths.runs_dir>/<run_name>-<run_hash>`` (a finished run is reused, so a sweep
       that is started again only re-evaluates);
    2. on the validation views: PSNR of IML + RecNN (hard mask; the RecNN inside an end-to-end IML
       checkpoint, else ``recnn.checkpoint``), of the RecNN alone (``recnn.checkpoint``), the gap,
       IPR and C-Image share of the IM;
    3. with ``with_ims``: train IMS on this IML (``model=ims iml.checkpoint=...``, composed from the
       same overrides) and evaluate IML/S + RecNN;
    4. latencies (``latency_views`` views, median of ``latency_repeats`` runs each).

    Args:
        cfg: the job's composed ``train`` config (with ``orp_job``).
        task_overrides: the job's overrides (needed for ``with_ims``; read from Hydra when omitted).

    Returns:
        The record (plain data), also written as ``orp_job.json`` in the job directory.

    Raises:
        ORPJobError: anything that makes the job fail (after writing ``orp_job.json`` with the error).
    """
    return _run_job(lambda job_dir, overrides: _orp_job(cfg, overrides, job_dir), cfg, task_overrides)


def _plain(node) -> Any:
    from omegaconf import DictConfig, ListConfig, OmegaConf

    return OmegaConf.to_container(node, resolve=True) if isinstance(node, (DictConfig, ListConfig)) else node


def _with_run_dir(cfg):
    """A copy of ``cfg`` whose output directory is the settings-hashed run directory."""
    import copy

    from omegaconf import open_dict

    cfg = copy.deepcopy(cfg)
    run_dir = Path(str(cfg.paths.runs_dir)) / f"{cfg.run_name}-{cfg.run_hash}"
    with open_dict(cfg):
        cfg.paths.output_dir = str(run_dir)
    return cfg


def _compose_train(overrides: list[str]):
    """Compose the ``train`` config with ``overrides`` (inside or outside a running Hydra app)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    if GlobalHydra.instance().is_initialized():
        return compose(config_name="train", overrides=overrides)
    conf_dir = Path(__file__).resolve().parents[2] / "conf"
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3", job_name="orp_ims"):
        return compose(config_name="train", overrides=overrides)


def _orp_job(cfg, task_overrides: list[str], job_dir: Path) -> dict[str, Any]:
    import torch

    from ..inference.pipeline import pick_device
    from ..inference.checkpoints import check_same_pattern, load_task
    from ..training.fit import train

    flag = _plain(cfg.orp_job)
    flag = dict(flag) if isinstance(flag, Mapping) else {}
    s = ORPSettings.from_mapping({k: v for k, v in flag.items() if k in DEFAULTS}, prefix="orp_job.")
    if not str(cfg.model.get("_target_", "")).endswith("IMLTask"):
        raise InputError(f"model={cfg.model.get('name')}: the ORP search trains the IML network; use model=iml")
    recnn_ckpt = cfg.recnn.get("checkpoint")
    if not recnn_ckpt:
        raise InputError("recnn.checkpoint: the ORP compares IML + RecNN with the RecNN alone; set recnn.checkpoint=<RecNN .ckpt> "
                         "(the ORP sweeper trains or reuses one by itself when it is not set)")
    u = float(_select_number(cfg, s.param))
    device = pick_device(s.device)
    recnn_alone_task = load_task(recnn_ckpt, expect="RecNNTask", what="recnn.checkpoint")

    # 1. train (or reuse) the IML
    result = train(_with_run_dir(cfg))
    iml_ckpt = result["best_checkpoint"]
    iml_task = load_task(iml_ckpt, expect="IMLTask", what="IML checkpoint")
    check_same_pattern(recnn_alone_task.hparams, iml_task.pattern, key="recnn.checkpoint", path=recnn_ckpt, network="RecNN",
                       against="the IML", hint="use a RecNN trained on the IML's pattern and resolution")
    recnn_iml = iml_task.recnn if iml_task.recnn is not None else recnn_alone_task.net
    recnn_source = "iml.checkpoint" if iml_task.recnn is not None else "recnn.checkpoint"

    # 3. (before evaluating, so one pass covers both) IMS on this IML
    ims_task, ims_ckpt, ims_minutes = None, None, None
    if s.with_ims:
        ims_cfg = _compose_train(ims_overrides_for(task_overrides, iml_ckpt, s.ims_overrides, recnn_checkpoint=str(recnn_ckpt)))
        ims_result = train(_with_run_dir(ims_cfg))
        ims_ckpt = ims_result["best_checkpoint"]
        ims_minutes = ims_result.get("train_minutes")
        ims_task = load_task(ims_ckpt, expect="IMSTask", what="IMS checkpoint")

    # 2. quality on the validation views
    from ..data.datamodule import ImlsDataModule

    dm = ImlsDataModule(scene=cfg.scene, data=cfg.data, renderer=cfg.renderer, pattern=iml_task.pattern,
                        fields=("view", "fr", "c"), progress=False)
    val = dm.dataset("val")
    if len(val) == 0:
        raise InputError("data: the cache has no validation views (raise data.num_views or data.val_fraction)")
    nets = [iml_task.iml, recnn_iml, recnn_alone_task.net] + ([ims_task] if ims_task is not None else [])
    for net in nets:
        net.to(device).eval()
    quality = evaluate_quality(val, int(cfg.data.get("batch_size", 8)), iml_task, recnn_iml, recnn_alone_task.net, ims_task, device)

    gap_iml = quality["psnr_recnn"] - quality["psnr_iml_recnn"]
    gap_imls = None if ims_task is None else quality["psnr_recnn"] - quality["psnr_imls_recnn"]
    gap = gap_imls if s.gap_of == "imls" else gap_iml

    # 4. latencies
    latency = None
    if s.latency_views > 0:
        latency = _latencies(cfg, s, val, iml_task, recnn_iml, recnn_alone_task.net, ims_ckpt, device,
                             recnn_checkpoint=None if iml_task.recnn is not None else str(recnn_ckpt))
    for net in nets:
        net.to("cpu")
    if device.type == "cuda":
        torch.cuda.empty_cache()

    fr = iml_task.pattern.fr_size
    return {
        "status": "ok",
        "mean": u,
        "param": s.param,
        "gap_db": gap,
        "gap_of": s.gap_of,
        "epsilon_db": s.epsilon_db,
        "meets_epsilon": bool(gap is not None and math.isfinite(gap) and gap <= s.epsilon_db),
        "gap_iml_db": gap_iml,
        "gap_imls_db": gap_imls,
        "psnr_db": {"iml_recnn": quality["psnr_iml_recnn"], "recnn": quality["psnr_recnn"],
                    "imls_recnn": quality.get("psnr_imls_recnn")},
        "ipr": quality["ipr"],
        "c_share": quality["c_share"],
        "imls_ipr": quality.get("imls_ipr"),
        "imls_c_share": quality.get("imls_c_share"),
        "pattern_ipr": iml_task.pattern.count / float(fr * fr),
        "val_views": len(val),
        "mode": iml_task.hparams["mode"],
        "recnn_source": recnn_source,
        "iml_checkpoint": str(iml_ckpt),
        "recnn_checkpoint": str(Path(str(recnn_ckpt)).expanduser().resolve()),
        "ims_checkpoint": ims_ckpt,
        "iml_train_minutes": result.get("train_minutes"),
        "ims_train_minutes": ims_minutes,
        "latency_ms": latency,
        "device": str(device),
        "job_dir": str(job_dir),
    }


def _select_number(cfg, key: str) -> Any:
    from omegaconf import OmegaConf

    val = OmegaConf.select(cfg, key, default=None)
    if val is None:
        raise InputError(f"{key}: not set in the config (the ORP sweeper's param must name a number such as model.mean)")
    return val


def evaluate_quality(dataset, batch_size: int, iml_task, recnn_iml, recnn_alone, ims_task, device) -> dict[str, float]:
    """Mean per-image PSNRs, IPR and C-share over ``dataset`` (hard masks, as at inference)."""
    import torch
    from torch.utils.data import DataLoader

    from ..models.iml import c_share, ipr
    from ..core.metrics import psnr_per_image

    fr = iml_task.pattern.fr_size
    valid = iml_task.pattern.valid.to(device)
    acc: dict[str, list[torch.Tensor]] = {}

    def add(key: str, value: torch.Tensor) -> None:
        acc.setdefault(key, []).append(value.detach().float().cpu())

    with torch.inference_mode():
        for batch in DataLoader(dataset, batch_size=max(1, batch_size), shuffle=False, num_workers=0):
            c, target = batch["c"].to(device), batch["fr"].to(device)
            add("psnr_recnn", psnr_per_image(recnn_alone(c), target))
            out = iml_task.iml(c, hard=True)
            add("psnr_iml_recnn", psnr_per_image(recnn_iml(out.c_recon), target))
            add("ipr", ipr(out.im, fr))
            add("c_share", c_share(out.im, valid))
            if ims_task is not None:
                im = ims_task.predict_im(batch["view"].to(device)).float()
                c_rec = ims_task.decoder(im * c, im)
                add("psnr_imls_recnn", psnr_per_image(recnn_iml(c_rec), target))
                add("imls_ipr", ipr(im, fr))
                add("imls_c_share", c_share(im, valid))
    # a NaN PSNR stays NaN here: the sweeper then records the job as failed
    return {k: float(torch.cat(v).mean()) for k, v in acc.items()}


def _latencies(cfg, s: ORPSettings, dataset, iml_task, recnn_iml, recnn_alone, ims_ckpt, device,
               recnn_checkpoint: str | None = None) -> dict[str, Any]:
    """Per-stage latency (ms; mean over views of the per-view median of ``latency_repeats`` runs).

    ``recnn``: RecNN alone (selective render of the whole pattern + RecNN). ``iml``: IML + RecNN
    (whole pattern rendered, importance from it: an upper bound, no speed-up). ``important_render``:
    ray-casting only the pixels the IML marks important, the selective render an IML/S of this IPR
    needs; ``imls_estimate_total`` adds the IML decoder and RecNN (IMS generator not included).
    With IMS, ``imls`` is the measured IML/S + RecNN renderer.
    """
    import numpy as np
    import torch

    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene

    from ..evaluation.timing import time_method
    from ..inference.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions, RecNNAlone

    renderer_cfg = _plain(cfg.renderer) if s.latency_renderer is None else {"name": s.latency_renderer}
    renderer = make_renderer(build_scene(_plain(cfg.scene)), renderer_cfg)
    pattern = iml_task.pattern
    m = pattern.fr_size
    opts = NetOptions(device=str(device))
    methods = {"recnn": RecNNAlone(renderer, pattern, recnn_alone, opts),
               "iml": IMLPlusRecNN(renderer, pattern, iml_task.iml, recnn_iml, opts)}
    if ims_ckpt:
        # a standalone IML's IMS uses the off-the-shelf RecNN, the one IML + RecNN is timed with
        methods["imls"] = IMLSRenderer.from_checkpoints(ims_ckpt, renderer=renderer, opts=opts, recnn_checkpoint=recnn_checkpoint,
                                                        mean="trained")  # the IML's mean, as IML + RecNN above
    rows = np.linspace(0, len(dataset) - 1, num=min(s.latency_views, len(dataset))).round().astype(int)
    per_view: dict[str, list[dict[str, float]]] = {k: [] for k in methods}
    important: list[float] = []
    whole: list[float] = []
    counts: list[int] = []
    for r in sorted(set(rows.tolist())):
        view = dataset[r]["view"].numpy().astype(np.float64)
        for name, method in methods.items():
            _, med, _ = time_method(method, view, repeats=s.latency_repeats, warmup=1)
            per_view[name].append(med)
        # the important pixels of this view, from the IML on the freshly rendered pattern
        colours = renderer.render_pixels(view, m, pattern.indices.numpy())
        n = pattern.c_size
        flat = np.zeros((n * n, 3), np.float32)
        flat[: pattern.count] = colours.astype(np.float32) / 255.0
        c = torch.from_numpy(flat).view(n, n, 3).permute(2, 0, 1)[None].to(device)
        with torch.inference_mode():
            im = iml_task.iml.importance(c, hard=True)[0, 0]
        pos = np.flatnonzero(im.reshape(-1)[: pattern.count].cpu().numpy() > 0.5)
        idx = pattern.indices.numpy()[pos]
        counts.append(int(len(idx)))
        for pixels, out in ((idx, important), (pattern.indices.numpy(), whole)):
            times = []
            renderer.render_pixels(view, m, pixels)  # warm-up
            for _ in range(s.latency_repeats):
                t = time.perf_counter()
                renderer.render_pixels(view, m, pixels)
                times.append(time.perf_counter() - t)
            out.append(float(np.median(times)))

    def mean_ms(values: list[float]) -> float:
        return round(1000.0 * float(np.mean(values)), 4)

    lat: dict[str, Any] = {}
    for name, meds in per_view.items():
        lat[name] = {k: mean_ms([d[k] for d in meds]) for k in meds[0]}
    lat["important_render"] = mean_ms(important)
    lat["pattern_render"] = mean_ms(whole)
    lat["important_pixels"] = float(np.mean(counts))
    lat["imls_estimate_total"] = round(lat["important_render"] + lat["iml"]["decoder"] + lat["iml"]["recnn"], 4)
    total = lat["imls"]["total"] if "imls" in lat else lat["imls_estimate_total"]
    lat["speedup_vs_recnn"] = round(lat["recnn"]["total"] / total, 4) if total > 0 else None
    lat["views"] = len(counts)
    lat["repeats"] = s.latency_repeats
    lat["renderer"] = renderer_cfg.get("name", "vtk")
    return lat

