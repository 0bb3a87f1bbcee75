"""Issue 31 on a lent GPU machine: one RecNN's pair (its IML, IMS, blue-noise decoder, sparser-pattern RecNN and,
for EnhanceNet, LAS) at 512^2, time-boxed, for the evaluation here.

The pair's RecNN may travel with the call (``carry``): a finished run is reused, or continued to the GPU schedule's
epochs inside its box. What 2 CPU cores cannot train in a sitting runs here, on the GPU schedule of
``conf/pipelines/bench_paper_gpu.yaml``:

* the scene's cache on all cores first (the lesson of the earlier lent runs: render, then train);
* then the RecNN on the GPU, while the IMS's own 1,500-view cache (C-pixels only for its training views) renders
  on most of the cores;
* then, side by side on the one GPU: the IML, the blue-noise decoder, the sparser-pattern RecNN and LAS;
* the IMS once the IML and its cache are done, until the deadline.

The stage commands are ``make bench-paper``'s own (its ``dry_run=true`` lines), each given a ``trainer.max_time``
box; trainer limits are not part of a run's settings hash, and a time-boxed run counts as finished, so
``python -m imls_lightning.bench_paper --config-name bench_paper_gpu scene=<scene> recnns=[<recnn>]`` here finds
every run and goes straight to the evaluation. Nothing is tuned here.

    python3 scripts/lent_gpu_pair.py --out "$OUT" --recnn enhancenet --scene flame_sheets --deadline 560

Writes ``<out>/summary.json`` (cache times, each stage's rc, epochs and best score), ``<out>/runs.tgz.NNN`` (the runs'
result.json, metrics, config and best checkpoint, one gzip tar split into parts of at most 15 MiB: an IMS
checkpoint is 46 MB and one file that comes back at most 16 MiB; ``cat runs.tgz.* | tar xz``) and ``<out>/logs.tgz``.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import shlex
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# the package, for the IMS cache's renders in a process of this script's own (a lent machine has it on no path:
# the first EnhanceNet pair's IMS cache failed there on the import, and its IMS ran out of time rendering it)
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from lent_gpu_regime import PY, Clock, box, gpu_name, pack_runs, start  # noqa: E402

PART = 15 * 2**20  # bytes per part that comes back
STARTUP = 30  # seconds from a training's start to its fit's first step (imports, data setup, the sanity check)
LABELS = 30   # the IMS labels its 1,620 views with the IML before its fit starts
END = 45      # seconds kept after the boxes: the last checkpoint, result.json, the pack


def stage_commands(scene: str, data: str, recnn: str) -> dict[str, list[str]]:
    """``{stage: argv}`` of bench-paper's pair for ``recnn``, from its dry run (the placeholders ``<RecNN>`` and ``<IML>``
    are the input checkpoints). The IMS's decoder stage, a second ``model=ims`` line that fine-tunes from ``<IMS>``, is
    ``ims_decoder``: this driver does not run it (bench-paper does, from the IMS run that comes back); taken for the
    IMS, it replaced the IMS's own command and failed on its unfilled placeholder."""
    out = subprocess.run([PY, "-m", "imls_lightning.bench_paper", "--config-name", "bench_paper_gpu", f"scene={scene}",
                          f"recnns=[{recnn}]", f"data={data}", "train_only=true", "dry_run=true"],
                         capture_output=True, text=True, check=True)
    stages: dict[str, list[str]] = {}
    for line in (out.stdout + out.stderr).splitlines():
        argv = shlex.split(line.strip()) if line.startswith("python -m ") else []
        if argv[:3] == ["python", "-m", "data_gen"]:
            stages["cache"] = [PY, *argv[1:]]
        elif argv[:3] == ["python", "-m", "imls_lightning.train"]:
            model = next(a.split("=", 1)[1] for a in argv if a.startswith("model="))
            name = {"recnn": "sparser" if any(a.startswith("pattern.") for a in argv) else "recnn", "las": "las",
                    "ims": "ims_decoder" if any(a.startswith("model.init_checkpoint=") for a in argv) else "ims",
                    "iml": "blue_noise" if "model.importance=uniform" in argv else "iml"}[model]
            stages[name] = [PY, *argv[1:]]
    # the paper's LAS does not serve a foveated RecNN (las_with), so only a grid pattern's pair has it
    missing = {"cache", "recnn", "sparser", "iml", "ims", "blue_noise", *(["las"] if recnn == "enhancenet" else [])} - set(stages)
    if missing:
        raise SystemExit(f"bench-paper's dry run named no {sorted(missing)} stage:\n{out.stdout}{out.stderr}")
    return stages


def with_inputs(argv: list[str], **ckpts: str) -> list[str]:
    return [a.replace("<RecNN>", ckpts.get("recnn", "<RecNN>")).replace("<IML>", ckpts.get("iml", "<IML>")) for a in argv]


def last_line(log: Path) -> str:
    lines = log.read_text().strip().splitlines() if log.is_file() else []
    return lines[-1].strip() if lines else ""


