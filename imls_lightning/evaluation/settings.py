"""The evaluation's settings: the keys of ``conf/evaluate.yaml`` validated into :class:`Settings`
(:func:`parse_settings`); a bad value is a one-line :class:`~imls_lightning.base.errors.InputError`."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError

from ..base.config import to_plain
from ..core.importance import check_sharpnesses
from ..inference.pipeline import NetOptions

MIN_REPEATS = 10
#: the shares of C at which the speed-quality front measures IML/S + RecNN (and blue noise + decoder)
FRONT_SHARES = (0.1, 0.2, 0.4, 0.6, 0.8, 1.0)
#: the IPRs (shares of the FR pixels) LAS at the product's promise is searched among (``las_searched``): finer where
#: the paper's LAS points lie (2.5-20%), up to twice a 4x super-resolution pattern's 25%
LAS_SEARCH_IPRS = (0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.12, 0.14, 0.17, 0.2, 0.25, 0.3, 0.4, 0.5)
#: where the ORP is searched: ``heldout`` views drawn like the training views from a seed of their own (no
#: network trained on them), ``path``: an exploratory path of their own, drawn like the test trajectory from a
#: seed of its own (never the test trajectory itself), or the cache's ``val`` split (whose eye directions an IMS
#: trained on a larger cache of the same seed has seen: sample_training_views draws every direction before any distance)
ORP_VIEWS = ("heldout", "path", "val")


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


def _sharpness(cfg) -> list[float]:
    """``ims_sharpness``: the IMS mask sharpnesses the ORP is searched at (a number or a list, each in [1, 8];
    the one whose operating point runs fastest on ``ims_sharpness_views`` search views is kept, or with 0 the one
    that ray-casts the smallest share of C). Needs the IMS's ``target=pim``."""
    v = to_plain(OmegaConf.select(cfg, "ims_sharpness", default=None))
    return [1.0] if v is None else check_sharpnesses(v, "ims_sharpness")


