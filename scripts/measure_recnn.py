#!/usr/bin/env python
"""Measure the two RecNNs against their classical baselines on the test trajectory (issue 3).

Trains, through the ordinary training command (``python -m imls_lightning.train``),

* EnhanceNet (``model=recnn recnn=enhancenet``, downsampling pattern: the C-Image is the 2x
  low-resolution image), and
* FoVolNet (``model=recnn recnn=fovolnet``, foveal pattern),

then evaluates each best checkpoint on the 120-view test trajectory next to a classical baseline
that sees exactly the same rendered pixels (the C-Image):

* EnhanceNet vs bicubic upsampling of the C-Image: ``F.interpolate(mode="bicubic")`` (what the
  issue asks; it assumes the low-res samples sit at block centres) and the bicubic upsampling
  aligned with the pattern's true grid (``EnhanceNet.bicubic``, its own skip path; the pattern takes
  the top-left pixel of each 2x2 block, so this is the fair baseline). Both clamped to [0, 1].
* FoVolNet vs nearest-pattern-pixel fill of the foveal PR-Image (every pixel takes the colour of the
  nearest rendered pattern pixel; Euclidean distance in pixels).

Metrics: mean per-image PSNR (dB) and mean SSIM over the test views, plus the training minutes and
epochs from each run's ``result.json``. Runs are keyed by their settings (``runs/<...>-<hash>``), so
running the script again reuses finished runs (and resumes an interrupted one).

Output: a Markdown table on stdout, written with the numbers (``.json`` beside it) to ``--out``.

Example (the CPU-scale measurement)::

    .venv/bin/python scripts/measure_recnn.py            # ct_head, data=small, numba, runs/measure
    .venv/bin/python scripts/measure_recnn.py --scene tiny --data tiny --enhancenet-epochs 1 \\
        --fovolnet-epochs 1 --enhancenet-channels 4 --enhancenet-blocks 1 --out /tmp/recnn.md
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Iterable, Sequence

import torch
import torch.nn.functional as F

from data_gen.errors import InputError, cli_errors

NAME = "measure_recnn"


# ---- progress ---------------------------------------------------------------------------------
class Progress:
    """Prints ``[name] (i/N) stage ... (elapsed)`` lines on stderr and a heartbeat while a stage runs."""

    def __init__(self, name: str, total: int, runs_dir: Path, heartbeat_s: float = 60.0):
        self.name, self.total, self.runs_dir, self.heartbeat_s = name, total, Path(runs_dir), heartbeat_s
        self.t0 = time.perf_counter()
        self.i = 0

    def elapsed(self) -> str:
        s = time.perf_counter() - self.t0
        return f"{s / 60:.1f} min" if s >= 60 else f"{s:.0f} s"

    def log(self, msg: str) -> None:
        print(f"[{self.name}] {msg} (elapsed {self.elapsed()})", file=sys.stderr, flush=True)

    def stage(self, title: str, fn: Callable[[], object]):
        """Run one stage; a background thread reports the newest epoch of a training meanwhile."""
        self.i += 1
        label = f"({self.i}/{self.total}) {title}"
        self.log(f"{label}: start")
        start_wall, t = time.time(), time.perf_counter()
        done = threading.Event()

        def beat():
            while not done.wait(self.heartbeat_s):
                ep = _newest_epoch(self.runs_dir, start_wall)
                extra = f", last logged: {ep}" if ep is not None else ""
                self.log(f"{label}: running {time.perf_counter() - t:.0f} s{extra}")

        th = threading.Thread(target=beat, daemon=True)
        th.start()
        try:
            return fn()
        finally:
            done.set()
            self.log(f"{label}: done in {time.perf_counter() - t:.1f} s")


def _newest_epoch(runs_dir: Path, since: float) -> str | None:
    """``"<run dir> epoch N"`` of the CSV log written most recently after ``since`` (None if none yet)."""
    logs = []
    for f in runs_dir.glob("*/csv/metrics.csv"):
        try:
            if f.stat().st_mtime >= since:
                logs.append((f.stat().st_mtime, f))
        except OSError:
            continue
    for _, f in sorted(logs, reverse=True):
        try:
            with f.open() as fh:
                eps = [int(float(r["epoch"])) for r in csv.DictReader(fh) if r.get("epoch")]
        except (OSError, ValueError, KeyError):
            continue
        if eps:
            return f"{f.parent.parent.name} epoch {max(eps)}"
    return None


# ---- training through the CLI -----------------------------------------------------------------
def common_overrides(args) -> list[str]:
    """Overrides every training of a measurement shares (scene, data, renderer, cache, runs, seed)."""
    return [f"scene={args.scene}", f"data={args.data}", f"renderer={args.renderer}", f"data.cache_dir={args.cache_dir}",
            f"paths.runs_dir={args.runs_dir}", f"seed={args.seed}", "trainer.enable_progress_bar=false",
            *(args.override or [])]


def recnn_loss_overrides(args) -> list[str]:
    return [f"model.loss={args.loss}", f"model.lr={args.lr:g}"]


def enhancenet_overrides(args) -> list[str]:
    return ["model=recnn", "recnn=enhancenet", *recnn_loss_overrides(args), f"recnn.net.channels={args.enhancenet_channels}",
            f"recnn.net.blocks={args.enhancenet_blocks}", f"trainer.max_epochs={args.enhancenet_epochs}"]


def fovolnet_overrides(args) -> list[str]:
    # ++: conf/recnn/fovolnet.yaml names only the _target_ (the sizes are the class defaults)
    return ["model=recnn", "recnn=fovolnet", *recnn_loss_overrides(args), f"++recnn.net.features={args.fovolnet_features}",
            f"++recnn.net.base_channels={args.fovolnet_base_channels}", f"++recnn.net.depth={args.fovolnet_depth}",
            f"trainer.max_epochs={args.fovolnet_epochs}"]


def train(name: str, overrides: Sequence[str], log=sys.stderr) -> tuple[Path, dict]:
    """Train (or reuse a finished run) through ``python -m imls_lightning.train``.

    Returns:
        ``(best checkpoint, result record)``: the record is the run's ``result.json``
        (``test`` metrics, ``train_minutes``, ``epochs``, ``config``).
    """
    from imls_lightning.pipelines import StageFailed, run_stage

    try:
        ckpt = Path(run_stage(name, ["-m", "imls_lightning.train", *overrides], log=log))
    except StageFailed as err:
        raise InputError(str(err)) from None
    result_file = ckpt.parent.parent / "result.json"
    if not ckpt.is_file() or not result_file.is_file():
        raise InputError(f"{name}: training printed {ckpt}, but no checkpoint with a result.json is there")
    return ckpt, json.loads(result_file.read_text())


def train_enhancenet(args, log=sys.stderr) -> tuple[Path, dict]:
    """The EnhanceNet run both measurement scripts use (same settings -> same run, reused)."""
    return train("EnhanceNet", [*enhancenet_overrides(args), *common_overrides(args)], log=log)


# ---- test data and metrics --------------------------------------------------------------------
def test_loader(result: dict, batch_size: int = 8):
    """DataLoader of the test trajectory (``fr``, ``c``) with the data settings of a finished run."""
    from imls_lightning.data import ImlsDataModule

    cfg = result["config"]
    data = dict(cfg["data"], batch_size=int(batch_size), loader_workers=0)
    dm = ImlsDataModule(cfg["scene"], data, cfg["renderer"], cfg["pattern"], fields=("fr", "c"), progress=False)
    dm.setup()  # finds the finished cache; renders nothing
    return dm.test_dataloader()


class ImageMetrics:
    """Running means of per-image PSNR (dB) and SSIM of several methods against the FR-Image."""

    def __init__(self):
        self.psnr: dict[str, float] = {}
        self.ssim: dict[str, float] = {}
        self.n = 0

    def add(self, name: str, pred: torch.Tensor, target: torch.Tensor) -> None:
        """``pred``, ``target``: ``(B, 3, m, m)``; ``pred`` is clamped to [0, 1] here."""
        from imls_lightning.core.metrics import psnr_per_image, ssim_metric as ssim

        b = target.shape[0]
        self.psnr[name] = self.psnr.get(name, 0.0) + float(psnr_per_image(pred, target).sum())
        self.ssim[name] = self.ssim.get(name, 0.0) + float(ssim(pred, target)) * b

    def means(self, n: int) -> dict[str, dict[str, float]]:
        return {k: {"psnr": self.psnr[k] / n, "ssim": self.ssim[k] / n} for k in self.psnr}


def nearest_pattern_pixel(indices: torch.Tensor, fr_size: int, chunk: int = 2048) -> torch.Tensor:
    """For every FR pixel, the position ``k`` (into ``indices``) of the nearest pattern pixel.

    Chunked exhaustive search (scipy is not a dependency): ``(m*m, K)`` distances, ``chunk`` rows at a
    time. Pattern pixels map to themselves; ties go to the lower raster index.

    Args:
        indices: ``(K,)`` ascending raster indices of the pattern pixels.
        fr_size: FR-Image side ``m``.

    Returns:
        ``(m*m,)`` int64 in ``[0, K)``.
    """
    m = int(fr_size)
    idx = indices.long().cpu()
    pat = torch.stack([idx // m, idx % m], 1).float()  # (K, 2) row, col
    allp = torch.arange(m * m)
    allp = torch.stack([allp // m, allp % m], 1).float()
    out = torch.empty(m * m, dtype=torch.long)
    for s in range(0, m * m, chunk):
        d = torch.cdist(allp[s:s + chunk], pat)  # (chunk, K)
        out[s:s + chunk] = d.argmin(1)
    return out


def nearest_fill(c_image: torch.Tensor, nearest: torch.Tensor, fr_size: int) -> torch.Tensor:
    """Fill the PR-Image from the C-Image: FR pixel ``p`` takes C pixel ``nearest[p]``.

    ``c_image`` ``(B, 3, n, n)`` (pattern pixels first in raster order) -> ``(B, 3, m, m)``.
    """
    b, c = c_image.shape[:2]
    return c_image.reshape(b, c, -1)[:, :, nearest.to(c_image.device)].reshape(b, c, fr_size, fr_size)


@torch.no_grad()
def evaluate_enhancenet(ckpt: Path, result: dict, batch_size: int = 8) -> dict[str, dict[str, float]]:
    """EnhanceNet, F.interpolate bicubic and grid-aligned bicubic on the test trajectory."""
    from imls_lightning.inference.checkpoints import load_task

    task = load_task(ckpt, expect="RecNNTask")
    net = task.net
    m = ImageMetrics()
    n = 0
    for batch in test_loader(result, batch_size):
        c, fr = batch["c"], batch["fr"]
        m.add("enhancenet", net(c), fr)
        m.add("bicubic_interpolate", F.interpolate(c, size=fr.shape[-2:], mode="bicubic", align_corners=False), fr)
        m.add("bicubic_aligned", net.bicubic(c), fr)
        n += fr.shape[0]
    return m.means(n) | {"_views": n}


@torch.no_grad()
def evaluate_fovolnet(ckpt: Path, result: dict, batch_size: int = 8) -> dict[str, dict[str, float]]:
    """FoVolNet and the nearest-pattern-pixel fill on the test trajectory."""
    from imls_lightning.inference.checkpoints import load_task

    task = load_task(ckpt, expect="RecNNTask")
    pat = task.pattern
    nearest = nearest_pattern_pixel(pat.indices, pat.fr_size)
    m = ImageMetrics()
    n = 0
    for batch in test_loader(result, batch_size):
        c, fr = batch["c"], batch["fr"]
        m.add("fovolnet", task.net(c), fr)
        m.add("nearest_fill", nearest_fill(c, nearest, pat.fr_size), fr)
        n += fr.shape[0]
    return m.means(n) | {"_views": n, "_pattern_pixels": int(pat.count), "_fr_pixels": int(pat.fr_size) ** 2}


# ---- output -----------------------------------------------------------------------------------
def atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_outputs(out: Path, markdown: str, record: dict) -> None:
    """``out`` (Markdown) and ``out`` with suffix ``.json`` (the numbers), each written atomically."""
    atomic_write(out, markdown)
    atomic_write(out.with_suffix(".json"), json.dumps(record, indent=2, default=str) + "\n")


def fmt(x, nd=2) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{nd}f}"


def recnn_table(rec: dict) -> str:
    """The Markdown table of a measure_recnn record."""
    rows = ["| RecNN (pattern) | method | test PSNR (dB) | test SSIM | gain vs baseline (dB) | train min | epochs |",
            "|---|---|---:|---:|---:|---:|---:|"]
    for key, title, net, baselines in (
        ("enhancenet", "EnhanceNet (downsample 2x)", "enhancenet",
         [("bicubic_interpolate", "bicubic, F.interpolate"), ("bicubic_aligned", "bicubic, grid-aligned")]),
        ("fovolnet", "FoVolNet (foveal)", "fovolnet", [("nearest_fill", "nearest pattern pixel")]),
    ):
        r = rec.get(key)
        if not r:
            continue
        mt = r["metrics"]
        rows.append(f"| {title} | **{net}** | {fmt(mt[net]['psnr'])} | {fmt(mt[net]['ssim'], 4)} | | "
                    f"{fmt(r['train_minutes'])} | {r['epochs']} |")
        for b, label in baselines:
            gain = mt[net]["psnr"] - mt[b]["psnr"]
            rows.append(f"| | {label} | {fmt(mt[b]['psnr'])} | {fmt(mt[b]['ssim'], 4)} | {gain:+.2f} | | |")
    return "\n".join(rows)


def markdown(title: str, command: str, settings: str, table: str, notes: Iterable[str] = ()) -> str:
    lines = [f"## {title}", "", f"`{command}`", "", settings, "", table, ""]
    lines += [f"- {n}" for n in notes]
    return "\n".join(lines).rstrip() + "\n"


# ---- command line -----------------------------------------------------------------------------
def add_common_args(p: argparse.ArgumentParser) -> None:
    """Options shared by both measurement scripts (data, where things go, the EnhanceNet run)."""
    p.add_argument("--scene", default="ct_head", help="scene preset (default: ct_head)")
    p.add_argument("--data", default="small", help="data preset (default: small = 300 views at 128^2 + 120 test views)")
    p.add_argument("--renderer", default="numba", help="renderer preset (default: numba)")
    p.add_argument("--cache-dir", default="cache", help="data.cache_dir (default: cache)")
    p.add_argument("--runs-dir", default="runs/measure", help="paths.runs_dir (default: runs/measure)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--loss", default="mse", choices=["mse", "l1"],
                   help="RecNN training loss (default: mse; with l1 the EnhanceNet's ReLUs died within ~20 steps on ct_head)")
    p.add_argument("--lr", type=float, default=1e-3, help="RecNN Adam learning rate (default: 1e-3)")
    p.add_argument("--enhancenet-epochs", type=int, default=8)
    p.add_argument("--enhancenet-channels", type=int, default=32)
    p.add_argument("--enhancenet-blocks", type=int, default=6)
    p.add_argument("--batch-size", type=int, default=8, help="evaluation batch size")
    p.add_argument("--override", action="append", metavar="KEY=VALUE",
                   help="extra training override for every run (repeatable), e.g. --override data.num_views=400")


def check_args(args) -> None:
    for k in [a for a in vars(args) if a.endswith(("_epochs", "_channels", "_blocks", "_features", "_depth")) or a == "batch_size"]:
        v = getattr(args, k)
        if v is not None and int(v) < (0 if k.endswith("_blocks") else 1):
            raise InputError(f"--{k.replace('_', '-')}={v}: expected a positive integer")


def command_line() -> str:
    return " ".join([".venv/bin/python" if ".venv" in sys.executable else Path(sys.executable).name,
                     *[a if " " not in a else repr(a) for a in sys.argv]])


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    add_common_args(p)
    p.add_argument("--fovolnet-epochs", type=int, default=3)
    p.add_argument("--fovolnet-features", type=int, default=16)
    p.add_argument("--fovolnet-base-channels", type=int, default=16)
    p.add_argument("--fovolnet-depth", type=int, default=4)
    p.add_argument("--out", default=None, help="Markdown output (default: <runs-dir>/recnn.md; the JSON of the numbers beside it)")
    args = p.parse_args(argv)
    check_args(args)
    return args


@cli_errors
def main(argv=None) -> dict:
    args = parse_args(argv)
    out = Path(args.out or Path(args.runs_dir) / "recnn.md")
    prog = Progress(NAME, 4, Path(args.runs_dir))
    cmd = command_line()
    record: dict = {"command": cmd, "args": vars(args)}

    ck_e, res_e = prog.stage("train EnhanceNet", lambda: train_enhancenet(args))
    met_e = prog.stage("evaluate EnhanceNet vs bicubic", lambda: evaluate_enhancenet(ck_e, res_e, args.batch_size))
    record["enhancenet"] = {"checkpoint": str(ck_e), "train_minutes": res_e.get("train_minutes"), "epochs": res_e.get("epochs"),
                            "result_test": res_e.get("test", {}), "metrics": met_e}
    ck_f, res_f = prog.stage("train FoVolNet", lambda: train("FoVolNet", [*fovolnet_overrides(args), *common_overrides(args)]))
    met_f = prog.stage("evaluate FoVolNet vs nearest fill", lambda: evaluate_fovolnet(ck_f, res_f, args.batch_size))
    record["fovolnet"] = {"checkpoint": str(ck_f), "train_minutes": res_f.get("train_minutes"), "epochs": res_f.get("epochs"),
                          "result_test": res_f.get("test", {}), "metrics": met_f}

    gain = met_e["enhancenet"]["psnr"] - max(met_e["bicubic_interpolate"]["psnr"], met_e["bicubic_aligned"]["psnr"])
    record["enhancenet_gain_db"] = gain
    record["enhancenet_beats_bicubic_by_1db"] = bool(gain >= 1.0)
    settings = (f"scene={args.scene}, data={args.data}, renderer={args.renderer}; {met_e['_views']} test views; "
                f"EnhanceNet {args.enhancenet_channels} ch x {args.enhancenet_blocks} blocks, max {args.enhancenet_epochs} epochs; "
                f"FoVolNet features {args.fovolnet_features}, depth {args.fovolnet_depth}, base {args.fovolnet_base_channels}, "
                f"max {args.fovolnet_epochs} epochs; loss {args.loss}, lr {args.lr:g}. PSNR = mean per-image PSNR, outputs clamped to [0, 1].")
    notes = [
        f"EnhanceNet gain over the better bicubic: {gain:+.2f} dB ({'meets' if gain >= 1.0 else 'MISSES'} the >= 1 dB requirement).",
        "bicubic, F.interpolate: align_corners=False treats each C pixel as a 2x2 block centre; the downsampling pattern "
        "samples the top-left pixel of each block, so this baseline is shifted by half an FR pixel. "
        "bicubic, grid-aligned: the same kernel at the true sample positions (EnhanceNet's own skip path).",
        f"FoVolNet pattern: {met_f['_pattern_pixels']} of {met_f['_fr_pixels']} FR pixels rendered; nearest fill = "
        "colour of the nearest rendered pattern pixel (exhaustive Euclidean search).",
    ]
    record["markdown"] = md = markdown("RecNN vs classical baselines (test trajectory)", cmd, settings, recnn_table(record), notes)
    write_outputs(out, md, record)
    print(md, flush=True)
    prog.log(f"wrote {out} and {out.with_suffix('.json')}")
    return record


if __name__ == "__main__":
    main()
