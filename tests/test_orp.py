"""ORP search: bisection / k-section logic, settings, the Hydra sweeper plugin and a real CLI sweep."""
from __future__ import annotations

import doctest
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from data_gen.errors import InputError
from imls_lightning import orp
from imls_lightning.orp import DEFAULTS, ORPSearch, ORPSettings, batched, evaluation_from

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def gap_curve(u_star: float, eps: float = 1.0):
    """Synthetic monotone PSNR gap (dB): decreasing in u, equal to ``eps`` exactly at ``u_star``."""
    return lambda u: eps + 3.0 * math.log2(u_star / u)


def check_brackets(res, u_star: float, tol: float = 0.1) -> None:
    """The answer is the smallest passing point, within ``tol`` (relative) above the true threshold."""
    assert res.found and res.mean == res.bracket[1]
    lo, hi = res.bracket
    assert lo < u_star <= hi, (lo, u_star, hi)
    assert hi <= lo * (1 + tol) + 1e-12
    assert u_star <= res.mean <= u_star * (1 + tol)


# ---- the search ---------------------------------------------------------------------------
@pytest.mark.parametrize("u_star", [0.0137, 0.137, 0.5, 0.97])
def test_bisection_finds_the_known_answer(u_star):
    res = ORPSearch(epsilon_db=1.0, tolerance=0.1).run(batched(gap_curve(u_star)))
    check_brackets(res, u_star)
    assert res.stop_reason == "tolerance" and not res.non_monotone
    assert all(e.status == "ok" for e in res.evaluations)
    # every point tried is on the right side of the threshold
    assert all(e.meets(1.0) == (e.u >= u_star) for e in res.evaluations)
    # bisection in log u over two decades to 10 %: ceil(log2(ln 100 / ln 1.1)) = 6 rounds
    # (+1 when the answer lies so close to the upper end that only u = 1 itself passes)
    assert res.rounds == res.jobs == (7 if u_star > 1 / 1.1 else 6)


def test_bisection_linear_scale_and_no_solution():
    res = ORPSearch(tolerance=0.05, scale="linear").run(batched(gap_curve(0.3)))
    check_brackets(res, 0.3, tol=0.05)
    assert res.evaluations[0].u == pytest.approx(0.505)  # the linear midpoint of [0.01, 1]

    none = ORPSearch(tolerance=0.1).run(batched(gap_curve(3.0)))  # needs u > 1: no ORP in the bracket
    assert not none.found and none.mean is None and none.stop_reason == "no_solution"
    assert none.evaluations[-1].u == 1.0  # the upper end was checked once, last


def test_failed_jobs_are_recorded_as_not_meeting_epsilon_and_the_search_goes_on():
    curve = gap_curve(0.05)
    kinds = ["raise", "none", "nan", "record"]  # the first four jobs fail, each in its own way

    def job(u):
        kind = kinds.pop(0) if kinds else None
        if kind == "raise":
            raise RuntimeError("CUDA out of memory")
        if kind == "none":
            return None
        if kind == "nan":
            return {"status": "ok", "gap_db": float("nan")}
        if kind == "record":
            return {"status": "failed", "error": "ORPJobError: boom"}
        return {"status": "ok", "gap_db": curve(u), "psnr_db": {"recnn": 30.0}}

    res = ORPSearch(tolerance=0.1).run(batched(job))
    failed = [e for e in res.evaluations if e.status == "failed"]
    assert [e.u for e in failed] == [0.1, 0.31623, 0.56234, 0.74989]  # each failure moves lo up
    assert failed[0].error == "RuntimeError: CUDA out of memory"
    assert failed[1].error == "missing result" and "non-finite" in failed[2].error
    assert failed[3].error == "ORPJobError: boom"
    assert all(not e.meets(1.0) for e in failed)
    # these would have passed; counted as failing, the search goes on above them and finds the next passing value
    assert res.found and res.bracket[0] == 0.74989 and res.mean <= 0.74989 * 1.1
    assert res.best.record["psnr_db"] == {"recnn": 30.0}
    assert len(res.evaluations) > len(failed)


def test_a_whole_round_failing_is_recorded_too():
    calls = []

    def objective(us):
        calls.append(list(us))
        if len(calls) == 1:
            raise OSError("launcher down")
        return [gap_curve(0.2)(u) for u in us]

    res = ORPSearch(k=2).run(objective)
    first = [e for e in res.evaluations if e.round == 1]
    assert len(first) == 2 and all(e.status == "failed" and "launcher down" in e.error for e in first)
    assert res.found and res.mean >= 0.2