def _decoders(cfg) -> list[str]:
    """``orp_decoders``: what may rebuild the C-Image at the operating point, each searched as a candidate
    (:data:`~imls_lightning.core.operating_point.POINT_DECODERS`: ``trained``, the IMS's own decoder; ``fill``, the
    pull-push fill of the same pixels); the fastest point within the bound is kept. A name or a list; default
    ``[trained]`` (the paper's)."""
    from ..core.operating_point import POINT_DECODERS

    v = to_plain(OmegaConf.select(cfg, "orp_decoders", default=None))
    if v is None:
        return ["trained"]
    names = [v] if isinstance(v, str) else v
    if not isinstance(names, (list, tuple)) or not names or any(n not in POINT_DECODERS for n in names) \
            or len(set(names)) != len(names):
        shown = "[" + ",".join(map(str, v)) + "]" if isinstance(v, (list, tuple)) else v  # as typed on the command line
        raise InputError(f"orp_decoders={shown}: expected a non-empty list of distinct names among {list(POINT_DECODERS)} "
                         "(trained: the IMS's own decoder; fill: the pull-push fill of the same pixels)")
    return [str(n) for n in names]


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
    ims_sharpness: list[float] = field(default_factory=lambda: [1.0])  # candidates: the ORP searched at each
    recnn_sparser: str | None = None
    front_shares: list[float] = field(default_factory=lambda: list(FRONT_SHARES))
    orp_confidence: float = 0.95
    orp_views: str = "heldout"
    orp_views_seed: int | None = None
    orp_strata: int = 1
    orp_by_distance: bool = False
    orp_paths: int = 4
    two_pass_base: float | None = None   # the two-pass sampler's first pass (share of C); None: not measured
    two_pass_floor: float = 0.25
    timing: str = "interleaved"          # the methods' runs on a timed view: in rounds, or each method's back to back
    ims_sharpness_views: int = 6         # search views the candidates' operating points are timed on (0: by share of C)
    orp_decoders: list[str] = field(default_factory=lambda: ["trained"])  # candidates: the ORP searched with each
    orp_object_floor: list[float] = field(default_factory=list)  # the object floor's candidate margins ([]: no floor)
    orp_object_floor_tau: float = 0.2    # PIM' above this counts as the object
    orp_object_floor_by_band: bool = False  # a margin per band of camera distance (needs orp_by_distance)
    orp_object_floor_tail: float = 1.0   # the share of a band's validation views a margin may leave over epsilon_db
    resume: bool = True                  # an interrupted run of the same settings continues from its partial/ results
    orp_from: str | None = None          # a finished evaluation's folder whose operating point is used, not searched
    orp_from_sha256: str | None = None   # its summary.json's bytes (part of this run's identity)
    las_searched: bool = False           # also LAS at the product's promise: its IPR searched on the ORP's search views
    las_search_iprs: list[float] = field(default_factory=lambda: list(LAS_SEARCH_IPRS))  # the IPRs it is searched among
    trajectory_seed: int | None = None   # a fresh test trajectory of this seed (evaluation.protocol); None: the cache's
    both_ray_casters: bool = True        # the RecNN alone and IML/S timed on the other ray caster too (skipping on/off)
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
            # blocked was the only order before the key: those evaluations keep their directories
            **({"timing": self.timing} if self.timing != "blocked" else {}),
            **({"orp_strata": self.orp_strata} if self.orp_strata != 1 else {}),
            **({"ims_sharpness": self.ims_sharpness} if self.ims_sharpness != [1.0] else {}),
            **({"ims_sharpness_views": self.ims_sharpness_views}
               if len(self.ims_sharpness) * len(self.orp_decoders) > 1 else {}),
            # only when set: evaluations made before the key existed keep their directories
            **({"orp_decoders": self.orp_decoders} if self.orp_decoders != ["trained"] else {}),
            **({"orp_by_distance": True} if self.orp_by_distance else {}),
            **({"orp_object_floor": {"margins": self.orp_object_floor, "tau": self.orp_object_floor_tau,
                                     # only when set: evaluations made before the keys existed keep their directories
                                     **({"by_band": True} if self.orp_object_floor_by_band else {}),
                                     **({"tail": self.orp_object_floor_tail} if self.orp_object_floor_tail != 1.0 else {})}}
               if self.orp_object_floor else {}),
            **({"orp_paths": self.orp_paths, "orp_bound": "passes"} if self.orp_views == "path" else {}),
            # the point taken from another evaluation: its summary's bytes (only when set)
            **({"orp_from": self.orp_from_sha256} if self.orp_from else {}),
            **({"las_searched": True, "las_search_iprs": self.las_search_iprs} if self.las_searched else {}),
            # only when set: evaluations made before the keys existed keep their directories
            **({"trajectory_seed": self.trajectory_seed} if self.trajectory_seed is not None else {}),
            **({"both_ray_casters": True} if self.both_ray_casters else {}),
            **({"two_pass": {"base": self.two_pass_base, "floor": self.two_pass_floor,
                             # its share per band of camera distance, as the ORP's mean value (results changed with it)
                             **({"by_distance": True} if self.orp_by_distance else {})}}
               if self.two_pass_base is not None else {}),
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
        reuse=bool(cfg.get("reuse", False)), progress=bool(cfg.get("progress", True)), resume=bool(cfg.get("resume", True)),
        blue_noise=ck.get("blue_noise") or None, orp=bool(cfg.get("orp", True)),
        epsilon_db=_floats(cfg, "epsilon_db", 0.0, 100.0)[0] if cfg.get("epsilon_db") is not None else 1.0,
        orp_max_views=_int(cfg, "orp_max_views", 1, allow_none=True),
        shares=_floats(cfg, "shares", 0.0, 1.0, lo_open=True) if cfg.get("shares") is not None else [],
        timed_views=_int(cfg, "timed_views", 1, allow_none=True),
        ims_lift=_lift(cfg), ims_sharpness=_sharpness(cfg), recnn_sparser=ck.get("recnn_sparser") or None,
        front_shares=_floats(cfg, "front_shares", 0.0, 1.0, lo_open=True),
        orp_confidence=_confidence(cfg), orp_views=_orp_views(cfg),
        orp_views_seed=_int(cfg, "orp_views_seed", 0, allow_none=True),
        orp_strata=_int(cfg, "orp_strata", 1) if OmegaConf.select(cfg, "orp_strata") is not None else 1,
        orp_by_distance=_by_distance(cfg), orp_paths=_paths(cfg), **_two_pass(cfg), timing=_timing(cfg),
        ims_sharpness_views=_int(cfg, "ims_sharpness_views", 0) if OmegaConf.select(cfg, "ims_sharpness_views") is not None else 6,
        orp_decoders=_decoders(cfg),
        **_object_floor(cfg), **_orp_from(cfg), **_las_searched(cfg),
        trajectory_seed=_trajectory_seed(cfg, views), both_ray_casters=_bool(cfg, "both_ray_casters", True),
    )


