"""The measurement scripts (scripts/measure_recnn.py, scripts/measure_iml.py) end to end on the tiny scene.

Real trainings through the CLI (1 epoch, tiny networks), real evaluation on the tiny test
trajectory; checks the printed/written tables and the numbers behind them. The two training tests
take ~65 s together on 2 busy cores (3 training subprocesses), so they are marked slow.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
TINY = ["--scene", "tiny", "--data", "tiny", "--enhancenet-epochs", "1", "--enhancenet-channels", "4",
        "--enhancenet-blocks", "1"]


def _run(script: str, args: list[str], tmp: Path, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, str(ROOT / "scripts" / script), *args, "--runs-dir", str(tmp / "runs"), "--cache-dir", str(tmp / "cache")]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    if check and p.returncode != 0:
        raise AssertionError(f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-3000:]}")
    return p


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("measure")


@pytest.fixture(scope="module")
def recnn_run(work):
    out = work / "recnn.md"
    p = _run("measure_recnn.py", [*TINY, "--fovolnet-epochs", "1", "--fovolnet-features", "4", "--fovolnet-base-channels", "4",
                                  "--fovolnet-depth", "2", "--out", str(out)], work)
    return p, out


@pytest.mark.slow
def test_smoke_measure_recnn_table_and_numbers(recnn_run):
    p, out = recnn_run
    rec = json.loads(out.with_suffix(".json").read_text())
    assert out.read_text() in p.stdout + "\n" or out.read_text().strip() in p.stdout  # same table on stdout and in the file
    for name in ("enhancenet", "bicubic_interpolate", "bicubic_aligned"):
        assert np.isfinite(rec["enhancenet"]["metrics"][name]["psnr"]) and 0 < rec["enhancenet"]["metrics"][name]["ssim"] <= 1
    for name in ("fovolnet", "nearest_fill"):
        assert np.isfinite(rec["fovolnet"]["metrics"][name]["psnr"])
    assert rec["enhancenet"]["metrics"]["_views"] == 12  # data=tiny: the 12-view test trajectory
    # our evaluation of the best checkpoint = the training's own test pass (same views, same PSNR)
    assert rec["enhancenet"]["metrics"]["enhancenet"]["psnr"] == pytest.approx(rec["enhancenet"]["result_test"]["test/fr_psnr"], abs=0.02)
    assert rec["enhancenet"]["train_minutes"] > 0 and rec["enhancenet"]["epochs"] >= 0
    assert "| EnhanceNet (downsample 2x) |" in out.read_text() and "nearest pattern pixel" in out.read_text()
    assert "(1/4) train EnhanceNet" in p.stderr and "elapsed" in p.stderr
    assert not list(out.parent.glob(".*.tmp"))  # atomic writes leave nothing behind


@pytest.mark.slow
def test_smoke_measure_iml_end_to_end_row(work, recnn_run):
    _, recnn_out = recnn_run
    ckpt = json.loads(recnn_out.with_suffix(".json").read_text())["enhancenet"]["checkpoint"]
    out = work / "iml.md"
    p = _run("measure_iml.py", [*TINY, "--iml-epochs", "1", "--iml-depth", "2", "--iml-base-channels", "4", "--means", "0.2",
                                "--modes", "end_to_end", "--recnn-checkpoint", ckpt, "--out", str(out)], work)
    rec = json.loads(out.with_suffix(".json").read_text())
    (row,) = rec["runs"]
    e = row["metrics"]
    assert row["mode"] == "end_to_end" and row["mean"] == 0.2 and e["views"] == 12
    # data=tiny 32^2 FR, 16^2 C-Image: IPR = C-share / 4 exactly for the 2x downsampling pattern
    assert e["ipr"] == pytest.approx(e["c_share"] / 4, rel=1e-6)
    assert 0 <= e["c_share"] <= 1 and e["pim_norm_mean"] == pytest.approx(0.2, rel=1e-3)
    # the hard-mask numbers agree with the run's own test pass
    t = row["result_test"]
    assert e["ipr"] == pytest.approx(t["test/ipr"], abs=1e-4) and e["psnr"] == pytest.approx(t["test/fr_psnr"], abs=0.02)
    assert rec["checks"] == []
    assert "| end_to_end | 0.2 |" in p.stdout and out.read_text().strip() in p.stdout


def test_exception_measure_iml_bad_means(tmp_path):
    p = _run("measure_iml.py", ["--means", "0.001,0.1"], tmp_path, check=False)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    err = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")]
    assert len(err) == 1 and err[0].startswith("error: --means=0.001: expected a number in [0.01, 1"), p.stderr[-2000:]


def test_measure_pixel_check_script(tmp_path):
    """scripts/measure_pixel_check.py: the cache's per-view CRC-32 check vs one render (issue 17, 2)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("measure_pixel_check", ROOT / "scripts" / "measure_pixel_check.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(["--resolution", "64", "--views", "3", "--repeats", "5", "--cache-dir", str(tmp_path)])
    assert out["check_ms"] > 0 and out["ratio"] > 20, out
