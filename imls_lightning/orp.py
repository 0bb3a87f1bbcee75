"""Optimal rendering percentage (ORP): search the IML mean value by bisection / k-section.

The ORP (paper, "Hyperparameter Tuning: Mean Value" and "Free Rendering Latency Improvement") is the
fewest important pixels whose IML + RecNN reconstruction stays within ``epsilon`` (1 dB) PSNR of the
RecNN alone. The share of important C-Image pixels follows the mean value ``u`` of the importance
normalization, so the search runs over ``u`` in ``[0.01, 1]``, assuming that the gap

    gap(u) = PSNR_RecNN - PSNR_IML+RecNN(u)                       (dB, on the validation views)

decreases as ``u`` grows. This module holds

* the search itself, pure and independent of Hydra: :class:`ORPSearch` (ask/tell: ``next_batch()``
  -> ``tell(...)``, or ``run(objective)``) and its result :class:`ORPResult`;
* the work of one sweep job, :func:`orp_job`: train the IML at one ``u`` (reusing a finished run),
  evaluate IML + RecNN (and IML/S + RecNN) against the RecNN alone on the validation views, time
  the stages, and return the record (also written as ``orp_job.json`` in the job directory);
  :func:`orp_recnn_job`, the sweep's preparatory job when ``recnn.checkpoint`` is not set: train
  (or reuse) the RecNN of the same scene/data; :func:`orp_main` dispatches between them (called
  by ``imls_lightning.train`` when the config has an ``orp_job`` node);
* the report: :func:`orp_report` (the ``orp.yaml`` data) and :func:`format_table`.

The Hydra side (``hydra/sweeper=orp``) is ``hydra_plugins/orp_sweeper``; see ``docs/ORP.md``.

Search rule. Each round evaluates ``k`` interior points that split the bracket ``[lo, hi]`` into
``k + 1`` equal parts (``k = 1``: bisection), evenly in ``log u`` by default (``scale="log"``: the
IPR is roughly proportional to ``u`` and the bracket spans two decades, so equal *relative* steps
give the same precision to a small and a large ORP; ``scale="linear"`` is available). The smallest
``u`` meeting epsilon becomes ``hi``, the largest failing ``u`` below it becomes ``lo``. The search
stops when ``hi <= lo * (1 + tolerance)`` (``tolerance`` is *relative*: 0.1 = the mean value is
known to 10 %) or after ``max_rounds`` rounds. The upper end itself is evaluated only when no
evaluated point met epsilon (one extra round): if it fails too, there is no ORP in the bracket and
the result says so. A failed evaluation (exception, NaN, missing result) is recorded and counts as
not meeting epsilon.

Example:
    >>> search = ORPSearch(epsilon_db=1.0, tolerance=0.1)
    >>> res = search.run(batched(lambda u: 10 * (0.2 - u) if u < 0.2 else 0.0))  # gap <= 1 dB from u = 0.1
    >>> res.found, 0.1 <= res.mean <= 0.11, res.rounds
    (True, True, 6)
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

from data_gen.errors import InputError, boolean, finite_number

__all__ = [
    "DEFAULTS",
    "MEAN_RANGE",
    "SCALES",
    "GAP_OF",
    "ORPSettings",
    "Evaluation",
    "ORPResult",
    "ORPSearch",
    "batched",
    "evaluation_from",
    "round_mean",
    "quote_override_value",
    "ORPJobError",
    "orp_main",
    "orp_job",
    "orp_recnn_job",
    "evaluate_quality",
    "orp_report",
    "format_table",
    "JOB_FILE",
    "REPORT_FILE",
]

# the paper's range of the mean value (== imls_lightning.importance.MEAN_RANGE; not imported, to
# keep this module free of torch for the Hydra plugin scan)
MEAN_RANGE = (0.01, 1.0)
SCALES = ("log", "linear")
GAP_OF = ("iml", "imls")
JOB_FILE = "orp_job.json"
REPORT_FILE = "orp.yaml"

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

# Plain-data keys of the job flag (``++orp_job={...}``) the sweeper passes to each IML job (the
# preparatory RecNN job gets ``++orp_job={stage:recnn}``).
STAGES = ("iml", "recnn")
JOB_KEYS = ("epsilon_db", "with_ims", "gap_of", "latency_views", "latency_repeats", "latency_renderer",
            "ims_overrides", "device", "param")


# --------------------------------------------------------------------------------------------
# settings
# --------------------------------------------------------------------------------------------
def _int(value: Any, key: str, lo: int) -> int:
    x = finite_number(value, key, f"an integer >= {lo}")
    if x != int(x) or x < lo:
        raise InputError(f"{key}={value!r}: expected an integer >= {lo}")
    return int(x)


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
        eps = finite_number(v["epsilon_db"], p + "epsilon_db", "a number of dB >= 0")
        if eps < 0:
            raise InputError(f"{p}epsilon_db={v['epsilon_db']}: expected a number of dB >= 0")
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
        tol = finite_number(v["tolerance"], p + "tolerance", "a relative width in [0.001, 10]")
        if not 1e-3 <= tol <= 10:
            raise InputError(f"{p}tolerance={v['tolerance']}: expected a relative width in [0.001, 10] (0.1 = 10 %)")
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
            epsilon_db=eps, bracket=(lo, hi), tolerance=tol, k=_int(v["k"], p + "k", 1),
            max_rounds=_int(v["max_rounds"], p + "max_rounds", 1), scale=scale, param=param,
            with_ims=with_ims, gap_of=gap_of, latency_views=_int(v["latency_views"], p + "latency_views", 0),
            latency_repeats=_int(v["latency_repeats"], p + "latency_repeats", 1),
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

    def meets(self, epsilon_db: float) -> bool:
        return self.status == "ok" and self.gap_db is not None and self.gap_db <= epsilon_db


def _describe(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return f"{type(err).__name__}: {text}"[:500] if text else type(err).__name__


def evaluation_from(u: float, round_: int, outcome: Any) -> Evaluation:
    """Normalize what an objective returned for ``u`` into an :class:`Evaluation`.

    ``outcome`` may be a gap (float), a record (mapping with ``gap_db``; an ``error`` key or a
    ``status`` other than ``"ok"`` marks a failure), an exception, or ``None`` (missing result).
    Non-finite gaps are failures.
    """
    if isinstance(outcome, BaseException):
        # ORPJobError already names the cause ("InputError: ...")
        text = " ".join(str(outcome).split())[:500] if isinstance(outcome, ORPJobError) else _describe(outcome)
        return Evaluation(u, round_, "failed", None, text)
    if outcome is None:
        return Evaluation(u, round_, "failed", None, "missing result")
    record: dict[str, Any] = {}
    if isinstance(outcome, Mapping):
        record = dict(outcome)
        if record.get("error") or record.get("status", "ok") != "ok":
            return Evaluation(u, round_, "failed", None, str(record.get("error") or f"status {record.get('status')}"), record)
        if "gap_db" not in record:
            return Evaluation(u, round_, "failed", None, "missing result (the job returned no gap_db)", record)
        outcome = record["gap_db"]
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

    Ask/tell: ``batch = s.next_batch()`` (empty when done) -> evaluate -> ``s.tell(outcomes)``;
    or ``s.run(objective)`` with ``objective(list of u) -> list of outcomes``
    (see :func:`evaluation_from`).

    Example:
        >>> s = ORPSearch(k=3, tolerance=0.1)
        >>> s.next_batch()  # quarter points of [0.01, 1] in log u
        [0.031623, 0.1, 0.31623]
    """

    def __init__(self, epsilon_db: float = 1.0, bracket: Sequence[float] = (0.01, 1.0), tolerance: float = 0.1,
                 k: int = 1, max_rounds: int = 10, scale: str = "log"):
        s = ORPSettings.from_mapping({"epsilon_db": epsilon_db, "bracket": list(bracket), "tolerance": tolerance,
                                      "k": k, "max_rounds": max_rounds, "scale": scale, "param": "u"}, prefix="")
        self.epsilon_db, self.tolerance, self.k, self.max_rounds, self.scale = s.epsilon_db, s.tolerance, s.k, s.max_rounds, s.scale
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
        ok = [e for e in self.evaluations if e.meets(self.epsilon_db)]
        return min(ok, key=lambda e: e.u) if ok else None

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
        new = [evaluation_from(u, self.rounds, outcomes[i] if i < len(outcomes) else None) for i, u in enumerate(us)]
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