def render_ims_cache(argv: list[str], workers: int) -> None:
    """Render the IMS stage's cache (its ``data.train_pixels=pattern`` views) as its training would, on ``workers``
    processes, so the IMS starts labelling as soon as the IML is done."""
    from hydra import compose, initialize_config_dir

    from imls_lightning.data.datamodule import ImlsDataModule
    from imls_lightning.pipelines.paths import CONF_DIR

    overrides = [a for a in argv if "=" in a and "checkpoint=" not in a and not a.startswith("-")] + [f"data.workers={workers}"]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", overrides=overrides)
    dm = ImlsDataModule(scene=cfg.scene, data=cfg.data, renderer=cfg.renderer, pattern=cfg.pattern, progress=False,
                        train_fr=False)
    dm.prepare_data()
    print(dm.cache_path, flush=True)


def ims_cache_command(a, stages: dict[str, list[str]], workers: int) -> list[str]:
    """This script in its ``--ims-cache`` mode: the IMS stage's own cache on ``workers`` processes."""
    return [PY, str(Path(__file__).resolve()), "--out", str(a.out), "--ims-cache-workers", str(workers),
            "--ims-cache", *stages["ims"][3:]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--deadline", type=float, default=540.0, help="seconds for everything, packing included")
    ap.add_argument("--recnn", default="fovolnet", choices=["enhancenet", "fovolnet"])
    ap.add_argument("--scene", default="rayleigh_taylor")
    ap.add_argument("--data", default="paper_cpu", help="the data preset (tiny: a local smoke test of this script)")
    ap.add_argument("--render-workers", type=int, default=15)
    ap.add_argument("--ims-cache-workers", type=int, default=10, help="render processes beside the trainings")
    ap.add_argument("--recnn-seconds", type=float, default=60.0, help="the RecNN's box (a finished run takes none)")
    ap.add_argument("--iml-seconds", type=float, default=150.0)
    ap.add_argument("--val-every", type=int, default=2, help="trainer.check_val_every_n_epoch (not part of the hash)")
    ap.add_argument("--ims-from", nargs=2, metavar=("RECNN_CKPT", "IML_CKPT"), default=None,
                    help="the IMS alone, from these carried checkpoints: its cache on every core, then its training "
                         "until the deadline (a second call when the first one's IMS ran out of time)")
    ap.add_argument("--override", action="append", default=[],
                    help="appended to every training stage (a smoke test on --data tiny: data.crop=null)")
    ap.add_argument("--ims-cache", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.ims_cache is not None:
        return render_ims_cache(a.ims_cache, a.ims_cache_workers)
    clock, logs = Clock(a.deadline), Path(tempfile.mkdtemp(prefix="lent_pair_")) / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"scene": a.scene, "recnn": a.recnn, "cpu_count": os.cpu_count(), "stages": {}}
    summary["gpu"] = gpu_name()
    stages = stage_commands(a.scene, a.data, a.recnn)
    limits = [f"trainer.check_val_every_n_epoch={a.val_every}", "data.loader_workers=1", *a.override]
    env = {**os.environ, "OMP_NUM_THREADS": "2", "PYTHONUNBUFFERED": "1"}
    procs: dict[str, subprocess.Popen] = {}
    if a.ims_from is not None:
        return ims_alone(a, stages, limits, env, clock, logs, summary)
    try:
        t = time.monotonic()
        rc = subprocess.run([*stages["cache"], f"data.workers={a.render_workers}"], stdout=open(logs / "cache.log", "w"),
                            stderr=subprocess.STDOUT, timeout=max(1, clock.left() - 200)).returncode
        summary["cache"] = {"rc": rc, "seconds": round(time.monotonic() - t, 1)}
        print(f"[lent] cache rc {rc} in {time.monotonic() - t:.0f} s ({clock.left():.0f} s left)", flush=True)
        # the IMS's own cache needs no network: it renders beside the RecNN and the trainings after it
        t_ims = time.monotonic()
        procs["ims_cache"] = start(ims_cache_command(a, stages, a.ims_cache_workers), logs / "ims_cache.log", env=env)
        # the RecNN: a carried, finished run is reused at once (a smoke test on --data tiny trains it)
        rc = subprocess.run([*stages["recnn"], *limits, box(a.recnn_seconds)], stdout=open(logs / "recnn.log", "w"),
                            stderr=subprocess.STDOUT, env=env, timeout=max(1, clock.left() - 150)).returncode
        recnn = last_line(logs / "recnn.log")
        summary["stages"]["recnn"] = {"rc": rc, "checkpoint": recnn}
        print(f"[lent] RecNN rc {rc}: {recnn} ({clock.left():.0f} s left)", flush=True)
        if rc != 0 or not recnn.endswith(".ckpt"):
            raise RuntimeError(f"the RecNN stage gave no checkpoint (rc {rc})")
        # the boxes end here, before the pack; a box counts from the fit's start, after imports and data setup
        late = a.deadline - END - STARTUP
        procs["iml"] = start([*with_inputs(stages["iml"], recnn=recnn), *limits, box(min(a.iml_seconds, late - clock.elapsed() - 120))],
                             logs / "iml.log", env=env)
        for name in ("blue_noise", "sparser", "las"):
            if name in stages:
                procs[name] = start([*with_inputs(stages[name], recnn=recnn), *limits, box(late - clock.elapsed())],
                                    logs / f"{name}.log", env=env)
        while clock.left() > END + STARTUP + LABELS + 30:
            done = {n: p.poll() is not None for n, p in procs.items()}
            if done["ims_cache"] and "ims_cache" not in summary:
                summary["ims_cache"] = {"rc": procs["ims_cache"].returncode, "seconds": round(time.monotonic() - t_ims, 1)}
                print(f"[lent] IMS cache rc {procs['ims_cache'].returncode} in {time.monotonic() - t_ims:.0f} s", flush=True)
            if "ims" not in procs and done["iml"] and done["ims_cache"]:
                iml = last_line(logs / "iml.log")
                if procs["iml"].returncode != 0 or not iml.endswith(".ckpt"):
                    raise RuntimeError(f"the IML stage gave no checkpoint (rc {procs['iml'].returncode})")
                summary["stages"]["iml_checkpoint"] = iml
                print(f"[lent] IMS starts ({clock.left():.0f} s left)", flush=True)
                procs["ims"] = start([*with_inputs(stages["ims"], recnn=recnn, iml=iml), *limits,
                                      box(clock.left() - END - STARTUP - LABELS)], logs / "ims.log", env=env)
            if all(done.values()) and "ims" in procs:
                break
            time.sleep(2)
    except Exception as err:  # whatever stopped the schedule, what was trained still comes back
        summary["error"] = f"{type(err).__name__}: {err}"
        print(f"[lent] {summary['error']}", flush=True)
    finish(a, procs, clock, logs, summary, f"runs/paper/*-{a.recnn}-{a.scene}-*")


def ims_alone(a, stages, limits, env, clock: Clock, logs: Path, summary: dict) -> None:
    """The IMS from carried RecNN and IML checkpoints: its cache on every core, then its training until the deadline."""
    recnn, iml = a.ims_from
    procs: dict[str, subprocess.Popen] = {}
    try:
        t = time.monotonic()
        rc = subprocess.run(ims_cache_command(a, stages, a.render_workers), stdout=open(logs / "ims_cache.log", "w"), stderr=subprocess.STDOUT,
                            env=env, timeout=max(1, clock.left() - END - STARTUP - LABELS - 30)).returncode
        summary["ims_cache"] = {"rc": rc, "seconds": round(time.monotonic() - t, 1)}
        print(f"[lent] IMS cache rc {rc} in {time.monotonic() - t:.0f} s ({clock.left():.0f} s left)", flush=True)
        if rc != 0:
            raise RuntimeError(f"the IMS cache failed (rc {rc})")
        summary["stages"]["iml_checkpoint"] = iml
        procs["ims"] = start([*with_inputs(stages["ims"], recnn=recnn, iml=iml), *limits,
                              box(clock.left() - END - STARTUP - LABELS)], logs / "ims.log", env=env)
    except Exception as err:  # what was trained still comes back
        summary["error"] = f"{type(err).__name__}: {err}"
        print(f"[lent] {summary['error']}", flush=True)
    finish(a, procs, clock, logs, summary, f"runs/paper/ims-{a.recnn}-{a.scene}-*")  # the carried runs are here already


def finish(a, procs: dict[str, subprocess.Popen], clock: Clock, logs: Path, summary: dict, pattern: str) -> None:
    """Wait for the stages until the deadline, then write the summary and pack the runs matching ``pattern`` and the
    logs into ``a.out``."""
    while any(p.poll() is None for p in procs.values()) and clock.left() > 20:
        time.sleep(2)
    for name, p in procs.items():
        if p.poll() is None:
            p.kill()
            p.wait()
        summary["stages"].setdefault(name, {})["rc"] = p.returncode
    # only the carried runs and this call's are there (the other sizes' runs did not travel)
    for run in sorted(glob.glob(pattern)):
        r = Path(run) / "result.json"
        if r.is_file():
            res = json.loads(r.read_text())
            summary["stages"][Path(run).name] = {k: res.get(k) for k in ("best_score", "monitor", "epochs", "train_minutes",
                                                                         "stopped_by", "best_checkpoint")}
    summary["seconds"] = round(clock.elapsed(), 1)
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    tgz = Path(tempfile.mkdtemp()) / "runs.tgz"
    pack_runs(tgz, pattern, sheets=False)
    data = tgz.read_bytes()
    for i in range(0, len(data), PART):
        (a.out / f"runs.tgz.{i // PART:03d}").write_bytes(data[i:i + PART])
    with tarfile.open(a.out / "logs.tgz", "w:gz") as tar:
        tar.add(str(logs), arcname="logs")
    print(json.dumps(summary, indent=1, default=str)[:8000], flush=True)


if __name__ == "__main__":
    main()
