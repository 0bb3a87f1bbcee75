"""The evaluation itself, :func:`evaluate`, in named steps: where the results go (and whether a finished
run of the same settings is reused), the views, the ORP, the methods, the measurement view by view
(the sweeps right after each sweep view's methods), the untrained baselines, the options sweep, and
the files and the report. What it has found and measured is kept as it goes (:mod:`.resume`): an interrupted run
of the same settings resumes at the view it was measuring. ``python -m imls_lightning.evaluate`` parses its config
and calls it."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig

from imls_lightning.base.errors import InputError

from .. import report as rep
from ..base.config import file_hash, settings_hash, to_plain
from ..inference.pipeline import FullRayCast, IMLPlusRecNN, IMLSRenderer, LASMethod, Method, RecNNAlone, pick_device
from ..models.iml import FillDecoder
from ..report.document import verdict_line
from ..core.operating_point import OperatingPoint
from ..report.names import TWIN_METHODS, ray_caster_twin
from .baselines import blue_noise_method, equal_share, sparser_method
from .measurement import measure_methods, progress_bar, spaced
from ..render.camera import view_tensor
from .networks import Networks, check_trained_on, load_networks, recnn_name
from .operating_point import (borrowed_point, camera_distance, gap_by_distance, orp_summary, paired_gap, point_of,
                              product_path_orp, record_operating_point, trained_decoder_point)
from .resume import EvaluationProgress
from .settings import Settings, parse_settings
from .protocol import check_view_seeds, fresh_trajectory_data, training_data_seed, trajectory_note
from ..report.speedup import ray_casters, speedup_intervals
from .sweeps import Sweeps, front_notes, options_sweep
from .baseline_point import SearchedPoint
from .las_point import describe_las, las_point, las_searched_method
from .two_pass import describe_two_pass, two_pass_method, two_pass_point

#: the checkpoint keys of ``checkpoints.<key>`` and the settings that name them
CHECKPOINT_KEYS = ("ims", "las", "recnn", "iml", "blue_noise", "recnn_sparser")


def sample_distance_voxels(scene, renderer_cfg) -> float | None:
    """The scene's ray-marching step in voxels (:func:`imls_lightning.render.scene.voxel_size`), for the reports."""
    from imls_lightning.render.scene import voxel_size

    try:
        return float(scene.sample_distance) / float(voxel_size(scene.volume))
    except (AttributeError, TypeError, ValueError, ZeroDivisionError):
        return None


def command_line() -> str:
    """The command that ran this evaluation, for the report."""
    from ..report import hydra_command

    return hydra_command("imls_lightning.evaluate", "evaluate(cfg) through the Python API (settings: config.yaml)")


def checkpoint_paths(s: Settings) -> dict[str, str]:
    """``{key: path}`` of the checkpoints given; a missing file is a one-line :class:`InputError`."""
    paths = {k: p for k, p in ((k, getattr(s, k)) for k in CHECKPOINT_KEYS) if p}
    for k, p in paths.items():
        if not Path(str(p)).expanduser().is_file():
            raise InputError(f"checkpoints.{k}={p}: file not found")
    return paths


def checkpoint_hashes(paths: dict[str, str]) -> dict[str, str]:
    """``{key: SHA-256}`` of the checkpoints :func:`checkpoint_paths` found (memoized per file by ``file_hash``)."""
    return {k: file_hash(Path(str(p)).expanduser()) for k, p in paths.items()}


def output_dir(cfg: DictConfig, s: Settings, scene, rcfg: dict[str, Any], paths: dict[str, str]) -> Path:
    """The evaluation's folder: ``output_dir``, else ``<runs_dir>/eval/<scene>-<recnn>-<hash>``, the hash of
    the checkpoints' bytes and every setting that changes the results (no network is built)."""
    from imls_lightning.render import renderer_pixel_settings

    ck_hashes = checkpoint_hashes(paths)
    # renderer.skip_empty=false changes no pixel but every time: such an evaluation is a run of its own
    costs = [{"skip_empty": False}] if rcfg.get("skip_empty", True) is False else []
    run_hash = settings_hash(ck_hashes, cfg.scene, cfg.data, renderer_pixel_settings(rcfg), s.hashed(), *costs)
    if s.output_dir:
        return Path(s.output_dir)
    return Path(str(cfg.paths.runs_dir)) / "eval" / f"{scene.name}-{recnn_name(s)}-{run_hash}"