@pytest.mark.parametrize("u_star", [0.02, 0.137, 0.61])
@pytest.mark.parametrize("k", [2, 3, 5])
def test_k_section_agrees_with_bisection(k, u_star):
    bis = ORPSearch(tolerance=0.1).run(batched(gap_curve(u_star)))
    ks = ORPSearch(tolerance=0.1, k=k).run(batched(gap_curve(u_star)))
    check_brackets(bis, u_star)
    check_brackets(ks, u_star)
    assert abs(math.log(ks.mean / bis.mean)) <= math.log(1.1)
    assert ks.rounds < bis.rounds  # the point of k-section: fewer (parallel) rounds
    assert all(len({e.u for e in ks.evaluations if e.round == r}) <= k for r in range(1, ks.rounds + 1))


def test_ask_tell_protocol_and_max_rounds():
    s = ORPSearch(k=3, max_rounds=2)
    batch = s.next_batch()
    assert batch == [0.031623, 0.1, 0.31623]
    with pytest.raises(RuntimeError, match="tell"):
        s.next_batch()
    s.tell([5.0, 0.5, 0.1])  # only 0.1 and 0.31623 pass
    assert (s.lo, s.hi) == (0.031623, 0.1)
    second = s.next_batch()
    assert len(second) == 3 and all(0.031623 < u < 0.1 for u in second)
    s.tell([5.0, 5.0, 5.0])  # none passes: 0.1 stays the answer, lo moves up
    assert (s.lo, s.hi) == (second[-1], 0.1)
    assert s.next_batch() == [] and s.result().stop_reason == "max_rounds" and s.result().mean == 0.1
    with pytest.raises(RuntimeError, match="pending"):
        s.tell([1.0])


def test_evaluation_from_normalizes_outcomes():
    assert evaluation_from(0.1, 1, 0.5).meets(1.0)
    assert not evaluation_from(0.1, 1, 1.5).meets(1.0)
    assert evaluation_from(0.1, 1, {"gap_db": 0.2, "ipr": 0.1}).record["ipr"] == 0.1
    assert evaluation_from(0.1, 1, {"ipr": 0.1}).status == "failed"           # no gap
    assert evaluation_from(0.1, 1, "abc").status == "failed"
    assert evaluation_from(0.1, 1, float("inf")).status == "failed"
    e = evaluation_from(0.1, 1, orp.ORPJobError("InputError: model.lr=-1: expected a positive number"))
    assert e.error == "InputError: model.lr=-1: expected a positive number"


@pytest.mark.parametrize("module", ["", ".search", ".overrides", ".job", ".report"])
def test_module_doctests(module):
    import importlib

    mod = importlib.import_module(f"imls_lightning.orp{module}")
    assert doctest.testmod(mod).failed == 0