def _trajectory_seed(cfg, views: str) -> int | None:
    """``trajectory_seed``: an integer >= 0 (a fresh test trajectory of that seed), or null (the cache's own)."""
    v = _int(cfg, "trajectory_seed", 0, allow_none=True)
    if v is not None and views != "test":
        raise InputError(f"trajectory_seed={v}: a fresh trajectory replaces the test views; it needs views=test (got {views})")
    return v


def _bool(cfg, key: str, default: bool) -> bool:
    v = OmegaConf.select(cfg, key, default=default)
    if not isinstance(v, bool):
        raise InputError(f"{key}={v!r}: expected true or false")
    return v


def _las_searched(cfg) -> dict[str, Any]:
    """``las_searched`` (true: LAS also at the product's promise, its IPR searched among ``las_search_iprs`` on the
    ORP's search views; needs ``checkpoints.las`` and the ORP) and the IPRs, each in (0.01, 1]."""
    on = OmegaConf.select(cfg, "las_searched", default=False)
    if not isinstance(on, bool):
        raise InputError(f"las_searched={on!r}: expected true or false")
    iprs = _floats(cfg, "las_search_iprs", 0.01, 1.0) if OmegaConf.select(cfg, "las_search_iprs") is not None \
        else list(LAS_SEARCH_IPRS)
    if on and not iprs:
        raise InputError("las_search_iprs=[]: expected at least one IPR in [0.01, 1] to search LAS's among")
    if on and not (cfg.get("checkpoints") or {}).get("las"):
        raise InputError("las_searched=true: needs checkpoints.las (the LAS checkpoint whose IPR is searched)")
    return {"las_searched": on, "las_search_iprs": sorted(iprs)}


def _orp_from(cfg) -> dict[str, Any]:
    """``orp_from``: a finished evaluation's folder (its ``summary.json`` and ``config.yaml``); this run uses the
    operating point that evaluation searched on its validation views instead of searching again (null: search).
    The folder must hold both files; whether its networks are this run's is checked when they are loaded."""
    from ..base.config import file_hash

    v = OmegaConf.select(cfg, "orp_from", default=None)
    if v is None or v == "":
        return {"orp_from": None}
    folder = Path(str(v)).expanduser()
    if folder.is_file() and folder.name == "summary.json":
        folder = folder.parent
    missing = [n for n in ("summary.json", "config.yaml") if not (folder / n).is_file()]
    if missing:
        raise InputError(f"orp_from={v}: expected a finished evaluation's folder (it has no {missing[0]})")
    return {"orp_from": str(folder), "orp_from_sha256": file_hash(folder / "summary.json")}


def _object_floor(cfg) -> dict[str, Any]:
    """``orp_object_floor``: candidate margins in [0, 1] of a floor on each view's mean value, its object's share of C
    (PIM' above ``orp_object_floor_tau``, in (0, 1)) plus the margin, chosen after the search on the cache's
    validation views (null or []: no floor). Needs the IMS's ``target=pim``; meant for lifted masks (``ims_lift``), whose u
    is their share of C."""
    from imls_lightning.base.validate import check_number

    v = to_plain(OmegaConf.select(cfg, "orp_object_floor", default=None))
    tau = check_number(OmegaConf.select(cfg, "orp_object_floor_tau", default=0.2), "orp_object_floor_tau", 0.0, 1.0,
                       lo_open=True, hi_open=True, what="an importance in (0, 1) above which a pixel counts as the object")
    items = [] if v is None else list(v) if isinstance(v, (list, tuple)) else [v]
    margins = set()
    for m in items:
        margins.add(check_number(m, "orp_object_floor", 0.0, 1.0,
                                 what="a margin or a list of margins in [0, 1] (shares of C above the object's own)"))
    by_band = OmegaConf.select(cfg, "orp_object_floor_by_band", default=False)
    if not isinstance(by_band, bool):
        raise InputError(f"orp_object_floor_by_band={by_band!r}: expected true or false")
    if by_band and margins and not OmegaConf.select(cfg, "orp_by_distance", default=False):
        raise InputError("orp_object_floor_by_band=true: a margin per band of camera distance needs the bands "
                         "(orp_by_distance=true)")
    tail = check_number(OmegaConf.select(cfg, "orp_object_floor_tail", default=1.0), "orp_object_floor_tail", 0.0, 1.0,
                        what="the share in [0, 1] of a band's validation views a margin may leave over epsilon_db")
    return {"orp_object_floor": sorted(margins), "orp_object_floor_tau": tau, "orp_object_floor_by_band": by_band,
            "orp_object_floor_tail": tail}