def open_views(cfg: DictConfig, s: Settings, scene, resolution: int):
    """``(cache, evaluated cache, rows, positions)``: the networks' cache (rendered if missing; its validation views
    choose the settings), the cache of the evaluated views (the same one, or with ``trajectory_seed`` the fresh
    trajectory's own: :func:`~.protocol.fresh_trajectory_data`), the rows of the evaluated split in it and the
    evaluated positions among them."""
    from data_gen.cache import ViewImageCache, ensure_cache

    evaluated = None
    if s.trajectory_seed is not None:  # rendered with the same renderer settings: the pixels do not depend on skipping
        evaluated = ViewImageCache.open(ensure_cache(scene, fresh_trajectory_data(s, cfg, scene), cfg.renderer, progress=s.progress))
    if evaluated is not None and s.orp_from:  # a point taken, not chosen: no validation view is read (a reproduction)
        cache = evaluated
    else:
        cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=s.progress))
    evaluated = evaluated if evaluated is not None else cache
    for c in (cache, evaluated):
        if c.resolution != resolution:
            raise InputError(f"data.resolution={resolution}: the cache {c.path} holds {c.resolution}^2 images")
    rows_all = evaluated.splits[s.views]
    if len(rows_all) == 0:
        raise InputError(f"views={s.views}: the cache {evaluated.path} has no {s.views} views")
    return cache, evaluated, rows_all, spaced(len(rows_all), s.max_views)


def operating_point(s: Settings, cfg, cache, scene, nets: Networks, device, positions, notes: list[str], renderer=None):
    """The ORP on the product path (validation views): ``(orp summary | None, the OperatingPoint IML/S runs at)``, the
    summary :func:`~.operating_point.orp_summary`'s, the point :func:`~.operating_point.point_of` it (its share ``None``:
    the trained one); ``renderer`` times the mask sharpnesses' operating points when there are several."""
    ims = nets.ims_task
    orp, imls_mean, lift = None, None, s.ims_lift is True  # lift: IML/S's masks lifted to their share
    if s.orp and ims.target == "pim":
        result = product_path_orp(s, cfg, cache, scene, nets, ims.pattern, device, future_views=len(positions),
                                  renderer=renderer)
        lift = result.lifted
        orp = orp_summary(result, s, lifted=lift)
        if result.found:
            imls_mean = float(result.mean)
        else:
            notes.append(f"ORP: no mean value in [0.01, 1] brings IML/S within {s.epsilon_db} dB of the RecNN alone on the "
                         "validation views; IML/S runs at its trained mean.")
    elif s.orp:
        notes.append(f"ORP search skipped: the IMS was trained with model.target={ims.target}, whose binary mask cannot be "
                     "rescaled to another mean (train the IMS with model.target=pim).")
    return orp, point_of(orp, imls_mean, lift)


def find_point(s: Settings, cfg, cache, scene, nets: Networks, device, positions, notes: list[str], renderer,
               progress: EvaluationProgress, borrowed: dict[str, Any] | None = None):
    """The operating point, the two-pass sampler's and LAS's at the promise: ``(orp summary | None, OperatingPoint,
    two_pass | None, las | None)``, restored from ``progress`` when an earlier sitting searched them, else taken from ``borrowed`` (``orp_from``:
    :func:`~.operating_point.borrowed_point`) or searched, and kept there."""
    point = progress.point
    if not point and borrowed is not None:
        tp = borrowed["two_pass"]  # kept only for the same first pass and floor; else searched below
        same_sampler = tp is not None and (tp.get("base"), tp.get("floor")) == (s.two_pass_base, s.two_pass_floor)
        las_b = borrowed.get("las_searched")  # kept only for the same IPRs searched among; else searched below
        same_las = (las_b is not None and s.las_searched
                    and sorted(float(r["ipr"]) for r in las_b.get("rows", [])) == sorted(s.las_search_iprs))
        progress.save_point({"orp": borrowed["orp"], "imls_mean": borrowed["imls_mean"], "lift": borrowed["lift"],
                             "notes": [*notes, *borrowed["notes"]], **({"two_pass": tp} if same_sampler else {}),
                             **({"las_searched": las_b} if same_las else {})})
        notes.clear()  # they come back from the point, as on a resumed run
        point = progress.point
    if point:
        notes += point["notes"]
        orp = point["orp"]
        imls = point_of(orp, point["imls_mean"], bool(point["lift"]))
    else:
        orp, imls = operating_point(s, cfg, cache, scene, nets, device, positions, notes, renderer)
        progress.save_point({"orp": orp, "imls_mean": imls.u, "lift": imls.lift, "notes": list(notes)})
    two_pass, las = None, None
    if s.two_pass_base is not None:
        if progress.point.get("two_pass") is not None:
            two_pass = SearchedPoint.from_dict(progress.point["two_pass"])
        else:
            two_pass = two_pass_point(s, cfg, cache, scene, nets, nets.ims_task.pattern, device, future_views=len(positions))
            progress.save_point({**progress.point, "two_pass": two_pass.to_dict()})
    if s.las_searched:
        if progress.point.get("las_searched") is not None:
            las = SearchedPoint.from_dict(progress.point["las_searched"])
        else:
            las = las_point(s, cfg, cache, scene, nets, renderer, device, future_views=len(positions))
            progress.save_point({**progress.point, "las_searched": las.to_dict()})
    return orp, imls, two_pass, las


