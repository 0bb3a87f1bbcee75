"""``hydra/sweeper=orp``: find the optimal rendering percentage by bisection / k-section of the mean value.

    python -m imls_lightning.train -m model=iml recnn=enhancenet hydra/sweeper=orp sweeper.epsilon_db=1.0

The search rule, the work of one job and the report live in :mod:`imls_lightning.orp`; this module
is the Hydra side:

1. validate the knobs (``sweeper.<knob>`` in the primary config, or ``hydra.sweeper.<knob>``,
   which wins) and the sweep's overrides (single values only: the sweeper chooses ``param``);
2. the RecNN the IML is compared with: ``recnn.checkpoint`` when set, else one preparatory job
   (``model=recnn`` with the sweep's other overrides) trains it in its settings-hashed run
   directory, or reuses that run when it already finished - the same run
   ``python -m imls_lightning.train model=recnn ...`` makes;
3. each round: ``k`` mean values from :class:`~imls_lightning.orp.ORPSearch`, launched together
   through the configured launcher (``hydra/launcher=basic|joblib|submitit_*``) with the overrides
   ``<param>=<u> recnn.checkpoint=<ckpt> ++orp_job={...}``; each job's return value (or its
   ``orp_job.json``) is told to the search; a failed job (exception, ``None``, NaN) is recorded and
   counts as not meeting epsilon;
4. ``orp.yaml`` in the sweep directory (rewritten atomically after every round) and a table on stdout.

Bad knobs or overrides end the sweep with one line ``error: ...`` and exit status 2 (project
convention), before any job runs.
"""
# no `from __future__ import annotations`: Hydra execs this module before it is in sys.modules,
# and dataclasses then cannot resolve string annotations
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, List, Optional, Sequence

from hydra.core.config_store import ConfigStore
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.launcher import Launcher
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


def _knob(key: str) -> str:
    # null when the primary config has no `sweeper.<key>`: imls_lightning.orp.DEFAULTS applies then
    return "${oc.select:sweeper." + key + ",null}"


@dataclass
class ORPSweeperConf:
    """Structured config of ``hydra/sweeper=orp``.

    Every knob reads the primary config's ``sweeper.<knob>`` (conf/train.yaml repeats
    ``imls_lightning.orp.DEFAULTS`` there), so ``sweeper.epsilon_db=0.5`` and
    ``hydra.sweeper.epsilon_db=0.5`` both work; ``null`` means the default. The meanings are in
    ``imls_lightning.orp.DEFAULTS`` and docs/ORP.md. Typed ``Any``: the sweeper validates them
    with messages naming the knob.
    """

    _target_: str = "hydra_plugins.orp_sweeper.orp_sweeper.ORPSweeper"
    epsilon_db: Any = _knob("epsilon_db")
    bracket: Any = _knob("bracket")
    tolerance: Any = _knob("tolerance")
    k: Any = _knob("k")
    max_rounds: Any = _knob("max_rounds")
    scale: Any = _knob("scale")
    param: Any = _knob("param")
    with_ims: Any = _knob("with_ims")
    gap_of: Any = _knob("gap_of")
    latency_views: Any = _knob("latency_views")
    latency_repeats: Any = _knob("latency_repeats")
    latency_renderer: Any = _knob("latency_renderer")
    ims_overrides: Any = _knob("ims_overrides")
    device: Any = _knob("device")


ConfigStore.instance().store(group="hydra/sweeper", name="orp", node=ORPSweeperConf, provider="imls_lightning")

KNOBS = tuple(k for k in ORPSweeperConf.__dataclass_fields__ if not k.startswith("_"))


class _SweepFailed(RuntimeError):
    """The sweep cannot go on (the RecNN could not be trained); printed as one line, exit 1."""


