"""``python -m imls_lightning.adaptive``: labels -> predictor -> comparison on the test trajectory
(:func:`run_adaptive`), with its settings (:func:`parse_settings`, ``conf/adaptive.yaml``).
"""
from __future__ import annotations

import copy
import json
import math
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable

import hydra
import numpy as np
import torch
from omegaconf import DictConfig

import data_gen  # noqa: F401  (registers the scene config resolvers)
from imls_lightning.base.errors import InputError, checked_command_line, cli_errors

from ..base.config import register_resolvers
from ..core.importance import MEAN_RANGE
from ..inference.checkpoints import check_resolution, check_trained_on, load_ims_and_recnn, require_pim_target, require_recnn
from ..inference.pipeline import IMLPlusRecNN, IMLSRenderer, pick_device
from ..base.paths import CONF_DIR  # the Hydra configs: an absolute path
from .checks import clamp_mean
from .labels import MeanLabels, compute_labels
from .predictor import ConstantMean, TableMean, train_predictor
from .renderer import AdaptiveIMLPlusRecNN, AdaptiveIMLSRenderer
from .report import markdown, plot_per_view, plot_tradeoff, read_results, reference_method, write_csv
from .settings import parse_settings
from .tradeoff import mean_for_ipr, quality_at_means, tradeoff

register_resolvers()


def run_dir_of(checkpoint: str | Path) -> Path:
    """The training run directory of a checkpoint (``<run>/checkpoints/x.ckpt`` -> ``<run>``).

    Example:
        >>> run_dir_of("/runs/ims-1a2b/checkpoints/last.ckpt").as_posix()
        '/runs/ims-1a2b'
        >>> run_dir_of("/runs/ims-1a2b/model.ckpt").as_posix()
        '/runs/ims-1a2b'
    """
    p = Path(str(checkpoint)).expanduser().resolve()
    return p.parent.parent if p.parent.name == "checkpoints" else p.parent


def ensure_labels(path: Path, make: Callable[[], MeanLabels], what: str) -> tuple[MeanLabels, bool]:
    """``(labels, reused)``: the labels saved at ``path``, or ``make()`` saved there."""
    if path.is_file():
        print(f"[adaptive] reusing {what} labels {path}", file=sys.stderr, flush=True)
        return MeanLabels.load(path), True
    labels = make()
    labels.save(path)
    return labels, False


#: the trade-off's row of the evaluation's by-distance operating point
BANDS_SETTING = "by camera distance (the evaluation's bands)"