def _imls_counts(imls: IMLSRenderer, cache, rows_all, positions, device) -> list[float]:
    """The pixels IML/S's mask selects on each evaluated view (the IMS network alone, no rendering)."""
    with torch.inference_mode():
        return [float(imls.predict_im(view_tensor(cache.views[rows_all[p]], device)).sum()) for p in positions]


def las_equal_point(las: SearchedPoint | None, orp: dict[str, Any] | None) -> SearchedPoint | None:
    """LAS at equal quality (:func:`~.las_point.equal_quality_point`), from its promise search; None without one."""
    from .las_point import equal_quality_point, imls_validation_gap

    gap = imls_validation_gap(orp)
    if las is None or gap is None or not las.rows:
        return None
    return equal_quality_point(las, gap)


def build_methods(s: Settings, nets: Networks, renderer, cache, rows_all, positions, device, m: int,
                  point: OperatingPoint, notes: list[str],
                  two_pass: SearchedPoint | None = None, las: SearchedPoint | None = None,
                  other_renderer=None, orp: dict[str, Any] | None = None) -> tuple[dict[str, Method], float | None]:
    """Every method measured (the networks are shared between methods with the same options) and the
    IPR LAS runs at (None without LAS). ``point``: IML/S's operating point (:func:`~.operating_point.point_of`);
    ``two_pass``: the two-pass sampler's operating point, ``las``: LAS's at the promise (None: not measured);
    ``other_renderer``: the other ray caster (:func:`other_ray_caster`), on which the RecNN alone and IML/S are
    timed too (their twins, :data:`~imls_lightning.report.names.TWIN_METHODS`)."""
    opts, pattern, ims = s.options, nets.ims_task.pattern, nets.ims_task
    imls = IMLSRenderer(renderer, pattern, ims.to(device).mask_head, ims.decoder, nets.recnn, opts, point=point)
    methods: dict[str, Method] = {
        "full": FullRayCast(renderer, m, opts),
        "recnn": RecNNAlone(renderer, pattern, nets.recnn, opts),
        **({"recnn_sparser": sparser_method(renderer, nets.recnn_sparser, opts)} if nets.recnn_sparser is not None else {}),
        "iml": IMLPlusRecNN(renderer, pattern, nets.iml, nets.recnn, opts, mean=point.u),
        "imls": imls,
        "imls_fill": IMLSRenderer(renderer, pattern, imls.predict_im, FillDecoder(pattern), nets.recnn, opts),
    }
    if (own := trained_decoder_point(orp)) is not None:  # the search kept the fill: the IMS's own decoder at its own point
        methods["imls_trained"] = IMLSRenderer(renderer, pattern, ims.mask_head, ims.decoder, nets.recnn, opts, point=own)
        notes.append(f"The operating point rebuilds the C-Image with the pull-push fill (orp_decoders: it ran fastest on the "
                     f"search views within the bound); imls_trained is the IMS's own decoder at the point its candidate "
                     f"found (u = {own.share:.3f}, no object floor), on the same views.")
    las_ipr_used = None
    if nets.las_task is not None:
        if s.las_ipr is not None:
            las_ipr_used, how = s.las_ipr, "fixed (las_ipr)"
        else:
            # IML/S's mean IPR on these views: the IMS network alone (no rendering) decides it
            mean_ipr = float(np.mean([int(c) for c in _imls_counts(imls, cache, rows_all, positions, device)])) / m**2
            las_ipr_used, how = max(mean_ipr, 1.0 / m**2), "matched to IML/S's mean IPR on these views"
            if mean_ipr < 1.0 / m**2:
                notes.append(f"IML/S selects no pixel on these views (IPR 0): LAS runs at the smallest IPR, 1 pixel ({las_ipr_used:.2e}).")
        methods["las"] = LASMethod(renderer, nets.las_task.net, m, int(nets.las_task.hparams["low_res"]), ipr=las_ipr_used, opts=opts)
        notes.append(f"LAS at IPR {las_ipr_used:.4f}, {how}; its mean u is bisected per view outside the timed stages (LAS's evaluation protocol).")
        if las is not None:
            methods["las_searched"] = las_searched_method(las, renderer, nets.las_task, m, opts)
            notes.append(describe_las(las))
            if (equal := las_equal_point(las, orp)) is not None:  # LAS at IML/S's quality (within 0.1 dB)
                methods["las_equal"] = las_searched_method(equal, renderer, nets.las_task, m, opts)
                methods["las_equal"].name = "las_equal"
                notes.append(f"LAS at equal quality: IPR {equal.value:.1%}, the smallest searched whose mean gap on "
                             f"{equal.where} ({equal.record['gap_db']:.2f} dB) is within {equal.record['margin_db']:g} dB "
                             f"of IML/S's validation gap ({equal.record['imls_gap_db']:.2f} dB)"
                             + ("" if equal.found else ": none was, so the closest") + ".")
    else:
        notes.append("LAS skipped: no LAS checkpoint (checkpoints.las=<LAS .ckpt>, trained with python -m imls_lightning.train model=las).")
    if nets.blue is not None:
        shares = [c / pattern.count for c in _imls_counts(imls, cache, rows_all, positions, device)]
        methods["blue_noise"] = blue_noise_method(renderer, pattern, nets.blue, nets.recnn, float(np.mean(shares)), opts)
    if two_pass is not None:
        methods["two_pass"] = two_pass_method(two_pass, renderer, pattern, nets.recnn, opts)
        notes.append(describe_two_pass(two_pass))
    if other_renderer is not None:
        methods.update(ray_caster_twins(methods, other_renderer))
        notes.append(f"Both ray casters: the RecNN alone and IML/S are timed with empty-space skipping "
                     f"{'off' if other_renderer.skip_empty is False else 'on'} too (the same pixels), interleaved with "
                     "the other methods on every timed view; the speed-up that counts is IML/S's faster configuration "
                     "against the faster RecNN alone (speedup_vs_fastest).")
    return methods, las_ipr_used


