"""Speed/accuracy evaluation of IML/S + RecNN against every baseline, on the same views in one run.

``python -m imls_lightning.evaluate scene=NAME checkpoints.ims=<IMS .ckpt> [checkpoints.las=<LAS .ckpt>]``

For each view of the cache's test trajectory (``views=test``; rendered if missing, with the
scene/data/renderer groups the networks were trained with) and each method - full ray cast, RecNN
alone, LAS (with a LAS checkpoint), IML + RecNN, IML/S + RecNN - every stage is timed (median of
``repeats`` runs after ``warmup``; see :func:`imls_lightning.inference.pipeline.time_method`) and the image is
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

Python:
    >>> from hydra import compose, initialize_config_dir          # doctest: +SKIP
    >>> with initialize_config_dir("/path/to/conf", version_base="1.3"):
    ...     cfg = compose("evaluate", overrides=["scene=tiny", "data=tiny", "checkpoints.ims=ims.ckpt"])
    >>> report = evaluate(cfg)                                      # doctest: +SKIP
    >>> summary(report.parent / "metrics.csv")["imls"]["latency_ms"]["total"]   # doctest: +SKIP
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import hydra
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

import data_gen  # noqa: F401  (registers the scene config resolvers)
from data_gen.errors import InputError, cli_errors, checked_command_line

from . import report as rep
from .inference.checkpoints import check_resolution, check_same_pattern, load_recnn, load_task, require_recnn
from .inference.checkpoints import check_trained_on as checkpoint_trained_on
from .config import file_hash, load_checkpoint, register_resolvers, settings_hash, to_plain
from .inference.pipeline import (
    STAGES,
    FullRayCast,
    IMLPlusRecNN,
    IMLSRenderer,
    LASMethod,
    Method,
    NetOptions,
    RecNNAlone,
    pick_device,
    time_method,
)
from .inference.baselines import equal_share_rows, mask_at_share, product_orp, summarize_equal_share
from .models.iml import FillDecoder
from .report import summary  # noqa: F401  (public: summary(metrics_csv) -> dict)

register_resolvers()

MIN_REPEATS = 10
#: the shares of C at which the speed-quality front measures IML/S + RecNN (and blue noise + decoder)
FRONT_SHARES = (0.1, 0.2, 0.4, 0.6, 0.8, 1.0)
#: where the ORP is searched: ``heldout`` views drawn like the training views from a seed of their own (no
#: network trained on them), or the cache's ``val`` split (whose eye directions an IMS trained on a larger cache
#: of the same seed has seen: sample_training_views draws every direction before any distance)
ORP_VIEWS = ("heldout", "val")


# ------------------------------------------------------------------------------------------------
# settings


def _int(cfg, key: str, minimum: int, allow_none: bool = False) -> int | None:
    v = OmegaConf.select(cfg, key)
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v or int(v) < minimum:
        what = f"an integer >= {minimum}" + (" or null" if allow_none else "")
        raise InputError(f"{key}={v}: expected {what}")
    return int(v)


def _lift(cfg) -> bool | str:
    v = OmegaConf.select(cfg, "ims_lift", default="auto")
    if v not in (True, False, "auto"):
        raise InputError(f"ims_lift={v}: expected auto, true or false")
    return v


def _floats(cfg, key: str, lo: float, hi: float, lo_open: bool = False) -> list[float]:
    v = to_plain(OmegaConf.select(cfg, key))
    if v is None:
        return []
    if not isinstance(v, (list, tuple)):
        v = [v]
    out = []
    for x in v:
        try:
            f = float(x)
        except (TypeError, ValueError):
            raise InputError(f"{key}={v}: expected a list of numbers in {'(' if lo_open else '['}{lo}, {hi}]") from None
        if not (math.isfinite(f) and (f > lo if lo_open else f >= lo) and f <= hi):
            raise InputError(f"{key}={v}: expected numbers in {'(' if lo_open else '['}{lo}, {hi}]")
        out.append(f)
    return out


@dataclass
class Settings:
    """The evaluation's validated settings (see ``conf/evaluate.yaml``)."""

    ims: str
    las: str | None
    recnn: str | None
    iml: str | None
    views: str
    max_views: int | None
    repeats: int
    warmup: int
    options: NetOptions
    options_sweep: bool
    options_sweep_options: list[str]
    options_sweep_views: int
    las_ipr: float | None
    las_iprs: list[float]
    mean_values: list[float]
    sweep_views: int | None
    grid_views: int
    output_dir: str | None
    reuse: bool
    progress: bool
    blue_noise: str | None = None
    orp: bool = True
    epsilon_db: float = 1.0
    orp_max_views: int | None = 30
    shares: list[float] = field(default_factory=lambda: [0.1, 0.2, 0.4])
    timed_views: int | None = None
    ims_lift: bool | str = "auto"
    recnn_sparser: str | None = None
    front_shares: list[float] = field(default_factory=lambda: list(FRONT_SHARES))
    orp_confidence: float = 0.95
    orp_views: str = "heldout"
    orp_views_seed: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def hashed(self) -> dict[str, Any]:
        """Settings that change the results (enter the output directory's hash)."""
        return {
            "views": self.views, "max_views": self.max_views, "repeats": self.repeats, "warmup": self.warmup,
            "options": vars(self.options), "options_sweep": self.options_sweep,
            "options_sweep_options": self.options_sweep_options, "options_sweep_views": self.options_sweep_views,
            "las_ipr": self.las_ipr, "las_iprs": self.las_iprs, "mean_values": self.mean_values,
            "sweep_views": self.sweep_views, "grid_views": self.grid_views, "orp": self.orp,
            "epsilon_db": self.epsilon_db, "orp_max_views": self.orp_max_views, "shares": self.shares,
            "ims_lift": self.ims_lift, "front_shares": self.front_shares, "orp_confidence": self.orp_confidence,
            "orp_views": self.orp_views, "orp_views_seed": self.orp_views_seed,
            # only when set: evaluations made before the key existed keep their directories
            **({"timed_views": self.timed_views} if self.timed_views is not None else {}),
        }