@pytest.mark.parametrize("module", ["imls_lightning.orp.search", "imls_lightning.orp"])
def test_search_imports_no_torch(module):
    """The search (and the package the Hydra sweeper plugin imports while Hydra scans plugins) loads no torch."""
    code = f"import sys, {module}; assert 'torch' not in sys.modules, sorted(m for m in sys.modules if 'torch' in m)[:5]"
    p = subprocess.run([PY, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]


# ---- settings -----------------------------------------------------------------------------
@pytest.mark.parametrize("knobs, needle", [
    ({"epsilon_db": -1}, "sweeper.epsilon_db=-1: expected a number of dB >= 0"),
    ({"epsilon_db": "abc"}, "sweeper.epsilon_db='abc'"),
    ({"bracket": [0.5, 0.1]}, "sweeper.bracket=[0.5, 0.1]: expected lo < hi"),
    ({"bracket": [0.001, 1]}, "must lie in [0.01, 1.0]"),
    ({"bracket": 0.5}, "sweeper.bracket=0.5: expected two mean values"),
    ({"tolerance": 0}, "sweeper.tolerance=0"),
    ({"k": 0}, "sweeper.k=0: expected an integer >= 1"),
    ({"k": 1.5}, "sweeper.k=1.5"),
    ({"max_rounds": 0}, "sweeper.max_rounds=0"),
    ({"scale": "exp"}, "sweeper.scale='exp'"),
    ({"gap_of": "imls"}, "needs sweeper.with_ims=true"),
    ({"with_ims": "yes"}, "sweeper.with_ims='yes'"),
    ({"ims_overrides": ["model.layers"]}, "sweeper.ims_overrides"),
    ({"latency_renderer": "ospray"}, "sweeper.latency_renderer='ospray'"),
    ({"device": "tpu"}, "sweeper.device='tpu'"),
    ({"param": "+model.mean"}, "sweeper.param='+model.mean'"),
    ({"epsilon": 1}, "sweeper.epsilon: unknown knob"),
])
def test_exception_bad_settings_are_one_line_input_errors(knobs, needle):
    with pytest.raises(InputError) as info:
        ORPSettings.from_mapping(knobs, prefix="sweeper.")
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_settings_defaults_agree_with_train_yaml_and_the_plugin():
    from hydra_plugins.orp_sweeper.orp_sweeper import KNOBS

    node = yaml.safe_load((ROOT / "conf" / "train.yaml").read_text())["sweeper"]
    assert node == DEFAULTS
    assert set(KNOBS) == set(DEFAULTS)
    s = ORPSettings.from_mapping(node)
    assert s.search().k == 1 and s.bracket == (0.01, 1.0)
    flag = s.job_flag()
    assert set(flag) == set(orp.JOB_KEYS)
    assert orp.quote_override_value(flag).startswith("{epsilon_db:1.0,")


# ---- the Hydra plugin ---------------------------------------------------------------------
def test_plugin_is_discovered_and_its_config_reads_the_sweeper_node():
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.plugins import Plugins
    from hydra.plugins.sweeper import Sweeper

    assert "ORPSweeper" in [p.__name__ for p in Plugins.instance().discover(Sweeper)]
    assert not (ROOT / "hydra_plugins" / "__init__.py").exists()  # a namespace package (Hydra issue 3252)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
            cfg = compose("train", overrides=["model=iml", "hydra/sweeper=orp", "sweeper.epsilon_db=0.5", "sweeper.k=3"],
                          return_hydra_config=True)
            sw = cfg.hydra.sweeper
            assert sw._target_ == "hydra_plugins.orp_sweeper.orp_sweeper.ORPSweeper"
            assert (sw.epsilon_db, sw.k, sw.param, sw.bracket[0]) == (0.5, 3, "model.mean", 0.01)
            cfg2 = compose("train", overrides=["hparams_search=orp", "hydra.sweeper.tolerance=0.2"], return_hydra_config=True)
            assert cfg2.model.name == "iml" and cfg2.hydra.sweeper.tolerance == 0.2
            assert cfg2.hydra.sweeper.epsilon_db == 1.0 and cfg2.orp_job is None
    finally:
        GlobalHydra.instance().clear()


def test_exception_bad_stage_fails_the_job_not_the_sweep(tmp_path):
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"orp_job": {"stage": "las"}, "paths": {"runs_dir": str(tmp_path)}})
    with pytest.raises(orp.ORPJobError, match="orp_job.stage='las'"):
        orp.orp_main(cfg)
    assert json.loads((tmp_path / "orp_job" / orp.JOB_FILE).read_text())["status"] == "failed"


# ---- the real CLI sweep -------------------------------------------------------------------
TINY = ["model=iml", "recnn=enhancenet", "hydra/sweeper=orp", "scene=tiny", "data=tiny", "renderer=numba",
        "trainer.max_epochs=1", "recnn.net.channels=8", "recnn.net.blocks=2", "model.depth=2", "model.base_channels=8",
        "test=false", "trainer.enable_progress_bar=false", "sweeper.latency_views=1", "sweeper.latency_repeats=2"]


def _sweep(args, tmp, check=True, timeout=300, base=TINY):
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.train", "-m", *base, *args, f"paths.runs_dir={tmp}/runs", f"data.cache_dir={tmp}/cache"]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-3000:]}")
    return p


def _report(p) -> tuple[Path, dict]:
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("[orp] ")][-1]
    path = Path(line[len("[orp] "):])
    return path, yaml.safe_load(path.read_text())


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("orp")