def other_ray_caster(s: Settings, scene, rcfg: dict[str, Any], renderer, notes: list[str]):
    """The ray caster with empty-space skipping flipped (``both_ray_casters``), or None: not asked for, or a
    renderer without the switch (one line in the notes)."""
    from imls_lightning.render import make_renderer

    if not s.both_ray_casters:
        return None
    if not hasattr(renderer, "skip_empty"):
        notes.append(f"Both ray casters: renderer={rcfg.get('name')} has no empty-space skipping switch; one ray caster timed.")
        return None
    return make_renderer(scene, {**rcfg, "skip_empty": not renderer.skip_empty})


def ray_caster_twins(methods: dict[str, Method], other_renderer) -> dict[str, Method]:
    """``recnn`` and ``imls`` on ``other_renderer``: shallow copies sharing their prepared networks (so the networks'
    times are the same code and weights), only the ray caster swapped."""
    twins = {}
    for name in ("recnn", "imls"):
        twins[ray_caster_twin(name, bool(other_renderer.skip_empty))] = methods[name].with_ray_caster(other_renderer)
    return twins


def mask_density(im, pattern, truth: np.ndarray, background) -> dict[str, float]:
    """The share of the C-Image's object pixels and of its background pixels an IM ``(n, n)`` keeps (the object: the
    pattern's pixels whose true colour is not the background's). With empty-space skipping a background pixel is
    nearly free, so what IML/S saves there is the object pixels it leaves out: ``{"object_density",
    "background_density", "object_fraction"}`` (empty without an IM)."""
    from ..estimate.measure import object_pixels

    if im is None:
        return {}
    k = pattern.count
    kept = np.asarray(im).reshape(-1)[:k].astype(bool)
    on = object_pixels(np.asarray(truth).reshape(-1, 3)[pattern.indices.numpy()], background)
    density = lambda sel: float(kept[sel].mean()) if sel.any() else float("nan")  # noqa: E731
    return {"object_density": density(on), "background_density": density(~on), "object_fraction": float(on.mean())}


