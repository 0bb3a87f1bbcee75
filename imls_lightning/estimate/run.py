"""``run_estimate(cfg)``: measure a scene before any training and write ``estimate.json``.

The output directory is named by a hash of everything that decides the numbers (scene, renderer,
pattern, resolution, network sizes, views, options); a finished estimate with the same settings and
a readable ``estimate.json`` is reused, anything else is measured again.
"""
from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.atomic import atomic_json, atomic_write
from data_gen.cache_keys import jsonable, settings_hash
from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_number
from imls_lightning.render import without_neutral_keys
from data_gen.views import camera_distance

from ..core.patterns import build_pattern
from ..inference.pipeline import NetOptions
from ..report.machine import BUSY_LIMIT, OtherLoad, busy_cores, shared_cores_warning
from .bound import SHARES, bound_intervals, bound_table, share_for_speedup, sharpness_key, slower_render, speedup_at
from .measure import (RecNNLead, build_networks, frame_subset, mean_c_render_ms, measure_view, network_ms, recnn_lead,
                      render_cost, render_curves, upsample_c_image, upsampler_name)
from .needed_share import NeededShare, needed_share

RESULT = "estimate.json"
#: the goal of issue 31 per pattern kind: 2x for super-resolution, 1.5x for foveated rendering
DEFAULT_TARGETS = {"downsample": 2.0, "foveal": 1.5}
def _busiest(est: Mapping[str, Any]) -> float | None:
    """The most cores other jobs kept busy around an estimate's timing: before it (``busy_cores``) or during it
    (``timing_busy_cores``, the other processes only; estimates before it have just the first).

    Example:
        >>> _busiest({"busy_cores": 0.02, "timing_busy_cores": 0.9}), _busiest({"busy_cores": 0.3}), _busiest({})
        (0.9, 0.3, None)
    """
    known = [float(v) for v in (est.get("busy_cores"), est.get("timing_busy_cores")) if v is not None]
    return max(known) if known else None


def _say(msg: str) -> None:
    print(f"[estimate] {msg}", file=sys.stderr, flush=True)