def parse_settings(cfg: DictConfig) -> Settings:
    """Validate the evaluation keys of ``cfg``; bad values raise a one-line :class:`InputError`."""
    ck = cfg.get("checkpoints")
    if ck is None or OmegaConf.is_missing(ck, "ims") or not ck.get("ims"):
        raise InputError("checkpoints.ims: required, the IMS checkpoint to evaluate (python -m imls_lightning.train model=ims ...)")
    repeats = OmegaConf.select(cfg, "repeats")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < MIN_REPEATS:
        raise InputError(f"repeats={repeats}: expected an integer >= {MIN_REPEATS} (stage times are medians of at least {MIN_REPEATS} runs per view)")
    views = str(cfg.get("views", "test"))
    if views not in ("test", "val"):
        raise InputError(f"views={views}: expected 'test' (the trajectory) or 'val'")
    options = NetOptions.from_config(to_plain(cfg.get("options")))
    sweep_opts = [str(o) for o in (to_plain(cfg.get("options_sweep_options")) or [])]
    bad = [o for o in sweep_opts if o not in NetOptions.SWITCHES]
    if bad:
        raise InputError(f"options_sweep_options={sweep_opts}: unknown option {bad[0]!r}; expected some of {list(NetOptions.SWITCHES)}")
    las_ipr = cfg.get("las_ipr")
    if las_ipr is not None:
        las_ipr = _floats(cfg, "las_ipr", 0.0, 1.0, lo_open=True)[0]
    return Settings(
        ims=str(ck.ims), las=ck.get("las") or None, recnn=ck.get("recnn") or None, iml=ck.get("iml") or None,
        views=views, max_views=_int(cfg, "max_views", 1, allow_none=True), repeats=int(repeats),
        warmup=_int(cfg, "warmup", 0), options=options, options_sweep=bool(cfg.get("options_sweep", False)),
        options_sweep_options=sweep_opts, options_sweep_views=_int(cfg, "options_sweep_views", 1),
        las_ipr=las_ipr, las_iprs=_floats(cfg, "las_iprs", 0.0, 1.0, lo_open=True),
        mean_values=_floats(cfg, "mean_values", 0.01, 1.0), sweep_views=_int(cfg, "sweep_views", 1, allow_none=True),
        grid_views=_int(cfg, "grid_views", 0), output_dir=cfg.get("output_dir") or None,
        reuse=bool(cfg.get("reuse", False)), progress=bool(cfg.get("progress", True)),
        blue_noise=ck.get("blue_noise") or None, orp=bool(cfg.get("orp", True)),
        epsilon_db=_floats(cfg, "epsilon_db", 0.0, 100.0)[0] if cfg.get("epsilon_db") is not None else 1.0,
        orp_max_views=_int(cfg, "orp_max_views", 1, allow_none=True),
        shares=_floats(cfg, "shares", 0.0, 1.0, lo_open=True) if cfg.get("shares") is not None else [],
        timed_views=_int(cfg, "timed_views", 1, allow_none=True),
        ims_lift=_lift(cfg), recnn_sparser=ck.get("recnn_sparser") or None,
        front_shares=_floats(cfg, "front_shares", 0.0, 1.0, lo_open=True),
        orp_confidence=_confidence(cfg), orp_views=_orp_views(cfg),
        orp_views_seed=_int(cfg, "orp_views_seed", 0, allow_none=True),
    )


def _orp_views(cfg) -> str:
    v = str(OmegaConf.select(cfg, "orp_views", default="heldout"))
    if v not in ORP_VIEWS:
        raise InputError(f"orp_views={v}: expected one of {list(ORP_VIEWS)} (heldout: views no network was trained on)")
    return v


def _confidence(cfg) -> float:
    """``orp_confidence``: the one-sided confidence of the ORP's bound on the mean validation gap, in [0.5, 1)."""
    from data_gen.validate import check_number

    return check_number(OmegaConf.select(cfg, "orp_confidence", default=0.95), "orp_confidence", 0.5, 1.0, hi_open=True,
                        what="a confidence in [0.5, 1) (0.5: the mean gap itself)")


# ------------------------------------------------------------------------------------------------
# networks


@dataclass
class Networks:
    """What the checkpoints provide."""

    ims_task: Any
    recnn: torch.nn.Module
    iml: torch.nn.Module
    las_task: Any | None
    recnn_name: str
    recnn_source: str
    iml_source: str
    blue: torch.nn.Module | None = None
    recnn_sparser: Any | None = None  # RecNNTask: the same RecNN kind on a sparser pattern of its own