def run_adaptive(cfg, command: str | None = None) -> Path:
    """The CLI's body: labels -> predictor -> comparison on the test trajectory; returns ``adaptive.md``."""
    from data_gen.cache import ViewImageCache, ensure_cache
    from data_gen.scenes import build_scene

    from ..base.config import file_hash, settings_hash
    from ..report import write_markdown

    s = parse_settings(cfg)
    t_start = time.perf_counter()
    ims, recnn = load_ims_and_recnn(s.ims, s.recnn)
    require_pim_target(ims.hparams, path=s.ims, what="the adaptive mean, which scales the regressed PIM',")
    resolution = int(cfg.data.resolution)
    check_resolution(ims.hparams, resolution, key="ims_checkpoint", path=s.ims, network="IMS")
    check_trained_on(ims.hparams, cfg.scene, cfg.renderer, key="ims_checkpoint", path=s.ims)
    recnn = require_recnn(recnn if recnn is not None else ims.recnn, key="ims_checkpoint", path=s.ims)
    device = pick_device(s.device)
    # every IML/S mask of this run (labels, ORP, trade-off curve, renderers) is the IMS mask head's, lifted
    # past the paper's rescale when the evaluation's ORP needed it (evaluate's ims_lift)
    lift = bool(s.ims_lift)
    u_train = float(ims.iml.mean)
    nets = SimpleNamespace(ims=ims, recnn=recnn, iml=ims.iml, pattern=ims.pattern, device=device, lift=lift, u_train=u_train,
                           m=resolution)

    scene = build_scene(cfg.scene)
    cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=s.progress))
    if cache.resolution != resolution:
        raise InputError(f"data.resolution={resolution}: the cache {cache.path} holds {cache.resolution}^2 images")
    ck_hashes = {"ims": file_hash(Path(s.ims).expanduser()), "recnn": file_hash(Path(s.recnn).expanduser()) if s.recnn else None}
    run_dir = run_dir_of(s.ims)
    label_dir = run_dir / "adaptive" / "labels"
    label_hash = settings_hash(ck_hashes, cache.path.name, s.label_key())
    bands = recorded_bands(s.ims, lift)
    # a by-distance record adds a row to the trade-off, so it names the run too (runs without one keep their folders)
    extra = [] if bands is None else [{"by_distance": bands[1]}]
    out = Path(s.output_dir) if s.output_dir else run_dir / "adaptive" / settings_hash(ck_hashes, cache.path.name, s.hashed(), *extra)
    if s.reuse and (out / "adaptive.md").is_file() and read_results(out)[1] is None:
        print(f"adaptive: reusing the finished run {out} (reuse=false runs it again)", file=sys.stderr, flush=True)
        return out / "adaptive.md"
    out.mkdir(parents=True, exist_ok=True)
    (out / "adaptive.md").unlink(missing_ok=True)
    timing: dict[str, Any] = {}

    # -- 1. labels ---------------------------------------------------------------------------------
    bracket = MEAN_RANGE if s.reference == "recnn" else (MEAN_RANGE[0], u_train)
    labels = make_labels(s, cache, nets, bracket, label_dir, label_hash, timing)
    train_l = labels["train"]
    val_l = labels.get("val")

    # -- 2. predictor --------------------------------------------------------------------------------
    p = s.predictor
    predictor, hist = train_predictor(train_l.views, train_l.u, val=(val_l.views, val_l.u) if val_l is not None else None,
                                      hidden=p["hidden"], layers=p["layers"], epochs=p["epochs"], lr=p["lr"],
                                      weight_decay=p["weight_decay"], seed=p["seed"], margin=p["margin"])
    predictor.save(out / "mean_predictor.pt")
    timing["train_predictor_s"] = round(hist["seconds"], 2)

    # -- fixed-mean ORP on the validation views, on the path the labels bisect ----------------------
    t0 = time.perf_counter()
    orp_res = fixed_mean_orp(s, cache, nets, bracket)
    u_orp = float(orp_res.mean) if orp_res.found else MEAN_RANGE[1]
    timing["orp_search_s"] = round(time.perf_counter() - t0, 2)

    # -- 3. evaluation on the trajectory -------------------------------------------------------------
    t_eval = time.perf_counter()
    ev = labels[s.views]
    run = compared_methods(s, cfg, scene, ev, nets, predictor, u_orp)
    per_view, lat = measure_trajectory(s, cache, ev, run)
    timing["evaluate_s"] = round(time.perf_counter() - t_eval, 2)

    # -- 4. trade-off curve: fixed means vs the predictor at several margins, on the label source's path --
    trade = tradeoff_curve(s, cache, ev, nets, predictor, run.views_t, out, bands and bands[0]) if s.tradeoff_means else None
    if trade is not None:
        timing["tradeoff_s"] = trade["seconds"]
    timing["total_s"] = round(time.perf_counter() - t_start, 2)

    # -- report ----------------------------------------------------------------------------------------
    summ = summarize_methods(s, list(run.methods), per_view, lat)
    write_csv(out / "adaptive.csv", per_view)
    plot_per_view(out / "adaptive.png", per_view, s.epsilon_db, s.reference)
    md = markdown(s, cfg, ims, cache, summ, per_view, hist, timing, labels, u_train, u_orp, orp_res, run.u_match,
                  run.adaptive_ipr_est, out, command or _command(), trade)
    write_results(out, s, cfg, summ, trade, timing, hist, u_train, u_orp, run.u_match, run.u_pred)
    return write_markdown(out / "adaptive.md", md)


def make_labels(s, cache, nets, bracket, label_dir: Path, label_hash: str, timing: dict[str, Any]) -> dict[str, MeanLabels]:
    """Step 1: the per-view mean labels of the training, validation and evaluated views (saved beside the
    IMS run, reused when there); their seconds go to ``timing``."""
    from ..evaluation import spaced

    labels: dict[str, MeanLabels] = {}
    for split in ("train", "val", s.views):
        if split in labels:
            continue
        rows = cache.splits[split]
        if split == s.views:
            rows = rows[spaced(len(rows), s.max_views)]
        if len(rows) == 0:
            if split == "train":
                raise InputError(f"data: the cache {cache.path} has no training views to label")
            continue
        t0 = time.perf_counter()
        tag = split if split != s.views or s.max_views is None else f"{split}{len(rows)}"
        labels[split], reused = ensure_labels(
            label_dir / f"{tag}-{label_hash}.npz",
            lambda rows=rows, split=split: compute_labels(cache, rows, nets.pattern, nets.iml, nets.recnn, nets.recnn, s.epsilon_db,
                                                         s.steps, s.batch_size, nets.device, s.progress, desc=f"labels {split}",
                                                         reference=s.reference, bracket=bracket,
                                                         unreachable=s.unreachable, source=s.label_source, ims=nets.ims,
                                                         lift=nets.lift),
            split)
        timing[f"labels_{split}_s"] = round(time.perf_counter() - t0, 2)
        timing[f"labels_{split}_reused"] = reused
    return labels