def ray_casters_line(rc: dict[str, Any] | None) -> str | None:
    """The report's line on the fastest baseline (:func:`~.speedup.ray_casters`), or None without both ray casters.

    Example:
        >>> print(ray_casters_line({"recnn_skip_ms": 180.0, "recnn_noskip_ms": 1900.0, "imls_skip_ms": 200.0,
        ...     "imls_noskip_ms": 860.0, "fastest_recnn": "skip", "fastest_imls": "skip", "speedup_vs_fastest": 0.9,
        ...     "speedup_vs_fastest_low": 0.85, "speedup_vs_fastest_high": 0.95, "speedup_noskip": 2.21, "views": 12}))
        **The fastest baseline** (12 timed views): the RecNN alone takes 180 ms with empty-space skipping and 1900 ms marching every sample; IML/S + RecNN 200 and 860 ms. IML/S's faster configuration against the faster RecNN alone: **0.90x** (0.85-0.95); without skipping on either side: 2.21x.
    """
    if rc is None:
        return None
    return (f"**The fastest baseline** ({rc['views']} timed views): the RecNN alone takes {rc['recnn_skip_ms']:.0f} ms with "
            f"empty-space skipping and {rc['recnn_noskip_ms']:.0f} ms marching every sample; IML/S + RecNN "
            f"{rc['imls_skip_ms']:.0f} and {rc['imls_noskip_ms']:.0f} ms. IML/S's faster configuration against the faster "
            f"RecNN alone: **{rc['speedup_vs_fastest']:.2f}x** ({rc['speedup_vs_fastest_low']:.2f}-"
            f"{rc['speedup_vs_fastest_high']:.2f}); without skipping on either side: {rc['speedup_noskip']:.2f}x.")


def measure_views(s: Settings, scene, cache, rows_all, positions, methods: dict[str, Method], order: list[str],
                  sweeps: Sweeps | None, grid_pos: set[int], timed_pos: set[int], sweep_pos: list[int],
                  progress: EvaluationProgress | None = None):
    """Every method on every evaluated view, the sweeps right after a sweep view's methods:
    ``(metric rows, sweep rows, image grid, load)``, ``load`` a ``{"view", "cores", "seconds"}`` per timed view: the
    cores other processes kept busy while it was timed (:class:`~imls_lightning.report.machine.OtherLoad`).
    ``progress``: the views an earlier sitting measured are taken from it, and each new one is kept there."""
    rows: list[dict[str, Any]] = []
    grid: dict[int, dict[str, Any]] = {}
    sweep_rows: list[dict[str, Any]] = []
    load: list[dict[str, Any]] = []
    done = progress.views if progress is not None else {}
    for p in progress_bar(positions, len(positions), f"evaluate {scene.name}", s.progress):
        p = int(p)
        if p in done:  # measured in an earlier sitting
            rec = done[p]
            rows += rec["rows"]
            sweep_rows += rec["sweep_rows"]
            if rec["grid"]:
                grid[p] = progress.grid(p)
            if rec["load"] is not None:
                load.append(rec["load"])
            continue
        r = int(rows_all[p])
        view, truth = np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r])
        view_rows, view_sweep, view_grid = [], [], {"truth": truth} if p in grid_pos else None
        timed = p in timed_pos
        # the other ray caster's twins only time: their images are their methods' (the same pixels)
        view_order = order if timed else [n for n in order if n not in TWIN_METHODS]
        with rep.OtherLoad() as other:  # the cores other jobs keep busy while this view is timed
            # a timed view's methods in one schedule (s.timing: rounds, or each method's runs back to back)
            measured = measure_methods({name: methods[name] for name in view_order}, view, truth, s.repeats if timed else 1,
                                       s.warmup if timed else 0, order=s.timing)
            if "imls" in measured:  # where the product's mask put its pixels: on the object or the background
                fields = measured["imls"][0]
                fields.update(mask_density(measured["imls"][2].get("im"), methods["imls"].pattern, truth, scene.background))
            for name in view_order:
                fields, image, info = measured[name]
                if not timed:  # one untimed run: its image counts, its stage times do not
                    fields.update({k: None for k in fields if k.endswith("_ms")})
                view_rows.append({"view": p, "row": r, "method": name, **fields})
                if view_grid is not None:
                    view_grid[name] = image
                    if name == "imls":
                        view_grid["imls_im"] = info.get("im")
            if sweeps is not None and p in sweep_pos:
                view_sweep = sweeps.run_view(p, r, view, truth)
        view_load = {"view": p, "cores": other.cores, "seconds": other.seconds} if timed else None
        if progress is not None:
            progress.add_view(p, view_rows, view_sweep, view_load, view_grid)
        rows += view_rows
        sweep_rows += view_sweep
        if view_grid is not None:
            grid[p] = view_grid
        if view_load is not None:
            load.append(view_load)
    return rows, sweep_rows, grid, load