def load_networks(s: Settings, resolution: int) -> Networks:
    """Load and cross-check the checkpoints (pattern, resolution) before anything is rendered."""
    ims = load_task(s.ims, expect="IMSTask", what="checkpoints.ims")
    check_resolution(ims.hparams, resolution, key="checkpoints.ims", path=s.ims, network="IMS", against="this evaluation uses")
    fr = int(ims.hparams["fr_size"])
    same = dict(against="the IMS", hint="pass checkpoints of the IMS's pattern and data.resolution")
    if s.recnn:
        recnn, rh = load_recnn(s.recnn, what="checkpoints.recnn")  # the bare RecNN, no task built
        check_same_pattern(rh, ims.pattern, key="checkpoints.recnn", path=s.recnn, network="RecNN", **same)
        recnn_source, recnn_name = s.recnn, rh.get("recnn_name", "recnn")
    else:
        recnn = require_recnn(ims.recnn, key="checkpoints.ims", path=s.ims, recnn_key="checkpoints.recnn")
        recnn_source = f"{s.ims} ({ims.hparams.get('recnn_source') or 'stored'})"
        recnn_name = (ims.hparams.get("recnn_hparams") or {}).get("recnn_name", "recnn")
    if s.iml:
        it = load_task(s.iml, expect="IMLTask", what="checkpoints.iml")
        check_same_pattern(it.hparams, ims.pattern, key="checkpoints.iml", path=s.iml, network="IML", **same)
        iml, iml_source = it.iml, s.iml
    else:
        iml, iml_source = ims.iml, f"{s.ims} (the IML its labels came from)"
        if float(ims.hparams.get("decoder_lr", 0.0)) > 0:
            iml_source += ", its decoder fine-tuned on the IMS's masks (pass checkpoints.iml= for the IML's own)"
    las = None
    if s.las:
        las = load_task(s.las, expect="LASTask", what="checkpoints.las")
        check_resolution(las.hparams, fr, key="checkpoints.las", path=s.las, network="LAS", against="the IMS at",
                         hint="pass a LAS trained at the IMS's data.resolution")
    blue = None
    if s.blue_noise:
        bt = load_task(s.blue_noise, expect="IMLTask", what="checkpoints.blue_noise")
        check_same_pattern(bt.hparams, ims.pattern, key="checkpoints.blue_noise", path=s.blue_noise, network="IML", **same)
        if bt.hparams.get("importance") != "uniform":
            raise InputError(f"checkpoints.blue_noise={s.blue_noise}: an IML trained with model.importance={bt.hparams.get('importance', 'learned')}; expected model.importance=uniform")
        blue = bt.iml
    sparser = load_sparser_recnn(s.recnn_sparser, ims.pattern, str(recnn_name)) if s.recnn_sparser else None
    return Networks(ims, recnn, iml, las, str(recnn_name), str(recnn_source), str(iml_source), blue, sparser)


def load_sparser_recnn(path: str, pattern, recnn_name: str):
    """The RecNN alone on a sparser pattern (``checkpoints.recnn_sparser``): what a user would do instead
    of IML/S. Checked against the evaluation's RecNN: the same kind (``recnn_name``), the same FR-Image
    size, and a pattern with at most half of ``pattern``'s pixels (EnhanceNet 4x instead of 2x: a
    quarter); otherwise a one-line :class:`InputError`."""
    task = load_task(path, expect="RecNNTask", what="checkpoints.recnn_sparser")
    hint = "train the same RecNN on a sparser pattern (e.g. model=recnn pattern.factor=4, or pattern.c_size_ratio=0.25)"
    kind = str(task.hparams.get("recnn_name", "recnn"))
    if kind != recnn_name:
        raise InputError(f"checkpoints.recnn_sparser={path}: a {kind} RecNN; the evaluation's RecNN is {recnn_name} ({hint})")
    sp = task.pattern
    if int(sp.fr_size) != int(pattern.fr_size):
        raise InputError(f"checkpoints.recnn_sparser={path}: trained at {sp.fr_size}^2, the evaluation at {pattern.fr_size}^2 ({hint})")
    if 2 * int(sp.count) > int(pattern.count):
        raise InputError(f"checkpoints.recnn_sparser={path}: its pattern has {sp.count} pixels, not at most half of the "
                         f"evaluation's {pattern.count} ({hint})")
    return task


def check_trained_on(cfg: DictConfig, s: Settings) -> None:
    """The scene and renderer of this evaluation must be those the IMS checkpoint was trained on
    (recorded in it); otherwise a one-line error, unless ``allow_mismatch=true``. (The sampling
    pattern and resolution are checked in :func:`load_networks`.) The check itself:
    :func:`imls_lightning.inference.checkpoints.check_trained_on`."""
    hp = load_checkpoint(s.ims, what="checkpoints.ims")["hyper_parameters"]
    if bool(cfg.get("allow_mismatch", False)):
        return
    checkpoint_trained_on(hp, cfg.scene, cfg.renderer, key="checkpoints.ims", path=s.ims, against="this evaluation",
                          escape="or allow_mismatch=true to evaluate it anyway")


def _recnn_name(s: Settings) -> str:
    """The RecNN's config name (``enhancenet``, ``fovolnet``) from the checkpoints' hyper-parameters
    alone, as :func:`load_networks` finds it (no network is built)."""
    if s.recnn:
        return str(load_checkpoint(s.recnn, what="checkpoints.recnn")["hyper_parameters"].get("recnn_name", "recnn"))
    hp = load_checkpoint(s.ims, what="checkpoints.ims")["hyper_parameters"]
    return str((hp.get("recnn_hparams") or {}).get("recnn_name", "recnn"))


# ------------------------------------------------------------------------------------------------
# measuring


