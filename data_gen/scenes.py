"""Scenes built from the ``scene`` config node: :func:`build_scene` (the volume loaded by
:func:`data_gen.volumes.load_volume`, the transfer function from points or derived from the volume's histogram,
:func:`auto_transfer_function`), the scene presets composed as ``python -m data_gen`` does
(:func:`preset_config`) and the config resolvers of the presets (:func:`register_resolvers`).

The scene itself (:class:`imls_lightning.render.scene.Scene`: what decides the pixels besides the view) is the ray
casters' input and lives with them; this module is how a user's config becomes one.
"""
from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_mapping
from imls_lightning.render.scene import Scene, Shading, TransferFunction, resolve_sample_distance
from imls_lightning.render.volume import Volume

REPO_DIR = Path(__file__).resolve().parents[1]


def default_volumes_dir() -> str:
    """Where the real volumes live: ``$IMLS_VOLUMES_DIR`` or ``<repo>/../shared/volumes``."""
    return os.environ.get("IMLS_VOLUMES_DIR") or str(REPO_DIR.parent / "shared" / "volumes")


def volume_name(name=None, path=None) -> str:
    """A scene name for a user's file: ``name`` if given, else the file name without extension and
    without the ``_XxYxZ_dtype`` suffix of the Open SciVis convention, else ``"file"``.

    Example:
        >>> volume_name(None, "/d/ct_head_256x256x108_int16.raw"), volume_name(None, "b.nii.gz")
        ('ct_head', 'b')
    """
    if name not in (None, "", "None", "null"):
        return str(name)
    if path in (None, "", "None", "null"):
        return "file"
    base = os.path.basename(str(path))
    for ext in (".nii.gz", ".raw", ".vti", ".nrrd", ".nhdr", ".mha", ".mhd", ".nii"):
        if base.lower().endswith(ext):
            base = base[: -len(ext)]
            break
    base = re.sub(r"_\d+x\d+x\d+_[A-Za-z0-9]+$", "", base)
    return base or "file"


def register_resolvers() -> None:
    """Register ``${imls_volumes_dir:}`` (real-volume presets) and ``${imls_volume_name:name,path}``
    (``scene=file``). Idempotent."""
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("imls_volumes_dir"):
        OmegaConf.register_new_resolver("imls_volumes_dir", default_volumes_dir)
    if not OmegaConf.has_resolver("imls_volume_name"):
        OmegaConf.register_new_resolver("imls_volume_name", volume_name)


def preset_config(name: str, overrides=(), context: str | None = None):
    """The ``conf/scene/<name>.yaml`` preset as ``python -m data_gen scene=<name>`` composes it: a preset may extend
    another through its defaults list (``flame_whole`` is ``flame_sheets`` framed from farther away), which a plain
    ``OmegaConf.load`` of the file would not follow.

    Example:
        >>> preset_config("flame_whole").camera_distance
        [5.6, 8.0]

    Raises:
        InputError: no such preset, or an override that does not apply to it (Hydra's message after ``context``,
            by default ``scene=<name> <overrides>``).
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException
    from hydra.initialize import get_gh_backup, restore_gh_from_backup
    from omegaconf.errors import OmegaConfBaseException

    conf = Path(__file__).resolve().parents[1] / "conf"
    if not (conf / "scene" / f"{name}.yaml").is_file():
        known = sorted(p.stem for p in (conf / "scene").glob("*.yaml"))
        raise InputError(f"scene={name!r}: no conf/scene/{name}.yaml; expected one of {', '.join(known)}")
    register_resolvers()
    backup = get_gh_backup()  # inside a running Hydra app: set its state aside, restore it after
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(conf), version_base="1.3", job_name="scene_preset"):
            return compose("data_gen", overrides=[f"scene={name}", *overrides]).scene
    except (HydraException, OmegaConfBaseException) as err:
        raise InputError(f"{context or f'scene={name} ' + ' '.join(overrides)}: {err}") from None
    finally:
        restore_gh_from_backup(backup)


def _plain(cfg) -> dict[str, Any]:
    """DictConfig or Mapping -> plain (resolved) dict."""
    register_resolvers()  # the volume-name interpolation resolves while the node is converted
    return check_mapping(cfg, "scene", "a mapping of scene settings")


def _restrict(points: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Express a piecewise-linear function given at raw scalar positions over [0, 1].

    ``points`` rows are ``(x_raw, values...)``. The function is cut to ``[lo, hi]`` (values there
    interpolated, constant beyond the end points, as the TF is) and ``x`` is mapped to [0, 1].
    """
    x = points[:, 0]
    inside = points[(x > lo) & (x < hi)]
    ends = np.stack([[lo] + [np.interp(lo, x, points[:, c]) for c in range(1, points.shape[1])],
                     [hi] + [np.interp(hi, x, points[:, c]) for c in range(1, points.shape[1])]])
    out = np.concatenate([ends[:1], inside, ends[1:]], axis=0)
    out[:, 0] = (out[:, 0] - lo) / (hi - lo)
    return out