def timing_load(load: list[dict[str, Any]]) -> dict[str, Any] | None:
    """``summary.json``'s ``timing_load``: the cores other processes kept busy over the timed views (mean, max, how
    many views over :data:`~imls_lightning.report.machine.BUSY_LIMIT`); None where it cannot be read.

    Example:
        >>> timing_load([{"view": 0, "cores": 0.02, "seconds": 30.0}, {"view": 9, "cores": 0.9, "seconds": 31.0}])
        {'views': 2, 'mean': 0.46, 'max': 0.9, 'over': 1, 'limit': 0.25}
    """
    cores = [float(x["cores"]) for x in load if x.get("cores") is not None]
    if not cores:
        return None
    return {"views": len(cores), "mean": round(float(np.mean(cores)), 3), "max": round(max(cores), 3),
            "over": sum(c > rep.BUSY_LIMIT for c in cores), "limit": rep.BUSY_LIMIT}


def load_note(tl: dict[str, Any] | None) -> str | None:
    """The report's line on the other jobs during the timing (a warning when they kept more than the limit busy)."""
    if tl is None:
        return None
    line = (f"Other processes kept {tl['mean']:.2f} cores busy on average (at most {tl['max']:.2f}) while the "
            f"{tl['views']} timed views ran.")
    if tl["over"]:
        line += (f" **Warning: on {tl['over']} of them more than {tl['limit']:.2f}; the stage times read high there "
                 "(time it again with the cores free).**")
    return line