class ORPSweeper(Sweeper):
    """Bisection (``k=1``) / k-section of the mean value; one round = one batch of the launcher."""

    def __init__(self, **knobs: Any) -> None:
        super().__init__()
        unknown = sorted(set(knobs) - set(KNOBS))
        if unknown:  # only reachable by instantiating the class by hand
            raise TypeError(f"ORPSweeper: unknown knobs {unknown}")
        self.knobs = {k: OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v for k, v in knobs.items()}
        self.hydra_context: Optional[HydraContext] = None
        self.config: Optional[DictConfig] = None
        self.launcher: Optional[Launcher] = None
        self.job_idx = 0

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from hydra.core.plugins import Plugins

        self.hydra_context = hydra_context
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    # -- entry point ----------------------------------------------------------------------------
    def sweep(self, arguments: List[str]) -> Any:
        from imls_lightning.base.errors import InputError

        try:
            return self._sweep(list(arguments))
        except InputError as err:
            print(f"error: {err}", file=sys.stderr, flush=True)
            sys.exit(2)
        except _SweepFailed as err:
            print(f"error: {err}", file=sys.stderr, flush=True)
            sys.exit(1)

    # -- helpers --------------------------------------------------------------------------------
    def _base_overrides(self, arguments: Sequence[str], param: str) -> list[str]:
        """The sweep's overrides every job repeats: single values, without ``param``/``orp_job``."""
        from hydra.core.override_parser.overrides_parser import OverridesParser

        from imls_lightning.base.errors import InputError

        assert self.hydra_context is not None
        parser = OverridesParser.create(config_loader=self.hydra_context.config_loader)
        base = []
        for text, ov in zip(arguments, parser.parse_overrides(list(arguments))):
            key = ov.key_or_group
            if ov.is_sweep_override():
                raise InputError(f"{text}: the ORP sweeper searches {param} itself; give every setting one value "
                                 f"(the range searched is sweeper.bracket)")
            if key == param:
                log.warning(f"ORP sweeper: ignoring the override {text}: the sweeper sets {param} itself")
                continue
            if key == "orp_job":
                continue
            base.append(text)
        return base

    def _launch(self, batch: list[list[str]]) -> Sequence[JobReturn]:
        from imls_lightning.base.errors import InputError

        assert self.launcher is not None
        try:
            self.validate_batch_is_legal(batch)
        except Exception as err:  # composition errors: the user's overrides, before any job runs
            text = " ".join(str(err).split())[:300]
            raise InputError(f"overrides {' '.join(batch[0])}: do not compose ({type(err).__name__}: {text})") from None
        rets = self.launcher.launch(batch, initial_job_idx=self.job_idx)
        self.job_idx += len(batch)
        return rets

    @staticmethod
    def _job_dir(ret: JobReturn) -> str | None:
        try:
            return str(ret.hydra_cfg.hydra.runtime.output_dir)  # type: ignore[union-attr]
        except Exception:
            return None

    @staticmethod
    def _outcome(ret: JobReturn) -> Any:
        """What the job returned: its record, its exception, or (no return value) its orp_job.json."""
        import json

        from imls_lightning.orp import JOB_FILE

        value = ret._return_value  # .return_value re-raises a failed job's exception
        if ret.status == JobStatus.FAILED:
            return value if isinstance(value, BaseException) else RuntimeError(f"job failed: {value!r}")
        if ret.status != JobStatus.COMPLETED:
            return RuntimeError(f"job status {ret.status.name}")
        job_dir = ORPSweeper._job_dir(ret)
        if value is None and job_dir and (Path(job_dir) / JOB_FILE).is_file():
            try:
                value = json.loads((Path(job_dir) / JOB_FILE).read_text())
            except ValueError as err:
                return RuntimeError(f"{Path(job_dir) / JOB_FILE}: unreadable ({err})")
        return value

    def _recnn_checkpoint(self, base: list[str], param: str) -> tuple[str, dict[str, Any]]:
        """``recnn.checkpoint`` when set, else train (or reuse) the RecNN in one preparatory job."""
        from imls_lightning.orp import quote_override_value

        from imls_lightning.base.errors import InputError

        assert self.config is not None
        given = OmegaConf.select(self.config, "recnn.checkpoint", default=None)
        if given:
            path = Path(str(given)).expanduser()
            if not path.is_file():
                raise InputError(f"recnn.checkpoint={given}: file not found")
            return str(path.resolve()), {"source": "recnn.checkpoint", "checkpoint": str(path.resolve())}
        # the IML's own settings (model, model.*, the searched param) do not apply to the RecNN
        drop = ("model", param)
        keep = [o for o in base if not any(_key(o) == d or _key(o).startswith(d + ".") for d in drop)]
        overrides = keep + ["model=recnn", f"++orp_job={quote_override_value({'stage': 'recnn'})}"]
        log.info(f"ORP sweeper: recnn.checkpoint is not set; training (or reusing) the RecNN: {' '.join(overrides)}")
        t0 = time.perf_counter()
        ret = self._launch([overrides])[0]
        out = self._outcome(ret)
        info = {"source": "trained by the sweep", "job_dir": self._job_dir(ret), "overrides": overrides,
                "minutes": round((time.perf_counter() - t0) / 60, 3)}
        if isinstance(out, dict) and out.get("status") == "ok" and out.get("recnn_checkpoint"):
            info.update({"checkpoint": out["recnn_checkpoint"], "run_dir": out.get("run_dir"),
                         "train_minutes": out.get("train_minutes")})
            return str(out["recnn_checkpoint"]), info
        err = out.get("error") if isinstance(out, dict) else (" ".join(str(out).split()) if out is not None else "missing result")
        info.update({"status": "failed", "error": err})
        raise _SweepFailed(f"recnn: training the RecNN to compare with failed ({str(err)[:300]}); job directory {info['job_dir']} "
                           "(or set recnn.checkpoint=<RecNN .ckpt>)")

    # -- the sweep ------------------------------------------------------------------------------
    def _sweep(self, arguments: list[str]) -> dict[str, Any]:
        from imls_lightning.orp import ORPSettings, format_table, orp_report, quote_override_value

        from imls_lightning.base.errors import InputError

        assert self.config is not None and self.launcher is not None
        settings = ORPSettings.from_mapping({k: v for k, v in self.knobs.items() if v is not None}, prefix="sweeper.")
        target = str(OmegaConf.select(self.config, "model._target_", default="") or "")
        if not target.endswith("IMLTask"):
            name = OmegaConf.select(self.config, "model.name", default=None)
            raise InputError(f"model={name}: the ORP sweeper trains the IML at each mean value; use model=iml")
        if OmegaConf.select(self.config, settings.param, default=None) is None:
            raise InputError(f"sweeper.param={settings.param}: not a key of the config (expected a number such as model.mean)")
        base = self._base_overrides(arguments, settings.param)
        given = OmegaConf.select(self.config, "recnn.checkpoint", default=None)
        if given and not Path(str(given)).expanduser().is_file():
            raise InputError(f"recnn.checkpoint={given}: file not found")

        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        started = time.strftime("%Y-%m-%d %H:%M:%S")
        t0 = time.perf_counter()
        context: dict[str, Any] = {"sweep_dir": str(sweep_dir.resolve()), "overrides": base,
                                   "launcher": type(self.launcher).__name__, "started": started}
        recnn_ckpt, context["recnn"] = self._recnn_checkpoint(base, settings.param)

        search = settings.search()
        flag = f"++orp_job={quote_override_value(settings.job_flag())}"
        fixed = [f"recnn.checkpoint={quote_override_value(recnn_ckpt)}", flag]
        job_dirs: dict[int, str] = {}
        report: dict[str, Any] = {}
        while True:
            batch_u = search.next_batch()
            if not batch_u:
                break
            batch = [base + [f"{settings.param}={u!r}"] + fixed for u in batch_u]
            log.info(f"ORP round {search.rounds + 1}: {settings.param} = {batch_u}")
            first = len(search.evaluations)
            try:
                rets = list(self._launch(batch))
                outcomes = [self._outcome(r) for r in rets]
                dirs = [self._job_dir(r) for r in rets] + [None] * (len(batch_u) - len(rets))
            except InputError:
                raise
            except Exception as err:  # the launcher itself failed: the whole round counts as failed
                log.error(f"ORP round {search.rounds + 1}: the launcher failed: {type(err).__name__}: {err}")
                outcomes, dirs = [err] * len(batch_u), [None] * len(batch_u)
            for i, ev in enumerate(search.tell(outcomes)):
                if dirs[i]:
                    job_dirs[first + i] = dirs[i]
                state = "meets epsilon" if ev.meets(settings.epsilon_db) else (
                    "FAILED: " + str(ev.error) if ev.status != "ok" else "gap too large")
                gap = f"{ev.gap_db:.3f} dB" if ev.gap_db is not None else "-"
                log.info(f"ORP job {settings.param}={ev.u}: gap {gap} ({state})")
            context["minutes"] = round((time.perf_counter() - t0) / 60, 3)
            report = orp_report(search.result(), settings, job_dirs=job_dirs, context=context)
            _write_yaml(sweep_dir / "orp.yaml", report)

        context["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
        context["minutes"] = round((time.perf_counter() - t0) / 60, 3)
        report = orp_report(search.result(), settings, job_dirs=job_dirs, context=context)
        _write_yaml(sweep_dir / "orp.yaml", report)
        print(format_table(report), flush=True)
        print(f"[orp] {sweep_dir / 'orp.yaml'}", flush=True)
        return report


def _key(text: str) -> str:
    from imls_lightning.orp import override_key

    return override_key(text)


def _write_yaml(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as YAML atomically, each process on its own temporary file (:func:`imls_lightning.report.write_yaml`)."""
    from imls_lightning.report import write_yaml

    write_yaml(path, data, unique=True)
