"""The ORP search, pure and torch-free: its knobs (:class:`ORPSettings`, :data:`DEFAULTS`), the
bisection / k-section over the mean value (:class:`ORPSearch`, ask/tell or ``run``) and its result
(:class:`ORPResult`, one :class:`Evaluation` per mean value tried).

No Hydra and no torch here: the Hydra sweeper plugin (``hydra_plugins/orp_sweeper``) imports this
module while Hydra scans its plugins (``tests/orp/test_search.py`` checks that importing it loads no torch).
The search rule is described in :mod:`imls_lightning.orp`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

from imls_lightning.base.errors import InputError, boolean, finite_number
from imls_lightning.base.validate import check_integer, check_number
from imls_lightning.core.smallest_within import smallest_within, within

# the paper's range of the mean value (== imls_lightning.core.importance.MEAN_RANGE; not imported, to
# keep this module free of torch for the Hydra plugin scan)
MEAN_RANGE = (0.01, 1.0)
SCALES = ("log", "linear")
GAP_OF = ("iml", "imls")

# Every knob of ``hydra/sweeper=orp``. conf/train.yaml's top-level ``sweeper:`` node repeats these
# values (tests check they agree) so that the short form ``sweeper.epsilon_db=...`` works.
DEFAULTS: dict[str, Any] = {
    "epsilon_db": 1.0,          # PSNR gap allowed between IML + RecNN and the RecNN alone (paper: 1 dB)
    "bracket": [0.01, 1.0],     # mean values searched (paper: [0.01, 1])
    "tolerance": 0.1,           # relative: stop when hi <= lo * (1 + tolerance)
    "k": 1,                     # mean values per round (1: bisection; k > 1: k-section, run in parallel by the launcher)
    "max_rounds": 10,           # rounds of k-section at most (the upper-end check may add one)
    "scale": "log",             # log | linear: where the interior points lie
    "param": "model.mean",      # the config key searched
    "with_ims": False,          # also train IMS on each IML and evaluate IML/S + RecNN
    "gap_of": "iml",            # iml | imls: which reconstruction's gap must stay within epsilon
    "latency_views": 3,         # validation views timed per job (0: no timing)
    "latency_repeats": 10,      # runs per view; the median is kept (>= 10 for reported numbers)
    "latency_renderer": None,   # renderer for the selective-render timing: null = the run's renderer
    "ims_overrides": [],        # extra overrides for the IMS training, e.g. [model.layers=6]
    "device": "auto",           # evaluation device: auto | cpu | cuda
}

# Plain-data keys of the job flag (``++orp_job={...}``) the sweeper passes to each IML job.
JOB_KEYS = ("epsilon_db", "with_ims", "gap_of", "latency_views", "latency_repeats", "latency_renderer",
            "ims_overrides", "device", "param")


# --------------------------------------------------------------------------------------------
# settings
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ORPSettings:
    """Validated knobs of the ORP search (see :data:`DEFAULTS` for their meaning).

    Build with :meth:`from_mapping`, which names the offending knob in its :class:`InputError`.
    """

    epsilon_db: float = 1.0
    bracket: tuple[float, float] = (0.01, 1.0)
    tolerance: float = 0.1
    k: int = 1
    max_rounds: int = 10
    scale: str = "log"
    param: str = "model.mean"
    with_ims: bool = False
    gap_of: str = "iml"
    latency_views: int = 3
    latency_repeats: int = 10
    latency_renderer: str | None = None
    ims_overrides: tuple[str, ...] = ()
    device: str = "auto"

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None = None, prefix: str = "hydra.sweeper.") -> "ORPSettings":
        """Validate a mapping of knobs (missing ones take :data:`DEFAULTS`; unknown ones are an error)."""
        v = dict(DEFAULTS)
        for key, val in dict(values or {}).items():
            if key.startswith("_"):
                continue  # _target_
            if key not in DEFAULTS:
                raise InputError(f"{prefix}{key}: unknown knob of the ORP sweeper (expected one of {sorted(DEFAULTS)})")
            v[key] = val
        p = prefix
        eps = check_number(v["epsilon_db"], p + "epsilon_db", 0, what="a number of dB >= 0")
        br = v["bracket"]
        if isinstance(br, (str, bytes)) or not isinstance(br, Iterable) or len(list(br)) != 2:
            raise InputError(f"{p}bracket={br!r}: expected two mean values [lo, hi]")
        lo, hi = (finite_number(x, p + "bracket", "two numbers [lo, hi]") for x in br)
        scale = str(v["scale"])
        if scale not in SCALES:
            raise InputError(f"{p}scale={scale!r}: expected one of {list(SCALES)}")
        param = str(v["param"])
        if not param or param.startswith(("+", "~")) or "=" in param:
            raise InputError(f"{p}param={param!r}: expected a config key such as model.mean")
        if not lo < hi:
            raise InputError(f"{p}bracket=[{lo}, {hi}]: expected lo < hi")
        if param == "model.mean" and not (MEAN_RANGE[0] <= lo and hi <= MEAN_RANGE[1]):
            raise InputError(f"{p}bracket=[{lo}, {hi}]: the mean value must lie in [{MEAN_RANGE[0]}, {MEAN_RANGE[1]}]")
        if scale == "log" and lo <= 0:
            raise InputError(f"{p}bracket=[{lo}, {hi}]: scale=log needs lo > 0")
        tol = check_number(v["tolerance"], p + "tolerance", 1e-3, 10, what="a relative width in [0.001, 10] (0.1 = 10 %)")
        gap_of = str(v["gap_of"])
        if gap_of not in GAP_OF:
            raise InputError(f"{p}gap_of={gap_of!r}: expected one of {list(GAP_OF)}")
        with_ims = boolean(v["with_ims"], p + "with_ims")
        if gap_of == "imls" and not with_ims:
            raise InputError(f"{p}gap_of=imls: needs {p}with_ims=true (IML/S is only evaluated with IMS)")
        ims = v["ims_overrides"] if v["ims_overrides"] is not None else []
        if isinstance(ims, str) or not all(isinstance(x, str) and "=" in x for x in ims):
            raise InputError(f"{p}ims_overrides={ims!r}: expected a list of overrides like [model.layers=6]")
        rend = v["latency_renderer"]
        if rend is not None and str(rend) not in ("vtk", "numba"):
            raise InputError(f"{p}latency_renderer={rend!r}: expected null (the run's renderer), vtk or numba")
        dev = str(v["device"])
        if dev != "auto" and not dev.startswith(("cpu", "cuda")):
            raise InputError(f"{p}device={dev!r}: expected auto, cpu or cuda[:N]")
        return cls(
            epsilon_db=eps, bracket=(lo, hi), tolerance=tol, k=check_integer(v["k"], p + "k", 1),
            max_rounds=check_integer(v["max_rounds"], p + "max_rounds", 1), scale=scale, param=param,
            with_ims=with_ims, gap_of=gap_of, latency_views=check_integer(v["latency_views"], p + "latency_views", 0),
            latency_repeats=check_integer(v["latency_repeats"], p + "latency_repeats", 1),
            latency_renderer=None if rend is None else str(rend), ims_overrides=tuple(ims), device=dev,
        )

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in DEFAULTS}
        d["bracket"] = list(self.bracket)
        d["ims_overrides"] = list(self.ims_overrides)
        return d

    def job_flag(self) -> dict[str, Any]:
        """What a job needs to know (passed as ``++orp_job={...}``)."""
        d = self.as_dict()
        return {k: d[k] for k in JOB_KEYS}

    def search(self) -> "ORPSearch":
        return ORPSearch(epsilon_db=self.epsilon_db, bracket=self.bracket, tolerance=self.tolerance,
                         k=self.k, max_rounds=self.max_rounds, scale=self.scale)


# --------------------------------------------------------------------------------------------
# the search
# --------------------------------------------------------------------------------------------
def round_mean(u: float) -> float:
    """Mean values are tried with 5 significant digits (readable overrides, exact records).

    Example:
        >>> round_mean(0.031622776601683794)
        0.031623
    """
    return float(f"{float(u):.5g}")


@dataclass(frozen=True)
class GapBound:
    """The per-view PSNR gaps of one mean value, summarized: ``mean`` and sample ``std`` (dB) over
    ``views`` views, and ``bound``, the one-sided upper bound at ``confidence`` on the mean gap of all
    such views (``future_views=None``) or of ``future_views`` new ones (:func:`gap_upper_bound`)."""

    mean: float
    std: float
    views: int
    bound: float
    confidence: float
    future_views: int | None = None
    #: with :func:`pass_gap_bound`: the passes the views form (``mean``, ``std`` and ``bound`` are over pass means)
    passes: int | None = None

    @property
    def margin(self) -> float:
        """``bound - mean`` (dB): what the spread of the views adds."""
        return self.bound - self.mean


def gap_upper_bound(gaps: Sequence[float], confidence: float = 0.95, future_views: int | None = None) -> GapBound:
    """One-sided upper bound on the mean PSNR gap over views (the ORP's margin for unseen views).

    ``bound = mean + z * s * sqrt(1/n + 1/m)``: ``s`` the sample standard deviation (``n - 1``) of
    the ``n`` per-view gaps, ``z`` the standard normal quantile at ``confidence`` (1.645 at 0.95; 0 at
    0.5, where the bound is the mean gap). With ``future_views=m`` it bounds the mean gap that ``m``
    new views will show (a prediction bound: the search views' mean and the new views' mean both
    vary); with ``None`` the ``1/m`` term is left out and it bounds the mean gap of all such views
    (a confidence bound). The ORP search requires ``bound <= epsilon``, so an operating point chosen on
    few or very different views keeps a margin for the views it was not chosen on. One view gives no
    spread: its bound is its gap.

    Args:
        gaps: ``(n,)`` per-view gaps (dB), ``PSNR_RecNN - PSNR_IML/S``; ``n >= 1``, all finite.
        confidence: in ``[0.5, 1)``.
        future_views: ``m >= 1`` or ``None``.

    Returns:
        :class:`GapBound`.

    Raises:
        InputError: no gaps, a non-finite gap, ``confidence`` outside ``[0.5, 1)`` or ``future_views < 1``.

    Example:
        >>> b = gap_upper_bound([0.5, 1.0, 1.5, 1.0], confidence=0.95)
        >>> round(b.mean, 3), round(b.std, 3), round(b.bound, 3)
        (1.0, 0.408, 1.336)
        >>> round(gap_upper_bound([0.5, 1.0, 1.5, 1.0], 0.95, future_views=4).bound, 3)
        1.475
    """
    from statistics import NormalDist

    conf = check_number(confidence, "orp_confidence", 0.5, 1.0, hi_open=True, what="a confidence in [0.5, 1)")
    m = None if future_views is None else check_integer(future_views, "future_views", 1)
    xs = [float(g) for g in gaps]
    if not xs:
        raise InputError("gap_upper_bound: no per-view gaps (expected at least one validation view)")
    if not all(math.isfinite(x) for x in xs):
        raise InputError(f"gap_upper_bound: non-finite per-view gap in {xs[:8]}")
    n = len(xs)
    mean = math.fsum(xs) / n
    std = math.sqrt(math.fsum((x - mean) ** 2 for x in xs) / (n - 1)) if n > 1 else 0.0
    z = NormalDist().inv_cdf(conf) if conf > 0.5 else 0.0
    spread = std * math.sqrt(1.0 / n + (1.0 / m if m else 0.0))
    return GapBound(mean=mean, std=std, views=n, bound=mean + z * spread, confidence=conf, future_views=m)


def path_passes(paths: Sequence[int], strata: Sequence[int] | None = None) -> list[int]:
    """A pass label per view of one or more camera paths, the views in path order: consecutive views of one
    path within one stratum (band of camera distance) form a pass.

    Neighbouring views of a path show nearly the same scene, so their gaps are nearly the same: on ct_head the
    per-view gap's lag-1 autocorrelation along a 40-view path is 0.9, and the farthest quarter of a path's views is
    one pass at one elevation (-35 degrees on the test path, -4 and +17 on two search paths: 1.3, 0.6 and 1.4 dB at
    the same mean value). A pass, not a view, is one observation (:func:`pass_gap_bound`).

    Example:
        >>> path_passes([0, 0, 0, 1, 1, 1], [0, 1, 1, 1, 1, 0])
        [0, 1, 1, 2, 2, 3]
    """
    labels = [int(x) for x in paths]
    bands = [0] * len(labels) if strata is None else [int(x) for x in strata]
    if len(bands) != len(labels):
        raise InputError(f"path_passes: {len(labels)} path labels but {len(bands)} stratum labels")
    out, current = [], -1
    for i, (path, band) in enumerate(zip(labels, bands)):
        if i == 0 or path != labels[i - 1] or band != bands[i - 1]:
            current += 1
        out.append(current)
    return out


def future_path_passes(passes: int, paths: int) -> int:
    """The passes one new path makes where ``paths`` search paths made ``passes``: ``passes / paths`` rounded,
    at least one. The promise is for the next trajectory, not for as many new views as the search had.

    Example:
        >>> future_path_passes(6, 4), future_path_passes(4, 4), future_path_passes(1, 4)
        (2, 1, 1)
    """
    return max(1, round(int(passes) / check_integer(paths, "orp_paths", 1)))


def pass_gap_bound(gaps: Sequence[float], passes: Sequence[int], confidence: float = 0.95,
                   future_passes: int | None = None) -> GapBound:
    """:func:`gap_upper_bound` with passes as the observations: the bound on the mean gap of ``future_passes`` new
    passes (``None``: of all passes), from the mean gap of each pass, each pass weighing alike.

    The views of one pass are one observation of the view distribution (:func:`path_passes`): a bound that counted
    them as independent would shrink with the number of views while the next path's pass falls elsewhere. One
    pass gives no spread between passes, so its bound is infinite (nothing is promised from it).

    Args:
        gaps: ``(n,)`` per-view gaps (dB), all finite.
        passes: ``(n,)`` a pass label per view.
        confidence, future_passes: as :func:`gap_upper_bound`'s ``confidence`` and ``future_views``.

    Returns:
        :class:`GapBound` whose ``views`` is ``n`` and ``passes`` the number of passes.

    Example:
        >>> b = pass_gap_bound([1.0, 1.2, 0.2, 0.4, 0.6, 0.6], [0, 0, 1, 1, 2, 2], 0.95, future_passes=1)
        >>> round(b.mean, 2), b.passes, round(b.bound, 2)
        (0.67, 3, 1.43)
        >>> pass_gap_bound([1.0, 1.2], [0, 0]).bound
        inf
    """
    xs, labels = [float(g) for g in gaps], [int(x) for x in passes]
    if len(xs) != len(labels):
        raise InputError(f"pass_gap_bound: {len(xs)} gaps but {len(labels)} pass labels")
    groups: dict[int, list[float]] = {}
    for g, lab in zip(xs, labels):
        groups.setdefault(lab, []).append(g)
    means = [math.fsum(v) / len(v) for v in groups.values()]
    b = gap_upper_bound(means, confidence, future_passes)
    if len(means) < 2:
        b = dataclasses.replace(b, bound=math.inf)
    return dataclasses.replace(b, views=len(xs), passes=len(means))


def strata_by_rank(values: Sequence[float], strata: int) -> list[int]:
    """A stratum label in ``[0, strata)`` per value: ``strata`` equal-count bins by rank (ties by position), e.g.
    the search views by camera distance.

    Example:
        >>> strata_by_rank([3.0, 2.4, 2.9, 2.5], 2)
        [1, 0, 1, 0]
    """
    k = check_integer(strata, "orp_strata", 1)
    order = sorted(range(len(values)), key=lambda i: (float(values[i]), i))
    labels = [0] * len(values)
    for rank, i in enumerate(order):
        labels[i] = rank * min(k, len(values)) // max(len(values), 1)
    return labels


def stratified_gap_bound(gaps: Sequence[float], strata: Sequence[int], confidence: float = 0.95,
                         future_views: int | None = None, passes: Sequence[int] | None = None,
                         paths: int = 1) -> tuple[GapBound, list[GapBound]]:
    """:func:`gap_upper_bound` in each stratum of the views, and the stratum whose bound is largest.

    A mean gap within epsilon on the search views holds on another trajectory only if that trajectory weights the
    views alike. Where the gap depends on the view (on seed_shell it grows on close-ups: 3.1 dB on the closest
    quarter of the test views, 0.1 dB on the farthest), a bound in every stratum holds for any mixture of them.
    Each stratum's bound is for its share of ``future_views``; with ``passes`` (the views of ``paths`` camera paths,
    :func:`path_passes`) it is :func:`pass_gap_bound` for the passes one new path makes through the stratum (its
    passes over ``paths``, at least one).

    Returns:
        ``(worst, per_stratum)``: the :class:`GapBound` with the largest bound, and one per stratum label (sorted).

    Example:
        >>> worst, each = stratified_gap_bound([2.0, 1.8, 0.2, 0.4], [0, 0, 1, 1], confidence=0.5)
        >>> round(worst.mean, 2), [round(b.mean, 2) for b in each]
        (1.9, [1.9, 0.3])
    """
    xs, labels = [float(g) for g in gaps], [int(x) for x in strata]
    if len(xs) != len(labels):
        raise InputError(f"stratified_gap_bound: {len(xs)} gaps but {len(labels)} stratum labels")
    each = []
    if passes is not None and len(passes) != len(xs):
        raise InputError(f"stratified_gap_bound: {len(xs)} gaps but {len(passes)} pass labels")
    for k in sorted(set(labels)):
        part = [g for g, lab in zip(xs, labels) if lab == k]
        if passes is not None:
            own = [p for p, lab in zip(passes, labels) if lab == k]
            each.append(pass_gap_bound(part, own, confidence, future_path_passes(len(set(own)), paths)))
            continue
        share = None if future_views is None else max(1, round(future_views * len(part) / len(xs)))
        each.append(gap_upper_bound(part, confidence, share))
    if not each:
        raise InputError("stratified_gap_bound: no per-view gaps (expected at least one validation view)")
    return max(each, key=lambda b: b.bound), each


def protocol_gap_record(gaps: Sequence[float], confidence: float = 0.95, future_views: int | None = None,
                        strata: Sequence[int] | None = None, passes: Sequence[int] | None = None,
                        paths: int = 1) -> dict[str, Any]:
    """The ORP protocol's judgement of per-view gaps, one home for every operating point searched on views: the
    mean gap and its bound for ``future_views`` new views (:func:`gap_upper_bound`); with ``passes`` (views along
    ``paths`` camera paths) the bound over passes for one new path (:func:`pass_gap_bound`); with ``strata`` the
    largest stratum's bound (:func:`stratified_gap_bound`), which must hold in each band.

    Returns:
        ``gap_db`` (the mean per-view gap), ``gap_std_db``, ``gap_bound_db`` (what a search compares with epsilon),
        ``views``, ``confidence``, ``future_views``; with ``passes`` also ``passes``, with ``strata`` also
        ``strata_gap_db`` (each stratum's mean gap).

    Example:
        >>> r = protocol_gap_record([0.4, 0.6, 0.5, 0.5], confidence=0.5)
        >>> round(r["gap_db"], 2), round(r["gap_bound_db"], 2)
        (0.5, 0.5)
    """
    b = gap_upper_bound(gaps, confidence, future_views)
    rec: dict[str, Any] = {"gap_db": b.mean, "gap_std_db": b.std, "gap_bound_db": b.bound, "views": b.views,
                           "confidence": b.confidence, "future_views": b.future_views}
    if passes is not None:  # views along camera paths: a pass, not a view, is one observation
        pb = pass_gap_bound(gaps, passes, confidence, future_path_passes(len(set(passes)), paths))
        rec.update(gap_bound_db=pb.bound, passes=pb.passes)
    if strata is not None:
        worst, each = stratified_gap_bound(gaps, strata, confidence, future_views, passes, paths)
        rec.update(gap_bound_db=worst.bound, strata_gap_db=[e.mean for e in each])
    return rec


@dataclass
class Evaluation:
    """One mean value tried: its gap (dB), status and the job's record.

    ``status`` is ``"ok"`` or ``"failed"`` (exception, NaN gap, missing result); a failed evaluation
    never meets epsilon.
    """

    u: float
    round: int
    status: str
    gap_db: float | None = None
    error: str | None = None
    record: dict[str, Any] = field(default_factory=dict)

    @property
    def gap(self) -> float:
        """The gap judged against epsilon: ``gap_db``, NaN (never within) for a failed evaluation."""
        return self.gap_db if self.status == "ok" and self.gap_db is not None else math.nan

    def meets(self, epsilon_db: float) -> bool:
        return within(self.gap, epsilon_db)


def describe_error(err: BaseException) -> str:
    """``"<ExceptionType>: <message on one line>"`` (at most 500 characters), as records show errors."""
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}"[:500] if text else type(err).__name__


class ORPJobError(RuntimeError):
    """A job of the ORP sweep could not run (bad input included).

    Deliberately *not* an :class:`InputError`: the CLI's ``cli_errors`` would turn that into
    ``sys.exit(2)``, which ends the whole sweep; Hydra records this one as a FAILED job instead.
    """


def evaluation_from(u: float, round_: int, outcome: Any, criterion: str = "gap_db") -> Evaluation:
    """Normalize what an objective returned for ``u`` into an :class:`Evaluation`.

    ``outcome`` may be a gap (float), a record (mapping with the ``criterion`` key, ``gap_db`` by
    default: the value compared with epsilon, e.g. ``gap_bound_db`` for a confidence bound; an
    ``error`` key or a ``status`` other than ``"ok"`` marks a failure), an exception, or ``None``
    (missing result). Non-finite gaps are failures.
    """
    if isinstance(outcome, BaseException):
        # ORPJobError already names the cause ("InputError: ...")
        text = " ".join(str(outcome).split())[:500] if isinstance(outcome, ORPJobError) else describe_error(outcome)
        return Evaluation(u, round_, "failed", None, text)
    if outcome is None:
        return Evaluation(u, round_, "failed", None, "missing result")
    record: dict[str, Any] = {}
    if isinstance(outcome, Mapping):
        record = dict(outcome)
        if record.get("error") or record.get("status", "ok") != "ok":
            return Evaluation(u, round_, "failed", None, str(record.get("error") or f"status {record.get('status')}"), record)
        if criterion not in record:
            return Evaluation(u, round_, "failed", None, f"missing result (the job returned no {criterion})", record)
        outcome = record[criterion]
    try:
        gap = float(outcome)
    except (TypeError, ValueError):
        return Evaluation(u, round_, "failed", None, f"not a gap: {outcome!r}"[:200], record)
    if not math.isfinite(gap):
        return Evaluation(u, round_, "failed", None, f"non-finite gap ({gap})", record)
    return Evaluation(u, round_, "ok", gap, None, record)


def batched(fn: Callable[[float], Any]) -> Callable[[Sequence[float]], list[Any]]:
    """Turn a one-point objective ``u -> gap | record`` into a batch objective; exceptions become
    failed outcomes instead of stopping the search."""

    def objective(us: Sequence[float]) -> list[Any]:
        out: list[Any] = []
        for u in us:
            try:
                out.append(fn(u))
            except Exception as err:  # a failed job: recorded, the search goes on
                out.append(err)
        return out

    return objective


@dataclass
class ORPResult:
    """Outcome of a search.

    Attributes:
        found: some evaluated mean value met epsilon.
        mean: the smallest evaluated mean value meeting epsilon (``None`` when not found).
        best: its :class:`Evaluation`.
        bracket: final ``(lo, hi)``; ``hi`` is verified when ``found``.
        rounds, jobs: batches launched (including an upper-end check) and mean values evaluated.
        stop_reason: why it stopped (``"tolerance"``, ``"max_rounds"``, ``"no_solution"``, ...).
        non_monotone: some failing mean value lies above a passing one (gap(u) is not monotone: the
            answer is the smallest passing value seen, but a re-run may differ).
        evaluations: every evaluation, in order.
    """

    found: bool
    mean: float | None
    best: Evaluation | None
    bracket: tuple[float, float]
    rounds: int
    jobs: int
    stop_reason: str
    non_monotone: bool
    evaluations: list[Evaluation]
    epsilon_db: float


class ORPSearch:
    """Bisection (``k=1``) or k-section of the mean value for the smallest ``u`` with gap <= epsilon.

    Args:
        epsilon_db: allowed PSNR gap (dB).
        bracket: ``(lo, hi)`` mean values; ``lo`` is assumed to fail (never evaluated), ``hi`` is
            evaluated only if nothing inside passes.
        tolerance: relative stopping width: stop when ``hi <= lo * (1 + tolerance)``.
        k: interior points per round (evaluated together, e.g. in parallel).
        max_rounds: k-section rounds at most.
        scale: ``"log"`` (points evenly spaced in ``log u``) or ``"linear"``.
        criterion: the key of an outcome record whose value must stay within epsilon
            (:func:`evaluation_from`; ``"gap_db"``, or ``"gap_bound_db"`` for a confidence bound).

    Ask/tell: ``batch = s.next_batch()`` (empty when done) -> evaluate -> ``s.tell(outcomes)``;
    or ``s.run(objective)`` with ``objective(list of u) -> list of outcomes``
    (see :func:`evaluation_from`).

    Example:
        >>> s = ORPSearch(k=3, tolerance=0.1)
        >>> s.next_batch()  # quarter points of [0.01, 1] in log u
        [0.031623, 0.1, 0.31623]
    """

    def __init__(self, epsilon_db: float = 1.0, bracket: Sequence[float] = (0.01, 1.0), tolerance: float = 0.1,
                 k: int = 1, max_rounds: int = 10, scale: str = "log", criterion: str = "gap_db"):
        s = ORPSettings.from_mapping({"epsilon_db": epsilon_db, "bracket": list(bracket), "tolerance": tolerance,
                                      "k": k, "max_rounds": max_rounds, "scale": scale, "param": "u"}, prefix="")
        self.epsilon_db, self.tolerance, self.k, self.max_rounds, self.scale = s.epsilon_db, s.tolerance, s.k, s.max_rounds, s.scale
        self.criterion = str(criterion)
        self.bracket0 = (round_mean(s.bracket[0]), round_mean(s.bracket[1]))
        self.lo, self.hi = self.bracket0
        self.evaluations: list[Evaluation] = []
        self.rounds = 0
        self.stop_reason: str | None = None
        self._pending: list[float] | None = None

    # -- state --------------------------------------------------------------------------------
    def _t(self, u: float) -> float:
        return math.log(u) if self.scale == "log" else u

    def _u(self, t: float) -> float:
        return math.exp(t) if self.scale == "log" else t

    def converged(self) -> bool:
        return self.hi <= self.lo * (1.0 + self.tolerance) if self.lo > 0 else self.hi - self.lo <= self.tolerance * self.hi

    def best(self) -> Evaluation | None:
        """The evaluation of the smallest mean value that meets epsilon (the earlier on a tie); None: none does."""
        return smallest_within(self.evaluations, self.epsilon_db, gap=lambda e: e.gap, value=lambda e: e.u).item

    def evaluated(self, u: float) -> bool:
        return any(e.u == u for e in self.evaluations)

    @property
    def done(self) -> bool:
        return self.stop_reason is not None

    # -- ask / tell ---------------------------------------------------------------------------
    def next_batch(self) -> list[float]:
        """The mean values to evaluate next (rounded, ascending); empty when the search is over."""
        if self.stop_reason is not None:
            return []
        if self._pending is not None:
            raise RuntimeError("ORPSearch.next_batch: tell() the outcomes of the previous batch first")
        reason = None
        if self.converged():
            reason = "tolerance"
        elif self.rounds >= self.max_rounds + (1 if self._upper_checked() else 0):
            reason = "max_rounds"
        else:
            t0, t1 = self._t(self.lo), self._t(self.hi)
            pts = sorted({round_mean(self._u(t0 + (t1 - t0) * i / (self.k + 1))) for i in range(1, self.k + 1)})
            pts = [u for u in pts if self.lo < u < self.hi and not self.evaluated(u)]
            if pts:
                self._pending = pts
                return list(pts)
            reason = "resolution"  # no new 5-digit mean value inside the bracket
        if self.best() is None and not self._upper_checked():
            # nothing passed: is there an ORP at all? (one extra round at the upper end)
            self._pending = [self.bracket0[1]]
            return [self.bracket0[1]]
        self.stop_reason = "no_solution" if self.best() is None else reason
        return []

    def _upper_checked(self) -> bool:
        return self.evaluated(self.bracket0[1])

    def tell(self, outcomes: Sequence[Any]) -> list[Evaluation]:
        """Record the outcomes of the last batch (same order; missing ones count as failed)."""
        if self._pending is None:
            raise RuntimeError("ORPSearch.tell: no batch is pending (call next_batch first)")
        us, self._pending = self._pending, None
        self.rounds += 1
        outcomes = list(outcomes)
        new = [evaluation_from(u, self.rounds, outcomes[i] if i < len(outcomes) else None, self.criterion)
               for i, u in enumerate(us)]
        self.evaluations.extend(new)
        best = self.best()
        self.hi = best.u if best is not None else self.bracket0[1]
        below = [e.u for e in self.evaluations if not e.meets(self.epsilon_db) and e.u < self.hi]
        self.lo = max(below, default=self.bracket0[0])
        if best is None and self._upper_checked():
            self.stop_reason = "no_solution"
        return new

    def run(self, objective: Callable[[Sequence[float]], Sequence[Any]]) -> ORPResult:
        """Run to the end: ``objective(list of u) -> outcomes`` per batch."""
        while True:
            batch = self.next_batch()
            if not batch:
                break
            try:
                outcomes = objective(batch)
            except Exception as err:  # the whole batch failed (e.g. the launcher): recorded, go on
                outcomes = [err] * len(batch)
            self.tell(outcomes)
        return self.result()

    def result(self) -> ORPResult:
        best = self.best()
        non_mono = best is not None and any(e.status == "ok" and not e.meets(self.epsilon_db) and e.u > best.u
                                            for e in self.evaluations)
        return ORPResult(
            found=best is not None, mean=None if best is None else best.u, best=best,
            bracket=(self.lo, self.hi), rounds=self.rounds, jobs=len(self.evaluations),
            stop_reason=self.stop_reason or "running", non_monotone=non_mono,
            evaluations=list(self.evaluations), epsilon_db=self.epsilon_db,
        )

