"""``python -m imls_lightning.export ims_checkpoint=ims.ckpt format=torchscript|onnx out=DIR
[recnn_checkpoint=recnn.ckpt] [overwrite=true] [share=null]``: export the per-view networks of an IMS
checkpoint to TorchScript or ONNX.

This entry point parses its ``key=value`` arguments and calls
:func:`imls_lightning.inference.export.export_renderer` (the export, the files it writes and
:class:`~imls_lightning.inference.export.ExportedIMLSRenderer`, which renders with them, live there).
It prints a summary line per file on stderr and the export directory as the last stdout line.

Example:
    python -m imls_lightning.export ims_checkpoint=runs/ims-.../checkpoints/last.ckpt format=torchscript out=exported
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Sequence

from imls_lightning.base.errors import InputError, cli_errors

from .inference.export import META, export_renderer
from .inference.operating_point import share_setting

__all__ = ["parse_args", "main"]

# share: the share of the C-Image the im network thresholds at (null: the recorded operating point); mean: its older name
_KEYS = {"ims_checkpoint": None, "format": "torchscript", "out": None, "recnn_checkpoint": None, "overwrite": "false",
         "share": None, "mean": None}


def parse_args(argv: Sequence[str]) -> dict[str, Any]:
    """``key=value`` arguments (Hydra style) -> settings; one-line InputError on anything else."""
    args = dict(_KEYS)
    for a in argv:
        key, sep, value = a.partition("=")
        key = key.lstrip("+")
        if not sep or key not in _KEYS:
            raise InputError(f"argument {a!r}: expected key=value with key one of {', '.join(_KEYS)}")
        args[key] = value
    for key in ("ims_checkpoint", "out"):
        if not args[key]:
            raise InputError(f"{key}: missing (usage: python -m imls_lightning.export ims_checkpoint=<IMS .ckpt> format=torchscript|onnx out=<dir>)")
    ov = str(args["overwrite"]).lower()
    if ov not in ("true", "false"):
        raise InputError(f"overwrite={args['overwrite']}: expected true or false")
    args["overwrite"] = ov == "true"
    for key in ("recnn_checkpoint", "share", "mean"):
        if args[key] in ("", "null", "None"):
            args[key] = None
    return args


@cli_errors
def main(argv: Sequence[str] | None = None) -> Path:
    """Export, print a summary line per file on stderr and the export directory as the last stdout line."""
    args = parse_args(sys.argv[1:] if argv is None else argv)
    value, key = share_setting(args)
    out = export_renderer(args["ims_checkpoint"], args["out"], args["format"], args["recnn_checkpoint"], args["overwrite"],
                          **{key: value})
    meta = json.loads((out / META).read_text())
    print(f"[export] im thresholds at u = {meta['mean']:.3f}" + (" (masks lifted)" if meta["lift"] else "")
          + (" (the evaluation's operating point)" if meta["operating_point"] else ""), file=sys.stderr)
    for name, fname in meta["files"].items():
        print(f"[export] {name}: {out / fname} ({(out / fname).stat().st_size / 1e6:.2f} MB)", file=sys.stderr)
    print(out, flush=True)
    return out


if __name__ == "__main__":
    main()