def image_quality(image: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """PSNR (dB, 100 for identical images) and SSIM of two ``(m, m, 3)`` uint8 images, by the same
    functions as the training logs (:mod:`imls_lightning.core.metrics`)."""
    from .core.metrics import psnr, ssim_metric

    # np.array copies: the cache's images are read-only memory maps (torch warns on those)
    p = torch.from_numpy(np.array(image)).permute(2, 0, 1)[None].float().div(255.0)
    t = torch.from_numpy(np.array(truth)).permute(2, 0, 1)[None].float().div(255.0)
    return float(psnr(p, t)), float(ssim_metric(p, t))


def measure(method: Method, view: np.ndarray, truth: np.ndarray, repeats: int, warmup: int,
            **run_args: Any) -> tuple[dict[str, Any], np.ndarray, dict[str, Any]]:
    """Time one method on one view and score it: ``(metric row fields, image, info)``."""
    image, med, info = time_method(method, view, repeats=repeats, warmup=warmup, **run_args)
    q_psnr, q_ssim = image_quality(image, truth)
    row: dict[str, Any] = {f"{k}_ms": 1e3 * v for k, v in med.items() if k != "total"}
    row["total_ms"] = 1e3 * med["total"]
    row.update(ipr=info.get("ipr"), c_share=info.get("c_share"), rendered_pixels=info.get("rendered_pixels"),
               psnr=q_psnr, ssim=q_ssim)
    return row, image, info


def spaced(n: int, k: int | None) -> np.ndarray:
    """``k`` indices evenly spaced over ``range(n)`` (all when ``k`` is None or >= n)."""
    if k is None or k >= n:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def _bar(iterable, total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit="view", file=sys.stderr, disable=not enabled, dynamic_ncols=True)


def _command() -> str:
    from .report import hydra_command

    return hydra_command("imls_lightning.evaluate", "evaluate(cfg) through the Python API (settings: config.yaml)")

# ------------------------------------------------------------------------------------------------
# the evaluation


def evaluate(cfg: DictConfig, command: str | None = None) -> Path:
    """Run the evaluation described by ``cfg`` (``conf/evaluate.yaml``); returns ``report.md``'s path."""
    from data_gen.cache import ViewImageCache, ensure_cache
    from data_gen.renderers import make_renderer, renderer_pixel_settings
    from data_gen.scene import build_scene

    s = parse_settings(cfg)
    resolution = int(cfg.data.resolution)
    paths = {k: p for k, p in (("ims", s.ims), ("las", s.las), ("recnn", s.recnn), ("iml", s.iml),
                               ("blue_noise", s.blue_noise), ("recnn_sparser", s.recnn_sparser)) if p}
    for k, p in paths.items():
        if not Path(str(p)).expanduser().is_file():
            raise InputError(f"checkpoints.{k}={p}: file not found")
    check_trained_on(cfg, s)
    scene = build_scene(cfg.scene)
    rcfg = to_plain(cfg.renderer)

    # the output directory and the reuse check need only the checkpoints' bytes and hyper-parameters:
    # a reused run returns before any network is built (or Lightning imported)
    ck_hashes = {k: file_hash(Path(str(p)).expanduser()) for k, p in paths.items()}
    run_hash = settings_hash(ck_hashes, cfg.scene, cfg.data, renderer_pixel_settings(rcfg), s.hashed())
    out = Path(s.output_dir) if s.output_dir else Path(str(cfg.paths.runs_dir)) / "eval" / f"{scene.name}-{_recnn_name(s)}-{run_hash}"
    report_path = out / "report.md"
    if s.reuse and report_path.is_file():
        print(f"[evaluate] {out} already has a report of these settings; reusing it (reuse=false re-measures)", file=sys.stderr, flush=True)
        return report_path
    nets = load_networks(s, resolution)
    ims = nets.ims_task
    out.mkdir(parents=True, exist_ok=True)
    report_path.unlink(missing_ok=True)  # no report.md = no finished evaluation in this folder

    cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=s.progress))
    if cache.resolution != resolution:
        raise InputError(f"data.resolution={resolution}: the cache {cache.path} holds {cache.resolution}^2 images")
    rows_all = cache.splits[s.views]
    if len(rows_all) == 0:
        raise InputError(f"views={s.views}: the cache {cache.path} has no {s.views} views")
    positions = spaced(len(rows_all), s.max_views)
    renderer = make_renderer(scene, rcfg)
    opts = s.options
    device = pick_device(opts.device)
    pattern = ims.pattern
    m = resolution

    notes: list[str] = []
    # -- the ORP on the product path (validation views), then IML/S runs at that mean ----------------
    orp_result, imls_mean, lift = None, None, s.ims_lift is True  # lift: IML/S's masks lifted to their share
    if s.orp and ims.target == "pim":
        orp_result = _product_orp(s, cfg, cache, scene, nets, pattern, device, future_views=len(positions))
        lift = orp_result.lifted
        if orp_result.found:
            imls_mean = float(orp_result.mean)
        else:
            notes.append(f"ORP: no mean value in [0.01, 1] brings IML/S within {s.epsilon_db} dB of the RecNN alone on the "
                         "validation views; IML/S runs at its trained mean.")
    elif s.orp:
        notes.append(f"ORP search skipped: the IMS was trained with model.target={ims.target}, whose binary mask cannot be "
                     "rescaled to another mean (train the IMS with model.target=pim).")

    # -- methods (the networks are shared between methods with the same options) -----------------
    imls = IMLSRenderer(renderer, pattern, ims.to(device).mask_head, ims.decoder, nets.recnn, opts, mean=imls_mean, lift=lift)
    methods: dict[str, Method] = {
        "full": FullRayCast(renderer, m, opts),
        "recnn": RecNNAlone(renderer, pattern, nets.recnn, opts),
        **({"recnn_sparser": sparser_method(renderer, nets.recnn_sparser, opts)} if nets.recnn_sparser is not None else {}),
        "iml": IMLPlusRecNN(renderer, pattern, nets.iml, nets.recnn, opts, mean=imls_mean),
        "imls": imls,
        "imls_fill": IMLSRenderer(renderer, pattern, imls.predict_im, FillDecoder(pattern), nets.recnn, opts),
    }
    las_ipr_used = None
    if nets.las_task is not None:
        if s.las_ipr is not None:
            las_ipr_used, how = s.las_ipr, "fixed (las_ipr)"
        else:
            # IML/S's mean IPR on these views: the IMS network alone (no rendering) decides it
            with torch.inference_mode():
                counts = [int(imls.predict_im(torch.from_numpy(np.array(cache.views[rows_all[p]], np.float32))[None].to(device)).sum())
                          for p in positions]
            mean_ipr = float(np.mean(counts)) / m**2
            las_ipr_used, how = max(mean_ipr, 1.0 / m**2), "matched to IML/S's mean IPR on these views"
            if mean_ipr < 1.0 / m**2:
                notes.append(f"IML/S selects no pixel on these views (IPR 0): LAS runs at the smallest IPR, 1 pixel ({las_ipr_used:.2e}).")
        methods["las"] = LASMethod(renderer, nets.las_task.net, m, int(nets.las_task.hparams["low_res"]), ipr=las_ipr_used, opts=opts)
        notes.append(f"LAS at IPR {las_ipr_used:.4f}, {how}; its mean u is bisected per view outside the timed stages (LAS's evaluation protocol).")
    else:
        notes.append("LAS skipped: no LAS checkpoint (checkpoints.las=<LAS .ckpt>, trained with python -m imls_lightning.train model=las).")
    if nets.blue is not None:
        with torch.inference_mode():
            shares = [float(imls.predict_im(torch.from_numpy(np.array(cache.views[rows_all[p]], np.float32))[None].to(device)).sum())
                      / pattern.count for p in positions]
        methods["blue_noise"] = blue_noise_method(renderer, pattern, nets.blue, nets.recnn, float(np.mean(shares)), opts)
    order = [k for k in rep.METHOD_ORDER if k in methods]

    # -- main loop -----------------------------------------------------------------------------
    grid_pos = set(int(positions[i]) for i in spaced(len(positions), s.grid_views)) if s.grid_views else set()
    sweep_pos = [int(positions[i]) for i in spaced(len(positions), s.sweep_views)]
    # latency on timed_views of the evaluated views (repeats runs each), quality on all of them; the sweep's
    # views are always timed: the speed-quality front puts every method on them
    timed_pos = set(int(positions[i]) for i in spaced(len(positions), s.timed_views)) | set(sweep_pos)
    if len(timed_pos) < len(positions):
        notes.append(f"Latency: stage times on {len(timed_pos)} of the {len(positions)} evaluated views (evenly spaced, "
                     f"median of {s.repeats} runs each); PSNR and SSIM on all {len(positions)}.")
    rows: list[dict[str, Any]] = []
    grid: dict[int, dict[str, Any]] = {}
    # the sweeps of the latency / PSNR plot and the speed-quality front: on the sweep's views, right after their methods
    sweeps = Sweeps(s, methods, nets, renderer, opts, m) if sweep_pos else None
    sweep_rows: list[dict[str, Any]] = []
    for p in _bar(positions, len(positions), f"evaluate {scene.name}", s.progress):
        p = int(p)
        r = int(rows_all[p])
        view, truth = np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r])
        if p in grid_pos:
            grid[p] = {"truth": truth}
        timed = p in timed_pos
        for name in order:
            fields, image, info = measure(methods[name], view, truth, s.repeats if timed else 1, s.warmup if timed else 0)
            if not timed:  # one untimed run: its image counts, its stage times do not
                fields.update({k: None for k in fields if k.endswith("_ms")})
            rows.append({"view": p, "row": r, "method": name, **fields})
            if p in grid_pos:
                grid[p][name] = image
                if name == "imls":
                    grid[p]["imls_im"] = info.get("im")
        if sweeps is not None and p in sweep_pos:
            sweep_rows += sweeps.run_view(p, r, view, truth)
    rep.write_metrics_csv(rows, out / "metrics.csv")
    rep.write_metrics_csv(sweep_rows, out / "sweep.csv", rep.SWEEP_COLUMNS)

    # -- untrained baselines at equal share (cache pixels = what the selective ray cast returns) ---------
    equal_share = _equal_share(s, cache, rows_all, positions, nets, pattern, device, lift) if s.shares else []

    # -- options -----------------------------------------------------------------------------------
    option_rows: list[dict[str, Any]] = []
    if s.options_sweep:
        opt_pos = [int(positions[i]) for i in spaced(len(positions), s.options_sweep_views)]
        option_rows = _options_sweep(s, renderer, cache, rows_all, opt_pos)
        rep.write_metrics_csv(option_rows, out / "options.csv", rep.OPTION_COLUMNS)

    # -- report ------------------------------------------------------------------------------------
    plain = {k: to_plain(cfg[k]) for k in ("scene", "data", "renderer") if k in cfg}
    plain.update(checkpoints=to_plain(cfg.checkpoints), settings=s.hashed(), output_dir=str(out))
    rep.atomic_write_text(out / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(plain)))
    orp_summary = _orp_summary(orp_result, s, lifted=lift) if orp_result is not None else None
    if orp_summary is not None:  # the same operating point on the evaluated (test) views, beside the validation gap
        orp_summary["test"] = paired_gap(rows, "recnn", "imls")
    front = rep.front_points(rows, sweep_rows, sweep_pos, notes=_front_notes(methods, imls_mean, orp_result, las_ipr_used))
    # the machine-readable results the benchmarks collect (make bench-paper)
    rep.atomic_write_text(out / "summary.json", json.dumps({
        "scene": scene.name, "recnn": nets.recnn_name, "fr_size": m, "c_size": int(pattern.c_size),
        "sample_distance_voxels": _sample_distance_voxels(scene, rcfg), "imls_mean": imls_mean, "orp": orp_summary,
        "las_ipr": las_ipr_used, "views": len(positions), "timed_views": len(timed_pos), "methods": rep.summarize_rows(rows),
        "equal_share": equal_share, "front": front, "front_views": [int(p) for p in sweep_pos]}, indent=1, default=float))
    ctx = rep.ReportContext(
        out=out, scene=scene.name, recnn_name=nets.recnn_name, resolution=m, c_size=pattern.c_size,
        pattern=pattern.summary(), renderer=str(rcfg.get("name")), views=s.views, positions=[int(p) for p in positions],
        trajectory_len=len(rows_all), repeats=s.repeats, warmup=s.warmup, options=vars(opts), device=str(device),
        checkpoints={"IMS": s.ims, "RecNN": nets.recnn_source, "IML (IML + RecNN)": nets.iml_source, "LAS": s.las or "–"},
        iml_mean=float(nets.iml.mean), rows=rows, sweep_rows=sweep_rows, option_rows=option_rows, order=order,
        sweep_positions=sweep_pos, grid=grid, pattern_obj=pattern, notes=notes, las_ipr=las_ipr_used,
        machine=rep.machine_info(str(device)), command=command or _command(), cache=str(cache.path),
        orp=orp_summary, equal_share=equal_share, front=front,
    )
    report = rep.write_report(ctx)
    if orp_summary is not None:  # after the report: only a finished evaluation records its point
        _record_operating_point(s, orp_summary, scene.name, report, int(orp_summary.get("views") or 0))
    return report