def test_smoke_two_job_k_section_sweep_through_the_cli(work):
    """k=2, one round: two IML jobs (after the RecNN job) through the basic launcher; orp.yaml lists them."""
    p = _sweep(["sweeper.k=2", "sweeper.max_rounds=1", "sweeper.epsilon_db=100"], work)
    path, rep = _report(p)
    assert path.name == "orp.yaml" and path.parent.parent == work / "runs" / "multirun"
    assert not list(path.parent.glob("*.tmp"))
    assert rep["found"] and rep["search"] == {"rounds": 1, "jobs": 2, "stop_reason": "max_rounds",
                                               "bracket_final": [0.01, 0.046416], "non_monotone": False}
    assert [j["mean"] for j in rep["jobs"]] == [0.046416, 0.21544]  # the third points of [0.01, 1] in log u
    for j in rep["jobs"]:
        assert j["status"] == "ok" and j["meets_epsilon"] and j["error"] is None
        assert j["gap_db"] == pytest.approx(j["psnr_db"]["recnn"] - j["psnr_db"]["iml_recnn"], abs=1e-3)
        assert 0 < j["c_share"] <= 1 and 0 < j["ipr"] < j["c_share"]  # the pattern is a quarter of the FR pixels
        assert Path(j["iml_checkpoint"]).is_file()
        assert json.loads((Path(j["job_dir"]) / orp.JOB_FILE).read_text())["mean"] == j["mean"]
    assert rep["mean"] == 0.046416 and rep["orp"]["mean"] == 0.046416 and rep["orp"]["c_share"] == rep["jobs"][0]["c_share"]
    assert rep["psnr_db"]["recnn"] > 10 and rep["latency_ms"]["recnn"]["total"] > 0 and rep["latency_ms"]["views"] == 1
    # the RecNN was trained by the sweep's preparatory job, in the run directory a plain model=recnn run uses
    rn = rep["context"]["recnn"]
    assert rn["source"] == "trained by the sweep" and Path(rn["checkpoint"]).is_file()
    assert Path(rn["run_dir"]).parent == work / "runs" and rep["recnn_checkpoint"] == rn["checkpoint"]
    assert rep["settings"]["k"] == 2 and rep["epsilon_db"] == 100.0
    assert "ORP: " in p.stdout and "2 jobs in 1 rounds" in p.stdout


@pytest.mark.slow
def test_failed_jobs_are_recorded_and_the_sweep_finishes(work):
    """Every IML job fails (bad learning rate): recorded with its error; the upper end is checked; no ORP."""
    p = _sweep(["model.lr=-1", "sweeper.k=3", "sweeper.max_rounds=1"], work)
    _, rep = _report(p)
    assert not rep["found"] and rep["orp"] is None and rep["search"]["stop_reason"] == "no_solution"
    assert [j["mean"] for j in rep["jobs"]] == [0.031623, 0.1, 0.31623, 1.0]
    for j in rep["jobs"]:
        assert j["status"] == "failed" and not j["meets_epsilon"] and "model.lr=-1" in j["error"]
        assert j["job_dir"] and json.loads((Path(j["job_dir"]) / orp.JOB_FILE).read_text())["status"] == "failed"
    assert rep["context"]["recnn"]["run_dir"]  # the RecNN run of the first sweep was reused
    assert "ORP: none" in p.stdout


@pytest.mark.parametrize("args, needle", [
    (["model.mean=0.1,0.2"], "error: model.mean=0.1,0.2: the ORP sweeper searches model.mean itself"),
    (["sweeper.epsilon_db=-1"], "error: sweeper.epsilon_db=-1: expected a number of dB >= 0"),
    # each case costs a process start (~5 s): the rest run with the slow tests
    pytest.param(["model=recnn", "hydra/sweeper=orp"], "error: model=recnn: the ORP sweeper trains the IML", marks=pytest.mark.slow),
    pytest.param(["recnn.checkpoint=/nonexistent/r.ckpt"], "error: recnn.checkpoint=/nonexistent/r.ckpt: file not found",
                 marks=pytest.mark.slow),
])
def test_exception_bad_sweeps_stop_before_any_job(tmp_path, args, needle):
    p = _sweep(args, tmp_path, check=False, timeout=120, base=[] if "model=recnn" in args else TINY)
    assert p.returncode == 2, p.stderr[-2000:]
    assert needle in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "runs" / "multirun").exists() or not list((tmp_path / "runs" / "multirun").rglob("orp_job.json"))
