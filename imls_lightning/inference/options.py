"""How the networks run: the device (:func:`pick_device`), the inference options (:class:`NetOptions`: reduced precision,
channels-last, torch.compile, each measured rather than assumed: :func:`half_is_faster`, :func:`compile_available`)
and a network prepared for them (:func:`prepare_net`). Every inference method takes its options from here
(:mod:`~imls_lightning.inference.pipeline`); nothing here renders.

Example:
    >>> NetOptions.from_config({"half": True}, device="cpu")
    NetOptions(device='cpu', half=True, channels_last=False, compile=False)
"""
from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import time
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
import torch

from imls_lightning.base.errors import InputError

__all__ = ["pick_device", "half_is_faster", "compile_available", "NetOptions", "prepare_net"]


def pick_device(device: str | torch.device = "auto") -> torch.device:
    """``"auto"``: CUDA when present, else the CPU."""
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    d = torch.device(device)
    if d.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"device={device}: CUDA is not available on this machine")
    return d


_HALF_IS_FASTER: dict[str, bool] = {}


def half_is_faster(device: torch.device) -> bool:
    """Whether reduced-precision autocast (bfloat16 on the CPU, float16 on CUDA) beats float32 here.

    Measured once per process and device on a small convolution stack (32 channels at 128², the width and size of
    this project's decoders), the two precisions interleaved run by run over 9 rounds after a warm-up of each, by
    their medians: a load that comes and goes slows both alike. A CPU with AVX-512 BF16 or AMX runs bfloat16 about
    1.5-2x faster; an AVX2-only CPU emulates it, 40-90x slower (measured on this project's machines):
    ``options.half: auto`` asks this instead of assuming. (Timed back to back on a 16-channel 96² stack, the answer
    flipped between runs on the AMX machine: an evaluation ran float32 where its estimate had run bfloat16.)
    """
    key = str(device)
    if key not in _HALF_IS_FASTER:
        net = torch.nn.Sequential(*[torch.nn.Conv2d(32, 32, 3, padding=1) for _ in range(3)]).to(device).eval()
        x = torch.rand(1, 32, 128, 128, device=device)
        opts = NetOptions(device=key, half=True)

        def once(half: bool) -> float:
            with torch.inference_mode():
                t0 = time.perf_counter()
                with opts.autocast(device) if half else contextlib.nullcontext():
                    net(x)
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                return time.perf_counter() - t0

        once(True), once(False)  # warm-up: the first call of each precision builds its kernels
        times: dict[bool, list[float]] = {True: [], False: []}
        for _ in range(9):
            for half in (True, False):
                times[half].append(once(half))
        _HALF_IS_FASTER[key] = float(np.median(times[True])) < float(np.median(times[False]))
    return _HALF_IS_FASTER[key]


def compile_available(device: torch.device) -> str | None:
    """``None`` where ``torch.compile`` can build kernels for ``device``, else why not, in a few words: on CUDA it
    needs Triton, on the CPU a C++ compiler (``$CXX``, else ``g++``, ``c++`` or ``clang++`` on the PATH).

    Example:
        >>> compile_available(torch.device("cpu")) in (None, "no C++ compiler ($CXX, g++, c++ or clang++) on the PATH")
        True
    """
    if device.type == "cuda":
        return None if importlib.util.find_spec("triton") is not None else "Triton is not installed"
    names = [os.environ["CXX"]] if os.environ.get("CXX") else ["g++", "c++", "clang++"]
    return None if any(shutil.which(n) for n in names) else "no C++ compiler ($CXX, g++, c++ or clang++) on the PATH"


@dataclass
class NetOptions:
    """Inference options, each measured rather than assumed (see ``evaluate.options``)."""

    device: str = "auto"
    half: bool = False            # float16 on CUDA, bfloat16 on the CPU (autocast); from_config also takes "auto"
    channels_last: bool = False
    compile: bool = False         # torch.compile each network (first call pays the compile); from_config takes "auto"

    #: the switches (besides ``device``), as in the ``options`` node of evaluate / adaptive
    SWITCHES = ("half", "channels_last", "compile")

    @classmethod
    def from_config(cls, options: Mapping[str, Any] | None, device: str | None = None, key: str = "options") -> "NetOptions":
        """Validated options from a config node ``{device?, half?, channels_last?, compile?}`` (``half`` and
        ``compile`` also take ``"auto"``: bfloat16 where it is faster here, :func:`half_is_faster`; torch.compile where it
        can build kernels, :func:`compile_available`);
        ``device`` (when given) is used instead of the node's. A bad key or value raises a one-line
        :class:`InputError` naming ``<key>.<name>``; a missing CUDA device fails here, not mid-run.

        Example:
            >>> NetOptions.from_config({"half": True}, device="cpu")
            NetOptions(device='cpu', half=True, channels_last=False, compile=False)
        """
        opt = dict(options or {})
        unknown = set(opt) - {"device", *cls.SWITCHES}
        if unknown:
            raise InputError(f"{key}.{sorted(unknown)[0]}: unknown option; expected device, {', '.join(cls.SWITCHES)}")
        dev = lambda: pick_device(str(device if device is not None else opt.get("device", "auto")))  # noqa: E731
        if opt.get("half") == "auto":
            opt["half"] = half_is_faster(dev())
        if opt.get("compile") in ("auto", True):
            why_not = compile_available(dev())
            if why_not and opt["compile"] is True:
                raise InputError(f"{key}.compile=true: torch.compile cannot run here ({why_not}); "
                                 "set compile=auto (compile where it can) or false")
            opt["compile"] = why_not is None
        for k in cls.SWITCHES:
            if not isinstance(opt.get(k, False), bool):
                raise InputError(f"{key}.{k}={opt.get(k)}: expected true or false" + (" or auto" if k in ("half", "compile") else ""))
        out = cls(device=str(device if device is not None else opt.get("device", "auto")),
                  **{k: bool(opt.get(k, False)) for k in cls.SWITCHES})
        pick_device(out.device)
        return out

    def autocast(self, device: torch.device):
        if not self.half:
            return contextlib.nullcontext()
        dtype = torch.float16 if device.type == "cuda" else torch.bfloat16
        return torch.autocast(device.type, dtype=dtype)


def prepare_net(net: torch.nn.Module | None, device: torch.device, opts: NetOptions):
    """``net`` on ``device`` in eval mode, channels-last and/or compiled as ``opts`` asks (``None`` stays ``None``)."""
    if net is None:
        return None
    net = net.to(device).eval()
    if opts.channels_last:
        net = net.to(memory_format=torch.channels_last)
    if opts.compile:
        net = torch.compile(net)
    return net
