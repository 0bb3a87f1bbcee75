#!/usr/bin/env python
"""Time the product path under each inference backend, side by side in one run (issue 19, lever 2).

The same IMS checkpoint, views and mask (the trained mean) run through :class:`IMLSRenderer` with

* PyTorch float32, bfloat16 autocast (``NetOptions.half``, what the paper-scale benchmark uses),
  bfloat16 + channels_last, and optionally ``torch.compile`` (``--compile``: its first call compiles);
* the exported networks (:func:`imls_lightning.inference.export.export_renderer`): TorchScript, and ONNX Runtime
  when ``onnx`` and ``onnxruntime`` are installed (``pip install -e '.[export]'``; otherwise the row
  says it was skipped).

Per backend: the median of each stage over the views (each view: ``--repeats`` timed runs after one
warm-up, :func:`~imls_lightning.inference.pipeline.time_method`) and the PSNR of the FR-Image against the
cached ground truth, with its difference to float32 (issue 19: bfloat16 only within 0.1 dB).
Backends run interleaved per view, so a slow spell of a shared machine hits every one alike.

Example::

    .venv/bin/python scripts/measure_backends.py runs/paper/ims-enhancenet-ct_head-11b68627/checkpoints/epoch002.ckpt \\
        --cache cache/ct_head-a1e18fbae574 --views 3 --out benchmarks/backends_ct_head.md
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STAGES = ("importance", "selective_render", "decoder", "recnn")
NETWORKS = ("importance", "decoder", "recnn")


def build_backends(ims_checkpoint: str, recnn_checkpoint: str | None, compile_: bool, export_dir: Path) -> dict:
    """``{name: method or reason skipped}``: every method renders with the same renderer object."""
    from imls_lightning.inference.export import ExportedIMLSRenderer, export_renderer, onnx_available
    from imls_lightning.inference.checkpoints import load_ims_nets, renderer_for
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    options = {"PyTorch float32": NetOptions(device="cpu"),
               "PyTorch bfloat16": NetOptions(device="cpu", half=True),
               "PyTorch bfloat16 + channels_last": NetOptions(device="cpu", half=True, channels_last=True)}
    if compile_:
        options["PyTorch bfloat16 + torch.compile"] = NetOptions(device="cpu", half=True, compile=True)
    renderer = None
    out: dict = {}
    for name, opts in options.items():
        nets = load_ims_nets(ims_checkpoint, recnn_checkpoint)  # each method prepares its own copy
        renderer = renderer or renderer_for(nets.hparams)
        out[name] = IMLSRenderer.from_nets(nets, renderer, opts)
    for fmt in ("torchscript", "onnx"):
        name = {"torchscript": "TorchScript float32 (export)", "onnx": "ONNX Runtime float32 (export)"}[fmt]
        if fmt == "onnx" and not onnx_available():
            out[name] = "skipped: onnx / onnxruntime not installed (pip install -e '.[export]')"
            continue
        path = export_renderer(ims_checkpoint, export_dir / fmt, format=fmt, recnn_checkpoint=recnn_checkpoint)
        out[name] = ExportedIMLSRenderer.load(path, renderer=renderer, device="cpu")
    return out


def measure(methods: dict, views: np.ndarray, truth: np.ndarray, repeats: int) -> dict[str, dict]:
    """Per method: stage medians over the views (ms), total, PSNR (dB) against ``truth`` (uint8)."""
    import torch

    from imls_lightning.core.metrics import psnr_per_image
    from imls_lightning.inference.pipeline import time_method

    runnable = {k: m for k, m in methods.items() if not isinstance(m, str)}
    per: dict[str, list[dict]] = {k: [] for k in runnable}
    psnr: dict[str, list[float]] = {k: [] for k in runnable}
    for i, view in enumerate(views):
        for name, method in runnable.items():  # interleaved: every backend sees the same machine state
            image, med, _ = time_method(method, view, repeats=repeats, warmup=1)
            per[name].append(med)
            a = torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255.0
            b = torch.from_numpy(np.asarray(truth[i])).permute(2, 0, 1)[None].float() / 255.0
            psnr[name].append(float(psnr_per_image(a, b)[0]))
        print(f"[backends] view {i + 1}/{len(views)} done", file=sys.stderr, flush=True)
    rows = {}
    for name in runnable:
        row = {s: 1e3 * float(np.median([r.get(s, 0.0) for r in per[name]])) for s in STAGES}
        row["networks"] = sum(row[s] for s in NETWORKS)
        row["total"] = 1e3 * float(np.median([r["total"] for r in per[name]]))
        row["psnr"] = float(np.mean(psnr[name]))
        rows[name] = row
    return rows


def markdown(rows: dict, skipped: dict, meta: str) -> str:
    base = rows.get("PyTorch float32")
    lines = [f"{meta}\n", "| backend | IMS (ms) | render (ms) | decoder (ms) | RecNN (ms) | networks (ms) | total (ms) | PSNR (dB) | vs float32 (dB) |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in rows.items():
        d = f"{r['psnr'] - base['psnr']:+.3f}" if base else "–"
        lines.append(f"| {name} | {r['importance']:.1f} | {r['selective_render']:.1f} | {r['decoder']:.1f} | {r['recnn']:.1f} | "
                     f"{r['networks']:.1f} | {r['total']:.1f} | {r['psnr']:.3f} | {d} |")
    for name, why in skipped.items():
        lines.append(f"| {name} | {why} | | | | | | | |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ims_checkpoint")
    ap.add_argument("--recnn", default=None, help="a RecNN checkpoint instead of the one inside the IMS checkpoint")
    ap.add_argument("--cache", required=True, help="the view cache (its test split gives the views and the ground truth)")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--compile", action="store_true", help="also time torch.compile (its first call compiles)")
    ap.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (default: PyTorch's)")
    ap.add_argument("--out", default=None, help="also write the Markdown table here")
    args = ap.parse_args(argv)

    import torch

    from data_gen.cache import ViewImageCache
    from data_gen.errors import InputError

    if args.views < 1 or args.repeats < 1:
        raise SystemExit("--views and --repeats: expected integers >= 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        cache = ViewImageCache.open(Path(args.cache))
    except (InputError, OSError) as err:
        raise SystemExit(f"--cache {args.cache}: {err}") from None
    from imls_lightning.evaluation import spaced

    rows_idx = np.asarray(cache.splits["test"])
    rows_idx = rows_idx[spaced(len(rows_idx), args.views)]  # the evaluation's own choice of evenly spaced views
    views = np.asarray(cache.views[rows_idx], np.float32)
    truth = np.stack([np.asarray(cache.images[r]) for r in rows_idx])
    with tempfile.TemporaryDirectory(prefix="imls-backends-") as tmp:
        methods = build_backends(args.ims_checkpoint, args.recnn, args.compile, Path(tmp))
        rows = measure(methods, views, truth, args.repeats)
    skipped = {k: m for k, m in methods.items() if isinstance(m, str)}
    meta = (f"`scripts/measure_backends.py {args.ims_checkpoint} --cache {args.cache} --views {args.views} --repeats {args.repeats}`: "
            f"{args.views} test views, medians of {args.repeats} runs each, {torch.get_num_threads()} threads, mask at the trained mean.")
    text = markdown(rows, skipped, meta)
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
