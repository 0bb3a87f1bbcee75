"""``make demo`` (``python -m imls_lightning.demo``): its config composes with overrides, and the
whole pipeline runs through the real CLIs on ``scene=tiny`` and is reused when run again."""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def _overrides(key: str, *items: str) -> str:
    """``key=['a=1','b=2']``: list elements holding '=' must be quoted in Hydra's override grammar."""
    return f"{key}=[" + ",".join(f"'{i}'" for i in items) + "]"


def test_demo_config_takes_scene_data_and_recnn_overrides():
    # the pipeline configs live apart from conf/'s groups, so scene=/data=/recnn= set plain keys
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_demo"):
        cfg = compose("demo", overrides=["scene=marschner_lobb", "data=tiny", "recnn=fovolnet", "renderer=vtk",
                                         _overrides("stages.recnn", "trainer.max_epochs=1")])
        default = compose("demo")
    assert (cfg.scene, cfg.data, cfg.recnn, cfg.renderer) == ("marschner_lobb", "tiny", "fovolnet", "vtk")
    assert list(cfg.stages.recnn) == ["trainer.max_epochs=1"]
    assert (default.scene, default.data, default.recnn, default.renderer) == ("flame", "small", "enhancenet", "numba")
    for stage in ("recnn", "iml", "ims", "las", "blue_noise"):
        assert list(default.stages[stage]), stage


TINY = ["scene=tiny", "data=tiny", "progress=false",
        _overrides("stages.recnn", "trainer.max_epochs=1", "recnn.net.channels=4", "recnn.net.blocks=1"),
        _overrides("stages.iml", "model.mode=end_to_end", "model.depth=2", "model.base_channels=4", "trainer.max_epochs=1"),
        _overrides("stages.ims", "model.target=pim", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0",
                   "model.loss.adversarial=0.0", "model.layers=3", "model.base_channels=8", "trainer.max_epochs=1"),
        _overrides("stages.las", "model.low_res=8", "trainer.max_epochs=1"),
        _overrides("stages.blue_noise", "model.mode=end_to_end", "model.depth=2", "model.base_channels=4", "trainer.max_epochs=1"),
        _overrides("evaluate", "max_views=2", "repeats=10", "warmup=0", "sweep_views=1", "grid_views=1")]


def test_smoke_demo_pipeline_on_tiny_and_reuse(tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.demo", *TINY, f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    first = time.perf_counter() - t0
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    report = Path(p.stdout.strip().splitlines()[-1])
    assert report.name == "report.md" and report.is_file()
    assert (report.parent / "metrics.csv").is_file()
    assert list(report.parent.glob("*.png")), "the report has no figures"
    sheets = list((tmp_path / "cache").rglob("contact_sheet.png"))
    assert len(sheets) == 1
    for stage in ("cache", "RecNN", "IML", "IMS", "blue-noise decoder", "LAS", "evaluation"):
        assert f"[demo] {stage} done in" in p.stderr, stage
    text = report.read_text()
    for method in ("RecNN", "LAS", "IML/S", "## ORP on the product path", "IML/S mask + fill", "blue noise + decoder",
                   "## Learned parts against untrained baselines, at equal share"):
        assert method in text, method

    # a second run reuses every stage and prints the same report path last
    t0 = time.perf_counter()
    p2 = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    second = time.perf_counter() - t0
    assert p2.returncode == 0, p2.stderr[-3000:]
    assert p2.stdout.strip().splitlines()[-1] == str(report)
    assert second < first


def test_exception_demo_stage_failure_names_the_stage(tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.run([PY, "-m", "imls_lightning.demo", "scene=no_such_scene", f"runs_dir={tmp_path}/runs",
                        f"cache_dir={tmp_path}/cache", "progress=false"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode != 0
    assert "error: demo stage 'cache' failed" in p.stderr and "no_such_scene" in p.stderr
    assert not (tmp_path / "runs").exists()


def test_echo_keeps_carriage_returns_and_returns_the_last_line():
    import io

    from imls_lightning.demo import _echo

    class Chunked:  # a pipe that hands out 3 bytes at a time (splits the UTF-8 'é' too)
        def __init__(self, data: bytes):
            self.buf = io.BytesIO(data)

        def read1(self, n: int) -> bytes:
            return self.buf.read(3)

    out = io.StringIO()
    last = _echo(Chunked("epoch\r 50%\r100%\n/run/best é.ckpt\n\n".encode()), out)
    assert last == "/run/best é.ckpt"
    assert out.getvalue() == "  epoch\r   50%\r  100%\n  /run/best é.ckpt\n\n"
    assert _echo(Chunked(b"no newline at the end"), io.StringIO()) == "no newline at the end"
