"""``python -m imls_lightning.cost_mask row=<name>``: how much of the render cost must a mask keep on this row?

The committed networks of a row (``conf/row/<name>.yaml``, checked by SHA-256) at its committed operating point, on
views drawn as training views are but from a seed no network trained on, with the fastest ray caster (empty-space
skipping). For the product's mask, the IML's (which sees the rendered C-Image) and an oracle that also knows each
pixel's ray cost (:mod:`imls_lightning.evaluation.cost_mask`): the share of the pattern's render cost each keeps
within ``epsilon_db`` of the RecNN alone, and the speed-up that cost allows, with the networks as timed and free.
Writes ``cost_mask.json``, ``cost_mask.md`` and ``cost_mask.png``; the last stdout line is the JSON's path.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig

from imls_lightning.base.atomic import atomic_json
from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_number

from ..base.paths import log
from .reproduce import row_files, row_spec


def check_seed(seed: int, trained: Mapping[str, int | None]) -> None:
    """Refuse a view seed some network trained on (``trained``: checkpoint key -> its training views' seed)."""
    for key, s in trained.items():
        if s is not None and int(s) == seed:
            raise InputError(f"seed={seed}: the {key} network trained on views of that seed; choose another")


def row_times(summary: Mapping[str, Any]) -> dict[str, Any] | None:
    """The stage times of the row's own evaluation (its ``summary.json``: medians of 10 runs on each timed view, on
    the ray caster it was evaluated with), for the ceilings; None when it lacks them (then this run's are used)."""
    methods = summary.get("methods") or {}
    alone, product = (methods.get(m, {}).get("latency_ms") or {} for m in ("recnn", "imls"))
    try:
        return {"pattern_ms": float(alone["selective_render"]), "recnn_ms": float(alone["recnn"]),
                "nets_ms": float(product["importance"]) + float(product["decoder"]),
                "source": f"the row's evaluation ({summary.get('timed_views')} timed views, "
                          f"{'skipping' if summary.get('skip_empty', True) else 'every sample marched'})"}
    except (KeyError, TypeError, ValueError):
        return None


def cost_masks(cfg: DictConfig) -> Path:
    """Measure ``cfg.row`` (module docstring); returns ``cost_mask.json``'s path."""
    from ..estimate.run import estimate_views
    from ..evaluation.cost_mask import measure_all, summarize
    from ..evaluation.operating_point import point_of, record_from_orp
    from ..evaluation.protocol import training_data_seed
    from ..inference.checkpoints import load_ims_nets, load_task, renderer_for
    from ..inference.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions, RecNNAlone

    row = row_spec(cfg)
    name = str(row["name"])
    folder, files, point_dir = row_files(row)
    views_n = check_integer(cfg.views, "views", 1)
    seed = check_integer(cfg.seed, "seed", 0)
    means = [check_number(u, "iml_means", 0.01, 1.0, what="IML mean values in [0.01, 1]") for u in list(cfg.iml_means or [])]
    check_seed(seed, {k: training_data_seed(p) for k, p in files.items() if k in ("ims", "iml", "recnn")})
    out = Path(str(cfg.output_dir)) if cfg.get("output_dir") else Path(str(cfg.runs_dir)) / "cost_mask" / f"{name}-seed{seed}-views{views_n}"
    summary = json.loads((point_dir / "summary.json").read_text(encoding="utf-8"))
    orp = summary["orp"]
    record = record_from_orp(orp, scene=str(summary.get("scene")))  # what the row's search measured, for the report
    point = point_of(orp, share=float(orp["mean"]) if orp.get("found") else None, lift=bool(orp.get("lift")))
    nets = load_ims_nets(files["ims"], files.get("recnn"))
    renderer_cfg = {**(nets.hparams.get("renderer") or {"name": "numba"}), "skip_empty": True}  # the fastest ray caster
    if str(renderer_cfg.get("name")) != "numba":
        raise InputError(f"row={name}: its renderer is {renderer_cfg.get('name')}; the ray costs need renderer=numba")
    ray = renderer_for(nets.hparams, renderer_cfg=renderer_cfg)
    opts = NetOptions.from_config(cfg.get("options"))
    product = IMLSRenderer(ray, nets.pattern, nets.head, nets.decoder, nets.recnn, opts, point=point, record=record)
    alone = RecNNAlone(ray, nets.pattern, nets.recnn, opts)
    iml = load_task(files["iml"], expect="IMLTask", what=f"row={name} iml").iml if "iml" in files and means else None
    iml_methods = {u: IMLPlusRecNN(ray, nets.pattern, iml, nets.recnn, opts, mean=u) for u in means} if iml is not None else {}
    views = estimate_views(ray.scene, views_n, seed)
    log(f"cost masks: row {name}, {views_n} views of seed {seed}, point {record.describe()}")
    measured = measure_all(views, lambda i: ray.render(views[i], nets.pattern.fr_size), alone, product, iml_methods,
                           progress=log)
    result = {"row": name, "seed": seed, "point": record.describe(),
              **summarize(measured, float(cfg.epsilon_db), row_times(summary) if cfg.get("times", "row") == "row" else None),
              "per_view": [{"view": v.view, "recnn_db": v.recnn_db, "object_share": v.object_share,
                            "object_cost": v.object_cost, "rows": v.rows} for v in measured]}
    out.mkdir(parents=True, exist_ok=True)
    from ..report import write_markdown
    from ..report.cost_mask import cost_mask_markdown, cost_mask_plot

    cost_mask_plot(result, out / "cost_mask.png")
    write_markdown(out / "cost_mask.md", cost_mask_markdown(result))
    return atomic_json(out / "cost_mask.json", result)


__all__ = ["cost_masks", "check_seed", "row_times"]
