"""Export the networks of the IML/S + RecNN renderer to TorchScript or ONNX, and render with them.

``python -m imls_lightning.export ims_checkpoint=ims.ckpt format=torchscript|onnx out=DIR
[recnn_checkpoint=recnn.ckpt] [overwrite=true] [mean=null]``

An IMS checkpoint carries every network the product runs (see :mod:`imls_lightning.tasks.ims`);
the export writes the three that run per view, each on its own so that a deployment can time and
place them like :class:`~imls_lightning.inference.pipeline.IMLSRenderer` does:

================  ===========================================  ===============================
file              input -> output                               what
================  ===========================================  ===============================
``im.*``          view ``(1, 9)`` float32 -> ``(1, 1, n, n)``   IMS generator + thresholding
                  bool                                          (``IMSTask.output_to_im_at``): the IM
``decoder.*``     ``[PR-C-Image, IM]`` ``(1, 4, n, n)`` ->      the IML decoder
                  ``(1, 3, n, n)`` float32
``recnn.*``       C-Image ``(1, 3, n, n)`` -> ``(1, 3, m, m)``  the RecNN (not clamped)
================  ===========================================  ===============================

plus ``export.json`` (format, sizes, pattern, provenance) and ``pattern_indices.npy`` (the ``(K,)``
FR raster indices of the sampling pattern: the loader needs no pattern code that could drift).
``.pt`` files are ``torch.jit.trace`` modules (``torch.jit.load``, also from C++ libtorch); ``.onnx``
files need the optional package ``onnx`` to write and ``onnxruntime`` to run (``pip install
imls-lightning[export]``; opset 17, written by torch's TorchScript-based exporter). The directory is written under a temporary name and
renamed when complete.

The IM is made at the operating point the evaluation recorded beside the IMS checkpoint
(``<ims.ckpt>.orp.json``: its mean value, the masks lifted if it lifted them), else at the trained
mean; ``mean=`` (a number, or ``trained``) overrides it. ``export.json`` carries the mean value
(``mean``, ``lift``) and the record (``operating_point``).

The selective ray cast between the networks is not a network: :class:`ExportedIMLSRenderer` takes
the scene's renderer for it, exactly as :class:`~imls_lightning.inference.pipeline.IMLSRenderer` (whose
``render(view) -> (image, timings)`` it inherits), so an exported renderer gives the same images.

Example:
    >>> out = export_renderer("ims.ckpt", "exported/", format="torchscript")        # doctest: +SKIP
    >>> r = ExportedIMLSRenderer.load(out, scene=scene, renderer_cfg={"name": "numba"})  # doctest: +SKIP
    >>> image, timings = r.render([0, 0, 3.5, 0, 0, 0, 0, 1, 0])                     # doctest: +SKIP
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from data_gen.errors import InputError, cli_errors

from .core.patterns import SamplingPattern
from .inference.checkpoints import load_ims_and_recnn, require_recnn, task_path
from .inference.pipeline import IMLSRenderer, NetOptions

__all__ = ["FORMATS", "IMPredictor", "ExportedIMLSRenderer", "export_renderer", "onnx_available", "main"]

FORMATS = ("torchscript", "onnx")
EXPORT_VERSION = 1
META = "export.json"
INDICES = "pattern_indices.npy"
PARTS = ("im", "decoder", "recnn")
_SUFFIX = {"torchscript": ".pt", "onnx": ".onnx"}
ONNX_OPSET = 17


def onnx_available() -> bool:
    """Whether the ``onnx`` package is importable (ONNX exports are offered only then)."""
    try:
        import onnx  # noqa: F401
    except ImportError:
        return False
    return True


def _onnxruntime():
    try:
        import onnxruntime
    except ImportError:
        raise InputError("format=onnx: running an ONNX export needs onnxruntime (pip install imls-lightning[export])") from None
    return onnxruntime


class IMPredictor(nn.Module):
    """IMS generator + thresholding: view ``(B, 9)`` float32 -> IM ``(B, 1, n, n)`` bool.

    The same arithmetic as :meth:`IMSTask.output_to_im_at` applied to ``generator(view)``:
    ``target="im"``: ``g > 0``; ``target="pim"``: ``(g + 1) / 2 > P  or  g >= 1`` at the trained
    mean, PIM' rescaled to ``mean`` otherwise (:func:`~imls_lightning.tasks.ims.scaled_pim_im`, lifted
    to the share ``mean`` with ``lift``); False on the C-Image padding (``valid``). ``target``, the
    mean and the lift are fixed at construction, so tracing sees one branch.

    Args:
        generator: the :class:`~imls_lightning.models.ims.IMSGenerator` (eval mode).
        target: ``"im"`` or ``"pim"``.
        P: ``(n, n)`` plastic rank pattern (used by ``target="pim"``).
        valid: ``(n, n)`` bool, the pattern's C-Image pixels.
        mean: the mean value ``u`` to threshold at (``None``: the trained one; ``target="pim"`` only).
        trained_mean, lower: the IML's trained mean and normalization lower bound (with ``mean``).
        lift: lift the rescaled PIM' to the share ``u`` above the trained mean, as
            ``IMSTask.lift_to_mean`` does (with ``mean``).
    """

    def __init__(self, generator: nn.Module, target: str, P: torch.Tensor, valid: torch.Tensor,
                 mean: float | None = None, trained_mean: float | None = None, lower: float = 0.0, lift: bool = False):
        super().__init__()
        if target not in ("im", "pim"):
            raise InputError(f"model.target={target!r}: expected 'im' or 'pim'")
        if mean is not None and (target != "pim" or trained_mean is None):
            raise InputError(f"mean={mean}: rescaling the IMS's mask needs model.target=pim and the trained mean")
        self.generator = generator
        self.target = target
        n = valid.shape[-1]
        self.register_buffer("P", P.detach().float().reshape(1, 1, n, n).clone())
        self.register_buffer("valid", valid.detach().bool().reshape(1, 1, n, n).clone())
        self.mean, self.lower = (None if mean is None else float(mean)), float(lower)
        if self.mean is not None:
            # the scale of scaled_pim_im, in its float32 arithmetic (the same IM bit for bit)
            scale = (torch.tensor([self.mean], dtype=torch.float32) - self.lower) / torch.tensor(float(trained_mean) - self.lower,
                                                                                                  dtype=torch.float32)
            self.register_buffer("scale", scale.reshape(1, 1, 1, 1))
            self.saturates = bool(scale >= 1.0)
            self.lift = bool(lift) and bool(scale > 1.0)  # below the trained mean nothing is lifted
            self.register_buffer("valid_index", torch.nonzero(self.valid.flatten()).flatten())
            self.mean32 = float(torch.tensor(self.mean, dtype=torch.float32))  # u as scaled_pim_im lifts to it

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        g = self.generator(view).float()
        if self.target == "im":
            im = g > 0
        elif self.mean is None:
            im = ((g + 1.0) * 0.5 > self.P) | (g >= 1.0)
        else:
            pim = (g + 1.0) * 0.5
            pim_u = pim * self.scale if self.lower == 0.0 else (pim - self.lower) * self.scale + self.lower
            saturated = (g >= 1.0) if self.saturates else torch.zeros_like(g, dtype=torch.bool)
            im = (pim_u > self.P) | saturated
            if self.lift:
                im = im | self._lifted(torch.where(saturated, pim_u.clamp_min(1.0), pim_u))
        return im & self.valid

    def _lifted(self, x: torch.Tensor) -> torch.Tensor:
        """:func:`~imls_lightning.core.importance.lift_to_share` and :func:`lifted_mask` at the share
        ``mean``, in tensor operations only (traceable): per view the smallest multiplier ``m >= 1``
        with ``mean(min(m x, 1)) = u`` over the pattern's pixels, or every pixel with importance and a
        blue-noise floor ``f`` on the rest."""
        vals = x.flatten(1).index_select(1, self.valid_index).double().clamp_min(0.0)  # (B, K)
        k = vals.shape[1]
        target = self.mean32 * k
        reached = vals.clamp(max=1.0).sum(1) >= target          # the rescale reaches u by itself
        npos = (vals > 0).sum(1)
        take_all = (npos.double() <= target) & ~reached          # every pixel with importance, then the floor
        floor = ((target - npos.double()) / (k - npos).clamp_min(1).double()).clamp(0.0, 1.0)
        xs = vals.sort(1, descending=True).values                # zeros last: they add nothing below
        rest = xs.flip(1).cumsum(1).flip(1)                      # rest[j] = sum of xs[j:]
        ranks = torch.arange(k, dtype=torch.float64, device=x.device)
        at_saturation = torch.where(xs > 0, ranks + rest / xs, torch.full_like(xs, float("inf")))
        j = torch.minimum((at_saturation < target).sum(1), (npos - 1).clamp_min(0))
        mult = ((target - j.double()) / rest.gather(1, j[:, None])[:, 0]).clamp_min(1.0)
        mult = torch.where(reached | take_all, torch.ones_like(mult), mult).float().view(-1, 1, 1, 1)
        f = torch.where(take_all, floor, torch.zeros_like(floor)).float().view(-1, 1, 1, 1)
        scaled = torch.where(take_all.view(-1, 1, 1, 1), (x > 0).to(x.dtype), x * mult)
        return (scaled > self.P) | (scaled >= 1.0) | (f > self.P) | (f >= 1.0)


class PackedDecoder(nn.Module):
    """The IML decoder with one input, for export: ``[PR-C-Image, IM]`` ``(B, 4, n, n)`` -> ``(B, 3, n, n)``."""

    def __init__(self, decoder: nn.Module):
        super().__init__()
        self.decoder = decoder

    def forward(self, packed: torch.Tensor) -> torch.Tensor:
        return self.decoder(packed[:, :3], packed[:, 3:4])


class UnpackedDecoder(nn.Module):
    """An exported :class:`PackedDecoder` behind the decoder's call ``(pr_c_image, im) -> C-Image``."""

    def __init__(self, packed: nn.Module):
        super().__init__()
        self.packed = packed

    def forward(self, pr_c_image: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
        return self.packed(torch.cat([pr_c_image, im.to(pr_c_image.dtype)], 1))


class _OnnxModule(nn.Module):
    """An ONNX Runtime session behind the ``nn.Module`` call interface (CPU tensors in and out;
    the result is moved to the input's device)."""

    def __init__(self, path: Path, providers: Sequence[str] | None = None):
        super().__init__()
        ort = _onnxruntime()
        so = ort.SessionOptions()
        so.log_severity_level = 3
        # no busy-waiting between runs: ORT's spinning intra-op threads took the cores from the ray caster
        # that runs between the networks (ct_head 512^2: its selective render 30 -> 54 ms)
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self.path = str(path)
        self.session = ort.InferenceSession(self.path, so, providers=list(providers or ["CPUExecutionProvider"]))
        self.input_name = self.session.get_inputs()[0].name

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.session.run(None, {self.input_name: x.detach().cpu().contiguous().numpy()})[0]
        return torch.from_numpy(np.ascontiguousarray(out)).to(x.device)

    def extra_repr(self) -> str:
        return self.path


# ---------------------------------------------------------------------------------------------
# export
# ---------------------------------------------------------------------------------------------
def _parts_from_task(task, recnn: nn.Module | None, mean: float | None = None) -> dict[str, nn.Module]:
    """The three exported modules; ``im`` thresholds at ``mean`` (``None``: the trained mean), lifted
    as ``task.lift_to_mean`` says."""
    recnn = require_recnn(task.recnn if recnn is None else recnn, key="ims_checkpoint", path=task_path(task))
    task.eval()
    rescale = {} if mean is None else {"mean": mean, "trained_mean": float(task.iml.mean),
                                       "lower": float(task.iml.normalization.lower), "lift": bool(task.lift_to_mean)}
    im = IMPredictor(task.generator, task.target, task.P, task.pattern.valid, **rescale).eval()
    return {"im": im, "decoder": PackedDecoder(task.decoder).eval(), "recnn": recnn.eval()}


def _example_inputs(pattern: SamplingPattern) -> dict[str, torch.Tensor]:
    n = pattern.c_size
    g = torch.Generator().manual_seed(0)
    view = torch.tensor([[0.0, 0.0, 3.5, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    packed = torch.rand(1, 4, n, n, generator=g)
    packed[:, 3] = (packed[:, 3] > 0.5).float()  # a 0/1 mask channel
    return {"im": view, "decoder": packed, "recnn": torch.rand(1, 3, n, n, generator=g)}


def _export_torchscript(module: nn.Module, example: torch.Tensor, path: Path) -> None:
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore", torch.jit.TracerWarning)  # shape checks in forward are constants at a fixed size
        traced = torch.jit.trace(module, (example,), check_trace=False)
    torch.jit.save(traced, str(path))


def _export_onnx(module: nn.Module, example: torch.Tensor, path: Path, name: str) -> None:
    """The TorchScript-based exporter (``dynamo=False``): it exports what ``torch.jit.trace``
    records, so the networks' data-dependent input checks (e.g. ``int(indices[-1])`` in
    :func:`~imls_lightning.core.compaction.decompact`) become constants at the fixed export size. The
    ``torch.export`` route (``dynamo=True``) refuses them (GuardOnDataDependentSymNode)."""
    import onnx

    try:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module, (example,), str(path), dynamo=False, opset_version=ONNX_OPSET,
                              input_names=[f"{name}_in"], output_names=[f"{name}_out"], do_constant_folding=True)
        onnx.checker.check_model(onnx.load(str(path)))
    except Exception as err:  # an operator the exporter cannot translate: say which network
        first = str(err).splitlines()[0] if str(err) else ""
        raise RuntimeError(f"ONNX export of the {name} network failed: {type(err).__name__}: {first}") from err


def _sha256(path: Path, length: int = 16) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:length]


def export_renderer(ims_checkpoint: str | os.PathLike, out: str | os.PathLike, format: str = "torchscript",
                    recnn_checkpoint: str | os.PathLike | None = None, overwrite: bool = False,
                    mean: float | str | None = None) -> Path:
    """Export the per-view networks of an IMS checkpoint (see the module doc); returns ``out``.

    The ``im`` network thresholds at the operating point the evaluation recorded for the checkpoint
    (``<ims.ckpt>.orp.json``; :mod:`imls_lightning.inference.operating_point`), else at the trained
    mean (one line on stderr says which); ``export.json`` carries the record (``operating_point``)
    and the mean value exported (``mean``, ``lift``).

    Args:
        ims_checkpoint: a ``.ckpt`` of ``model=ims`` (it carries the IML decoder and the RecNN).
        out: the directory to create (must not exist unless ``overwrite``).
        format: ``"torchscript"`` or ``"onnx"`` (needs the ``onnx`` package).
        recnn_checkpoint: a RecNN checkpoint to use instead of the one in the IMS checkpoint
            (needed when the IML was standalone and no RecNN was stored).
        overwrite: replace an existing export directory.
        mean: ``None``: the recorded operating point, else the trained mean; a number in
            ``[0.01, 1]`` or ``"trained"``: that mean value (nothing is read).

    Raises:
        InputError: a bad format, a missing/wrong checkpoint, ``out`` exists, ONNX not installed.
    """
    fmt = str(format).lower()
    if fmt not in FORMATS:
        raise InputError(f"format={format}: expected one of {', '.join(FORMATS)}")
    if fmt == "onnx" and not onnx_available():
        raise InputError("format=onnx: needs the onnx package (pip install imls-lightning[export])")
    out = Path(out).expanduser()
    if out.exists() and not overwrite:
        raise InputError(f"out={out}: already exists; choose a new directory or pass overwrite=true")
    if out.exists() and not (out / META).is_file():
        raise InputError(f"out={out}: exists and is not an export directory (no {META}); refusing to replace it")
    if not out.parent.is_dir():
        raise InputError(f"out={out}: directory {out.parent} does not exist")

    from dataclasses import asdict

    from .inference.operating_point import mean_to_run

    task, recnn = load_ims_and_recnn(ims_checkpoint, recnn_checkpoint)
    u, point = mean_to_run(task, ims_checkpoint, mean)
    if u is not None and task.target != "pim":
        raise InputError(f"mean={mean}: the IMS was trained with model.target={task.target}; only its trained mean can be exported")
    parts = _parts_from_task(task, recnn, u)
    pattern = task.pattern
    examples = _example_inputs(pattern)

    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        files = {}
        for name in PARTS:
            fname = name + _SUFFIX[fmt]
            if fmt == "torchscript":
                _export_torchscript(parts[name], examples[name], tmp / fname)
            else:
                _export_onnx(parts[name], examples[name], tmp / fname, name)
            files[name] = fname
        idx = pattern.indices.numpy().astype(np.int64)
        np.save(tmp / INDICES, idx, allow_pickle=False)
        meta = {
            "export_version": EXPORT_VERSION,
            "format": fmt,
            "files": files,
            "fr_size": int(pattern.fr_size),
            "c_size": int(pattern.c_size),
            "pattern": {"kind": pattern.kind, "params": pattern.param_dict, "count": pattern.count,
                        "fingerprint": pattern.fingerprint(), "indices": INDICES,
                        "indices_sha256": hashlib.sha256(idx.tobytes()).hexdigest()},
            "target": task.target,
            # the mean value the im network thresholds at, and the evaluation's record it came from (null: none)
            "mean": float(task.iml.mean) if u is None else u,
            "trained_mean": float(task.iml.mean),
            "lift": u is not None and bool(task.lift_to_mean),
            "operating_point": None if point is None else asdict(point),
            "inputs": {"im": [1, 9], "decoder": [1, 4, pattern.c_size, pattern.c_size], "recnn": [1, 3, pattern.c_size, pattern.c_size]},
            "ims_checkpoint": str(Path(ims_checkpoint).expanduser().resolve()),
            "ims_checkpoint_sha256": _sha256(Path(ims_checkpoint).expanduser()),
            "recnn_checkpoint": None if not recnn_checkpoint else str(Path(recnn_checkpoint).expanduser().resolve()),
            "recnn_source": "recnn_checkpoint" if recnn_checkpoint else task.hparams.get("recnn_source"),
            "torch_version": torch.__version__,
            "onnx_opset": ONNX_OPSET if fmt == "onnx" else None,
        }
        with open(tmp / META, "w") as f:
            json.dump(meta, f, indent=1, default=str)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        old = None
        if out.exists():  # overwrite: move the old one aside first, so `out` is never half-made
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


# ---------------------------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------------------------
def read_export(path: str | os.PathLike) -> tuple[dict[str, Any], SamplingPattern]:
    """``(export.json as a dict, the SamplingPattern)`` of an export directory (checked)."""
    p = Path(path).expanduser()
    if not (p / META).is_file():
        raise InputError(f"exported={p}: not an export directory (no {META}); make one with python -m imls_lightning.export")
    try:
        meta = json.loads((p / META).read_text())
        idx = np.load(p / meta["pattern"]["indices"], allow_pickle=False)
    except (OSError, ValueError, KeyError) as err:
        raise InputError(f"exported={p}: unreadable ({type(err).__name__}: {err})") from None
    if meta.get("export_version") != EXPORT_VERSION or meta.get("format") not in FORMATS:
        raise InputError(f"exported={p}: export version {meta.get('export_version')} / format {meta.get('format')} not understood")
    if hashlib.sha256(np.ascontiguousarray(idx, np.int64).tobytes()).hexdigest() != meta["pattern"]["indices_sha256"]:
        raise InputError(f"exported={p}: {meta['pattern']['indices']} does not match {META}")
    params = tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in meta["pattern"]["params"].items())
    pattern = SamplingPattern(meta["pattern"]["kind"], int(meta["fr_size"]), int(meta["c_size"]),
                              torch.from_numpy(np.asarray(idx, np.int64)), params)
    return meta, pattern


class ExportedIMLSRenderer(IMLSRenderer):
    """:class:`~imls_lightning.inference.pipeline.IMLSRenderer` running exported networks.

    Same stages, timings and ``render(view) -> ((m, m, 3) uint8, {stage: seconds})``; the IM, the
    decoder and the RecNN are the TorchScript modules or ONNX Runtime sessions of an export
    directory, the selective ray cast is the scene's renderer. Build it with :meth:`load`.
    """

    name = "imls_exported"

    @classmethod
    def load(cls, path: str | os.PathLike, *, scene=None, renderer=None, renderer_cfg=None,
             device: str = "auto") -> "ExportedIMLSRenderer":
        """Load an export directory.

        Args:
            path: what :func:`export_renderer` wrote.
            scene / renderer / renderer_cfg: a built renderer, or a scene (+ renderer config).
            device: ``auto`` | ``cpu`` | ``cuda`` (TorchScript modules move there; ONNX sessions
                use the CUDA execution provider when the device is CUDA and it is installed).
        """
        from .inference.pipeline import pick_device

        p = Path(path).expanduser()
        meta, pattern = read_export(p)
        dev = pick_device(device)
        files = {k: p / v for k, v in meta["files"].items()}
        missing = [str(f) for f in files.values() if not f.is_file()]
        if missing:
            raise InputError(f"exported={p}: missing {missing[0]}")
        if meta["format"] == "torchscript":
            mods = {k: torch.jit.load(str(f), map_location=dev).eval() for k, f in files.items()}
        else:
            providers = ["CPUExecutionProvider"]
            if dev.type == "cuda":
                providers.insert(0, "CUDAExecutionProvider")
            mods = {k: _OnnxModule(f, providers) for k, f in files.items()}
        if renderer is None:
            if scene is None:
                raise InputError("ExportedIMLSRenderer.load needs a renderer or a scene")
            from data_gen.renderers import make_renderer

            renderer = make_renderer(scene, renderer_cfg)
        r = cls(renderer, pattern, mods["im"], UnpackedDecoder(mods["decoder"]), mods["recnn"], NetOptions(device=str(dev)))
        r.meta = meta
        r.export_path = p
        r.mean = meta.get("mean")  # the mean value its im network thresholds at (None: an export made before it was recorded)
        r.operating_point = meta.get("operating_point")  # the evaluation's record it came from (dict), or None
        return r


# ---------------------------------------------------------------------------------------------
# command line
# ---------------------------------------------------------------------------------------------
_KEYS = {"ims_checkpoint": None, "format": "torchscript", "out": None, "recnn_checkpoint": None, "overwrite": "false",
         "mean": None}


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
    for key in ("recnn_checkpoint", "mean"):
        if args[key] in ("", "null", "None"):
            args[key] = None
    return args


@cli_errors
def main(argv: Sequence[str] | None = None) -> Path:
    """Export, print a summary line per file on stderr and the export directory as the last stdout line."""
    args = parse_args(sys.argv[1:] if argv is None else argv)
    out = export_renderer(args["ims_checkpoint"], args["out"], args["format"], args["recnn_checkpoint"], args["overwrite"],
                          mean=args["mean"])
    meta = json.loads((out / META).read_text())
    print(f"[export] im thresholds at u = {meta['mean']:.3f}" + (" (masks lifted)" if meta["lift"] else "")
          + (" (the evaluation's operating point)" if meta["operating_point"] else ""), file=sys.stderr)
    for name, fname in meta["files"].items():
        print(f"[export] {name}: {out / fname} ({(out / fname).stat().st_size / 1e6:.2f} MB)", file=sys.stderr)
    print(out, flush=True)
    return out


if __name__ == "__main__":
    main()