def _tf_from_cfg(tcfg: Mapping[str, Any], volume: Volume) -> TransferFunction:
    if tcfg.get("auto", False):
        return auto_transfer_function(volume, colormap=tcfg.get("colormap") or "magma")
    units = tcfg.get("units", "normalized")
    for key in ("color", "opacity"):
        if tcfg.get(key) is None:
            raise InputError(f"scene.transfer_function.{key}: missing (give points, or set scene.transfer_function.auto=true)")
    color = np.asarray(tcfg["color"], dtype=np.float64)
    opacity = np.asarray(tcfg["opacity"], dtype=np.float64)
    if units == "raw":
        # positions in the volume's own units (e.g. Hounsfield for CT): robust to how the value
        # range was normalized (percentile clipping changes [0, 1] but not the tissue values)
        lo, hi = volume.value_range
        for key, a, w in (("color", color, 4), ("opacity", opacity, 2)):
            if a.ndim != 2 or a.shape[1] != w or len(a) < 2 or not np.all(np.isfinite(a)) or np.any(np.diff(a[:, 0]) < 0):
                raise InputError(f"scene.transfer_function.{key}: expected at least 2 rows of {w} finite numbers with ascending positions")
        color, opacity = _restrict(color, lo, hi), _restrict(opacity, lo, hi)
    elif units != "normalized":
        raise InputError(f"scene.transfer_function.units={units!r}: expected 'normalized' or 'raw'")
    tf = TransferFunction(color, opacity)
    if units == "raw" and float(tf.opacity[:, 1].max()) <= 0.0:
        raise InputError("scene.transfer_function.opacity: no opacity inside the volume's value range")
    return tf


def build_scene(cfg, volume: Volume | None = None) -> Scene:
    """Make a :class:`Scene` from the ``scene`` config node.

    Args:
        cfg: mapping (or DictConfig) with ``name``, ``volume`` (the node passed to
            :func:`data_gen.volumes.load_volume`), ``transfer_function`` (``auto: true`` for a
            histogram-derived one, or ``color``/``opacity`` points with ``units: normalized|raw``),
            ``shading``, ``sample_distance`` (``auto`` or normalized units),
            ``sample_distance_voxels`` (voxels; with ``sample_distance: auto``),
            ``opacity_unit_distance``, ``background``, ``camera_distance``, ``view_angle``.
        volume: an already loaded volume to use instead of loading ``cfg.volume``.

    Example:
        >>> s = build_scene({"name": "b", "transfer_function": {"auto": True}}, volume=v)  # doctest: +SKIP
    """
    c = _plain(cfg)
    if volume is None:
        if c.get("volume") is None:
            raise InputError("scene.volume: missing (give kind: file with a path, or kind: procedural)")
        from .volumes import load_volume

        volume = load_volume(c["volume"])
    tcfg = c.get("transfer_function") or {"auto": True}
    tf = _tf_from_cfg(tcfg, volume)
    sh = c.get("shading") or {}
    unknown = set(sh) - {"enabled", "ambient", "diffuse", "specular", "specular_power"}
    if unknown:
        raise InputError(f"scene.shading: unknown keys {sorted(unknown)}")
    kw = {k: c[k] for k in ("opacity_unit_distance", "background", "camera_distance", "view_angle") if c.get(k) is not None}
    kw["sample_distance"] = resolve_sample_distance(volume, c.get("sample_distance", "auto"), c.get("sample_distance_voxels"))
    for k in ("background", "camera_distance"):
        if k in kw:
            kw[k] = tuple(kw[k])
    return Scene(str(c.get("name") or volume.name), volume, tf, Shading(**sh), **kw, config=c)


# ---------------------------------------------------------------------------------------------
# Automatic transfer function
# ---------------------------------------------------------------------------------------------


def _colormap(name: str, x: np.ndarray) -> np.ndarray:
    """RGB of a matplotlib colormap at ``x`` in [0, 1] -> ``(len(x), 3)``."""
    try:
        import matplotlib

        cmap = matplotlib.colormaps[name]
    except KeyError:
        raise InputError(f"scene.transfer_function.colormap={name!r}: not a matplotlib colormap name") from None
    return np.asarray(cmap(np.clip(x, 0, 1)))[:, :3]


