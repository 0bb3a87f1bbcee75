#!/usr/bin/env python
"""IMS loss ablation (paper, Table "loss functions of IMS Net") plus the PIM' regression option.

Trains the IMS network once per variant through the ordinary training command and prints, per
variant, the IM IoU / accuracy against the IML labels, the predicted vs label IPR and the final
IML/S + RecNN PSNR/SSIM on the test trajectory (with the IML + RecNN upper bound: the same path
driven by the label IM), and the training minutes. Every number comes from the ``result.json`` of
the run (the best checkpoint, chosen on ``val/im_error``, tested on the test trajectory).

Variants (``--variants``, default ``bce,mse,per,per_adv,pim``):

    bce       BCE only                              model.loss: bce 1, perceptual 0, adversarial 0
    mse       MSE only                              mse 1, perceptual 0, adversarial 0
    per       perceptual only                       perceptual 1, adversarial 0
    per_adv   perceptual + adversarial (paper)      perceptual 1, adversarial 0.01
    pim       PIM' regression + dithering vs P      per_adv with model.target=pim
    pim_mse   PIM' regression with MSE              mse 1, perceptual 0, adversarial 0, target=pim

Without ``--iml-checkpoint`` the prerequisites are trained first with the same common overrides:
a RecNN (``model=recnn``), then the IML end-to-end with it (``model=iml model.mode=end_to_end``).
Runs are keyed by their settings (``runs/<name>-<hash>``): running the script again reuses
finished runs and just prints the table.

Example (the CPU-scale measurement of the closing note)::

    python scripts/ims_loss_ablation.py --out ablation.json -- \\
        scene=ct_head recnn=enhancenet data.resolution=128 data.num_views=400 \\
        trainer.max_epochs=30 paths.runs_dir=runs/ablation
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

VARIANTS = {
    "bce": ["model.loss.bce=1.0", "model.loss.mse=0.0", "model.loss.perceptual.weight=0.0", "model.loss.adversarial=0.0"],
    "mse": ["model.loss.bce=0.0", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0", "model.loss.adversarial=0.0"],
    "per": ["model.loss.bce=0.0", "model.loss.mse=0.0", "model.loss.perceptual.weight=1.0", "model.loss.adversarial=0.0"],
    "per_adv": ["model.loss.bce=0.0", "model.loss.mse=0.0", "model.loss.perceptual.weight=1.0", "model.loss.adversarial=0.01"],
    "pim": ["model.target=pim", "model.loss.bce=0.0", "model.loss.mse=0.0", "model.loss.perceptual.weight=1.0",
            "model.loss.adversarial=0.01"],
    "pim_mse": ["model.target=pim", "model.loss.bce=0.0", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0",
                "model.loss.adversarial=0.0"],
}
LABELS = {"bce": "BCE", "mse": "MSE", "per": "PER", "per_adv": "PER + ADV (paper)", "pim": "PIM' + PER + ADV",
          "pim_mse": "PIM' + MSE"}


def train(overrides: list[str], log_dir: Path, tag: str) -> dict:
    """Run ``python -m imls_lightning.train`` and return its result record (result.json)."""
    cmd = [sys.executable, "-m", "imls_lightning.train", *overrides]
    log_dir.mkdir(parents=True, exist_ok=True)
    log = log_dir / f"{tag}.log"
    print(f"[ablation] {tag}: {' '.join(overrides)}", flush=True)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=f, text=True)
    f_out = proc.stdout
    (log_dir / f"{tag}.out").write_text(f_out)
    if proc.returncode != 0:
        raise SystemExit(f"[ablation] {tag} failed (exit {proc.returncode}); see {log}")
    ckpt = Path(f_out.strip().splitlines()[-1])
    result_file = ckpt.parent.parent / "result.json"
    if not result_file.is_file():
        raise SystemExit(f"[ablation] {tag}: no {result_file} (fast_dev_run?); see {log}")
    result = json.loads(result_file.read_text())
    result["wall_minutes"] = (time.perf_counter() - t0) / 60.0
    print(f"[ablation] {tag}: done in {result['wall_minutes']:.1f} min -> {ckpt}", flush=True)
    return result


def fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def table(rows: list[dict]) -> str:
    head = ("| variant | test IM IoU | test IM acc. | test IPR (label) | test IML/S+RecNN PSNR | SSIM | "
            "label IM PSNR (IML+RecNN) | epochs | train min |")
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        t = r["test"]
        lines.append(
            f"| {LABELS.get(r['variant'], r['variant'])} | {fmt(t.get('test/im_iou'), '.3f')} | {fmt(t.get('test/im_accuracy'), '.3f')} | "
            f"{fmt(t.get('test/ipr'), '.4f')} ({fmt(t.get('test/label_ipr'), '.4f')}) | {fmt(t.get('test/fr_psnr'), '.2f')} | "
            f"{fmt(t.get('test/fr_ssim'), '.3f')} | {fmt(t.get('test/label_fr_psnr'), '.2f')} | {r['epochs']} | {fmt(r['train_minutes'], '.1f')} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--iml-checkpoint", help="a trained IML checkpoint (default: train a RecNN and an end-to-end IML first)")
    ap.add_argument("--recnn-checkpoint", help="RecNN for a standalone IML (ignored for an end-to-end IML)")
    ap.add_argument("--variants", default="bce,mse,per,per_adv,pim", help=f"comma list of {','.join(VARIANTS)}")
    ap.add_argument("--recnn-args", default="", help="extra overrides for the RecNN stage (space separated)")
    ap.add_argument("--iml-args", default="", help="extra overrides for the IML stage (space separated)")
    ap.add_argument("--ims-args", default="", help="extra overrides for every IMS run (space separated)")
    ap.add_argument("--out", help="write the rows as JSON here")
    ap.add_argument("--logs", default="ablation_logs", help="directory for the runs' stdout/stderr")
    ap.add_argument("overrides", nargs="*", help="Hydra overrides common to every stage (after --)")
    a = ap.parse_args(argv)
    variants = [v.strip() for v in a.variants.split(",") if v.strip()]
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        ap.error(f"--variants: unknown {bad}; expected some of {list(VARIANTS)}")
    common, logs = list(a.overrides), Path(a.logs)
    prep: dict = {}
    iml = a.iml_checkpoint
    if not iml:
        rec = train(["model=recnn", *common, *a.recnn_args.split()], logs, "recnn")
        iml_res = train(["model=iml", "model.mode=end_to_end", f"recnn.checkpoint={rec['best_checkpoint']}", *common,
                         *a.iml_args.split()], logs, "iml")
        iml = iml_res["best_checkpoint"]
        prep = {"recnn": rec, "iml": iml_res}
    extra = [f"recnn.checkpoint={a.recnn_checkpoint}"] if a.recnn_checkpoint else []
    rows = []
    for v in variants:
        r = train(["model=ims", f"iml.checkpoint={iml}", *extra, *common, *a.ims_args.split(), *VARIANTS[v]], logs, f"ims-{v}")
        rows.append({"variant": v, **r})
    print()
    if prep:
        t = prep["iml"]["test"]
        print(f"IML + RecNN (labels' source): test IPR {fmt(t.get('test/ipr'), '.4f')}, "
              f"test PSNR {fmt(t.get('test/fr_psnr'), '.2f')} dB; RecNN alone: "
              f"{fmt(prep['recnn']['test'].get('test/fr_psnr'), '.2f')} dB")
    print(table(rows))
    if a.out:
        Path(a.out).write_text(json.dumps({"iml_checkpoint": iml, "overrides": common, "prep": prep, "rows": rows}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