def _command_line_keys() -> set[str]:
    """The keys set on the command line (empty outside a Hydra run)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return set()
    return {str(o).split("=", 1)[0].lstrip("+~") for o in HydraConfig.get().overrides.task}


def recnn_net(cfg: DictConfig) -> dict[str, Any]:
    """The RecNN's ``net`` node with the sizes ``recnn_sizes.<recnn.name>`` put over its defaults; a
    ``recnn.net.<key>=...`` given on the command line wins over both."""
    net = OmegaConf.to_container(cfg.recnn.net, resolve=True)
    sizes = OmegaConf.to_container(OmegaConf.create(dict((cfg.get("recnn_sizes") or {}).get(str(cfg.recnn.name)) or {})),
                                   resolve=True)
    explicit = {k[len("recnn.net."):] for k in _command_line_keys() if k.startswith("recnn.net.")}
    return {**net, **{k: v for k, v in sizes.items() if k not in explicit}}


def background_density(cfg: DictConfig) -> float:
    """The mask's density on the background relative to the object's: ``cfg.background_density``, a number, or an
    evaluation of trained networks (its ``summary.json``, or the folder holding it, e.g. a committed row's
    ``benchmarks/rows/<name>/point``) whose ``mask_density`` measured it at its operating point.

    Raises:
        InputError: a number outside (0, 1], or an evaluation whose summary is unreadable or has no mask density.
    """
    value = cfg.get("background_density", 0.25)
    if isinstance(value, str):
        path = Path(value).expanduser()
        path = path / "summary.json" if path.is_dir() else path
        try:
            md = json.loads(path.read_text(encoding="utf-8")).get("mask_density") or {}
            return check_number(float(md["background_density"]) / max(float(md["object_density"]), 1e-6),
                                "background_density", 0.0, 1.0, lo_open=True)
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            raise InputError(f"background_density={value}: expected a number in (0, 1] or an evaluation's summary.json "
                             "(or its folder) with a mask_density (python -m imls_lightning.evaluate writes it)") from None
    return check_number(value, "background_density", 0.0, 1.0, lo_open=True,
                        what="a density relative to the object's in (0, 1], or an evaluation's summary.json")


def estimate_settings(cfg: DictConfig, volume_fingerprint: str | None = None) -> dict[str, Any]:
    """What decides the numbers (hashed into the output directory's name). ``volume_fingerprint``: the
    volume's content (:meth:`~imls_lightning.render.volume.Volume.fingerprint`), so that a volume replaced at the same
    path, or a procedural generator that changed, is measured again instead of reusing its old estimate."""
    scene = OmegaConf.to_container(cfg.scene, resolve=True)
    return jsonable({
        "scene": scene, "volume": volume_fingerprint, "recnn_lead": _lead_settings(cfg),
        "renderer": without_neutral_keys(OmegaConf.to_container(cfg.renderer, resolve=True)),
        "pattern": OmegaConf.to_container(cfg.pattern, resolve=True), "resolution": int(cfg.resolution),
        "recnn": recnn_net(cfg), "iml": OmegaConf.to_container(cfg.iml, resolve=True),
        "ims": OmegaConf.to_container(cfg.ims, resolve=True),
        "candidates": OmegaConf.to_container(cfg.get("candidates") or OmegaConf.create([]), resolve=True), "views": int(cfg.views), "seed": int(cfg.seed),
        # the full frames on a subset of the views (one untimed cast first, no FR render on the others)
        "frame_views": min(check_integer(cfg.get("frame_views", cfg.views), "frame_views", 1),
                           check_integer(cfg.views, "views", 1)),
        "repeats": int(cfg.repeats), "options": OmegaConf.to_container(cfg.options, resolve=True),
        "background_density": background_density(cfg), "target": cfg.target,
        "needed_share": bool(cfg.get("needed_share", True)), "epsilon_db": cfg.get("epsilon_db", 1.0),
        "silhouette_blur": cfg.get("silhouette_blur", 4.0), "render_bound": "slower of silhouette (each view a fraction of its pattern) and per-pixel model",
        "ims_timing": "the product's mask head: sharpened, rescaled, lifted",
        "network_timing": "each call after a ray cast", "view_distances": "stratified",
        # renders averaged over the views on each one's own pattern (was: the median view's); the needed share's too
        "render_over_views": "mean, each view's fractions of its own pattern",
        "mask_repeats": check_integer(cfg.get("mask_repeats", 1), "mask_repeats", 1),
        # the needed share's masks ray-cast only around it (its gaps need no ray cast)
        "needed_renders": "the two shares around the needed share",
        "curves": "every sharpness in one pass per view, a pixel set cast once",
        # only when set: the paper's masks alone hash as they did before the key
        **({"sharpness": _sharpness(cfg)} if _sharpness(cfg) != [1.0] else {}),
        # the other ray caster timed too (the bound against the fastest RecNN alone); off: hashes as before the key
        **({"both_ray_casters": True} if bool(cfg.get("both_ray_casters", True)) else {}),
    })


def read_estimate(path: Path, settings: Mapping[str, Any] | None = None) -> dict[str, Any] | None:
    """The content of an ``estimate.json`` if it is whole (every key of the contract) and, when
    ``settings`` is given, made with them; ``None`` otherwise."""
    try:
        est = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    keys = ("c_render_ms", "nets_ms", "recnn_ms", "bilinear_db", "bound", "share_for_2x", "render_cost", "render_curve",
            "settings")
    if not isinstance(est, dict) or any(k not in est for k in keys) or len(est["bound"]) != 10:
        return None
    if settings is not None and est["settings"] != jsonable(settings):
        return None
    return est


def write_contact_sheet(views, path: Path, thumb: int = 256) -> Path:
    """Per view: the FR render, the classical upsampling of its C-Image and their difference (x4)."""
    from PIL import Image

    rows = []
    for v in views:
        err = np.clip(np.abs(v.fr.astype(np.int16) - v.upsampled.astype(np.int16)) * 4, 0, 255).astype(np.uint8)
        tiles = [Image.fromarray(a).resize((thumb, thumb), Image.LANCZOS) for a in (v.fr, v.upsampled, err)]
        rows.append(np.concatenate([np.asarray(t) for t in tiles], axis=1))
    sheet = Image.fromarray(np.concatenate(rows, axis=0))
    return atomic_write(path, lambda f: sheet.save(f, format="PNG"))


def _lead_settings(cfg: DictConfig) -> dict[str, Any]:
    """``recnn_lead`` checked: ``steps`` 0 (off) or more, ``train_views`` and ``crop`` at least 1, ``lr`` > 0."""
    lead = OmegaConf.to_container(cfg.get("recnn_lead") or OmegaConf.create({}), resolve=True)
    out = {"steps": check_integer(lead.get("steps", 0), "recnn_lead.steps", 0),
           "train_views": check_integer(lead.get("train_views", 8), "recnn_lead.train_views", 1),
           "crop": check_integer(lead.get("crop", 128), "recnn_lead.crop", 1),
           "batch": check_integer(lead.get("batch", 8), "recnn_lead.batch", 1)}
    try:
        out["lr"] = float(lead.get("lr", 1e-3))
        if not out["lr"] > 0:
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"recnn_lead.lr={lead.get('lr')!r}: expected a positive learning rate") from None
    return out if out["steps"] else {"steps": 0}  # off: the other keys change no number


def _blur(cfg: DictConfig) -> float:
    """``silhouette_blur``: a number >= 0 of C-pixels (a one-line error otherwise)."""
    return check_number(cfg.get("silhouette_blur", 4.0), "silhouette_blur", 0.0,
                        what="a blur radius >= 0 in C-pixels (the smoothness of a trained IMS's mask)")


def _sharpness(cfg: DictConfig) -> list[float]:
    """``sharpness``: the IMS mask sharpnesses (a number or a list, each in [1, 8]) whose masks get a render curve of
    their own; sorted, 1 (the paper's masks) always among them."""
    from ..core.importance import check_sharpnesses

    raw = cfg.get("sharpness", [1.0])
    raw = OmegaConf.to_container(raw, resolve=True) if OmegaConf.is_config(raw) else raw
    return sorted({1.0, *check_sharpnesses(raw, "sharpness")})


def _target(cfg: DictConfig, pattern) -> float:
    t = cfg.get("target")
    if t is None:
        return DEFAULT_TARGETS.get(pattern.kind, 2.0)
    try:
        t = float(t)
        if not t > 1.0:
            raise ValueError
    except (TypeError, ValueError):
        raise InputError(f"target={cfg.get('target')!r}: expected a speed-up > 1 (null: 2 for EnhanceNet, 1.5 for FoVolNet)") from None
    return t


def estimate_views(scene, count: int, seed: int) -> list:
    """The estimate's views of ``scene``: random, as training views are drawn (another seed: never the test
    trajectory), their camera distances stratified, one per slice of ``scene.camera_distance``."""
    from data_gen.views import sample_training_views

    return sample_training_views(count, scene.camera_distance, seed=seed, lookat_jitter=0.1, stratify_distance=True)


def measure(cfg: DictConfig, out_dir: Path, scene=None) -> dict[str, Any]:
    """Run every measurement and return the estimate's content (also writes the contact sheet).
    ``scene``: the built scene (built here from ``cfg.scene`` when None)."""
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene, register_resolvers

    register_resolvers()
    n_views = check_integer(cfg.views, "views", 1)
    n_frames = check_integer(cfg.get("frame_views", n_views), "frame_views", 1)
    lead_cfg = _lead_settings(cfg)
    check_number(cfg.get("epsilon_db", 1.0), "epsilon_db", 0.0, lo_open=True, what="a positive PSNR tolerance in dB")
    repeats = check_integer(cfg.repeats, "repeats", 1)
    warmup = check_integer(cfg.warmup, "warmup", 0)
    mask_repeats = check_integer(cfg.get("mask_repeats", 1), "mask_repeats", 1)
    opts = NetOptions.from_config(OmegaConf.to_container(cfg.options, resolve=True))  # half: auto measured here
    t_start = time.perf_counter()
    scene = scene if scene is not None else build_scene(cfg.scene)
    pattern = build_pattern(cfg.pattern, int(cfg.resolution))
    target = _target(cfg, pattern)
    cands = check_candidates(cfg)  # before any render
    sharpnesses = _sharpness(cfg)
    blur = _blur(cfg)
    nets = build_networks(pattern, recnn_net(cfg), cfg.iml, cfg.ims)  # bad sizes fail before any render
    renderer = make_renderer(scene, cfg.renderer)
    # random views as the training views are drawn (another seed): never the test trajectory
    # distances stratified: a view's cost and object size follow its distance, and a few independent draws can
    # miss a part of the range (flame_whole: one view's mask pixels cost 0.36-0.66 of its pattern at the same share)
    views = estimate_views(scene, n_views, int(cfg.seed))
    # the quality half (full frames: bilinear PSNR, contact sheet, needed share) on a subset spread over the distances;
    # every view times the pattern (the speed-up's variance is the views')
    framed = set(frame_subset([camera_distance(v) for v in views], n_frames))
    # one untimed ray cast before any timing: numba compiles and the volume's pages load on the first call
    renderer.render_pixels(views[0], pattern.fr_size, pattern.indices.numpy())
    measured = []
    for i, view in enumerate(views):
        measured.append(measure_view(renderer, pattern, view, scene.background, repeats, warmup, full_frame=i in framed))
        v = measured[-1]
        quality = (f"frame {v.full_ms:.0f} ms, bilinear {v.bilinear_db:.2f} dB, " if v.fr is not None else "")
        _say(f"view {i + 1}/{n_views}: {quality}C pattern {v.c_render_ms:.1f} ms, "
             f"object {v.object_px / max(v.object_px + v.background_px, 1):.0%} of C ({time.perf_counter() - t_start:.0f} s)")
    frames = [v for v in measured if v.fr is not None]
    framed_views = [view for i, view in enumerate(views) if i in framed]
    # the IMS's stage as the product runs it at a lifted ORP: sharpened (the largest sharpness asked), rescaled, lifted
    cast = ray_cast_between(renderer, pattern, views[0])
    nets_t = network_ms(nets, pattern, opts, repeats=max(repeats, 10), warmup=max(warmup, 2), sharpness=max(sharpnesses),
                        before=cast)
    model = render_cost(measured)
    c_render_ms = mean_c_render_ms(measured)  # the mean, as the render curves and a row's speed-up average views
    nets_ms = nets_t["ims_ms"] + nets_t["decoder_ms"]
    density = background_density(cfg)
    # the render of exactly the pixels of a mask of a trained IMS's shape at each share, and the per-pixel model:
    # the bound takes the slower at each share (each misses a cost the other sees; bound.slower_render)
    fractions_by: dict[float, list[list[float]]] = {}
    curves = render_curves(renderer, pattern, views, measured, SHARES, blur=blur, floor=density, repeats=mask_repeats,
                           fixed_ms=model.fixed_ms, sharpnesses=sharpnesses, progress=_say, per_view=fractions_by)
    silhouette, fractions = curves[1.0], fractions_by[1.0]
    cost = slower_render(silhouette, model, density)
    by_sharpness = {sharpness_key(g): sharpened_bound(g, curves[g], fractions_by[g], model, density, c_render_ms, nets_ms,
                                                      nets_t["recnn_ms"], target)
                    for g in sharpnesses if g != 1.0}
    table = bound_table(cost, c_render_ms=c_render_ms, nets_ms=nets_ms, recnn_ms=nets_t["recnn_ms"])
    modelled = bound_table(model, c_render_ms=c_render_ms, nets_ms=nets_ms, recnn_ms=nets_t["recnn_ms"],
                           background_density=density)
    silhouette_table = bound_table(silhouette, c_render_ms=c_render_ms, nets_ms=nets_ms, recnn_ms=nets_t["recnn_ms"])
    sheet = write_contact_sheet(frames, out_dir / "contact_sheet.png")
    train_frames = lead_frames(cfg, lead_cfg, renderer, pattern, scene)
    eval_frames = [v.fr for v in frames]
    candidates = candidate_rows(cfg, cands, pattern, opts, cost, c_render_ms, target, density, repeats, warmup,
                                sharpness=max(sharpnesses), before=cast,
                                lead=lambda net, label: measure_lead(cfg, lead_cfg, net, pattern, train_frames,
                                                                     eval_frames, opts, label))
    lead = measure_lead(cfg, lead_cfg, recnn_net(cfg), pattern, train_frames, eval_frames, opts)
    needed = measure_needed_share(cfg, lead, renderer, pattern, framed_views, frames, mask_repeats)
    alone = c_render_ms + nets_t["recnn_ms"]
    fastest = both_ray_casters(cfg, scene, renderer, pattern, views, measured, model, cost, c_render_ms, nets_ms,
                               nets_t["recnn_ms"], needed, blur, density, mask_repeats)
    return {
        "ray_casters": fastest,
        "candidates": candidates, "recnn_lead": lead.to_dict() if lead else None,
        "needed": needed.to_dict() if needed else None,
        "needed_share": needed.needed_share if needed else None,
        # the speed-up at the needed share: the render of exactly the untrained mask's pixels, and the bound's model
        "speedup_at_needed": (alone / (nets_ms + needed.render_at(needed.needed_share) + nets_t["recnn_ms"])
                              if needed and needed.needed_share is not None else None),
        "bound_at_needed": (speedup_at(cost, needed.needed_share, c_render_ms=c_render_ms, nets_ms=nets_ms,
                                       recnn_ms=nets_t["recnn_ms"])
                            if needed and needed.needed_share is not None else None),
        "scene": scene.name, "volume_dims": "x".join(str(d) for d in scene.volume.dims),
        "recnn": str(cfg.recnn.name), "pattern": pattern.kind, "fr_size": pattern.fr_size, "c_size": pattern.c_size,
        "c_render_ms": c_render_ms, "full_frame_ms": float(np.median([v.full_ms for v in frames])),
        "nets_ms": nets_ms, "ims_ms": nets_t["ims_ms"], "decoder_ms": nets_t["decoder_ms"], "recnn_ms": nets_t["recnn_ms"],
        "render_to_nets": c_render_ms / nets_ms, "bilinear_db": float(np.mean([v.bilinear_db for v in frames])),
        # the views whose full frame was rendered (frame_views of them), in per_view's order
        "bilinear_db_per_view": [v.bilinear_db for v in frames], "frame_view_indices": sorted(framed),
        # each view's own: what the medians and means above are taken over (a mask's cost at one share differs by
        # up to 2x between views); silhouette_fractions: each share's silhouette render over that view's pattern
        "per_view": [{"camera_distance": camera_distance(view), "c_render_ms": v.c_render_ms,
                      "full_ms": v.full_ms, "object_fraction": v.object_px / max(v.object_px + v.background_px, 1),
                      "silhouette_fractions": f} for view, v, f in zip(views, measured, fractions)],
        "upsampler": upsampler_name(pattern),
        "object_fraction": model.object_fraction, "render_cost": model.to_dict(),
        "modelled_c_render_ms": model.render_ms(1.0, density), "background_density": density,
        "render_curve": cost.to_dict(), "silhouette_ms": list(silhouette.times_ms), "silhouette_blur": blur,
        "bound": [{"share": r["share"], "speedup": r["speedup"]} for r in table],
        "bound_modelled": [{"share": r["share"], "speedup": r["speedup"]} for r in modelled],
        "bound_silhouette": [{"share": r["share"], "speedup": r["speedup"]} for r in silhouette_table],
        "limit": [{"share": r["share"], "speedup": r["limit"]} for r in table],
        # a render curve per IMS mask sharpness (conf/evaluate.yaml ims_sharpness): a sharpened mask keeps the
        # object's dear rays and drops the cheap floor, so its pixels cost more each
        "by_sharpness": by_sharpness,
        "target": target, "share_for_target": share_for_speedup(table, target),
        "share_for_2x": share_for_speedup(table, 2.0), "share_for_1_5x": share_for_speedup(table, 1.5),
        "contact_sheet": str(sheet), "seconds": time.perf_counter() - t_start,
        "options": {"half": opts.half, "channels_last": opts.channels_last, "compile": opts.compile, "device": opts.device},
    }


def both_ray_casters(cfg: DictConfig, scene, renderer, pattern, views, measured, model, cost, c_render_ms: float,
                     nets_ms: float, recnn_ms: float, needed, blur: float, density: float, repeats: int) -> dict[str, Any] | None:
    """The bound on both ray casters and against the fastest RecNN alone (``both_ray_casters``, default true;
    :mod:`.ray_casters`); None when off or when the renderer has no empty-space skipping switch."""
    from imls_lightning.render import make_renderer

    from .ray_casters import fastest_bounds, other_ray_caster_curve

    if not bool(cfg.get("both_ray_casters", True)) or not hasattr(renderer, "skip_empty"):
        return None
    other = make_renderer(scene, {**OmegaConf.to_container(cfg.renderer, resolve=True), "skip_empty": not renderer.skip_empty})
    _say(f"the other ray caster (empty-space skipping {'off' if renderer.skip_empty else 'on'}): the same views and masks")
    other_c, other_curve = other_ray_caster_curve(other, pattern, views, measured, SHARES, blur=blur, floor=density,
                                                  repeats=repeats, fixed_ms=model.fixed_ms, progress=_say)
    share = needed.needed_share if needed is not None else None
    return fastest_bounds(bool(renderer.skip_empty), c_render_ms, cost, other_c, other_curve, nets_ms=nets_ms,
                          recnn_ms=recnn_ms, shares=SHARES, needed_share=share,
                          needed_render_ms=needed.render_at(share) if share is not None else None)


def add_intervals(est: dict[str, Any]) -> dict[str, Any]:
    """``bound_interval`` in ``est`` and in each sharpness of its ``by_sharpness``: the bound's 95% interval at every
    share over the estimate's views resampled (:func:`~.bound.bound_intervals`; None without per-view times)."""
    est["bound_interval"] = bound_intervals(est)
    for key, b in (est.get("by_sharpness") or {}).items():
        b["bound_interval"] = bound_intervals(est, float(key))
    return est


def ray_cast_between(renderer, pattern, view, stride: int = 8):
    """What the product runs between two network calls, for :func:`~.measure.network_ms`'s ``before``: a ray cast, of
    every ``stride``-th pixel of the pattern of ``view`` (the volume's data pass through the caches, as in the
    product, at an eighth of the pattern's time)."""
    pix = pattern.indices.numpy()[::stride].copy()

    def cast() -> None:
        renderer.render_pixels(view, pattern.fr_size, pix)
    return cast


def sharpened_bound(gamma: float, curve, fractions: list[list[float]], model, density: float, c_render_ms: float,
                    nets_ms: float, recnn_ms: float, target: float) -> dict[str, Any]:
    """The bound of masks sharpened by ``gamma``: ``curve``, the silhouette mask sharpened as the IMS's head sharpens
    its own, rendered at each share (:func:`~.measure.render_curves`, ``fractions`` its views' own), against the
    per-pixel model whose background density falls to ``density ** gamma`` (the floor's importance ratio to the
    object's, raised to ``gamma``); the slower render at each share."""
    cost = slower_render(curve, model, density ** gamma)
    table = bound_table(cost, c_render_ms=c_render_ms, nets_ms=nets_ms, recnn_ms=recnn_ms)
    return {"sharpness": float(gamma), "render_curve": cost.to_dict(), "silhouette_ms": list(curve.times_ms),
            "silhouette_fractions_per_view": fractions,
            "background_density": density ** gamma,
            "bound": [{"share": r["share"], "speedup": r["speedup"]} for r in table],
            "share_for_2x": share_for_speedup(table, 2.0), "share_for_target": share_for_speedup(table, target)}


def lead_frames(cfg: DictConfig, lead_cfg: Mapping[str, Any], renderer, pattern, scene) -> list[np.ndarray] | None:
    """The quick RecNN's training frames: ``recnn_lead.train_views`` more random views (another seed than the
    estimate's), rendered once for every size trained on them; None when ``recnn_lead`` is off."""
    from data_gen.views import sample_training_views

    if not lead_cfg["steps"]:
        return None
    views = sample_training_views(lead_cfg["train_views"], scene.camera_distance, seed=int(cfg.seed) + 1, lookat_jitter=0.1)
    frames = []
    for i, view in enumerate(views):
        frames.append(renderer.render(view, pattern.fr_size))
        _say(f"RecNN lead: training view {i + 1}/{len(views)} rendered")
    return frames


def measure_lead(cfg: DictConfig, lead_cfg: Mapping[str, Any], net: Mapping[str, Any], pattern, frames: list | None,
                 eval_frames: list, opts: NetOptions, label: str = "RecNN lead") -> RecNNLead | None:
    """Issue 31's third bar, before any cache: a RecNN of the sizes ``net`` (the ``recnn.net`` node) trained
    ``recnn_lead.steps`` steps on ``frames`` (:func:`lead_frames`), scored on the estimate's views; None when off.
    Every size starts from the same seed, so a candidate of the chosen sizes gets the chosen lead."""
    if frames is None:
        return None
    seed = int(cfg.seed)
    torch.manual_seed(seed)  # the RecNN's initial weights
    recnn = build_networks(pattern, net, cfg.iml, cfg.ims)["recnn"]
    lead = recnn_lead(recnn, pattern, frames, eval_frames, lead_cfg["steps"], crop=lead_cfg["crop"],
                      batch=lead_cfg["batch"], lr=lead_cfg["lr"], seed=seed, device=opts.device)
    _say(f"{label}: {lead.steps} steps on {lead.train_views} views in {lead.seconds:.0f} s: {lead.recnn_db:.2f} dB, "
         f"{lead.lead_db:+.2f} dB over {lead.upsampled_db:.2f} dB")
    return lead


def measure_needed_share(cfg: DictConfig, lead: RecNNLead | None, renderer, pattern, views, measured,
                         mask_repeats: int = 1) -> NeededShare | None:
    """The share of C the scene needs within ``epsilon_db``, from an untrained importance and fill
    (:mod:`.needed_share`), rebuilt by the quick RecNN when ``recnn_lead`` trained one, else by the classical
    upsampling; None when ``needed_share=false``."""
    if not cfg.get("needed_share", True):
        return None
    if lead is not None and lead.net is not None:
        net = lead.net
        dev = next(net.parameters()).device

        def rebuild(c):
            return net(c.to(dev)).float().cpu()
        name = f"recnn ({lead.steps} steps)"
    else:
        def rebuild(c):
            return upsample_c_image(c, pattern)[0]
        name = upsampler_name(pattern)
    # 20 masks on every view, each rendered mask_repeats times (no warm-up: the renderer is warm)
    ns = needed_share(rebuild, name, pattern, renderer, views, [v.fr for v in measured],
                      epsilon_db=cfg.get("epsilon_db", 1.0), floor=background_density(cfg),
                      repeats=mask_repeats, warmup=0, seed=int(cfg.seed), progress=_say,
                      c_render_ms=[v.c_render_ms for v in measured])
    where = f"{ns.needed_share:.0%} of C" if ns.needed_share is not None else "no share"
    _say(f"needed share: an untrained importance mask and fill, rebuilt by the {name}, stay within "
         f"{ns.epsilon_db:g} dB at {where} ({ns.seconds:.0f} s)")
    return ns


def check_candidates(cfg: DictConfig) -> list[dict[str, Any]]:
    """``candidates`` as a list of non-empty mappings (a one-line error otherwise)."""
    cands = OmegaConf.to_container(cfg.get("candidates") or OmegaConf.create([]), resolve=True)
    if not isinstance(cands, list):
        raise InputError(f"candidates={cands!r}: expected a list of mappings of sizes, e.g. [{{channels: 8, blocks: 2}}]")
    for i, cand in enumerate(cands):
        if not isinstance(cand, dict) or not cand:
            raise InputError(f"candidates[{i}]={cand!r}: expected a mapping of sizes, e.g. {{channels: 8, blocks: 2}}")
    return cands


def candidate_rows(cfg: DictConfig, cands: list[dict[str, Any]], pattern, opts: NetOptions, cost, c_render_ms: float,
                   target: float, density: float, repeats: int, warmup: int, sharpness: float = 1.0,
                   before=None, lead=None) -> list[dict[str, Any]]:
    """The size table ("model only what a scene requires"): for each entry of ``candidates`` (a mapping of sizes put
    over the RecNN's ``net``; ``iml.*`` / ``ims.*`` keys size those networks), the networks' times and the bound, on
    the render costs measured once; timed as the chosen sizes are (``sharpness`` and ``before``:
    :func:`~.measure.network_ms`). Its quality half: ``lead(net, label)``, when given, trains that size's quick RecNN
    (:func:`measure_lead`; ``recnn_lead`` None when off) on the same frames as the chosen size's."""
    rows = []
    for cand in cands:
        iml = {**OmegaConf.to_container(cfg.iml, resolve=True), **{k[4:]: v for k, v in cand.items() if k.startswith("iml.")}}
        ims = {**OmegaConf.to_container(cfg.ims, resolve=True), **{k[4:]: v for k, v in cand.items() if k.startswith("ims.")}}
        net = {**recnn_net(cfg), **{k: v for k, v in cand.items() if not k.startswith(("iml.", "ims."))}}
        t = network_ms(build_networks(pattern, net, iml, ims), pattern, opts, repeats=max(repeats, 10), warmup=max(warmup, 2),
                       sharpness=sharpness, before=before)
        nets_ms = t["ims_ms"] + t["decoder_ms"]
        table = bound_table(cost, c_render_ms=c_render_ms, nets_ms=nets_ms, recnn_ms=t["recnn_ms"], background_density=density)
        quick = lead(net, f"candidate {cand}: RecNN lead") if lead is not None else None
        rows.append({"sizes": cand, **t, "nets_ms": nets_ms, "bound_20": table[1]["speedup"],
                     "share_for_target": share_for_speedup(table, target),
                     "recnn_lead": quick.to_dict() if quick else None})
        _say(f"candidate {cand}: RecNN {t['recnn_ms']:.1f} ms, networks IML/S adds {nets_ms:.1f} ms, "
             f"bound at 20% of C {table[1]['speedup']:.2f}x")
    return rows


def format_report(est: Mapping[str, Any]) -> str:
    """The estimate as a few lines of text (stdout)."""
    lines = [
        f"{est['scene']} ({est['volume_dims']} voxels), {est['recnn']} on the {est['pattern']} pattern, "
        f"{est['fr_size']}^2 FR / {est['c_size']}^2 C",
        f"  full frame {est['full_frame_ms']:.0f} ms; C pattern {est['c_render_ms']:.1f} ms "
        f"({est['object_fraction']:.0%} of it on the object); {est['upsampler']} C->FR {est['bilinear_db']:.2f} dB",
        f"  networks IML/S adds {est['nets_ms']:.1f} ms (IMS {est['ims_ms']:.1f}, decoder {est['decoder_ms']:.1f}); "
        f"RecNN {est['recnn_ms']:.1f} ms; render / networks = {est['render_to_nets']:.1f}x",
        "  share of C   " + " ".join(f"{r['share']:>5.0%}" for r in est["bound"]),
        "  speed-up     " + " ".join(f"{r['speedup']:>5.2f}" for r in est["bound"]),
        "  no networks  " + " ".join(f"{r['speedup']:>5.2f}" for r in est["limit"]),
    ]
    if est.get("bound_modelled") and est.get("bound_silhouette"):  # the speed-up row is the slower render of these two
        lines.append("  silhouette   " + " ".join(f"{r['speedup']:>5.2f}" for r in est["bound_silhouette"])
                     + "  (a mask of the trained IMS's shape, rendered)")
        lines.append("  per-px model " + " ".join(f"{r['speedup']:>5.2f}" for r in est["bound_modelled"])
                     + "  (object first, mean background cost); the speed-up takes the slower render")
    for key, b in sorted((est.get("by_sharpness") or {}).items(), key=lambda kv: float(kv[0])):
        lines.append(f"  γ = {key:<9}" + " ".join(f"{r['speedup']:>5.2f}" for r in b["bound"])
                     + "  (the mask sharpened: its pixels are the dearer object's)")
    if est.get("bound_interval"):  # how far the views drawn move it: a narrow pass needs more views
        lines.append(f"  the speed-up's 95% interval over the {len(est.get('per_view') or [])} views resampled: "
                     + ", ".join(f"{r['low']:.2f}-{r['high']:.2f}x at {r['share']:.0%}" for r in est["bound_interval"][1:5])
                     + " of C")
    lead = est.get("recnn_lead")
    if lead:
        lines.append(f"  a RecNN trained {lead['steps']} steps on {lead['train_views']} views: {lead['recnn_db']:.2f} dB, "
                     f"{lead['lead_db']:+.2f} dB over {est['upsampler']} (the paper regime asks +2 dB of the trained RecNN)")
    need = est.get("needed")
    if need:
        rows = need["rows"]
        lines.append(f"  untrained importance + fill, rebuilt by the {need['reference']}: gap to it (dB) at")
        lines.append("  share of C   " + " ".join(f"{r['kept']:>5.0%}" for r in rows[1::2]))
        lines.append("  gap (dB)     " + " ".join(f"{r['gap_db']:>5.2f}" for r in rows[1::2]))
        lines.append("  render (ms)  " + " ".join(f"{r['render_ms']:>5.0f}" if r["render_ms"] is not None else f"{'-':>5}"
                                              for r in rows[1::2])
                     + "  (-: not ray-cast; the masks around the needed share are)")
        if est.get("needed_share") is not None:
            lines.append(f"  needed share within {need['epsilon_db']:g} dB: {est['needed_share']:.0%} of C, where IML/S "
                         f"would run at {est['speedup_at_needed']:.2f}x (rendering exactly those pixels; a mask of the "
                         f"trained IMS's shape, the bound, {est['bound_at_needed']:.2f}x)")
        else:
            lines.append(f"  no share keeps {need['epsilon_db']:g} dB")
    for c in est.get("candidates") or []:
        reach = f"up to {c['share_for_target']:.0%} of C" if c["share_for_target"] is not None else "nowhere"
        quick = c.get("recnn_lead")
        lines.append(f"  sizes {c['sizes']}: RecNN {c['recnn_ms']:.1f} ms, IML/S adds {c['nets_ms']:.1f} ms, "
                     f"{c['bound_20']:.2f}x at 20% of C, {est['target']:g}x {reach}"
                     + (f"; its quick RecNN {quick['recnn_db']:.2f} dB, {quick['lead_db']:+.2f} dB over "
                        f"{est['upsampler']}" if quick else ""))
    from .ray_casters import report_lines

    lines += report_lines(est)
    s = est["share_for_target"]
    lines.append(f"  {est['target']:g}x is reachable up to {s:.0%} of C" if s is not None else
                 f"  {est['target']:g}x is out of reach at any share of C (best {est['bound'][0]['speedup']:.2f}x at 10%)")
    return "\n".join(lines)


#: the columns of the estimates table (``table=...``): one row per (scene, RecNN), the newest estimate
TABLE_COLUMNS = ("scene", "recnn", "volume_dims", "full_frame_ms", "c_render_ms", "object_fraction", "ims_ms", "decoder_ms",
                 "nets_ms", "recnn_ms", "render_to_nets", "bilinear_db", "half", "bound_10", "bound_20", "bound_40",
                 "limit_20", "target", "share_for_target", "recnn_lead_db", "needed_share", "speedup_at_needed",
                 "seconds", "path",
                 # against the fastest RecNN alone (both_ray_casters): the other ray caster's pattern, the bound at the
                 # needed share, the best share, and the same with the IMS and decoder free (issue 84's scene-by-scene bound)
                 "c_render_noskip_ms", "vs_fastest_at_needed", "vs_fastest_best", "vs_fastest_best_share",
                 "free_networks_vs_fastest_at_needed", "free_networks_vs_fastest_best")


def _sig(v: Any) -> Any:
    """A float to four significant digits (anything else as it is)."""
    return float(f"{v:.4g}") if isinstance(v, float) else v


def table_row(est: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """The estimate as a row of :data:`TABLE_COLUMNS`."""
    bound = {round(r["share"], 1): r["speedup"] for r in est["bound"]}
    limit = {round(r["share"], 1): r["speedup"] for r in est["limit"]}
    # four significant digits: the timings are medians of a few runs, and the table is read by people
    row = {k: _sig(est.get(k, "")) for k in TABLE_COLUMNS}
    row.update(half=est["options"]["half"], bound_10=_sig(bound[0.1]), bound_20=_sig(bound[0.2]), bound_40=_sig(bound[0.4]),
               limit_20=_sig(limit[0.2]), recnn_lead_db=_sig((est.get("recnn_lead") or {}).get("lead_db", "")),
               share_for_target=est["share_for_target"] if est["share_for_target"] is not None else "", path=str(path),
               needed_share=_sig(est.get("needed_share")) if est.get("needed_share") is not None else "",
               speedup_at_needed=_sig(est.get("speedup_at_needed")) if est.get("speedup_at_needed") is not None else "")
    row.update(fastest_columns(est))
    return row


def fastest_columns(est: Mapping[str, Any]) -> dict[str, Any]:
    """The estimate against the fastest RecNN alone as table columns (empty without ``ray_casters``)."""
    rc = est.get("ray_casters") or {}
    if not rc:
        return {}
    vs, free = rc["vs_fastest"], rc["free_networks_vs_fastest"]
    best = max(vs, key=lambda r: r["speedup"])
    need = est.get("needed_share")
    at = lambda curve: _sig(float(np.interp(need, [r["share"] for r in curve], [r["speedup"] for r in curve])))  # noqa: E731
    return {"c_render_noskip_ms": _sig(float((rc.get("noskip") or {}).get("c_render_ms", float("nan")))),
            "vs_fastest_at_needed": _sig(rc["speedup_vs_fastest_at_needed"]) if rc.get("speedup_vs_fastest_at_needed") is not None else "",
            "vs_fastest_best": _sig(best["speedup"]), "vs_fastest_best_share": best["share"],
            "free_networks_vs_fastest_at_needed": at(free) if need is not None else "",
            "free_networks_vs_fastest_best": _sig(max(r["speedup"] for r in free))}


def update_table(path: Path, row: Mapping[str, Any]) -> Path:
    """Put ``row`` into the CSV at ``path`` (replacing the row of the same scene and RecNN); a CSV with other
    columns is refused in one line."""
    import csv

    from ..report.metrics_csv import write_metrics_csv

    rows: list[dict[str, Any]] = []
    if path.is_file():
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            cols = tuple(reader.fieldnames or ())
            # an older table (fewer columns, in this order) is extended: its rows get the new columns empty
            if not cols or cols != tuple(c for c in TABLE_COLUMNS if c in cols) or not {"scene", "recnn"} <= set(cols):
                raise InputError(f"table={path}: its columns are not an estimates table's; choose another file")
            rows = [{**dict.fromkeys(TABLE_COLUMNS, ""), **r} for r in reader
                    if (r["scene"], r["recnn"]) != (str(row["scene"]), str(row["recnn"]))]
    rows.append({k: row[k] for k in TABLE_COLUMNS})
    rows.sort(key=lambda r: (str(r["recnn"]), str(r["scene"])))
    return write_metrics_csv(rows, path, TABLE_COLUMNS)


def run_estimate(cfg: DictConfig) -> Path:
    """Measure (or reuse) and write ``<output_dir>/estimate.json``; returns its path. The scene is built first:
    an estimate is reused only for the same volume content."""
    from data_gen.scenes import build_scene, register_resolvers

    register_resolvers()
    scene = build_scene(cfg.scene)
    settings = estimate_settings(cfg, scene.volume.fingerprint())
    out_dir = Path(str(cfg.output_dir)) if cfg.get("output_dir") else \
        Path(str(cfg.runs_dir)) / "estimate" / f"{cfg.scene.name}-{cfg.recnn.name}-{settings_hash(settings)[:8]}"
    path = out_dir / RESULT
    est = read_estimate(path, settings)
    if est is not None:
        _say(f"reusing {path} (same settings)")
        warning = shared_cores_warning(_busiest(est), f"{path}")
        if warning:
            _say(f"{warning} (delete {out_dir} to measure it again)")
    else:
        busy = busy_cores()
        warning = shared_cores_warning(busy, "this estimate")
        if warning:
            _say(warning)
        created = next((d for d in reversed([out_dir, *out_dir.parents]) if not d.exists()), None)  # the topmost new folder
        out_dir.mkdir(parents=True, exist_ok=True)
        try:
            with OtherLoad() as during:  # a job that starts during the timing: the reading before it misses that one
                measured = measure(cfg, out_dir, scene=scene)
        except BaseException:
            if created is not None:  # a setting refused, or an interrupt: no folder of a measurement that never finished
                shutil.rmtree(created, ignore_errors=True)
            raise
        est = dict(measured, settings=settings, busy_cores=busy, timing_busy_cores=during.cores)
        add_intervals(est)
        if not warning and (late := shared_cores_warning(during.cores, "this estimate")):
            _say(late)
        atomic_json(path, est)
    if cfg.get("table"):
        update_table(Path(str(cfg.table)), table_row(est, path))
    print(format_report(est), flush=True)
    return path


__all__ = ["run_estimate", "measure", "read_estimate", "estimate_settings", "format_report", "write_contact_sheet",
           "shared_cores_warning", "DEFAULT_TARGETS", "RESULT", "BUSY_LIMIT"]