def _record_operating_point(s: Settings, orp: dict[str, Any], scene: str, report: Path, views: int) -> None:
    """Record the ORP IML/S ran at beside the IMS checkpoint (``<ims.ckpt>.orp.json``, see
    :mod:`imls_lightning.inference.operating_point`), where renderers built from the checkpoint alone
    find it; a folder that cannot be written is a one-line warning (the report holds the point)."""
    from .inference.operating_point import OperatingPoint, write_operating_point

    opt = lambda k: None if orp.get(k) is None else float(orp[k])  # noqa: E731
    point = OperatingPoint(mean=opt("mean") if orp["found"] else None, lift=bool(orp["lift"]), c_share=opt("c_share"),
                           ipr=opt("ipr"), epsilon_db=float(orp["epsilon_db"]), gap_db=opt("gap_db"), views=int(views),
                           scene=scene, report=str(Path(report).resolve()))
    try:
        path = write_operating_point(s.ims, point)
    except OSError as err:
        print(f"[evaluate] warning: cannot record the operating point beside {s.ims} ({err.strerror or type(err).__name__}): "
              "renderers built from the checkpoint alone run at its trained mean", file=sys.stderr, flush=True)
        return
    print(f"[evaluate] operating point {point.describe()} recorded for the IMS checkpoint: {path}", file=sys.stderr, flush=True)