def fixed_mean_orp(s, cache, nets, bracket):
    """The fixed-mean ORP on the validation views (the training views without any), on the path the labels
    bisect: the product path as the evaluation searches it (``orp_path=product``), else the IML + RecNN's."""
    from ..data.datamodule import ViewImageDataset
    from ..orp.job import evaluate_quality
    from ..orp.search import ORPSearch, batched

    ims, iml, recnn, device, pattern = nets.ims, nets.iml, nets.recnn, nets.device, nets.pattern
    orp_rows = cache.splits["val"] if len(cache.splits["val"]) else cache.splits["train"]
    orp_ds = ViewImageDataset(cache.path, orp_rows, pattern, fields=("view", "fr", "c"))
    if s.orp_path == "product":
        # the product path, as the evaluation searches it (IMS mask at u, those C-pixels, the decoder,
        # the RecNN): its "IML/S, fixed u (ORP)" row is then the evaluation's ORP, not the IML bound's u
        from torch.utils.data import DataLoader

        from ..orp.product import product_orp

        with torch.inference_mode():
            batches = list(DataLoader(orp_ds, batch_size=s.batch_size, shuffle=False, num_workers=0))
            return product_orp(ims.to(device).eval().mask_head, ims.decoder, recnn.to(device).eval(), batches, s.epsilon_db,
                               lift=nets.lift, device=device)

    def orp_quality(u: float) -> dict[str, float]:
        it = copy.deepcopy(iml)
        it.mean = clamp_mean(u)
        return evaluate_quality(orp_ds, s.batch_size, SimpleNamespace(iml=it.to(device), pattern=pattern), recnn.to(device),
                                recnn.to(device), None, device)

    ref_q = orp_quality(nets.u_train)["psnr_iml_recnn"] if s.reference == "iml" else None

    def orp_gap(u: float) -> float:
        q = orp_quality(u)
        return (q["psnr_recnn"] if ref_q is None else ref_q) - q["psnr_iml_recnn"]

    return ORPSearch(epsilon_db=s.epsilon_db, bracket=bracket, tolerance=0.05, k=1, max_rounds=12, scale="log").run(batched(orp_gap))


def compared_methods(s, cfg, scene, ev: MeanLabels, nets, predictor, u_orp: float) -> SimpleNamespace:
    """Step 3's methods on the evaluated views: the RecNN alone, IML/S and IML + RecNN at the trained,
    ORP, IPR-matched, predicted and oracle means; with the views as a tensor, the predicted means, the
    matched mean and the adaptive IPR the IMS alone estimates."""
    from imls_lightning.render import make_renderer

    from ..base.config import to_plain
    from ..inference.pipeline import RecNNAlone

    ims, iml, recnn, device, pattern, lift, opts = nets.ims, nets.iml, nets.recnn, nets.device, nets.pattern, nets.lift, s.options
    rows = ev.rows
    renderer = make_renderer(scene, to_plain(cfg.renderer))
    ims.to(device).eval()
    views_t = torch.as_tensor(np.asarray(ev.views, np.float32)).to(device)
    with torch.inference_mode():
        g_all = ims.generator(views_t).float()
        u_pred = predictor.to(device)(views_t).double().cpu().numpy()

    def imls_ipr(u: float | np.ndarray) -> float:
        with torch.inference_mode():
            im = ims.mask_head.threshold(g_all, torch.as_tensor(u, dtype=torch.float32).expand(len(rows)), lift)
        return float(im.flatten(1).sum(1).double().mean()) / nets.m**2

    adaptive_ipr_est = imls_ipr(u_pred)
    u_match = mean_for_ipr(imls_ipr, adaptive_ipr_est)
    const = {"fixed": nets.u_train, "orp": u_orp, "matched": u_match}
    methods: dict[str, Any] = {"recnn": RecNNAlone(renderer, pattern, recnn, opts),
                               "imls_fixed": IMLSRenderer(renderer, pattern, ims.mask_head, ims.decoder, recnn, opts)}

    def adaptive(mean_of) -> AdaptiveIMLSRenderer:
        return AdaptiveIMLSRenderer(renderer, pattern, ims.mask_head, ims.decoder, recnn, mean_of, opts, lift=lift)

    for k in ("orp", "matched"):
        methods[f"imls_{k}"] = adaptive(ConstantMean(clamp_mean(const[k])))
    methods["imls_adaptive"] = adaptive(predictor)
    oracle = TableMean(ev.views, ev.u)
    methods["imls_oracle"] = adaptive(oracle)
    methods["iml_fixed"] = IMLPlusRecNN(renderer, pattern, iml, recnn, opts)
    methods["iml_orp"] = IMLPlusRecNN(renderer, pattern, iml, recnn, opts, mean=clamp_mean(u_orp))
    methods["iml_adaptive"] = AdaptiveIMLPlusRecNN(renderer, pattern, iml, recnn, predictor, opts)
    methods["iml_oracle"] = AdaptiveIMLPlusRecNN(renderer, pattern, iml, recnn, oracle, opts)
    return SimpleNamespace(methods=methods, views_t=views_t, u_pred=u_pred, u_match=u_match, adaptive_ipr_est=adaptive_ipr_est,
                           u_train=nets.u_train, u_orp=u_orp)