# --------------------------------------------------------------------------------------------
# Hydra override helpers
# --------------------------------------------------------------------------------------------
def quote_override_value(value: Any) -> str:
    """A value written so that Hydra's override grammar reads it back unchanged.

    Strings are single-quoted (with ``\\`` and ``'`` escaped), lists/dicts recursively, ``None`` is
    ``null``; numbers and booleans as such.

    Example:
        >>> quote_override_value({"a": [1, "x=y"], "b": None, "c": True})
        "{a:[1,'x=y'],b:null,c:true}"
    """
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, Mapping):
        return "{" + ",".join(f"{k}:{quote_override_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(quote_override_value(v) for v in value) + "]"
    s = str(value)
    return "'" + s.replace("\\", "\\\\").replace("'", "\\'") + "'"


def override_key(text: str) -> str:
    """The config key an override line sets (``+model.x=1`` -> ``model.x``; ``model=ims`` -> ``model``)."""
    head = text.split("=", 1)[0].lstrip("+~")
    return head.split("@", 1)[0]


# --------------------------------------------------------------------------------------------
# one sweep job
# --------------------------------------------------------------------------------------------
class ORPJobError(RuntimeError):
    """A job of the ORP sweep could not run (bad input included).

    Deliberately *not* an :class:`InputError`: the CLI's ``cli_errors`` would turn that into
    ``sys.exit(2)``, which ends the whole sweep; Hydra records this one as a FAILED job instead.
    """


