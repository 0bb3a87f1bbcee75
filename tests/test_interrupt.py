"""Long commands stop cleanly: on Ctrl-C ``estimate``, ``evaluate``, ``demo``, ``bench_paper`` and ``reproduce`` print one
line saying what was kept and how to resume, then exit 130, with no traceback (:func:`imls_lightning.base.errors.exit_interrupted`);
a pipeline's stage leaves that line to its pipeline. And the estimate refuses a resource-absurd resolution before
anything is allocated, naming the setting the user typed."""
from __future__ import annotations

import io
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from imls_lightning.base.errors import INTERRUPTED_EXIT, PIPELINE_STAGE_ENV, InputError, cli_errors, exit_interrupted
from tests.cli import run_in_process

ROOT = Path(__file__).resolve().parents[1]


def _interrupted_line(r) -> str:
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == INTERRUPTED_EXIT and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    assert len(lines) == 1 and lines[0].startswith("interrupted: "), lines
    return lines[0]


def _stopped(*_a, **_k):
    raise KeyboardInterrupt


def test_cli_errors_turns_ctrl_c_into_one_line(capsys, monkeypatch):
    monkeypatch.delenv(PIPELINE_STAGE_ENV, raising=False)

    @cli_errors(interrupted=lambda x: f"kept {x}; run it again")
    def main(x):
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as stop:
        main(3)
    assert stop.value.code == 130 and capsys.readouterr().err == "interrupted: kept 3; run it again\n"
    monkeypatch.setenv(PIPELINE_STAGE_ENV, "1")  # a pipeline's stage: the pipeline says it
    with pytest.raises(SystemExit) as stop:
        exit_interrupted("kept")
    assert stop.value.code == 130 and capsys.readouterr().err == ""

    @cli_errors
    def plain():
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # a command that says nothing about what it keeps is not changed
        plain()


def test_the_evaluation_says_what_it_kept(monkeypatch):
    import imls_lightning.evaluation

    monkeypatch.setattr(imls_lightning.evaluation, "evaluate", _stopped)
    line = _interrupted_line(run_in_process("imls_lightning.evaluate", ["checkpoints.ims=x.ckpt"]))
    assert "every view measured are kept (partial/" in line and line.endswith("run the same command again to continue from them")
    line = _interrupted_line(run_in_process("imls_lightning.evaluate", ["checkpoints.ims=x.ckpt", "resume=false"]))
    assert line.endswith("run it again with resume=true to continue from them")


@pytest.mark.parametrize("module, target", [("imls_lightning.demo", "imls_lightning.pipelines.demo.demo"),
                                            ("imls_lightning.bench_paper", "imls_lightning.pipelines.bench_paper.bench_paper")])
def test_a_pipeline_says_what_it_kept(monkeypatch, module, target):
    import importlib

    mod, name = target.rsplit(".", 1)
    monkeypatch.setattr(importlib.import_module(mod), name, _stopped)
    line = _interrupted_line(run_in_process(module, []))
    assert line == "interrupted: the stages that finished are kept (each command reuses its finished run; a training " \
                   "continues from its last.ckpt, an evaluation from its partial results); run the same command again to continue"


def test_a_stage_stopped_by_ctrl_c_stops_its_pipeline():
    """A stage exits 130 without a line of its own (its environment says it is a stage); the pipeline stops there."""
    from imls_lightning.pipelines.stages import run_stage

    code = f"import os, sys; sys.exit(130 if os.environ.get('{PIPELINE_STAGE_ENV}') == '1' else 1)"
    with pytest.raises(KeyboardInterrupt):
        run_stage("stage", ["-c", code], log=io.StringIO())


def test_reproduce_says_what_it_kept():
    from omegaconf import OmegaConf

    from imls_lightning.reproduce import kept_when_interrupted

    msg = kept_when_interrupted(OmegaConf.create({"output_dir": None, "runs_dir": "runs"}))
    assert "kept (the evaluation's partial/ under runs/reproduce/)" in msg and msg.endswith("run the same command again to continue from them")
    assert "under /o" in kept_when_interrupted(OmegaConf.create({"output_dir": "/o", "runs_dir": "runs"}))


def test_the_estimate_stops_on_ctrl_c_in_one_line(tmp_path):
    """A real SIGINT while the estimate times its views: one line, exit 130, nothing of the estimate left."""
    out = tmp_path / "estimate"
    # SIGINT as a terminal delivers it: a pytest-xdist worker ignores SIGINT, and an ignored signal stays ignored in a child
    restore = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # noqa: E731
    p = subprocess.Popen([sys.executable, "-m", "imls_lightning.estimate", "scene=tiny", "resolution=64", "views=3",
                          "frame_views=1", f"output_dir={out}"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=restore)
    seen, t0 = [], time.time()
    try:
        while time.time() - t0 < 240:
            line = p.stderr.readline()
            if not line:
                break
            seen.append(line)
            if "[estimate] view 1/" in line:
                p.send_signal(signal.SIGINT)
                break
        stdout, rest = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert any("[estimate] view 1/" in ln for ln in seen), "".join(seen)
    after = [ln for ln in rest.splitlines() if ln.strip() and not ln.startswith("[estimate]")]
    assert p.returncode == 130 and "Traceback" not in rest and len(after) == 1, rest
    assert after[0].startswith("interrupted: nothing of this estimate is kept") and not out.exists() and stdout == ""


@pytest.mark.parametrize("args, message", [
    (["resolution=100000"], r"^resolution=100000: the estimate's frames, masks and network activations at 100000\^2 take at "
                            r"least [\d.]+ TiB, more than the [\d.]+ GiB of memory here; expected at most \d+$"),
    (["resolution=7"], r"^resolution=7: expected a multiple of 2 \(pattern.factor=2: enhancenet renders one pixel of every "
                       r"2x2 block\), e.g. 6 or 8$"),
    (["resolution=0"], r"^resolution=0: expected an integer >= 1$"),
    (["pattern.factor=3"], r"^resolution=512: expected a multiple of 3 \(pattern.factor=3: .*\), e.g. 510 or 513$"),
])
def test_exception_the_estimate_refuses_a_resolution_before_anything_is_allocated(args, message):
    """Checked before the scene is built: a 20 GB allocation never starts, and the message names ``resolution``."""
    import re

    r = run_in_process("imls_lightning.estimate", ["scene=tiny", *args])
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and re.match(message, lines[0][len("error: "):]), r.stderr


def test_check_frame_memory():
    from imls_lightning.base.validate import check_frame_memory

    assert check_frame_memory(512, "data.resolution", 256, "frames", total=2 ** 33) == 512
    with pytest.raises(InputError, match=r"^data.resolution=8192: frames at 8192\^2 take at least 16.0 GiB, more than the "
                                         r"8.0 GiB of memory here; expected at most 5792$"):
        check_frame_memory(8192, "data.resolution", 256, "frames", total=2 ** 33)