def _loader(cache, rows, pattern, batch_size: int = 16):
    from torch.utils.data import DataLoader

    from .data.datamodule import ViewImageDataset

    ds = ViewImageDataset(cache.path, np.asarray(rows), pattern, fields=("view", "fr", "c"))
    return DataLoader(ds, batch_size=batch_size, shuffle=False, num_workers=0)


def _sample_distance_voxels(scene, renderer_cfg) -> float | None:
    """The scene's ray-marching step in voxels (:func:`data_gen.scene.voxel_size`), for the reports."""
    from data_gen.scene import voxel_size

    try:
        return float(scene.sample_distance) / float(voxel_size(scene.volume))
    except (AttributeError, TypeError, ValueError, ZeroDivisionError):
        return None


def orp_search_views(s: Settings, cfg, cache, scene):
    """The views the ORP is searched on: ``(cache, rows, description)``.

    ``orp_views=val``: ``orp_max_views`` of the cache's validation views, evenly spaced. ``heldout``
    (default): ``orp_max_views`` views (null: as many as the cache has validation views) drawn like the
    training views but from a seed of their own (``orp_views_seed``; null: ``data.seed + 1``), rendered
    into a cache of their own (``data.num_views`` of them, no trajectory): no network was trained on them
    nor on their eye directions. The validation split is not held out from an IMS trained on a larger
    cache of the same seed (the demo's 1,500 views): the first training draws of both caches share their
    eye directions (:func:`data_gen.views.sample_training_views`).
    """
    from data_gen.cache import ViewImageCache, ensure_cache

    val = cache.splits["val"]
    if s.orp_views == "val":
        if len(val) == 0:
            raise InputError(f"orp=true: the cache {cache.path} has no validation views to search the ORP on; pass orp=false")
        rows = val[spaced(len(val), s.orp_max_views)]
        return cache, rows, f"{len(rows)} of the cache's validation views"
    n = s.orp_max_views or max(len(val), 1)
    seed = int(cfg.data.seed) + 1 if s.orp_views_seed is None else int(s.orp_views_seed)
    # a cache of its own (never cache_path, the evaluated cache's exact folder), rendered whole (no shard)
    data = OmegaConf.merge(cfg.data, {"num_views": int(n), "seed": seed, "test_views": 0, "val_fraction": 0.0,
                                      "test_trajectory": None, "cache_path": None, "shard": None})
    held = ViewImageCache.open(ensure_cache(scene, data, cfg.renderer, progress=s.progress))
    return held, held.splits["train"], f"{n} held-out views (seed {seed}: no network trained on them)"


def _product_orp(s: Settings, cfg, cache, scene, nets: Networks, pattern, device, future_views: int | None = None):
    """The ORP on the product path, searched on :func:`orp_search_views` (see :func:`baselines.product_orp`);
    its bound is for the mean gap of ``future_views`` new views (the evaluated ones)."""
    cache, rows, where = orp_search_views(s, cfg, cache, scene)
    print(f"[evaluate] ORP: searched on {where}, judged by the {s.orp_confidence:.0%} upper bound on the mean gap of "
          f"{future_views or 'all'} new views", file=sys.stderr, flush=True)
    ims = nets.ims_task.to(device)
    with torch.inference_mode():
        batches = list(_loader(cache, rows, pattern))
        recnn = nets.recnn.to(device).eval()
        result = orp_with_lift(lambda lift: product_orp(ims.mask_head, ims.decoder, recnn, batches, s.epsilon_db, device=device,
                                                        confidence=s.orp_confidence, lift=lift, future_views=future_views),
                               s.ims_lift)
    result.where = where
    return result


def orp_with_lift(search: Callable[[bool], Any], lift: bool | str) -> Any:
    """Run the ORP ``search(lift)`` with the IMS's masks lifted or not, as ``lift`` says (``ims_lift``).

    ``auto``: the paper's rescale first; when it finds no ORP (its share saturates short of
    the bound), search again with the masks lifted to their mean value, which then stay lifted for the
    rest of the evaluation. The result keeps the first search's points as ``rescale_points``, and
    ``lifted``: whether its masks were lifted.
    """
    lifted = lift is True
    result = search(lifted)
    if lift == "auto" and not result.found:
        print(f"[evaluate] ORP: none with the paper's rescale (largest share {_largest_share(result):.1%} of C); "
              "searching again with the IMS's masks lifted to their mean value (ims_lift=auto)", file=sys.stderr, flush=True)
        lifted = True
        plain = _points(result)
        result = search(lifted)
        result.rescale_points = plain  # kept for the report: what the paper's rescale reached
    result.lifted = lifted
    return result


