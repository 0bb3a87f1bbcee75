"""The ORP Hydra sweeper (``hydra/sweeper=orp``, ``hydra_plugins/orp_sweeper``): its settings agree with
``conf/train.yaml``, it is discovered, and real sweeps through the train CLI (cross-cutting: plugin + CLI +
``imls_lightning.orp``). The search itself is tested in ``tests/orp/``."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from imls_lightning import orp
from imls_lightning.orp import DEFAULTS, ORPSettings

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
TINY = ["model=iml", "recnn=enhancenet", "hydra/sweeper=orp", "scene=tiny", "data=tiny", "renderer=numba",
        "trainer.max_epochs=1", "recnn.net.channels=8", "recnn.net.blocks=2", "model.depth=2", "model.base_channels=8",
        "test=false", "trainer.enable_progress_bar=false", "sweeper.latency_views=1", "sweeper.latency_repeats=2"]


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