def _sample_normalized(volume: Volume, max_samples: int = 2_000_000) -> np.ndarray:
    flat = volume.data.reshape(-1)
    step = max(1, flat.size // max_samples)
    s = np.asarray(flat[::step], dtype=np.float64)
    s = s[np.isfinite(s)]
    lo, hi = volume.value_range
    return np.clip((s - lo) / (hi - lo), 0.0, 1.0)


def auto_transfer_function(volume: Volume, colormap: str = "magma", bins: int = 256) -> TransferFunction:
    """A transfer function derived from the volume's histogram.

    The most populated histogram bin is taken as the background (air around a scan, empty
    space, bulk solvent); everything below the end of its peak is transparent. Above it, the
    foreground values are split by their quantiles: a faint, wide layer shows the outer boundary
    of the foreground (skin, brain surface, low density), and an opacity ramp over the upper
    quantiles shows the dense structures (bone, white matter, density blobs) nearly opaquely.
    Colours come from a perceptual colormap over the foreground range, so structures of
    different value get distinct, ordered colours.

    Args:
        volume: the volume (only a strided sample of at most ~2M voxels is read).
        colormap: a matplotlib colormap name.
        bins: histogram bins over the normalized range.

    Returns:
        :class:`TransferFunction` in normalized scalar units.

    Example:
        >>> tf = auto_transfer_function(volume)                 # doctest: +SKIP
        >>> float(tf.alpha(0.0)), float(tf.alpha(1.0)) > 0.5
        (0.0, True)
    """
    s = _sample_normalized(volume)
    hist, edges = np.histogram(s, bins=bins, range=(0.0, 1.0))
    centres = (edges[:-1] + edges[1:]) / 2
    # smooth a little so single-bin spikes (quantized data) do not define peaks
    k = np.exp(-0.5 * (np.arange(-3, 4) / 1.5) ** 2)
    hs = np.convolve(hist.astype(np.float64), k / k.sum(), mode="same")
    b = int(np.argmax(hs))
    # end of the background peak: the first bin right of it that falls below 2% of the peak or
    # that starts rising again (a valley before the next structure)
    t = b
    while t + 1 < bins and hs[t + 1] > 0.02 * hs[b] and not (hs[t + 1] > hs[t] and hs[t] < 0.5 * hs[b]):
        t += 1
    t0 = float(edges[min(t + 1, bins)])
    fg = s[s > t0]
    if fg.size < 100:  # nearly everything is background: use the values above the peak itself
        t0 = float(edges[b + 1]) if b + 1 < bins else float(centres[b])
        fg = s[s > t0]
    if fg.size < 10:
        raise InputError(f"volume '{volume.name}': no structure above the background value to show (set scene.transfer_function points)")
    q = np.quantile(fg, [0.05, 0.35, 0.7, 0.9, 0.99])
    q = np.maximum.accumulate(np.maximum(q, t0 + 1e-6))
    top = max(float(q[-1]), t0 + 1e-3)
    # opacity: faint boundary layer right above the background, a gentle plateau, then a ramp up
    # to nearly opaque dense structures
    xs = [0.0, t0, float(q[0]), float(q[1]), float(q[2]), float(q[3]), top, 1.0]
    a_s = [0.0, 0.0, 0.06, 0.02, 0.02, 0.35, 0.8, 0.9]
    op = _monotone_rows(np.column_stack([xs, a_s]))
    cx = np.array([0.0, t0, float(q[1]), float(q[2]), float(q[3]), top, 1.0])
    cpos = np.array([0.15, 0.2, 0.45, 0.65, 0.8, 0.95, 0.98])
    col = _monotone_rows(np.column_stack([cx, _colormap(colormap, cpos)]))
    return TransferFunction(col, op)


def _monotone_rows(a: np.ndarray) -> np.ndarray:
    """Drop rows whose position does not increase (keeps the first of equal positions)."""
    a = np.asarray(a, dtype=np.float64)
    a[:, 0] = np.clip(a[:, 0], 0.0, 1.0)
    keep = [0]
    for i in range(1, len(a)):
        if a[i, 0] > a[keep[-1], 0] + 1e-9:
            keep.append(i)
    out = a[keep]
    if len(out) < 2:
        out = np.concatenate([out, out[-1:]], axis=0)
        out[-1, 0] = 1.0
    return out