def evaluate(cfg: DictConfig, command: str | None = None) -> Path:
    """Run the evaluation described by ``cfg`` (``conf/evaluate.yaml``); returns ``report.md``'s path."""
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene

    s = parse_settings(cfg)
    resolution = int(cfg.data.resolution)
    paths = checkpoint_paths(s)
    check_trained_on(cfg, s)
    check_view_seeds(s, cfg, training_data_seed(s.ims))  # settings on views nobody trained on; a fresh trajectory
    scene = build_scene(cfg.scene)
    rcfg = to_plain(cfg.renderer)
    # a point taken from another evaluation is checked against these networks before anything is loaded
    borrowed = borrowed_point(s, checkpoint_hashes(paths), scene.name) \
        if s.orp_from else None

    # the output directory and the reuse check need only the checkpoints' bytes and hyper-parameters:
    # a reused run returns before any network is built (or Lightning imported)
    out = output_dir(cfg, s, scene, rcfg, paths)
    report_path = out / "report.md"
    if s.reuse and report_path.is_file():
        print(f"[evaluate] {out} already has a report of these settings; reusing it (reuse=false re-measures)", file=sys.stderr, flush=True)
        return report_path
    nets = load_networks(s, resolution)
    out.mkdir(parents=True, exist_ok=True)
    report_path.unlink(missing_ok=True)  # no report.md = no finished evaluation in this folder

    val_cache, cache, rows_all, positions = open_views(cfg, s, scene, resolution)
    renderer = make_renderer(scene, rcfg)
    device = pick_device(s.options.device)
    notes: list[str] = []
    if s.trajectory_seed is not None:
        notes.append(f"Test views: a fresh trajectory of seed {s.trajectory_seed} (the same path model and camera distances; "
                     f"cache {cache.path}); the settings were chosen on other views.")
    grid_pos = set(int(positions[i]) for i in spaced(len(positions), s.grid_views)) if s.grid_views else set()
    sweep_pos = [int(positions[i]) for i in spaced(len(positions), s.sweep_views)]
    # latency on timed_views of the evaluated views (repeats runs each), quality on all of them; the sweep's
    # views are always timed: the speed-quality front puts every method on them
    timed_pos = set(int(positions[i]) for i in spaced(len(positions), s.timed_views)) | set(sweep_pos)
    # what an interrupted run of these settings measured: its point and views are kept, the rest measured
    progress = EvaluationProgress(out, positions, timed_pos, resume=s.resume)
    orp, point, two_pass, las = find_point(s, cfg, val_cache, scene, nets, device, positions, notes, renderer,
                                           progress, borrowed)
    methods, las_ipr_used = build_methods(s, nets, renderer, cache, rows_all, positions, device, resolution, point, notes,
                                          two_pass=two_pass, las=las, orp=orp,
                                          other_renderer=other_ray_caster(s, scene, rcfg, renderer, notes))
    order = [k for k in rep.METHOD_ORDER if k in methods]
    if len(timed_pos) < len(positions):
        notes.append(f"Latency: stage times on {len(timed_pos)} of the {len(positions)} evaluated views (evenly spaced, "
                     f"median of {s.repeats} runs each); PSNR and SSIM on all {len(positions)}.")
    # the sweeps of the latency / PSNR plot and the speed-quality front: on the sweep's views, right after their methods
    sweeps = Sweeps(s, methods, nets, renderer, s.options, resolution) if sweep_pos else None
    rows, sweep_rows, grid, load = measure_views(s, scene, cache, rows_all, positions, methods, order, sweeps, grid_pos, timed_pos,
                                                 sweep_pos, progress)
    if (note := progress.note()) is not None:
        notes.append(note)
    both = ray_casters(rows, main_skip=rcfg.get("skip_empty", True) is not False)  # the fastest baseline, once
    if (line := ray_casters_line(both)) is not None:
        notes.append(line)
    load_summary = timing_load(load)
    if (note := load_note(load_summary)) is not None:
        notes.append(note)
        warning = rep.shared_cores_warning(load_summary["max"], f"this evaluation ({out})")
        if warning:
            print(f"[evaluate] {warning}", file=sys.stderr, flush=True)
    rep.write_metrics_csv(rows, out / "metrics.csv")
    rep.write_metrics_csv(sweep_rows, out / "sweep.csv", rep.SWEEP_COLUMNS)

    # untrained baselines at equal share (cache pixels = what the selective ray cast returns)
    shares = equal_share(s, cache, rows_all, positions, nets, nets.ims_task.pattern, device, point) if s.shares else []
    option_rows: list[dict[str, Any]] = []
    if s.options_sweep:
        opt_pos = [int(positions[i]) for i in spaced(len(positions), s.options_sweep_views)]
        option_rows = options_sweep(s, renderer, cache, rows_all, opt_pos)
        rep.write_metrics_csv(option_rows, out / "options.csv", rep.OPTION_COLUMNS)

    results = dict(rows=rows, sweep_rows=sweep_rows, option_rows=option_rows, grid=grid, order=order, notes=notes,
                   methods=methods, imls_mean=point.u, lift=point.lift, las_ipr=las_ipr_used, orp=orp,
                   equal_share=shares, positions=positions, sweep_pos=sweep_pos, timed_pos=timed_pos, two_pass=two_pass,
                   las_searched=las, timing_load=load_summary, ray_casters=both)
    report = write_results(cfg, s, out, scene, rcfg, cache, rows_all, nets, device, results, command)
    progress.finish()
    return report