def measure_trajectory(s, cache, ev: MeanLabels, run: SimpleNamespace) -> tuple[list[dict[str, Any]], dict[str, list[dict[str, float]]]]:
    """Every method on every evaluated view: ``(per-view records, stage times of the timed methods)``."""
    from tqdm import tqdm

    from ..evaluation import measure, spaced

    rows = ev.rows
    timed = {"recnn", "imls_fixed", "imls_adaptive"}
    timing_pos = set(spaced(len(rows), s.timing_views).tolist()) if s.timing_views else set()
    per_view: list[dict[str, Any]] = []
    lat: dict[str, list[dict[str, float]]] = {k: [] for k in timed}
    for i in tqdm(range(len(rows)), desc=f"evaluate {s.views}", unit="view", file=sys.stderr, disable=not s.progress,
                  dynamic_ncols=True):
        r = int(rows[i])
        view, truth = np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r])
        rec: dict[str, Any] = {"view": i, "row": r, "complexity": float(ev.complexity[i]), "u_label": float(ev.u[i]),
                               "label_met": bool(ev.met[i]), "u_pred": float(run.u_pred[i]), "u_fixed": run.u_train,
                               "u_orp": run.u_orp, "u_matched": run.u_match}
        for name, method in run.methods.items():
            reps = s.repeats if (name in timed and i in timing_pos) else 1
            fields_, _, _ = measure(method, view, truth, reps, 1 if reps > 1 else 0)
            rec[f"psnr_{name}"] = fields_["psnr"]
            rec[f"ipr_{name}"] = fields_["ipr"]
            if reps > 1:
                lat[name].append({k[:-3]: v for k, v in fields_.items() if k.endswith("_ms")})
        per_view.append(rec)
    return per_view, lat


def recorded_bands(ims_checkpoint: str, lift: bool):
    """The evaluation's by-distance operating point for this IMS (``orp_by_distance``): ``(DistanceMeans, its record)``,
    or ``None`` without one, or when it was searched with other masks than this run makes (another ``lift``, a
    mask sharpness other than 1 or an object floor: this module's labels and masks are the paper's)."""
    from ..inference.operating_point import read_operating_point

    from ..models.ims import DistanceMeans

    record = read_operating_point(ims_checkpoint, log=None)
    point = None if record is None else record.point
    if point is None or point.bands is None or point.lift != bool(lift) or point.sharpness != 1.0 \
            or point.object_floor is not None:
        return None
    b = point.bands
    return DistanceMeans(b.edges, b.shares, b.floor_margins), record.by_distance