def _points(result) -> list[tuple]:
    """``(u, mean gap, C-share, gap bound)`` of every mean value the search tried, by ``u``."""
    return sorted(((e.u, (e.record or {}).get("gap_db"), (e.record or {}).get("c_share"), (e.record or {}).get("gap_bound_db"))
                   for e in result.evaluations))


def _largest_share(result) -> float:
    shares = [(e.record or {}).get("c_share") for e in result.evaluations]
    return max((float(x) for x in shares if x is not None), default=float("nan"))


def paired_gap(rows: Sequence[dict[str, Any]], reference: str, method: str) -> dict[str, Any] | None:
    """The per-view PSNR gap ``reference - method`` over the views both were scored on, summarized as the
    ORP's validation gap is (:func:`~imls_lightning.orp.search.gap_upper_bound` at confidence 0.5: mean,
    sample std, views) plus both mean PSNRs; ``None`` when they share no view.

    Example:
        >>> rows = [{"view": 0, "method": "recnn", "psnr": 40.0}, {"view": 0, "method": "imls", "psnr": 39.0},
        ...         {"view": 1, "method": "recnn", "psnr": 38.0}, {"view": 1, "method": "imls", "psnr": 36.0}]
        >>> paired_gap(rows, "recnn", "imls")["gap_db"]
        1.5
    """
    from .orp import gap_upper_bound

    ref = {int(r["view"]): float(r["psnr"]) for r in rows if r["method"] == reference and r.get("psnr") is not None}
    got = {int(r["view"]): float(r["psnr"]) for r in rows if r["method"] == method and r.get("psnr") is not None}
    views = sorted(set(ref) & set(got))
    if not views:
        return None
    b = gap_upper_bound([ref[v] - got[v] for v in views], 0.5)
    return {"gap_db": b.mean, "gap_std_db": b.std, "views": b.views, "psnr_recnn": float(np.mean([ref[v] for v in views])),
            "psnr_imls": float(np.mean([got[v] for v in views]))}


def _front_notes(methods: dict[str, Method], imls_mean: float | None, orp_result, las_ipr: float | None) -> dict[str, str]:
    """How each method's operating point in the main rows is shown on the speed-quality front."""
    at = f"ORP u={imls_mean:.3g}" if imls_mean is not None and orp_result is not None and orp_result.found else "trained u"
    notes = {"full": "every pixel", "recnn": "its pattern", "imls": at, "iml": f"{at} (bound)", "imls_fill": f"IML/S's pixels, {at}",
             "blue_noise": "IML/S's share"}
    if "recnn_sparser" in methods:
        pat = methods["recnn_sparser"].pattern
        notes["recnn_sparser"] = f"{pat.count} pixels ({pat.count / methods['recnn'].pattern.count:.0%} of C)"
    if las_ipr is not None:
        notes["las"] = f"IPR={las_ipr:.3g} (IML/S's)"
    return notes


def _orp_summary(result, s: Settings, lifted: bool = False) -> dict[str, Any]:
    best = result.best
    rec = best.record if best is not None else {}
    return {"found": result.found, "mean": result.mean, "epsilon_db": s.epsilon_db, "gap_db": rec.get("gap_db"),
            "gap_std_db": rec.get("gap_std_db"), "gap_bound_db": rec.get("gap_bound_db"), "views": rec.get("views"),
            "confidence": s.orp_confidence, "future_views": rec.get("future_views"), "where": getattr(result, "where", None),
            "c_share": rec.get("c_share"), "ipr": rec.get("ipr"), "psnr_imls": rec.get("psnr_imls"),
            "psnr_recnn": rec.get("psnr_recnn"), "evaluations": len(result.evaluations), "lift": lifted,
            "points": _points(result), "rescale_points": getattr(result, "rescale_points", None)}


def _equal_share(s: Settings, cache, rows_all, positions, nets: Networks, pattern, device, lift: bool = False) -> list[dict[str, Any]]:
    ims = nets.ims_task.to(device)
    out = []
    with torch.inference_mode():
        for b in _loader(cache, rows_all[positions], pattern):
            out.append(equal_share_rows(b["c"].to(device), b["fr"].to(device), b["view"].to(device), nets.recnn.to(device).eval(),
                                        iml=nets.iml.to(device).eval(), ims_task=ims, blue=None if nets.blue is None else nets.blue.to(device).eval(),
                                        shares=s.shares, pattern=pattern, ims_lift=lift))
    return summarize_equal_share(out)


def sparser_method(renderer, task, opts: NetOptions | None = None) -> RecNNAlone:
    """The RecNN alone on its own sparser pattern (a ``RecNNTask`` from :func:`load_sparser_recnn`): the
    whole sparser pattern ray-cast, then its RecNN."""
    method = RecNNAlone(renderer, task.pattern, task.net, opts)
    method.name = "recnn_sparser"
    return method


def blue_noise_method(renderer, pattern, blue_iml, recnn, share: float, opts: NetOptions | None = None) -> IMLSRenderer:
    """The blue-noise baseline on the product path: the plastic mask ``u > P`` at ``share`` of the
    pattern's pixels (the same for every view; no network picks it), exactly those pixels ray-cast,
    the decoder trained for blue-noise masks, the RecNN."""
    n = pattern.c_size
    valid = pattern.valid.bool()
    P = blue_iml.sampling.P.detach().cpu()
    mask = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P.view(1, 1, n, n), max(share, 1.0 / pattern.count), valid, 1)
    mask = mask.bool()

    def predict_im(view: torch.Tensor) -> torch.Tensor:
        return mask.to(view.device)

    method = IMLSRenderer(renderer, pattern, predict_im, blue_iml.decoder, recnn, opts)
    method.name = "blue_noise"
    return method


