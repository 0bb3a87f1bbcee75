"""Issue 31 on a lent GPU machine: the paper-regime scenes' caches and RecNNs, then the first scene's IML,
time-boxed, bringing back only the evidence and the checkpoints.

A lent machine has 16 cores and a GPU for minutes (BENCHMARKS.md, "What the lent H100 taught"): render each
cache on all but two cores, train its RecNN on the GPU while the next cache renders, and pack what the
evaluation here needs. Every step is the CLI that ``make bench-paper`` runs (the GPU schedule of
``conf/pipelines/bench_paper_gpu.yaml``, each stage also time-boxed with ``trainer.max_time``), so the runs
land in the same directories as there. Nothing is tuned here: the regime evidence reads the test trajectory
only to report it.

    python3 scripts/lent_gpu_regime.py --out "$OUT" --deadline 540

Write runs and caches outside any path a later call carries: a carried folder replaces its copy there, and
what was written into it is gone (the first lent run lost its runs so).

Writes ``<out>/summary.json`` (per scene: cache time, RecNN run and its validation/test PSNR, the bilinear
C -> FR PSNR on the test trajectory), ``<out>/runs.tgz`` (each run's result.json, metrics and best
checkpoint, the caches' contact sheets) and ``<out>/logs.tgz``: three files, as few as comes back whole.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

PY = sys.executable
SCENES = ["rayleigh_taylor", "flame_sheets", "seed_shell"]
COMMON = ["renderer=numba", "data.cache_dir=cache"]
TRAIN = ["recnn=enhancenet", "paths.runs_dir=runs/paper", "seed=0", "trainer.enable_progress_bar=false",
         "recnn.net.channels=16", "recnn.net.blocks=4", "data.loader_workers=0"]
# conf/pipelines/bench_paper_gpu.yaml's stages, with the RecNN's test pass kept (its PSNR is the evidence)
RECNN = ["trainer.max_epochs=30", "trainer.check_val_every_n_epoch=5"]
IML = ["model.mode=end_to_end", "model.mean=0.2", "model.mean_range=[0.1,0.6]", "model.depth=4",
       "model.base_channels=8", "trainer.max_epochs=40", "trainer.check_val_every_n_epoch=5", "test=false"]


class Clock:
    def __init__(self, seconds: float):
        self.t0, self.seconds = time.monotonic(), seconds

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def left(self) -> float:
        return self.seconds - self.elapsed()


def gpu_name() -> str | None:
    """The lent machine's GPU for a summary (None without one; what could not be read, said in the string)."""
    try:
        import torch
        return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    except Exception as err:  # the summary says what it could not read
        return f"unknown ({err})"


def box(seconds: float) -> str:
    """``trainer.max_time`` for a fit of at most ``seconds`` (DD:HH:MM:SS)."""
    s = max(30, int(seconds))
    return f"trainer.max_time=00:00:{s // 60:02d}:{s % 60:02d}"


def start(cmd: list[str], log: Path, env: dict | None = None) -> subprocess.Popen:
    f = open(log, "w")
    print(f"$ {' '.join(cmd)}  > {log}", flush=True)
    return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=env)


def finished_run(pattern: str) -> Path | None:
    """The newest run directory matching ``pattern`` with a result.json."""
    runs = sorted((Path(p) for p in glob.glob(pattern) if (Path(p) / "result.json").is_file()),
                  key=lambda p: (p / "result.json").stat().st_mtime)
    return runs[-1] if runs else None


