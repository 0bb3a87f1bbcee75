"""``make bench`` (imls_lightning.bench): the BENCHMARKS.md tables from real result files, and the
whole benchmark through the real CLIs at CI size (slow)."""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from imls_lightning import orp
from imls_lightning.pipelines import bench
from imls_lightning.report import SWEEP_COLUMNS, write_metrics_csv

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


# ---- real result files, written by the writers the CLIs use ---------------------------------
def _orp_yaml(path: Path, gap, tag: str) -> Path:
    """A real ``orp.yaml``: the real search (tolerance 0.25) over a known gap(u), reported by orp_report."""
    settings = orp.ORPSettings.from_mapping({"epsilon_db": 1.0, "tolerance": 0.25}, prefix="sweeper.")

    def job(u: float) -> dict:
        return {"status": "ok", "gap_db": gap(u), "c_share": u, "ipr": u / 4, "psnr_db": {"iml_recnn": 30 - gap(u), "recnn": 30.0},
                "iml_checkpoint": f"/runs/iml-{tag}-{u}.ckpt", "job_dir": f"/sweep/{tag}/{u}"}

    result = settings.search().run(orp.batched(job))
    report = orp.orp_report(result, settings, context={"finished": "2026-01-01 00:00:00"})
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(report, sort_keys=False))
    return path


def _eval_dir(d: Path, recnn_ms: float, imls_ms: float, full_ms: float, means, las_iprs, with_las: bool) -> Path:
    """metrics.csv (two views x methods) and sweep.csv in the evaluation's formats."""
    rows = []
    for v in (0, 1):
        rows += [{"view": v, "row": 10 + v, "method": "full", "render_ms": full_ms, "total_ms": full_ms, "ipr": 1.0, "psnr": 100.0, "ssim": 1.0},
                 {"view": v, "row": 10 + v, "method": "recnn", "selective_render_ms": recnn_ms / 2, "recnn_ms": recnn_ms / 2,
                  "total_ms": recnn_ms, "ipr": 0.25, "psnr": 30.0 + v, "ssim": 0.9},
                 {"view": v, "row": 10 + v, "method": "imls", "importance_ms": 1.0, "selective_render_ms": imls_ms - 1.0,
                  "total_ms": imls_ms, "ipr": 0.04 + 0.01 * v, "psnr": 29.5 + v, "ssim": 0.88}]
        if with_las:
            rows.append({"view": v, "row": 10 + v, "method": "las", "low_res_render_ms": 4.0, "total_ms": 4 * imls_ms,
                         "ipr": 0.045, "psnr": 29.0, "ssim": 0.87})
    write_metrics_csv(rows, d / "metrics.csv")
    sweep = []
    for v in (0, 1):
        for u, ipr in zip(means, las_iprs):
            sweep.append({"view": v, "row": 10 + v, "method": "iml_selective", "setting": "mean", "value": u,
                          "total_ms": 10 * ipr, "ipr": ipr * 1.1, "psnr": 28 + 10 * ipr, "ssim": 0.8})
            if with_las:
                sweep.append({"view": v, "row": 10 + v, "method": "las", "setting": "ipr", "value": ipr,
                              "total_ms": 30 * ipr, "ipr": ipr, "psnr": 27 + 10 * ipr, "ssim": 0.7})
    write_metrics_csv(sweep, d / "sweep.csv", SWEEP_COLUMNS)
    return d