def _write_json(path: Path, data: Mapping[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str))
    tmp.replace(path)


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
        msg = _describe(err)
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
        from .training import train

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

    1. train the IML with :func:`imls_lightning.training.train` in its own settings-hashed run
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
    conf_dir = Path(__file__).resolve().parents[1] / "conf"
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3", job_name="orp_ims"):
        return compose(config_name="train", overrides=overrides)


def ims_overrides_for(task_overrides: Sequence[str], iml_checkpoint: str, extra: Sequence[str] = (),
                      recnn_checkpoint: str | None = None) -> list[str]:
    """Overrides that train IMS on ``iml_checkpoint`` with the job's scene/data/RecNN/trainer settings.

    Drops the IML's own ``model`` settings and the ORP flag; keeps everything else (scene, data,
    recnn.checkpoint, trainer limits, paths, ...), sets ``recnn.checkpoint=recnn_checkpoint`` when
    given (the RecNN an IMS checkpoint carries when the IML was standalone), then adds ``extra``.

    Example:
        >>> ims_overrides_for(["model=iml", "model.mean=0.1", "scene=tiny", "++orp_job={k:1}"], "/r/a.ckpt")
        ['scene=tiny', 'model=ims', "iml.checkpoint='/r/a.ckpt'"]
    """
    drop = ("model", "orp_job", "iml.checkpoint") + (("recnn.checkpoint",) if recnn_checkpoint else ())
    keep = [o for o in task_overrides if not any(override_key(o) == d or override_key(o).startswith(d + ".") for d in drop)]
    out = keep + ["model=ims", f"iml.checkpoint={quote_override_value(str(iml_checkpoint))}"]
    if recnn_checkpoint:
        out.append(f"recnn.checkpoint={quote_override_value(str(recnn_checkpoint))}")
    return out + list(extra)


def _orp_job(cfg, task_overrides: list[str], job_dir: Path) -> dict[str, Any]:
    import torch

    from .pipeline import pick_device
    from .tasks.base import load_task
    from .training import train

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
    if recnn_alone_task.pattern.fingerprint() != iml_task.pattern.fingerprint():
        raise InputError(f"recnn.checkpoint={recnn_ckpt}: trained on another sampling pattern/resolution than the IML "
                         f"({recnn_alone_task.pattern.summary()} vs {iml_task.pattern.summary()})")
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
    from .data import ImlsDataModule

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

    from .models.iml import c_share, ipr
    from .metrics import psnr_per_image

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

    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene

    from .pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions, RecNNAlone, time_method

    renderer_cfg = _plain(cfg.renderer) if s.latency_renderer is None else {"name": s.latency_renderer}
    renderer = make_renderer(build_scene(_plain(cfg.scene)), renderer_cfg)
    pattern = iml_task.pattern
    m = pattern.fr_size
    opts = NetOptions(device=str(device))
    methods = {"recnn": RecNNAlone(renderer, pattern, recnn_alone, opts),
               "iml": IMLPlusRecNN(renderer, pattern, iml_task.iml, recnn_iml, opts)}
    if ims_ckpt:
        # a standalone IML's IMS uses the off-the-shelf RecNN, the one IML + RecNN is timed with
        methods["imls"] = IMLSRenderer.from_checkpoints(ims_ckpt, renderer=renderer, opts=opts, recnn_checkpoint=recnn_checkpoint)
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


# --------------------------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------------------------
def _r(x: Any, nd: int = 4) -> Any:
    return round(float(x), nd) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(float(x)) else x


