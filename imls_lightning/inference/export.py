"""Export the networks of the IML/S + RecNN renderer to TorchScript or ONNX, and render with them.

The command line is ``python -m imls_lightning.export ims_checkpoint=ims.ckpt format=torchscript|onnx
out=DIR [recnn_checkpoint=recnn.ckpt] [overwrite=true] [mean=null]`` (:mod:`imls_lightning.export`,
which parses its arguments and calls :func:`export_renderer`).

An IMS checkpoint carries every network the product runs (see :mod:`imls_lightning.tasks.ims`);
the export writes the three that run per view, each on its own so that a deployment can time and
place them like :class:`~imls_lightning.inference.pipeline.IMLSRenderer` does:

================  ===========================================  ===============================
file              input -> output                               what
================  ===========================================  ===============================
``im.*``          view ``(1, 9)`` float32 -> ``(1, 1, n, n)``   IMS generator + thresholding
                  bool                                          (``IMSMaskHead`` at the mean): the IM
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
mean; ``mean=`` (a number, or ``trained``) overrides it. A point recorded by camera distance
(``orp_by_distance``) is exported as it runs: the ``im`` network picks each view's band's mean value.
``export.json`` carries the mean value (``mean``, ``lift``), the bands (``by_distance``) and the record
(``operating_point``).

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
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from imls_lightning.base.errors import InputError

from ..core.patterns import SamplingPattern
from ..core.operating_point import Bands, OperatingPoint
from ..models.iml import decoder_at
from ..models.ims import MaskAt
from .checkpoints import IMSNets, load_product, require_recnn
from .pipeline import IMLSRenderer, NetOptions

__all__ = ["FORMATS", "META", "IMPredictor", "ExportedIMLSRenderer", "export_renderer", "read_export", "onnx_available"]

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


class IMPredictor(MaskAt):
    """The exported ``im`` network: view ``(B, 9)`` float32 -> IM ``(B, 1, n, n)`` bool, an
    :class:`~imls_lightning.models.ims.IMSMaskHead` with its operating point bound
    (:class:`~imls_lightning.models.ims.MaskAt`), so tracing sees one branch. The thresholding is the
    head's own (its one home; :func:`~imls_lightning.core.importance.lift_to_share` is traceable), so
    the export makes the IMs :class:`~imls_lightning.inference.pipeline.IMLSRenderer` makes, bit for bit.

    Args:
        head: the :class:`~imls_lightning.models.ims.IMSMaskHead` (eval mode).
        point: the :class:`~imls_lightning.core.operating_point.OperatingPoint` to threshold at (``None``: the
            trained share); or a mean value ``u`` (``target="pim"`` only) or a
            :class:`~imls_lightning.models.ims.DistanceMeans` (each view at its band's) with ``lift``.
        lift: with a mean value, lift the rescaled PIM' to the share ``u`` above the trained mean.

    Example:
        >>> im = IMPredictor(nets.head, OperatingPoint(share=0.4)).eval()   # doctest: +SKIP
        >>> torch.jit.trace(im, (view,))                     # doctest: +SKIP
    """


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
def export_parts(nets: IMSNets, point: OperatingPoint | None = None) -> dict[str, nn.Module]:
    """The three exported modules of the product's networks; ``im`` thresholds at ``point`` (an
    :class:`~imls_lightning.core.operating_point.OperatingPoint`: its share or bands of camera distance, lift,
    sharpness and floor; ``None``: the trained share); ``decoder`` is the point's (the IMS's own, or the pull-push fill)."""
    recnn = require_recnn(nets.recnn, key="ims_checkpoint", path=nets.path)
    im = IMPredictor(nets.head.eval(), point).eval()
    decoder = decoder_at("trained" if point is None else point.decoder, nets.decoder, nets.pattern)
    return {"im": im, "decoder": PackedDecoder(decoder).eval(), "recnn": recnn.eval()}


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
                    mean: float | str | None = None, *, share: float | str | None = None) -> Path:
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
        share: ``None``: the recorded operating point, else the trained share; a number in
            ``[0.01, 1]`` or ``"trained"``: that share of the C-Image (nothing is read). ``mean``: the same (its
            older name).

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

    value, key = (share, "share") if share is not None else (mean, "mean")
    product = load_product(ims_checkpoint, recnn_checkpoint, share=value, share_key=key)
    nets, point, record = product.nets, product.point, product.record
    if point is not None and nets.target != "pim":
        raise InputError(f"{key}={value}: the IMS was trained with model.target={nets.target}; only its trained mean can be exported")
    u, lift, bands = product.mean, product.lift, None if point is None else point.bands
    parts = export_parts(nets, point)
    pattern = nets.pattern
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
            "target": nets.target,
            # the mean value the im network thresholds at, and the evaluation's record it came from (null: none)
            "mean": nets.trained_mean if u is None else u,
            "trained_mean": nets.trained_mean,
            "lift": lift,
            # the im network's masks, sharpened as the record's ORP was searched
            "sharpness": float(nets.head.sharpness if point is None else point.sharpness),
            # the im network's floor on each view's mean value (its object + margin), as the record's evaluation chose it
            # (its band's margin where the record chose one per band: by_distance's floor_margins)
            "object_floor": None if point is None or point.object_floor is None else dict(zip(("margin", "tau"), point.object_floor)),
            "floor_margins": None if bands is None or bands.floor_margins is None else list(bands.floor_margins),
            # what the decoder network is: the IMS's own, or the pull-push fill where the record's search kept it
            "decoder": "trained" if point is None else point.decoder,
            "by_distance": None if bands is None else record.by_distance,
            "operating_point": None if record is None else asdict(record),
            "inputs": {"im": [1, 9], "decoder": [1, 4, pattern.c_size, pattern.c_size], "recnn": [1, 3, pattern.c_size, pattern.c_size]},
            "ims_checkpoint": str(Path(ims_checkpoint).expanduser().resolve()),
            "ims_checkpoint_sha256": _sha256(Path(ims_checkpoint).expanduser()),
            "recnn_checkpoint": None if not recnn_checkpoint else str(Path(recnn_checkpoint).expanduser().resolve()),
            "recnn_source": "recnn_checkpoint" if recnn_checkpoint else nets.hparams.get("recnn_source"),
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

    @staticmethod
    def _point_decoder(decoder, pattern, point):
        """The exported decoder is already the point's (:func:`export_parts` exported the fill where the point keeps
        it): it runs as exported."""
        return decoder

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
        from .pipeline import pick_device

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
            from imls_lightning.render import make_renderer

            renderer = make_renderer(scene, renderer_cfg)
        # the point its im network thresholds at (None: an export made before it was recorded), and the evaluation's
        # record it came from (a dict), both given at construction
        r = cls(renderer, pattern, mods["im"], UnpackedDecoder(mods["decoder"]), mods["recnn"], NetOptions(device=str(dev)),
                point=exported_point(meta), record=meta.get("operating_point"))
        r.meta = meta
        r.export_path = p
        return r


def exported_point(meta: dict) -> OperatingPoint | None:
    """The :class:`~imls_lightning.core.operating_point.OperatingPoint` an export's ``im`` network thresholds at, from
    its ``export.json`` (``None``: an export made before the mean value was recorded)."""
    if meta.get("mean") is None:
        return None
    bands = meta.get("by_distance")
    floor = meta.get("object_floor")
    return OperatingPoint(share=meta["mean"], lift=bool(meta.get("lift", False)),
                          bands=None if not bands else Bands(bands["edges"], bands["means"], meta.get("floor_margins")),
                          sharpness=float(meta.get("sharpness", 1.0)),
                          object_floor=None if not floor else (floor["margin"], floor["tau"]),
                          decoder=str(meta.get("decoder", "trained")))
