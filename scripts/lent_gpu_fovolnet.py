"""Issue 31 item 3 on a lent GPU machine: the quality half of FoVolNet's size table.

The latency half is measured on this CPU (``python -m imls_lightning.estimate scene=rayleigh_taylor
recnn=fovolnet candidates=[...]``, BENCHMARKS.md "FoVolNet's sizes"). Here each candidate trains at 512^2 on
the same cache, side by side on the one GPU, the same schedule and seed: the RecNN stage that ``make
bench-paper`` runs for FoVolNet (whole 512^2 images), validated every ``--val-every`` epochs so the candidates
can be compared at equal epochs even when the time box stops the wider ones first. Nothing is chosen here:
the size is chosen on the validation PSNR, and the test trajectory's PSNR (the train CLI's test pass) is only
reported.

    python3 scripts/lent_gpu_fovolnet.py --out "$OUT" --deadline 520

Writes ``<out>/summary.json`` (the cache's time; per candidate its run, epochs reached, validation PSNR per
validated epoch and test PSNR), ``<out>/run_<candidate>.tgz`` (its result.json, metrics, config and best
checkpoint) and ``<out>/logs.tgz`` (the logs and the cache's contact sheet): eight files at most, as comes back.
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from lent_gpu_regime import PY, Clock, box, finished_run, gpu_name, pack_runs, start  # noqa: E402

# the estimate's candidates (benchmarks/paper_regime_estimates.csv): features / base / filter channels, depth,
# levels, kernel; the first is FoVolNet's default
CANDIDATES = {
    "default": dict(features=16, base_channels=16, filter_channels=16, depth=4, levels=3, kernel_size=5),
    "w8": dict(features=8, base_channels=8, filter_channels=8, depth=4, levels=3, kernel_size=5),
    "w4": dict(features=4, base_channels=4, filter_channels=4, depth=4, levels=3, kernel_size=5),
    "w8-l2k3": dict(features=8, base_channels=8, filter_channels=8, depth=4, levels=2, kernel_size=3),
    "w4-d3l2k3": dict(features=4, base_channels=4, filter_channels=4, depth=3, levels=2, kernel_size=3),
}
# the default again with another seed: the spread between two seeds is the yardstick for "within 0.5 dB"
SEEDS = {"default-seed1": ("default", 1)}


def val_curve(run: Path) -> dict[int, float]:
    """``{epoch: val PSNR}`` from a run's Lightning CSV log (the last value logged for each epoch)."""
    out: dict[int, float] = {}
    for f in glob.glob(f"{run}/**/metrics.csv", recursive=True):
        with open(f) as fh:
            for row in csv.DictReader(fh):
                v = row.get("val/psnr") or row.get("val/fr_psnr")
                if v not in (None, ""):
                    out[int(row["epoch"])] = round(float(v), 3)
    return dict(sorted(out.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--deadline", type=float, default=520.0, help="seconds for everything, packing included")
    ap.add_argument("--scene", default="rayleigh_taylor")
    ap.add_argument("--data", default="paper_cpu", help="the data preset (tiny: a local smoke test of this script)")
    ap.add_argument("--candidates", nargs="*", default=[*CANDIDATES, *SEEDS])
    ap.add_argument("--render-workers", type=int, default=15)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--val-every", type=int, default=2)
    ap.add_argument("--loader-workers", type=int, default=1)
    a = ap.parse_args()
    # the logs live outside <out> and come back as one archive: every file under <out> counts against the eight
    clock, logs = Clock(a.deadline), Path(tempfile.mkdtemp(prefix="lent_fovolnet_")) / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    a.out.mkdir(parents=True, exist_ok=True)
    common = [f"data={a.data}", "renderer=numba", "data.cache_dir=cache", f"scene={a.scene}"]
    summary: dict = {"scene": a.scene, "cpu_count": os.cpu_count(), "candidates": {}}
    summary["gpu"] = gpu_name()
    try:
        import torch
        summary["torch"] = torch.__version__
    except ImportError:
        pass
    t = time.monotonic()
    rc = subprocess.run([PY, "-m", "data_gen", *common, "contact_sheet=true", "progress=False",
                         f"data.workers={a.render_workers}"], stdout=open(logs / "cache.log", "w"),
                        stderr=subprocess.STDOUT, timeout=max(1, clock.left() - 120)).returncode
    summary["cache"] = {"rc": rc, "seconds": round(time.monotonic() - t, 1)}
    print(f"[lent] cache rc {rc} in {time.monotonic() - t:.0f} s ({clock.left():.0f} s left)", flush=True)
    procs: dict[str, subprocess.Popen] = {}
    if rc == 0:
        env = {**os.environ, "OMP_NUM_THREADS": "2"}  # six trainings share 16 cores
        seconds = clock.left() - 75  # their test pass, the summary and the pack after the box
        for name in a.candidates:
            size, seed = SEEDS.get(name, (name, 0))
            sizes = [f"++recnn.net.{k}={v}" for k, v in CANDIDATES[size].items()]
            cmd = [PY, "-m", "imls_lightning.train", "model=recnn", *common, "recnn=fovolnet", "paths.runs_dir=runs/paper",
                   f"seed={seed}", "trainer.enable_progress_bar=false", f"data.loader_workers={a.loader_workers}", *sizes,
                   f"trainer.max_epochs={a.epochs}", f"trainer.check_val_every_n_epoch={a.val_every}", box(seconds)]
            procs[name] = start(cmd, logs / f"recnn_{name}.log", env=env)
    while procs and clock.left() > 25 and any(p.poll() is None for p in procs.values()):
        time.sleep(2)
    for p in procs.values():
        if p.poll() is None:
            p.kill()
    for name, p in procs.items():
        size, seed = SEEDS.get(name, (name, 0))
        sizes = CANDIDATES[size]
        tag = "-".join(str(v) for v in sizes.values())
        row: dict = {"sizes": sizes, "seed": seed, "rc": p.returncode}
        # the run's folder is named by its settings hash; its .hydra overrides name the sizes and the seed
        wanted = [f"recnn.net.{k}={v}" for k, v in sizes.items()] + [f"seed={seed}"]
        for run in sorted(glob.glob(f"runs/paper/recnn-fovolnet-{a.scene}-*")):
            cfgf = Path(run) / ".hydra" / "overrides.yaml"
            given = {line.lstrip("- ").lstrip("+") for line in cfgf.read_text().splitlines()} if cfgf.is_file() else set()
            if all(w in given for w in wanted):
                row["run"] = Path(run).name
                row["val_psnr"] = val_curve(Path(run))
                r = Path(run) / "result.json"
                if r.is_file():
                    row["result"] = {k: v for k, v in json.loads(r.read_text()).items()
                                     if k in ("best_score", "monitor", "epochs", "train_minutes", "stopped_by", "unfinished", "test")}
        summary["candidates"][name] = row
        print(f"[lent] {name} ({tag}): rc {p.returncode}, val {row.get('val_psnr')}", flush=True)
    summary["seconds"] = round(clock.elapsed(), 1)
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    # one bundle per run: what comes back is at most 8 files of 16 MB (a default FoVolNet checkpoint is 6 MB)
    for name, row in summary["candidates"].items():
        if row.get("run"):
            pack_runs(a.out / f"run_{name}.tgz", f"runs/paper/{row['run']}", sheets=False)
    with tarfile.open(a.out / "logs.tgz", "w:gz") as tar:
        tar.add(str(logs), arcname="logs")
        for sheet in glob.glob(f"cache/{a.scene}-*/contact_sheet.png"):
            tar.add(sheet)
    print(json.dumps(summary, indent=1, default=str)[:8000], flush=True)


if __name__ == "__main__":
    main()