def test_tables_from_real_result_files(tmp_path):
    """ORP and LAS tables from a real orp.yaml (the real search + report) and metrics/sweep CSVs."""
    iprs = [0.05, 0.1, 0.15]
    o_sr = bench.read_orp(_orp_yaml(tmp_path / "a" / "orp.yaml", lambda u: 8 * (0.3 - u) if u < 0.3 else 0.2, "sr"))
    # gap never within 1 dB: no ORP; the job with the smallest gap stands in
    o_fov = bench.read_orp(_orp_yaml(tmp_path / "b" / "orp.yaml", lambda u: 5.0 - u, "fov"))
    assert o_sr["found"] and o_sr["finished"] and o_sr["pattern_ipr"] == pytest.approx(0.25, rel=1e-3)
    assert 0.175 <= o_sr["mean"] <= 0.22 and o_sr["c_share"] == pytest.approx(o_sr["mean"], abs=1e-4)
    assert not o_fov["found"] and o_fov["mean"] == 1.0 and o_fov["iml_checkpoint"] == "/runs/iml-fov-1.0.ckpt"
    means = bench.sweep_means(iprs, o_sr["pattern_ipr"])
    assert means == [0.2, 0.4, 0.6]

    r_sr = bench.collect_pair("mri_head", "enhancenet", o_sr, _eval_dir(tmp_path / "e1", 20.0, 8.0, 40.0, means, iprs, True), iprs, means, True)
    r_fov = bench.collect_pair("mri_head", "fovolnet", o_fov, _eval_dir(tmp_path / "e2", 24.0, 12.0, 44.0, means, iprs, False), iprs, means, False)
    assert r_sr["methods"]["imls"]["latency_ms"]["total"] == pytest.approx(8.0)
    assert r_sr["points"][1]["las"]["total_ms"] == pytest.approx(3.0) and r_sr["points"][1]["imls"]["ipr"] == pytest.approx(0.11)
    assert r_fov["points"][0]["las"] is None and r_fov["points"][0]["imls"]["total_ms"] == pytest.approx(0.5)

    times = {"mri_head/enhancenet": {"recnn": 60.0, "orp": 300.0, "ims": 30.0, "las": 40.0, "evaluate": 100.0}}
    meta = {"scenes": ["mri_head", "ct_head"], "recnns": ["enhancenet", "fovolnet"], "command": "python -m imls_lightning.bench x=1",
            "machine": {"cpu": "test cpu", "cores": "2"}, "scale": ["data=bench"], "times": times, "elapsed_s": 75.0,
            "done": 2, "total": 4}
    text = bench.render_markdown([r_sr, r_fov], meta)
    assert "**partial**: 2 of 4" in text and "python -m imls_lightning.bench x=1" in text and "| cpu | test cpu |" in text
    lines = text.splitlines()
    orp_row = next(ln for ln in lines if ln.startswith("| mri_head | ") and "(none)" in ln)
    cells = [c.strip() for c in orp_row.strip("|").split("|")]
    # Dataset | ORP SR | ORP Fov | latency SR | latency Fov | speed-up SR | speed-up Fov
    assert cells == ["mri_head", f"{100 * o_sr['c_share']:.1f}%", "100.0% (none)", "8.0", "12.0", "2.50×", "2.00×"]
    las_rows = [ln for ln in lines if re.match(r"\| (mri_head)? \| (42\.0)? \| (\d+\.\d%|at ORP)", ln)]
    assert len(las_rows) == 4  # three IPRs and the ORP row
    c = [x.strip() for x in las_rows[1].strip("|").split("|")]
    # IPR 10%: LAS 3.0 ms vs IML/S 1.0 ms (SR), NS for foveated; full ray cast = mean of both evaluations
    assert las_rows[0].startswith("| mri_head | 42.0 | 5.0% |")
    assert c[2:9] == ["10.0%", "3.0", "**1.0**", "3.00×", "NS", "**1.0**", "–"]
    assert c[9:] == ["28.00 / 0.700", "29.00 / 0.800", "NS", "29.00 / 0.800"]
    orp_las = [x.strip() for x in las_rows[3].strip("|").split("|")]
    assert orp_las[2] == "at ORP: 4.5%, 4.5%" and orp_las[3:6] == ["32.0", "**8.0**", "4.00×"]
    assert "| mri_head | enhancenet | 1:00 | 5:00 | 0:30 | 0:40 | 1:40 | 8:50 |" in text
    assert "ct_head" not in text.split("## Comparison with LAS")[0].split("## ORP for")[1]  # not run yet: no row


def test_read_orp_without_any_successful_job_is_an_input_error(tmp_path):
    settings = orp.ORPSettings.from_mapping({"max_rounds": 1}, prefix="sweeper.")
    result = settings.search().run(orp.batched(lambda u: {"status": "failed", "error": "boom"}))
    p = tmp_path / "orp.yaml"
    p.write_text(yaml.safe_dump(orp.orp_report(result, settings)))
    with pytest.raises(bench.InputError, match="no job of the ORP sweep succeeded"):
        bench.read_orp(p)
    assert not bench.read_orp_finished(p)


