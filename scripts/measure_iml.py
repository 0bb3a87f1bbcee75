#!/usr/bin/env python
"""Measure what the IML network achieves per mean value u, standalone and end-to-end (issue 4).

With the EnhanceNet run of ``scripts/measure_recnn.py`` (trained here the same way when missing;
same settings -> the same run, reused), trains for every mean value ``u`` in ``--means`` and every
mode in ``--modes``, through ``python -m imls_lightning.train``::

    model=iml recnn=enhancenet model.mean=u model.mode=standalone
    model=iml recnn=enhancenet model.mean=u model.mode=end_to_end recnn.checkpoint=<EnhanceNet .ckpt>

and evaluates each best checkpoint on the 120-view test trajectory with the hard mask, as at
inference (importance from the rendered C-Image):

* C-share: important / valid C-Image pixels (the share of the C-Image that is kept), and its ratio
  to ``u``. With ``P`` uniform in (0, 1] the expected share is ``mean(min(PIM', 1))``, i.e. ``u``
  when no ``PIM'`` exceeds 1 (reported as ``E[min(PIM',1)]``); the paper says the share converges
  to about ``10 u``: the table settles which holds.
* IPR: important / FR-Image pixels (``m * m``; the pattern keeps a quarter of them, so IPR =
  C-share / 4 for the 2x downsampling pattern), and its ratio to ``u``.
* PSNR / SSIM of IML + RecNN (decoder output -> RecNN) against the FR-Image, next to the RecNN
  alone on the full C-Image. Standalone runs attach their decoder to the separately trained
  EnhanceNet (the paper's off-the-shelf case, :class:`imls_lightning.models.iml.IMLRecNN`);
  end-to-end runs use the (frozen) RecNN they were trained with, the same weights.
* Training minutes and epochs from each run's ``result.json``.

The table (and a JSON of the numbers) is rewritten after every finished run, so an interrupted
measurement leaves the rows it has; running the script again reuses finished runs.

Example (the CPU-scale measurement)::

    .venv/bin/python scripts/measure_iml.py              # ct_head, data=small, numba, runs/measure
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import measure_recnn as mr  # noqa: E402  (shared: training, progress, test data, metrics, output)

from data_gen.errors import InputError, cli_errors  # noqa: E402

NAME = "measure_iml"
MODES = ("standalone", "end_to_end")


def iml_overrides(args, mode: str, mean: float, recnn_ckpt: Path) -> list[str]:
    o = ["model=iml", "recnn=enhancenet", f"model.mode={mode}", f"model.mean={mean}", f"model.depth={args.iml_depth}",
         f"model.base_channels={args.iml_base_channels}", f"trainer.max_epochs={args.iml_epochs}",
         # the RecNN sizes: the pattern comes from recnn=..., the net config must match the checkpoint's
         f"recnn.net.channels={args.enhancenet_channels}", f"recnn.net.blocks={args.enhancenet_blocks}"]
    if mode == "end_to_end":
        o.append(f"recnn.checkpoint={recnn_ckpt}")
    return o


@torch.no_grad()
def evaluate_recnn_alone(recnn_ckpt: Path, result: dict, batch_size: int) -> dict:
    """The RecNN on the full C-Image (the reference an IML is compared with)."""
    from imls_lightning.inference.checkpoints import load_task

    net = load_task(recnn_ckpt, expect="RecNNTask").net
    m, n = mr.ImageMetrics(), 0
    for batch in mr.test_loader(result, batch_size):
        m.add("recnn", net(batch["c"]), batch["fr"])
        n += batch["fr"].shape[0]
    return m.means(n)["recnn"]


@torch.no_grad()
def evaluate_iml(iml_ckpt: Path, result: dict, recnn_ckpt: Path, batch_size: int) -> dict:
    """Hard-mask IPR / C-share and IML + RecNN image quality of one IML checkpoint on the test views."""
    from imls_lightning.models.iml import IMLRecNN, c_share, ipr
    from imls_lightning.inference.checkpoints import load_task
    from imls_lightning.core.metrics import psnr_per_image

    task = load_task(iml_ckpt, expect="IMLTask")
    rec = task.recnn if task.recnn is not None else load_task(recnn_ckpt, expect="RecNNTask").net
    pat = task.pattern
    if task.recnn is None and load_task(recnn_ckpt, expect="RecNNTask").pattern.fingerprint() != pat.fingerprint():
        raise InputError(f"{recnn_ckpt}: the RecNN's sampling pattern differs from the IML's")
    model = IMLRecNN(task.iml, rec).eval()
    valid = pat.valid.to(torch.float32)
    m = mr.ImageMetrics()
    n, share, ipr_sum, exp_share, pim_mean, c_psnr = 0, 0.0, 0.0, 0.0, 0.0, 0.0
    for batch in mr.test_loader(result, batch_size):
        c, fr = batch["c"], batch["fr"]
        out = task.iml(c, hard=True)
        m.add("iml_recnn", model.recnn(out.c_recon), fr)
        share += float(c_share(out.im, pat.valid).sum())
        ipr_sum += float(ipr(out.im, pat.fr_size).sum())
        # with P uniform in (0, 1], pixel (i, j) is kept with probability min(PIM'_ij, 1)
        v = valid.view(1, 1, *valid.shape)
        exp_share += float(((out.pim_norm.clamp(0, 1) * v).flatten(1).sum(1) / v.sum()).sum())
        pim_mean += float(((out.pim_norm * v).flatten(1).sum(1) / v.sum()).sum())
        c_psnr += float(psnr_per_image(out.c_recon, c).sum())
        n += fr.shape[0]
    img = m.means(n)["iml_recnn"]
    return {"c_share": share / n, "ipr": ipr_sum / n, "expected_share": exp_share / n, "pim_norm_mean": pim_mean / n,
            "psnr": img["psnr"], "ssim": img["ssim"], "c_psnr": c_psnr / n, "views": n,
            "recnn_used": "trained with (frozen)" if task.recnn is not None else "separate EnhanceNet (off the shelf)"}


def iml_table(rec: dict) -> str:
    rows = ["| mode | mean u | C-share (hard IM) | C-share / u | E[min(PIM',1)] | IPR (of FR px) | IPR / u "
            "| IML+RecNN PSNR (dB) | SSIM | RecNN alone PSNR (dB) | gap (dB) | train min | epochs |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    ref = rec.get("recnn_alone") or {}
    for r in rec.get("runs", []):
        e, u = r["metrics"], r["mean"]
        gap = e["psnr"] - ref["psnr"] if ref else float("nan")
        rows.append(f"| {r['mode']} | {u:g} | {e['c_share']:.4f} | {e['c_share'] / u:.2f} | {e['expected_share']:.4f} | "
                    f"{e['ipr']:.4f} | {e['ipr'] / u:.2f} | {mr.fmt(e['psnr'])} | {mr.fmt(e['ssim'], 4)} | "
                    f"{mr.fmt(ref.get('psnr'))} | {gap:+.2f} | {mr.fmt(r['train_minutes'])} | {r['epochs']} |")
    return "\n".join(rows)


def render(rec: dict, args, cmd: str) -> str:
    ref = rec.get("recnn_alone") or {}
    settings = (f"scene={args.scene}, data={args.data}, renderer={args.renderer}; RecNN = EnhanceNet "
                f"{args.enhancenet_channels} ch x {args.enhancenet_blocks} blocks ({rec.get('recnn_checkpoint')}); "
                f"IML U-Nets depth {args.iml_depth}, base {args.iml_base_channels} ch, max {args.iml_epochs} epochs; "
                f"hard mask on the test trajectory; PSNR = mean per-image PSNR, outputs clamped to [0, 1].")
    notes = [f"RecNN alone: PSNR {mr.fmt(ref.get('psnr'))} dB, SSIM {mr.fmt(ref.get('ssim'), 4)}." if ref else "",
             "C-share = important / valid C-Image pixels; IPR = important / FR pixels (m^2). "
             "E[min(PIM',1)] = the share expected from PIM' when P is uniform in (0, 1].",
             "standalone rows: the decoder feeds the separately trained EnhanceNet (off-the-shelf); "
             "end_to_end rows: the frozen copy of the same EnhanceNet inside the IML checkpoint."]
    notes += rec.get("checks", [])
    done = len(rec.get("runs", []))
    if done < rec.get("planned", done):
        notes.append(f"PARTIAL: {done} of {rec['planned']} runs finished so far.")
    return mr.markdown("IML: achieved share and quality per mean value (test trajectory)", cmd, settings, iml_table(rec),
                       [n for n in notes if n])


def parse_args(argv=None) -> argparse.Namespace:
    from imls_lightning.core.importance import check_mean

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    mr.add_common_args(p)
    p.add_argument("--means", default="0.05,0.1,0.2,0.4", help="comma-separated mean values u (default: 0.05,0.1,0.2,0.4)")
    p.add_argument("--modes", default="standalone,end_to_end", help="comma-separated: standalone, end_to_end")
    p.add_argument("--iml-epochs", type=int, default=2)
    p.add_argument("--iml-depth", type=int, default=4)
    p.add_argument("--iml-base-channels", type=int, default=8)
    p.add_argument("--recnn-checkpoint", default=None,
                   help="an EnhanceNet RecNNTask .ckpt to use instead of training/reusing the measure_recnn one")
    p.add_argument("--out", default=None, help="Markdown output (default: <runs-dir>/iml.md; the JSON of the numbers beside it)")
    args = p.parse_args(argv)
    mr.check_args(args)
    try:
        values = [float(x) for x in args.means.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--means={args.means}: expected comma-separated numbers in [0.01, 1]") from None
    args.mean_values = [check_mean(v, "--means") for v in values]
    args.mode_list = [x.strip() for x in args.modes.split(",") if x.strip()]
    bad = [x for x in args.mode_list if x not in MODES]
    if bad or not args.mode_list or not args.mean_values:
        raise InputError(f"--modes={args.modes} / --means={args.means}: expected non-empty lists, modes from {list(MODES)}")
    if args.recnn_checkpoint and not Path(args.recnn_checkpoint).is_file():
        raise InputError(f"--recnn-checkpoint={args.recnn_checkpoint}: file not found")
    return args


@cli_errors
def main(argv=None) -> dict:
    args = parse_args(argv)
    out = Path(args.out or Path(args.runs_dir) / "iml.md")
    jobs = [(u, mode) for u in args.mean_values for mode in args.mode_list]  # mean-major: both modes per u early
    prog = mr.Progress(NAME, 2 + 2 * len(jobs), Path(args.runs_dir))
    cmd = mr.command_line()

    if args.recnn_checkpoint:
        recnn_ckpt = Path(args.recnn_checkpoint).resolve()
        result_file = recnn_ckpt.parent.parent / "result.json"
        if not result_file.is_file():
            raise InputError(f"--recnn-checkpoint={args.recnn_checkpoint}: no result.json of its run next to checkpoints/")
        recnn_res = prog.stage("EnhanceNet (given)", lambda: __import__("json").loads(result_file.read_text()))
    else:
        recnn_ckpt, recnn_res = prog.stage("train/reuse EnhanceNet", lambda: mr.train_enhancenet(args))
    rec: dict = {"command": cmd, "args": {k: v for k, v in vars(args).items()}, "recnn_checkpoint": str(recnn_ckpt),
                 "recnn_train_minutes": recnn_res.get("train_minutes"), "planned": len(jobs), "runs": [], "checks": []}
    rec["recnn_alone"] = prog.stage("evaluate EnhanceNet alone", lambda: evaluate_recnn_alone(recnn_ckpt, recnn_res, args.batch_size))

    for u, mode in jobs:
        tag = f"IML {mode} mean={u:g}"
        ck, res = prog.stage(f"train {tag}", lambda: mr.train(tag, [*iml_overrides(args, mode, u, recnn_ckpt), *mr.common_overrides(args)]))
        ev = prog.stage(f"evaluate {tag}", lambda: evaluate_iml(ck, res, recnn_ckpt, args.batch_size))
        t = res.get("test", {})
        # the run's own test pass logs the same hard-mask numbers (batch means): a cross-check
        for key, mine in (("test/ipr", ev["ipr"]), ("test/c_share", ev["c_share"]), ("test/fr_psnr", ev["psnr"])):
            if key in t and abs(float(t[key]) - mine) > (0.02 if key.endswith("psnr") else 1e-3):
                rec["checks"].append(f"{tag}: {key} here {mine:.4f} vs result.json {float(t[key]):.4f}")
        rec["runs"].append({"mode": mode, "mean": u, "checkpoint": str(ck), "train_minutes": res.get("train_minutes"),
                            "epochs": res.get("epochs"), "result_test": t, "metrics": ev})
        rec["markdown"] = md = render(rec, args, cmd)
        mr.write_outputs(out, md, rec)  # partial table after every run
        prog.log(f"{tag}: C-share {ev['c_share']:.4f} (u={u:g}), IPR {ev['ipr']:.4f}, PSNR {ev['psnr']:.2f} dB; wrote {out}")

    rec["markdown"] = md = render(rec, args, cmd)
    mr.write_outputs(out, md, rec)
    print(md, flush=True)
    prog.log(f"wrote {out} and {out.with_suffix('.json')}")
    return rec


if __name__ == "__main__":
    main()
