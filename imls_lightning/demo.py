"""``make demo``: the whole IML/S pipeline on a built-in procedural scene, at a small scale.

Runs, one after the other, the commands a user would type (``conf/pipelines/demo.yaml`` lists their
overrides), so the demo exercises exactly the product's CLIs:

1. ``python -m data_gen ... contact_sheet=true``       the (view, image) cache and a contact sheet
2. ``python -m imls_lightning.train model=recnn``      the RecNN on its sampling pattern
3. ``python -m imls_lightning.train model=iml``        the IML network, end to end through the RecNN
4. ``python -m imls_lightning.train model=ims``        the IMS network on the IML's labels
5. ``python -m imls_lightning.train model=iml model.importance=uniform``  the blue-noise mask
   baseline's decoder (``stages.blue_noise=null`` skips it)
6. ``python -m imls_lightning.train model=las``        the LAS baseline (``stages.las=null`` skips it)
7. ``python -m imls_lightning.evaluate``               the ORP on the product path (validation
   views), then every method and the untrained baselines on the 120-view test trajectory

Each CLI prints its result (cache directory, best checkpoint, report) as its last stdout line and
reuses a finished run of the same settings, so running the demo again costs seconds. The report's
path is the last line this command prints.

Example:
    python -m imls_lightning.demo                                   # flame, EnhanceNet
    python -m imls_lightning.demo scene=marschner_lobb recnn=fovolnet
"""
from __future__ import annotations

import codecs
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.errors import InputError, cli_errors

ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = str(ROOT / "conf")


class StageFailed(RuntimeError):
    """A stage's command exited with an error; its own message was already printed."""


def run_stage(name: str, args: Sequence[str], log=sys.stderr, tag: str = "demo") -> str:
    """Run ``python <args>``, echo its stdout, and return its last stdout line (the stage's result).

    ``tag`` prefixes the progress lines (``[demo]``, ``[bench]``)."""
    cmd = [sys.executable, *args]
    print(f"\n[{tag}] {name}: {' '.join(args)}", file=log, flush=True)
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with subprocess.Popen(cmd, cwd=os.getcwd(), env=env, stdout=subprocess.PIPE) as proc:
        assert proc.stdout is not None
        last = _echo(proc.stdout, log)
        code = proc.wait()
    if code != 0:
        raise StageFailed(f"{tag} stage '{name}' failed (exit {code}); its message is above. Command: python {' '.join(args)}")
    print(f"[{tag}] {name} done in {time.perf_counter() - t0:.1f} s -> {last}", file=log, flush=True)
    return last


def _echo(stream, log) -> str:
    """Copy a child's stdout to ``log`` indented, keeping its carriage returns (progress bars redraw
    in place instead of printing a line per update); returns its last non-empty line."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    current, last, line_start = "", "", True
    while chunk := stream.read1(65536):
        for piece in re.split(r"([\r\n])", decoder.decode(chunk)):
            if piece in ("\r", "\n"):
                if piece == "\n" and current.strip():
                    last = current.strip()
                current, line_start = "", True
                log.write(piece)
            elif piece:
                if line_start:
                    log.write("  ")
                    line_start = False
                current += piece
                log.write(piece)
        log.flush()
    if current.strip():
        last = current.strip()
    return last


def _list(cfg: DictConfig, key: str) -> list[str]:
    v = OmegaConf.select(cfg, key)
    if v is None:
        return []
    if not OmegaConf.is_list(v):
        raise InputError(f"{key}={v}: expected a list of overrides; on the command line quote each one: \"{key}=['trainer.max_epochs=5']\"")
    return [str(x) for x in v]


def demo(cfg: DictConfig) -> Path:
    """Run every stage; returns the evaluation report's path."""
    runs = str(cfg.runs_dir)
    common = [f"scene={cfg.scene}", f"data={cfg.data}", f"renderer={cfg.renderer}", f"data.cache_dir={cfg.cache_dir}"]
    train_common = [*common, f"recnn={cfg.recnn}", f"paths.runs_dir={runs}", f"seed={int(cfg.seed)}"]
    if not cfg.progress:
        train_common.append("trainer.enable_progress_bar=false")
    t0 = time.perf_counter()

    cache = run_stage("cache", ["-m", "data_gen", *common, "contact_sheet=true", f"progress={bool(cfg.progress)}"])
    sheet = Path(cache) / "contact_sheet.png"
    print(f"[demo] contact sheet of the cached views: {sheet}", file=sys.stderr, flush=True)

    train = ["-m", "imls_lightning.train"]
    recnn = run_stage("RecNN", [*train, "model=recnn", *train_common, *_list(cfg, "stages.recnn")])
    iml = run_stage("IML", [*train, "model=iml", *train_common, f"recnn.checkpoint={recnn}", *_list(cfg, "stages.iml")])
    ims = run_stage("IMS", [*train, "model=ims", *train_common, f"iml.checkpoint={iml}", f"recnn.checkpoint={recnn}",
                            *_list(cfg, "stages.ims")])
    blue = None
    if OmegaConf.select(cfg, "stages.blue_noise") is not None:
        # the untrained-mask baseline: the blue-noise mask u > P with a decoder trained for it
        blue = run_stage("blue-noise decoder", [*train, "model=iml", *train_common, f"recnn.checkpoint={recnn}",
                                                "model.importance=uniform", *_list(cfg, "stages.blue_noise")])
    las = None
    if OmegaConf.select(cfg, "stages.las") is not None:
        las = run_stage("LAS", [*train, "model=las", *train_common, *_list(cfg, "stages.las")])

    ev = ["-m", "imls_lightning.evaluate", *common, f"paths.runs_dir={runs}", f"checkpoints.ims={ims}",
          f"checkpoints.recnn={recnn}", f"progress={bool(cfg.progress)}", "reuse=true", *_list(cfg, "evaluate")]
    if las:
        ev.append(f"checkpoints.las={las}")
    if blue:
        ev.append(f"checkpoints.blue_noise={blue}")
    report = Path(run_stage("evaluation", ev))
    minutes = (time.perf_counter() - t0) / 60
    print(f"\n[demo] finished in {minutes:.1f} min. Contact sheet: {sheet}", file=sys.stderr, flush=True)
    print(f"[demo] report (tables, plots, image grid): {report}", file=sys.stderr, flush=True)
    return report


@hydra.main(version_base="1.3", config_path=str(ROOT / "conf" / "pipelines"), config_name="demo")
@cli_errors
def main(cfg: DictConfig) -> None:
    try:
        report = demo(cfg)
    except StageFailed as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        sys.exit(1)
    print(report, flush=True)


if __name__ == "__main__":
    main()