def tradeoff_curve(s, cache, ev: MeanLabels, nets, predictor, views_t: torch.Tensor, out: Path, bands=None) -> dict[str, Any]:
    """Step 4: fixed means vs the predictor at several margins, on the label source's path;
    ``tradeoff.csv`` and ``tradeoff.png`` written, ``{"curve", "points", "seconds"}`` returned. ``bands``: the
    evaluation's mean value per band of camera distance (:func:`recorded_bands`), the untrained per-view
    alternative the predictor has to beat, compared as one more setting."""
    t0 = time.perf_counter()
    u_train = nets.u_train
    with torch.inference_mode():
        u_raw = predictor.log_mean(views_t).exp().double().cpu().numpy()
        u_bands = None if bands is None else bands(views_t.float().cpu()).double().numpy()
    fixed_us = np.exp(np.linspace(math.log(0.05), 0.0, s.tradeoff_means)) if s.tradeoff_means > 1 else np.array([u_train])
    means: dict[str, Any] = {f"fixed:{u:.6g}": float(u) for u in fixed_us}
    means.update({f"adaptive x{mg:g}": u_raw * mg for mg in s.tradeoff_margins})
    if u_bands is not None:
        means[BANDS_SETTING] = u_bands
    means["oracle (labels)"] = ev.u
    if s.reference == "iml":  # the reference is the path itself at the trained mean: measured in the same pass
        means["reference"] = u_train
    q = quality_at_means(cache, ev.rows, nets.pattern, nets.iml, nets.recnn, means, source=s.label_source, ims=nets.ims,
                         lift=nets.lift, batch_size=s.batch_size, device=nets.device, progress=s.progress)
    ref_psnr = q.pop("reference" if s.reference == "iml" else "recnn")["psnr"]
    q.pop("recnn", None)
    curve, compared = tradeoff(ref_psnr, {float(k[6:]): v for k, v in q.items() if k.startswith("fixed:")},
                               {k: v for k, v in q.items() if not k.startswith("fixed:")}, s.epsilon_db)
    trade = {"curve": curve, "points": compared, "seconds": round(time.perf_counter() - t0, 2)}
    write_csv(out / "tradeoff.csv", [{"setting": f"fixed u={r['u']:.5g}", **r} for r in curve] +
              [{"setting": p.name, "u": None, "ipr": p.ipr, "psnr": p.psnr, "within": p.within, "fixed_psnr": p.fixed_psnr,
                "fixed_ipr": p.fixed_ipr, "fixed_within": p.fixed_within} for p in compared])
    plot_tradeoff(out / "tradeoff.png", curve, compared, s.epsilon_db, s.label_source)
    return trade


def summarize_methods(s, names, per_view: list[dict[str, Any]], lat: dict[str, list[dict[str, float]]]) -> dict[str, dict[str, Any]]:
    """Per method: mean IPR and PSNR, the gaps to the RecNN alone and to its reference, the share of views
    within epsilon of the reference, and the mean stage times of the timed methods."""
    eps = s.epsilon_db
    summ: dict[str, dict[str, Any]] = {}
    base = np.array([r["psnr_recnn"] for r in per_view])
    for name in names:
        ps = np.array([r[f"psnr_{name}"] for r in per_view])
        ip = np.array([r[f"ipr_{name}"] for r in per_view])
        gap = base - ps
        ref = np.array([r[f"psnr_{reference_method(name, s.reference)}"] for r in per_view])
        gap_ref = ref - ps
        summ[name] = {"ipr": float(ip.mean()), "psnr": float(ps.mean()), "gap": float(gap.mean()),
                      "gap_ref": float(gap_ref.mean()), "max_gap_ref": float(gap_ref.max()),
                      "max_gap": float(gap.max()), "within": float((gap_ref <= eps + 1e-9).mean()),
                      "ipr_min": float(ip.min()), "ipr_max": float(ip.max())}
        if lat.get(name):
            summ[name]["latency_ms"] = {k: float(np.mean([d.get(k, 0.0) for d in lat[name]])) for k in lat[name][0]}
    return summ


def write_results(out: Path, s, cfg, summ, trade, timing, hist, u_train: float, u_orp: float, u_match: float, u_pred) -> None:
    """``adaptive.json`` (the summary, the trade-off, the timing, the means) and ``config.yaml``."""
    from ..base.config import to_plain
    from ..report import atomic_write_text, write_config

    trade_json = None if trade is None else {"curve": trade["curve"], "points": [
        {**p.__dict__, "d_psnr": p.d_psnr, "d_ipr": p.d_ipr} for p in trade["points"]]}
    atomic_write_text(out / "adaptive.json", json.dumps({"summary": summ, "tradeoff": trade_json, "timing": timing, "predictor": hist,
                                                         "u_train": u_train, "u_orp": u_orp, "u_matched": u_match,
                                                         "u_adaptive": {"median": float(np.median(u_pred)), "min": float(u_pred.min()),
                                                                        "max": float(u_pred.max())},
                                                         "epsilon_db": s.epsilon_db}, indent=2, default=str))
    write_config(out / "config.yaml", {k: to_plain(cfg[k]) for k in ("scene", "data", "renderer") if k in cfg}
                 | {"settings": s.hashed(), "ims_checkpoint": s.ims, "recnn_checkpoint": s.recnn})


def _command() -> str:
    from ..report import hydra_command

    return hydra_command("imls_lightning.adaptive", "run_adaptive(cfg) through the Python API")


@checked_command_line(CONF_DIR, "adaptive")
@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="adaptive")
@cli_errors
def main(cfg: DictConfig) -> None:
    """``python -m imls_lightning.adaptive ...``: prints the report's path last."""
    path = run_adaptive(cfg)
    print(path, flush=True)