class Sweeps:
    """The sweeps of the latency / PSNR plot and the speed-quality front, run view by view.

    IML + RecNN and "IML IM, selectively rendered" at each mean; LAS at each IPR; for the front, IML/S
    + RecNN at each share of ``front_shares`` (the IMS mask of each view brought to that share of C by
    :func:`ims_mask_at_share`, outside the timed stages; the IMS network itself runs in the timed
    importance stage) and blue noise + decoder at each share below 1. :meth:`run_view` measures every
    job on one view; the evaluation calls it right after that view's methods, so every point of the
    front on a view is timed within the same seconds (a load that changes during the run moves them
    together, not apart).
    """

    def __init__(self, s: Settings, methods, nets: Networks, renderer, opts, m: int):
        self.s, self.nets = s, nets
        imls: IMLSRenderer = methods["imls"]  # type: ignore[assignment]
        self.lift = imls.lift
        # the IML/S pipeline rendering another mask than the IMS's (run's im): the IMS still runs, timed
        self.selective = IMLSRenderer(renderer, imls.pattern, imls.mask, nets.ims_task.decoder, nets.recnn, opts)
        jobs: list[tuple[str, str, float, Method | None]] = []
        for u in s.mean_values:
            jobs.append(("iml", "mean", u, IMLPlusRecNN(renderer, imls.pattern, nets.iml, nets.recnn, opts, mean=u)))
            jobs.append(("iml_selective", "mean", u, None))  # runs right after iml, with its mask
        if nets.las_task is not None:
            for ipr in s.las_iprs:
                jobs.append(("las", "ipr", ipr, LASMethod(renderer, nets.las_task.net, m, int(nets.las_task.hparams["low_res"]),
                                                          ipr=ipr, opts=opts)))
        for share in s.front_shares:
            jobs.append(("imls", "share", share, None))  # the selective pipeline, with the IMS mask at this share
            if nets.blue is not None and share < 1.0:
                jobs.append(("blue_noise", "share", share, blue_noise_method(renderer, imls.pattern, nets.blue, nets.recnn, share, opts)))
        self.jobs = jobs

    def run_view(self, p: int, r: int, view: np.ndarray, truth: np.ndarray) -> list[dict[str, Any]]:
        """Every job on the view at trajectory position ``p`` (cache row ``r``): its sweep.csv rows."""
        s, out, iml_im = self.s, [], None
        for name, setting, value, method in self.jobs:
            if name == "iml_selective":
                fields, _, _ = measure(self.selective, view, truth, s.repeats, s.warmup, im=iml_im)
            elif name == "imls" and setting == "share":
                im = ims_mask_at_share(self.nets.ims_task, view, value, lift=self.lift)
                fields, _, _ = measure(self.selective, view, truth, s.repeats, s.warmup, im=im)
            else:
                fields, _, info = measure(method, view, truth, s.repeats, s.warmup)
                if name == "iml":
                    iml_im = info["im"]
            out.append({"view": p, "row": r, "method": name, "setting": setting, "value": value, **fields})
        return out


def ims_mask_at_share(ims_task, view: np.ndarray, share: float, lift: bool = False) -> torch.Tensor:
    """The IMS's mask of ``view`` brought to ``share`` of the pattern's pixels: ``(n, n)`` bool.

    Bisection on the mean value (:func:`~imls_lightning.inference.baselines.mask_at_share`, the
    equal-share protocol) of the IMS output rescaled to each mean (lifted with ``lift``, as the evaluation's);
    ``share = 1`` is the whole pattern. Needs an IMS trained with ``model.target=pim``.
    """
    valid = ims_task.valid.bool().view(ims_task.valid.shape[-2:])
    if share >= 1.0:
        return valid.clone().cpu()
    device = valid.device
    with torch.inference_mode():
        g = ims_task.generator(torch.as_tensor(np.asarray(view, np.float32))[None].to(device)).float()
        im = mask_at_share(lambda u: ims_task.output_to_im_at(g, u.to(device), lift), share, valid, 1)
    return im[0, 0].bool().cpu()


def _options_sweep(s: Settings, renderer, cache, rows_all, positions) -> list[dict[str, Any]]:
    """IML/S with each inference option alone (fresh networks per option); failures are reported."""
    import time

    out = []
    configs = [("baseline", {})] + [(o, {o: True}) for o in s.options_sweep_options]
    for name, kw in configs:
        opts = NetOptions(device=s.options.device, **kw)
        row: dict[str, Any] = {"option": name}
        try:
            method = IMLSRenderer.from_checkpoints(s.ims, renderer=renderer, recnn_checkpoint=s.recnn, opts=opts, mean="trained")
            first = int(rows_all[positions[0]])
            t0 = time.perf_counter()
            method.render(cache.views[first])  # first call: pays torch.compile's compilation
            row["first_call_s"] = time.perf_counter() - t0
            fields = []
            for p in positions:
                r = int(rows_all[p])
                f, _, _ = measure(method, np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r]), s.repeats, max(s.warmup, 1))
                fields.append(f)
            for k in ("importance_ms", "selective_render_ms", "decoder_ms", "recnn_ms", "total_ms", "psnr"):
                row[k] = float(np.mean([f.get(k, math.nan) for f in fields]))
            row["networks_ms"] = row["importance_ms"] + row["decoder_ms"] + row["recnn_ms"]
        except InputError:
            raise
        except Exception as err:  # e.g. torch.compile without a working C++ toolchain: report it
            row["error"] = f"{type(err).__name__}: {str(err).splitlines()[0][:160] if str(err) else ''}"
        out.append(row)
    return out


@checked_command_line(Path(__file__).resolve().parents[1] / "conf")
@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
@cli_errors
def main(cfg: DictConfig) -> None:
    path = evaluate(cfg)
    print(path, flush=True)


if __name__ == "__main__":
    main()
