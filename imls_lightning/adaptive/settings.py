"""Validated settings of ``python -m imls_lightning.adaptive`` (``conf/adaptive.yaml``): :class:`Settings`,
built by :func:`parse_settings`."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from imls_lightning.base.errors import InputError, finite_number

from ..inference.pipeline import NetOptions
from .checks import check_epsilon, check_integer
from .labels import REFERENCES, SOURCES, UNREACHABLE


@dataclass
class Settings:
    """Validated keys of ``conf/adaptive.yaml``."""

    ims: str
    recnn: str | None
    epsilon_db: float
    reference: str
    steps: int
    unreachable: str
    label_source: str
    tradeoff_means: int
    tradeoff_margins: tuple[float, ...]
    batch_size: int
    predictor: dict[str, Any]
    views: str
    max_views: int | None
    repeats: int
    timing_views: int
    device: str
    output_dir: str | None
    progress: bool
    ims_lift: bool = False
    reuse: bool = False
    options: NetOptions = field(default_factory=NetOptions)

    def label_key(self) -> dict[str, Any]:
        key = {"epsilon_db": self.epsilon_db, "reference": self.reference, "steps": self.steps,
               "unreachable": self.unreachable, "source": self.label_source}
        if self.ims_lift:  # only when set: labels made before the setting existed keep their names
            key["ims_lift"] = True
        return key

    @property
    def orp_path(self) -> str:
        """Where the fixed-mean ORP is searched: ``"product"`` (IMS mask at u, decoder, RecNN, against the
        RecNN alone: the evaluation's ORP) when the labels bisect the product path against the RecNN
        alone; else ``"iml"`` (IML + RecNN, against the labels' reference)."""
        return "product" if self.label_source == "ims" and self.reference == "recnn" else "iml"

    def hashed(self) -> dict[str, Any]:
        # orp_path: runs from before the product-path search searched the IML's u; they are not reused
        return {**self.label_key(), "orp_path": self.orp_path, "predictor": self.predictor, "views": self.views, "max_views": self.max_views,
                "repeats": self.repeats, "timing_views": self.timing_views,
                "tradeoff_means": self.tradeoff_means, "tradeoff_margins": list(self.tradeoff_margins),
                **({"options": {k: getattr(self.options, k) for k in NetOptions.SWITCHES}}
                   if any(getattr(self.options, k) for k in NetOptions.SWITCHES) else {})}


PREDICTOR_DEFAULTS = {"hidden": 64, "layers": 2, "epochs": 600, "lr": 3e-3, "weight_decay": 1e-4, "seed": 0, "margin": 1.0}


def parse_settings(cfg) -> Settings:
    """Validate ``cfg`` (``conf/adaptive.yaml``); bad values raise a one-line :class:`InputError`.

    Example:
        >>> import tempfile
        >>> from omegaconf import OmegaConf
        >>> with tempfile.NamedTemporaryFile(suffix=".ckpt") as ckpt:
        ...     s = parse_settings(OmegaConf.create({"ims_checkpoint": ckpt.name, "epsilon_db": 0.5}))
        ...     parse_settings(OmegaConf.create({"ims_checkpoint": ckpt.name, "views": "train"}))
        Traceback (most recent call last):
        imls_lightning.base.errors.InputError: views=train: expected 'test' (the trajectory) or 'val'
        >>> s.epsilon_db, s.reference, s.orp_path, s.predictor["hidden"]
        (0.5, 'recnn', 'product', 64)
    """
    from omegaconf import OmegaConf

    from ..base.config import to_plain

    ims = OmegaConf.select(cfg, "ims_checkpoint", default=None) if not OmegaConf.is_missing(cfg, "ims_checkpoint") else None
    if not ims:
        raise InputError("ims_checkpoint: required, an IMS checkpoint trained with model.target=pim (python -m imls_lightning.train model=ims model.target=pim ...)")
    recnn = cfg.get("recnn_checkpoint") or None
    for key, p in (("ims_checkpoint", ims), ("recnn_checkpoint", recnn)):
        if p and not Path(str(p)).expanduser().is_file():
            raise InputError(f"{key}={p}: file not found")
    pred = dict(PREDICTOR_DEFAULTS)
    given = to_plain(cfg.get("predictor")) or {}
    unknown = set(given) - set(PREDICTOR_DEFAULTS)
    if unknown:
        raise InputError(f"predictor.{sorted(unknown)[0]}: unknown key; expected some of {sorted(PREDICTOR_DEFAULTS)}")
    pred.update(given)
    pred["hidden"] = check_integer(pred["hidden"], "predictor.hidden", 1, 4096)
    pred["layers"] = check_integer(pred["layers"], "predictor.layers", 0, 16)
    pred["epochs"] = check_integer(pred["epochs"], "predictor.epochs", 1, 1_000_000)
    pred["seed"] = check_integer(pred["seed"], "predictor.seed", 0)
    for k in ("lr", "weight_decay", "margin"):
        pred[k] = finite_number(pred[k], f"predictor.{k}", "a finite number")
    if pred["lr"] <= 0 or pred["weight_decay"] < 0 or not 0 < pred["margin"] <= 10:
        raise InputError(f"predictor: expected lr > 0, weight_decay >= 0 and margin in (0, 10] (got {pred['lr']}, {pred['weight_decay']}, {pred['margin']})")
    views = str(cfg.get("views", "test"))
    if views not in ("test", "val"):
        raise InputError(f"views={views}: expected 'test' (the trajectory) or 'val'")
    mv = cfg.get("max_views")
    reference = str(cfg.get("reference", "recnn"))
    if reference not in REFERENCES:
        raise InputError(f"reference={reference}: expected recnn (within epsilon of the RecNN alone) or iml (of IML + RecNN at the trained mean)")
    unreachable = str(cfg.get("unreachable", "best"))
    if unreachable not in UNREACHABLE:
        raise InputError(f"unreachable={unreachable}: expected best (within epsilon of the view's best gap) or hi (the bracket's top)")
    source = str(cfg.get("label_source", "ims"))
    if source not in SOURCES:
        raise InputError(f"label_source={source}: expected ims (labels on the IML/S path, the product) or iml (the IML on the rendered C-Image)")
    margins = to_plain(cfg.get("tradeoff_margins", [0.8, 1.0, 1.25, 1.5]))
    if isinstance(margins, (int, float)) and not isinstance(margins, bool):
        margins = [margins]
    if not isinstance(margins, list) or not margins:
        raise InputError(f"tradeoff_margins={margins}: expected a list of factors in (0, 10], e.g. [0.8,1,1.25]")
    margins = [finite_number(x, "tradeoff_margins", "factors in (0, 10]") for x in margins]
    if not all(0 < x <= 10 for x in margins):
        raise InputError(f"tradeoff_margins={margins}: expected factors in (0, 10]")
    device = str(cfg.get("device", "auto"))
    options = NetOptions.from_config(to_plain(cfg.get("options")), device=device)
    ims_lift = cfg.get("ims_lift", False)
    if not isinstance(ims_lift, bool):
        raise InputError(f"ims_lift={ims_lift}: expected true (lift the IMS's masks to each mean value's share, as "
                         "evaluate's ims_lift) or false (the paper's rescale)")
    return Settings(
        ims=str(ims), recnn=str(recnn) if recnn else None, epsilon_db=check_epsilon(cfg.get("epsilon_db", 1.0)), reference=reference,
        steps=check_integer(cfg.get("steps", 8), "steps", 1, 30), unreachable=unreachable, label_source=source,
        tradeoff_means=check_integer(cfg.get("tradeoff_means", 16), "tradeoff_means", 0, 200),
        tradeoff_margins=tuple(sorted(set(margins))), batch_size=check_integer(cfg.get("batch_size", 16), "batch_size", 1),
        predictor=pred, views=views, max_views=None if mv is None else check_integer(mv, "max_views", 1),
        repeats=check_integer(cfg.get("repeats", 10), "repeats", 1), timing_views=check_integer(cfg.get("timing_views", 20), "timing_views", 0),
        device=device, output_dir=cfg.get("output_dir") or None, progress=bool(cfg.get("progress", True)),
        ims_lift=ims_lift, options=options, reuse=bool(cfg.get("reuse", False)),
    )