def test_exception_bad_settings_stop_before_any_stage(tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.run([PY, "-m", "imls_lightning.bench", "las_iprs=[0.1,2]", f"runs_dir={tmp_path}/runs",
                        f"output={tmp_path}/B.md"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "error: las_iprs=[0.1, 2]: expected a non-empty list of numbers in (0.0, 1.0]" in p.stderr
    assert "Traceback" not in p.stderr and not (tmp_path / "runs").exists() and not (tmp_path / "B.md").exists()


# ---- the whole benchmark through the CLIs, CI-sized --------------------------------------------
def _overrides(key: str, *items: str) -> str:
    """``key=['a=1','b=2']``: list elements holding '=' must be quoted in Hydra's override grammar."""
    return f"{key}=[" + ",".join(f"'{i}'" for i in items) + "]"


TINY = ["scenes=[tiny]", "recnns=[enhancenet]", "data=tiny", "las_iprs=[0.05,0.1,0.2]",
        _overrides("recnn_net.enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2"),
        _overrides("stages.recnn", "trainer.max_epochs=1"),
        _overrides("stages.iml", "model.mode=standalone", "model.depth=2", "model.base_channels=8", "trainer.max_epochs=1"),
        _overrides("stages.orp", "sweeper.k=2", "sweeper.max_rounds=1", "sweeper.epsilon_db=100", "sweeper.latency_views=0"),
        _overrides("stages.ims", "model.target=pim", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0",
                   "model.loss.adversarial=0.0", "model.layers=3", "model.base_channels=8", "trainer.max_epochs=1"),
        _overrides("stages.las", "model.low_res=8", "trainer.max_epochs=1"),
        _overrides("evaluate", "max_views=2", "repeats=10", "warmup=0", "sweep_views=1", "grid_views=0")]


@pytest.mark.slow
def test_smoke_tiny_benchmark_through_the_clis_and_resume(tmp_path):
    """scene=tiny data=tiny, one RecNN, 1 epoch everything, k=2 one-round ORP: BENCHMARKS.md in a tmp dir;
    a second run reuses every stage."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    out = tmp_path / "BENCHMARKS.md"
    cmd = [PY, "-m", "imls_lightning.bench", *TINY, f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache", f"output={out}"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    first = time.perf_counter() - t0
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    assert p.stdout.strip().splitlines()[-1] == str(out) and out.is_file()
    text = out.read_text()
    assert text in p.stdout and "Status: complete" in text
    for section in ("## Machine", "## ORP for free rendering latency improvement", "## Comparison with LAS", "## Stage times"):
        assert section in text
    lines = text.splitlines()
    orp_row = [c.strip() for c in next(ln for ln in lines if ln.startswith("| tiny | ") and "×" in ln).strip("|").split("|")]
    assert len(orp_row) == 4 and orp_row[1].endswith("%") and float(orp_row[2]) > 0 and orp_row[3].endswith("×")
    las_rows = [ln for ln in lines if re.match(r"\| (tiny)? \| (\d+\.\d+)? \| (\d+\.\d%|at ORP)", ln)]
    assert len(las_rows) == 4 and las_rows[0].startswith("| tiny | ") and "| 5.0% |" in las_rows[0]
    for ln in las_rows:
        c = [x.strip() for x in ln.strip("|").split("|")]
        assert float(c[3]) > 0 and float(c[4].strip("*")) > 0 and c[5].endswith("×") and " / " in c[6] and " / " in c[7]
    orp_yaml = next((tmp_path / "runs" / "orp").glob("tiny-enhancenet-*/orp.yaml"))
    rep = yaml.safe_load(orp_yaml.read_text())
    assert rep["found"] and rep["search"]["jobs"] == 2 and rep["context"]["finished"]
    assert (tmp_path / "runs" / bench.TIMES_FILE).is_file() and not list(tmp_path.rglob(".*.tmp"))

    # resume: every stage is reused (trainings return at once, the finished orp.yaml is read, evaluate reuse=true)
    t0 = time.perf_counter()
    p2 = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    second = time.perf_counter() - t0
    assert p2.returncode == 0, p2.stderr[-3000:]
    assert "ORP search already finished; reusing" in p2.stderr and "already has a report of these settings" in p2.stderr
    assert p2.stderr.count("already finished; reusing it") >= 3  # RecNN, IMS, LAS
    assert second < first
    # the stage times of the first run are kept, so the tables are the same but for the date and wall time
    strip = lambda t: [ln for ln in t.splitlines() if not ln.startswith(("Status:", "Wall time"))]  # noqa: E731
    assert strip(out.read_text()) == strip(text)
