"""The viewer command's body (:func:`viewer`): check the settings before anything slow, build the
renderer from the checkpoint(s), then write a screenshot or open the window (see :mod:`imls_lightning.viewer`)."""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError, boolean, finite_number

from ..inference.camera import orbit_view
from ..inference.operating_point import share_setting
from ..inference.pipeline import IMLSRenderer, NetOptions
from .window import Viewer

__all__ = ["check_writable", "viewer"]


def _interactive_backend_error() -> str | None:
    """Why no window can be opened here (one line), or ``None``."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY is not set)"
    import matplotlib

    backend = matplotlib.get_backend().lower()
    try:
        from matplotlib.backends import BackendFilter, backend_registry

        non_interactive = set(backend_registry.list_builtin(BackendFilter.NON_INTERACTIVE))
    except ImportError:  # matplotlib < 3.9
        non_interactive = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"}
    if backend in non_interactive:
        return f"matplotlib's backend is {backend!r}, which opens no window"
    return None


def check_writable(path, key: str) -> None:
    """A file can be written at ``path`` (its folder exists and takes a new file, or can be made):
    checked with a real probe file, removed at once. One-line :class:`InputError` naming ``key``."""
    out = Path(str(path)).expanduser()
    if out.is_dir():
        raise InputError(f"{key}={path}: is a directory, expected a .png file path")
    parent = out.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent  # the folders missing on the way are made when the file is written
    if not parent.is_dir():
        raise InputError(f"{key}={path}: {parent} is not a directory")
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=parent)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise InputError(f"{key}={path}: cannot write into {parent} ({err.strerror or type(err).__name__})") from None


def viewer(cfg: DictConfig) -> Path | None:
    """The CLI's body: build the renderer from the checkpoint(s), then a screenshot or the window.

    Returns the screenshot's path (``None`` after an interactive session).
    """
    if OmegaConf.is_missing(cfg, "ims_checkpoint") or not cfg.get("ims_checkpoint"):
        raise InputError("ims_checkpoint: required (usage: python -m imls_lightning.viewer ims_checkpoint=<IMS .ckpt> "
                         "[recnn_checkpoint=<RecNN .ckpt>] [screenshot=out.png])")
    screenshot = cfg.get("screenshot") or None
    if screenshot is not None:
        if Path(str(screenshot)).suffix.lower() != ".png":
            raise InputError(f"screenshot={screenshot}: expected a .png path")
        check_writable(screenshot, "screenshot")  # before any work, not after it
    for key in ("azimuth", "elevation"):
        finite_number(cfg.get(key), key, "a finite number")
    orbit_view(cfg.azimuth, cfg.elevation, 1.0)  # elevation range, before anything slow
    show_mask = boolean(cfg.get("mask", True), "mask")
    if cfg.get("distance") is not None:
        finite_number(cfg.distance, "distance", "a finite number")  # its range needs the scene: checked by the Viewer
    threads = cfg.get("threads")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise InputError(f"threads={threads}: expected an integer >= 1 (torch CPU threads) or null")
    import matplotlib

    if screenshot is None:
        why = _interactive_backend_error()
        if why is not None:
            raise InputError(f"{why}: pass screenshot=out.png to render the viewer headless into a PNG")
    else:
        matplotlib.use("Agg")
    if threads is not None:
        torch.set_num_threads(threads)
    opts = NetOptions(**OmegaConf.to_container(cfg.options, resolve=True)) if cfg.get("options") else NetOptions()
    t0 = time.perf_counter()
    value, key = share_setting(cfg)  # share (mean: its older name)
    renderer = IMLSRenderer.from_checkpoints(str(cfg.ims_checkpoint), recnn_checkpoint=cfg.get("recnn_checkpoint") or None,
                                             opts=opts, **{key: value})
    print(f"[viewer] renderer ready in {time.perf_counter() - t0:.1f} s (scene FR {renderer.fr_size}^2, "
          f"networks on {renderer.device}, share of C u = {float(renderer.mean):.3f}"
          + (", per band of camera distance" if renderer.by_distance is not None else "") + ")", file=sys.stderr, flush=True)
    try:
        v = Viewer(renderer, azimuth=cfg.azimuth, elevation=cfg.elevation, distance=cfg.get("distance"),
                   show_mask=show_mask, interactive=screenshot is None, figsize=tuple(cfg.figsize), dpi=cfg.dpi,
                   warmup=cfg.warmup)
    except InputError:
        raise
    except Exception as err:  # a GUI toolkit that cannot start (e.g. Tk without a usable display)
        if screenshot is None and type(err).__name__ in ("TclError", "RuntimeError", "ImportError"):
            raise InputError(f"cannot open a window ({type(err).__name__}: {err}): pass screenshot=out.png to render headless") from None
        raise
    if screenshot is not None:
        out = v.save_screenshot(screenshot)
        t = v.imls.timings
        print(f"[viewer] IML/S total {1e3 * t['total']:.1f} ms, ray cast {1e3 * v.truth.timings['total']:.1f} ms, "
              f"IPR {v.imls.info['ipr']:.3f}, PSNR {v.psnr:.2f} dB", file=sys.stderr, flush=True)
        return out
    v.show()
    return None