def _timing(cfg) -> str:
    """``timing``: how a timed view's methods are run (:data:`~imls_lightning.evaluation.timing.TIMING_ORDERS`)."""
    from .timing import TIMING_ORDERS

    v = OmegaConf.select(cfg, "timing", default="interleaved")
    if v not in TIMING_ORDERS:
        raise InputError(f"timing={v}: expected one of {list(TIMING_ORDERS)} (interleaved: each method once per round, "
                         "so a passing load slows them alike)")
    return str(v)


def _two_pass(cfg) -> dict[str, Any]:
    """``two_pass.base`` (the first pass's share of C, in (0, 1); null: the two-pass sampler is not measured) and
    ``two_pass.floor`` (the importance every pixel keeps, relative to the mean, >= 0)."""
    base = OmegaConf.select(cfg, "two_pass.base", default=None)
    floor = OmegaConf.select(cfg, "two_pass.floor", default=0.25)
    if base is not None and (isinstance(base, bool) or not isinstance(base, (int, float)) or not 0.0 < float(base) < 1.0):
        raise InputError(f"two_pass.base={base}: expected the first pass's share of C in (0, 1), or null (no two-pass sampler)")
    if isinstance(floor, bool) or not isinstance(floor, (int, float)) or not math.isfinite(float(floor)) or float(floor) < 0.0:
        raise InputError(f"two_pass.floor={floor}: expected a number >= 0 (the importance every pixel keeps, relative to the mean)")
    return {"two_pass_base": None if base is None else float(base), "two_pass_floor": float(floor)}


def _paths(cfg) -> int:
    """``orp_paths``: with ``orp_views=path``, the camera paths (of seeds of their own) the search views lie on.
    A path's views within a band of camera distance are one or two passes, each one observation, so a bound
    needs passes of several paths."""
    v = _int(cfg, "orp_paths", 2) if OmegaConf.select(cfg, "orp_paths") is not None else 4
    n = _int(cfg, "orp_max_views", 1, allow_none=True)
    if OmegaConf.select(cfg, "orp_views", default="heldout") == "path" and n is not None and n < 2 * v:
        raise InputError(f"orp_max_views={n}: orp_views=path needs at least 2 views per path (orp_paths={v})")
    return v


def _by_distance(cfg) -> bool:
    """``orp_by_distance``: a mean value per band of camera distance; the bands are ``orp_strata``'s (at least 2)."""
    v = OmegaConf.select(cfg, "orp_by_distance", default=False)
    if v not in (True, False, None):
        raise InputError(f"orp_by_distance={v}: expected true or false")
    strata = OmegaConf.select(cfg, "orp_strata", default=1) or 1
    if v and (isinstance(strata, bool) or not isinstance(strata, int) or strata < 2):
        raise InputError(f"orp_by_distance=true: needs orp_strata >= 2 (got {strata}): each band of camera distance "
                         "gets its own mean value")
    return bool(v)


def _orp_views(cfg) -> str:
    v = str(OmegaConf.select(cfg, "orp_views", default="heldout"))
    if v not in ORP_VIEWS:
        raise InputError(f"orp_views={v}: expected one of {list(ORP_VIEWS)} (heldout: views no network was trained on)")
    return v


def _confidence(cfg) -> float:
    """``orp_confidence``: the one-sided confidence of the ORP's bound on the mean validation gap, in [0.5, 1)."""
    from imls_lightning.base.validate import check_number

    return check_number(OmegaConf.select(cfg, "orp_confidence", default=0.95), "orp_confidence", 0.5, 1.0, hi_open=True,
                        what="a confidence in [0.5, 1) (0.5: the mean gap itself)")