def pack_runs(tgz: Path, pattern: str, sheets: bool = True) -> None:
    """Only what the evaluation here needs: each finished run's result.json, metrics, config and best
    checkpoint (the last lent run's bundle outgrew what comes back), and the caches' contact sheets."""
    with tarfile.open(tgz, "w:gz") as tar:
        for run in glob.glob(pattern):
            r = Path(run) / "result.json"
            if not r.is_file():
                continue
            tar.add(str(r))
            for name in ("metrics.csv", "config.yaml", "overrides.yaml"):
                for f in glob.glob(f"{run}/**/{name}", recursive=True) + glob.glob(f"{run}/.hydra/{name}"):
                    tar.add(f)
            best = json.loads(r.read_text()).get("best_checkpoint")
            if best and Path(best).is_file():
                tar.add(best, arcname=os.path.relpath(best))
        for sheet in glob.glob("cache/*/contact_sheet.png") if sheets else []:
            tar.add(sheet)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--deadline", type=float, default=540.0, help="seconds for everything, packing included")
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--data", default="paper_cpu", help="the data preset (tiny: a local smoke test of this script)")
    ap.add_argument("--crop", type=int, default=128, help="data.crop of the fully convolutional networks")
    ap.add_argument("--render-workers", type=int, default=7)
    ap.add_argument("--recnn-seconds", type=float, default=150.0)
    ap.add_argument("--iml-seconds", type=float, default=200.0, help="0: no IML")
    a = ap.parse_args()
    # the logs live outside <out> and come back as one archive: every file under <out> counts against the eight
    clock, logs = Clock(a.deadline), Path(tempfile.mkdtemp(prefix="lent_regime_")) / "logs"
    COMMON.insert(0, f"data={a.data}")
    TRAIN.append(f"data.crop={a.crop}")
    logs.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"scenes": {}, "cpu_count": os.cpu_count()}
    summary["gpu"] = gpu_name()
    recnns: dict[str, subprocess.Popen] = {}
    iml: subprocess.Popen | None = None
    for scene in a.scenes:
        if clock.left() < 150:
            summary["scenes"][scene] = {"skipped": f"{clock.left():.0f} s left"}
            continue
        t = time.monotonic()
        rc = subprocess.run([PY, "-m", "data_gen", f"scene={scene}", *COMMON, "contact_sheet=true", "progress=False",
                             f"data.workers={a.render_workers}"], stdout=open(logs / f"cache_{scene}.log", "w"),
                            stderr=subprocess.STDOUT, timeout=max(1, clock.left() - 60)).returncode
        summary["scenes"][scene] = {"cache_rc": rc, "cache_seconds": round(time.monotonic() - t, 1)}
        print(f"[lent] {scene}: cache rc {rc} in {time.monotonic() - t:.0f} s ({clock.left():.0f} s left)", flush=True)
        if rc == 0:
            recnns[scene] = start([PY, "-m", "imls_lightning.train", "model=recnn", f"scene={scene}", *COMMON, *TRAIN,
                                   *RECNN, box(min(a.recnn_seconds, clock.left() - 90))], logs / f"recnn_{scene}.log")
    # the first scene's IML once its RecNN is done (the GPU then has room for it)
    first = next(iter(recnns), None)
    while recnns and clock.left() > 45:
        if first and iml is None and a.iml_seconds > 0 and recnns[first].poll() is not None:
            run = finished_run(f"runs/paper/recnn-enhancenet-{first}-*")
            ckpt = json.loads((run / "result.json").read_text()).get("best_checkpoint") if run else None
            if ckpt and clock.left() > 120:
                iml = start([PY, "-m", "imls_lightning.train", "model=iml", f"scene={first}", *COMMON, *TRAIN,
                             f"recnn.checkpoint={ckpt}", *IML, box(min(a.iml_seconds, clock.left() - 60))],
                            logs / f"iml_{first}.log")
        if all(p.poll() is not None for p in recnns.values()) and (iml is None or iml.poll() is not None):
            break
        time.sleep(2)
    for p in [*recnns.values(), *([iml] if iml else [])]:
        if p.poll() is None:
            p.kill()
    for scene in recnns:
        cache = sorted(glob.glob(f"cache/{scene}-*"))
        run = finished_run(f"runs/paper/recnn-enhancenet-{scene}-*")
        row = summary["scenes"][scene]
        row["recnn_rc"] = recnns[scene].returncode
        if cache and clock.left() > 20:
            ev = a.out / f"evidence_{scene}.json"
            cmd = [PY, "scripts/regime_evidence.py", cache[-1], *([str(run)] if run else []), "--json", str(ev)]
            try:  # a slow evidence must not cost the pack below (the first lent run lost its checkpoints so)
                subprocess.run(cmd, stdout=open(logs / f"evidence_{scene}.log", "w"), stderr=subprocess.STDOUT,
                               timeout=max(1, clock.left() - 15))
            except subprocess.TimeoutExpired:
                row["evidence"] = "timed out"
            if ev.is_file():
                row["evidence"] = json.loads(ev.read_text())
                ev.unlink()
        if run:
            r = json.loads((run / "result.json").read_text())
            row["recnn_run"] = run.name
            row["recnn_best"] = {k: v for k, v in r.items() if k in ("best_score", "monitor", "epochs", "train_minutes", "stopped")}
    if iml is not None:
        run = finished_run(f"runs/paper/iml-enhancenet-{first}-*")
        summary["iml"] = {"scene": first, "rc": iml.returncode, "run": run.name if run else None}
    summary["seconds"] = round(clock.elapsed(), 1)
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    pack_runs(a.out / "runs.tgz", "runs/paper/*")
    with tarfile.open(a.out / "logs.tgz", "w:gz") as tar:
        tar.add(str(logs), arcname="logs")
    print(json.dumps(summary, indent=1, default=str)[:6000], flush=True)


if __name__ == "__main__":
    main()