def orp_report(result: ORPResult, settings: ORPSettings, *, job_dirs: Mapping[int, str] | None = None,
               context: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ``orp.yaml`` data: the ORP at the chosen mean value, its PSNRs, gap and latencies,
    every job tried, the search's progress and the settings (plain data).

    ``job_dirs`` maps the index of an evaluation (in ``result.evaluations``) to its job directory
    when the record does not carry it (failed jobs).
    """
    job_dirs = dict(job_dirs or {})
    best = result.best
    rec = best.record if best is not None else {}
    jobs = []
    for i, e in enumerate(result.evaluations):
        r = e.record
        jobs.append({
            "job": i, "round": e.round, "mean": e.u, "status": e.status,
            "meets_epsilon": e.meets(result.epsilon_db), "gap_db": _r(e.gap_db),
            "psnr_db": {k: _r(v) for k, v in (r.get("psnr_db") or {}).items()} or None,
            "ipr": _r(r.get("ipr")), "c_share": _r(r.get("c_share")),
            "imls_ipr": _r(r.get("imls_ipr")), "imls_c_share": _r(r.get("imls_c_share")),
            "job_dir": r.get("job_dir") or job_dirs.get(i), "iml_checkpoint": r.get("iml_checkpoint"),
            "ims_checkpoint": r.get("ims_checkpoint"), "minutes": r.get("minutes"), "error": e.error,
        })
    orp = None
    if best is not None:
        # the paper's ORP is the share of the C-Image rendered; the IPR is the share of the FR-Image
        orp = {"c_share": _r(rec.get("imls_c_share") if settings.gap_of == "imls" else rec.get("c_share")),
               "ipr": _r(rec.get("imls_ipr") if settings.gap_of == "imls" else rec.get("ipr")),
               "mean": best.u, "gap_of": settings.gap_of}
    return {
        "orp": orp,
        "found": result.found,
        "mean": result.mean,
        "epsilon_db": result.epsilon_db,
        "gap_db": _r(best.gap_db) if best is not None else None,
        "psnr_db": {k: _r(v) for k, v in (rec.get("psnr_db") or {}).items()} if best is not None else None,
        "latency_ms": rec.get("latency_ms") if best is not None else None,
        "iml_checkpoint": rec.get("iml_checkpoint"),
        "ims_checkpoint": rec.get("ims_checkpoint"),
        "recnn_checkpoint": rec.get("recnn_checkpoint"),
        "search": {"rounds": result.rounds, "jobs": result.jobs, "stop_reason": result.stop_reason,
                   "bracket_final": [result.bracket[0], result.bracket[1]], "non_monotone": result.non_monotone},
        "settings": settings.as_dict(),
        **({"context": dict(context)} if context else {}),
        "jobs": jobs,
    }


def format_table(report: Mapping[str, Any]) -> str:
    """A short text table of the jobs tried and the ORP found."""

    def f(x: Any, spec: str) -> str:
        return format(x, spec) if isinstance(x, (int, float)) and not isinstance(x, bool) else "-"

    lines = [f"{'job':>3} {'round':>5} {'mean':>9} {'status':>6} {'gap dB':>8} {'IML+RecNN':>10} {'RecNN':>8} {'IML/S':>8} {'C-share':>8} {'IPR':>7}  ok"]
    for j in report["jobs"]:
        p = j.get("psnr_db") or {}
        lines.append(
            f"{j['job']:>3} {j['round']:>5} {j['mean']:>9.5g} {j['status']:>6} {f(j['gap_db'], '8.3f'):>8} "
            f"{f(p.get('iml_recnn'), '10.2f'):>10} {f(p.get('recnn'), '8.2f'):>8} {f(p.get('imls_recnn'), '8.2f'):>8} "
            f"{f(j['c_share'], '8.3f'):>8} {f(j['ipr'], '7.3f'):>7}  {'yes' if j['meets_epsilon'] else 'no'}"
            + (f"   ({j['error'][:80]})" if j.get("error") else "")
        )
    s = report["search"]
    if report["orp"]:
        o = report["orp"]
        lat = report.get("latency_ms") or {}
        speed = lat.get("speedup_vs_recnn")
        share = f"{100 * o['c_share']:.1f}% of the C-Image" if isinstance(o["c_share"], (int, float)) else "?"
        ipr = f"IPR {100 * o['ipr']:.2f}%" if isinstance(o["ipr"], (int, float)) else "IPR ?"
        lines.append(f"ORP: {share} ({ipr}) at {report['settings']['param']}={o['mean']:.5g}, "
                     f"gap {report['gap_db']:.3f} dB <= {report['epsilon_db']} dB"
                     + (f", selective-render speed-up x{speed:.2f}" if isinstance(speed, (int, float)) else ""))
    else:
        lines.append(f"ORP: none - no mean value in {report['settings']['bracket']} kept the gap within {report['epsilon_db']} dB")
    lines.append(f"({s['jobs']} jobs in {s['rounds']} rounds; stopped: {s['stop_reason']}"
                 + ("; gap(u) was not monotone" if s["non_monotone"] else "") + ")")
    return "\n".join(lines)