def write_results(cfg: DictConfig, s: Settings, out: Path, scene, rcfg: dict[str, Any], cache, rows_all, nets: Networks,
                  device, res: dict[str, Any], command: str | None) -> Path:
    """``config.yaml``, ``summary.json`` and the report (last), then the operating point beside the IMS
    checkpoint; returns ``report.md``'s path."""
    m, pattern, rows, sweep_rows = int(cfg.data.resolution), nets.ims_task.pattern, res["rows"], res["sweep_rows"]
    positions, sweep_pos = res["positions"], res["sweep_pos"]
    plain = {k: to_plain(cfg[k]) for k in ("scene", "data", "renderer") if k in cfg}
    plain.update(checkpoints=to_plain(cfg.checkpoints), settings=s.hashed(), output_dir=str(out))
    rep.write_config(out / "config.yaml", plain)
    orp = None if res["orp"] is None else dict(res["orp"])
    if orp is not None:  # the same operating point on the evaluated (test) views, beside the validation gap
        orp["test"] = paired_gap(rows, "recnn", "imls")
        # and where on them it is lost: the gap by camera distance (seed_shell's grew on close-ups)
        orp["test_by_distance"] = gap_by_distance(rows, lambda row: camera_distance(cache, row))
    two_pass = None
    if res.get("two_pass") is not None:  # its search beside its gap on the evaluated views, as the ORP's
        two_pass = {**res["two_pass"].to_dict(), "test": paired_gap(rows, "recnn", "two_pass"),
                    "test_by_distance": gap_by_distance(rows, lambda row: camera_distance(cache, row), method="two_pass")}
    las_searched = None
    if res.get("las_searched") is not None:  # its search beside its gap on the evaluated views, as the ORP's
        las_searched = {**res["las_searched"].to_dict(), "test": paired_gap(rows, "recnn", "las_searched"),
                        "test_by_distance": gap_by_distance(rows, lambda row: camera_distance(cache, row), method="las_searched")}
    front = rep.front_points(rows, sweep_rows, sweep_pos,
                             notes=front_notes(res["methods"], res["imls_mean"], bool(orp and orp["found"]), res["las_ipr"]))
    # the machine-readable results the benchmarks collect (make bench-paper)
    rep.atomic_write_text(out / "summary.json", json.dumps({
        "scene": scene.name, "recnn": nets.recnn_name, "fr_size": m, "c_size": int(pattern.c_size),
        # the networks' bytes: another evaluation may use this one's operating point only with the same (orp_from)
        "checkpoints_sha256": checkpoint_hashes(checkpoint_paths(s)),
        "sample_distance_voxels": sample_distance_voxels(scene, rcfg), "skip_empty": rcfg.get("skip_empty", True) is not False,
        "imls_mean": res["imls_mean"], "orp": orp,
        "las_ipr": res["las_ipr"], "views": len(positions), "timed_views": len(res["timed_pos"]), "timing": s.timing,
        "repeats": s.repeats, "methods": rep.summarize_rows(rows),
        "speedup_interval": speedup_intervals(rows),  # each method over the RecNN alone, the timed views resampled
        "equal_share": res["equal_share"], "front": front, "front_views": [int(p) for p in sweep_pos], "two_pass": two_pass,
        **({"las_searched": las_searched} if las_searched is not None else {}), "timing_load": res.get("timing_load"),
        # the fastest baseline: both ray casters timed in this run (both_ray_casters), and the fresh trajectory's seed
        "ray_casters": res.get("ray_casters"),
        # where IML/S's mask put its pixels, averaged over the evaluated views (the density on object and background)
        "mask_density": {k: float(np.nanmean([r[k] for r in rows if r["method"] == "imls" and k in r] or [np.nan]))
                         for k in ("object_density", "background_density", "object_fraction")},
        "trajectory": trajectory_note(s, cache)},
        indent=1, default=float))
    ctx = rep.ReportContext(
        out=out, scene=scene.name, recnn_name=nets.recnn_name, resolution=m, c_size=pattern.c_size,
        pattern=pattern.summary(), renderer=str(rcfg.get("name")), views=s.views, positions=[int(p) for p in positions],
        trajectory_len=len(rows_all), repeats=s.repeats, warmup=s.warmup, timing=s.timing, options=vars(s.options), device=str(device),
        checkpoints={"IMS": s.ims, "RecNN": nets.recnn_source, "IML (IML + RecNN)": nets.iml_source, "LAS": s.las or "–"},
        iml_mean=float(nets.iml.mean), rows=rows, sweep_rows=sweep_rows, option_rows=res["option_rows"], order=res["order"],
        sweep_positions=sweep_pos, grid=res["grid"], pattern_obj=pattern, notes=res["notes"], las_ipr=res["las_ipr"],
        machine=rep.machine_info(str(device)), command=command or command_line(), cache=str(cache.path),
        orp=orp, equal_share=res["equal_share"], front=front, two_pass=two_pass,
        verdict=verdict_line(res.get("ray_casters"),
                             (paired_gap(rows, "recnn", "imls") or {}).get("gap_db"), s.epsilon_db),
    )
    report = rep.write_report(ctx)
    if orp is not None and not s.orp_from:  # after the report: only a finished search records its point
        record_operating_point(s, orp, scene.name, report, int(orp.get("views") or 0))
    return report
