"""The ray casters, the product's foundation below the data: what they render (:mod:`.volume`: a Volume in
the normalized space; :mod:`.scene`: volume + transfer function + shading + sampling), the camera's ray geometry
(:mod:`.camera`), VTK's ray caster (:mod:`.vtk`, the renderer of record) and the project's own compiled one
(:mod:`.numba`), and here the renderer selection: ``make_renderer(scene, renderer_cfg)`` for the ``renderer``
config group. Nothing here reads a config file or a volume file (``data_gen`` does, and builds the scene).

One renderer (``renderer=vtk`` or ``renderer=numba``) serves both the cache and the selective
rendering of a run. Every renderer has ``render(view, resolution) -> (m, m, 3) uint8``,
``render_pixels(view, resolution, pixels) -> (K, 3) uint8`` and ``last_render_seconds``.

The ``renderer`` node:

* ``name``: ``vtk`` | ``numba``.
* ``mapper`` (vtk): ``fixed_point`` (CPU, default) | ``gpu``.
* ``threads``: CPU threads of one renderer; ``0`` = automatic (the cache divides the machine's
  cores among its worker processes).
* ``skip_empty`` (numba): empty-space skipping, ``true`` by default; ``false`` marches every sample in the
  volume's box, as a ray caster without it does (same pixels, other costs: where IML/S is meant to pay).
* ``interpolation`` (numba): ``trilinear`` (default) | ``tricubic`` (the cubic B-spline, shaded from its gradient:
  smoother surfaces, dearer object pixels). VTK's ray casters interpolate trilinearly only (VTK 9.7's
  ``vtkVolumeProperty`` accepts nearest or linear), so ``renderer=vtk`` refuses ``tricubic``.

Keys that cannot change pixels (``threads``, ``skip_empty``) are left out of :func:`renderer_pixel_settings`, the
part of the renderer config that is hashed into cache keys; so are keys at the value every earlier render had
(:data:`PIXEL_KEYS_NEUTRAL_AT`), so that caches and runs made before the key existed keep their hashes.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Callable

import numpy as np

from imls_lightning.base.config import KEYS_NEUTRAL_AT
from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_mapping

from .scene import Scene

# keys of the renderer node that never change the pixels (how fast, not what)
NON_PIXEL_KEYS = frozenset({"threads", "skip_empty"})
# pixel keys added after caches and runs existed, left out of hashes while they hold the value every earlier render
# had: their neutral values live once, in the run hash's own list (imls_lightning.base.config.KEYS_NEUTRAL_AT)
PIXEL_KEYS_NEUTRAL_AT = {k: KEYS_NEUTRAL_AT[k] for k in ("interpolation",)}


def without_neutral_keys(cfg: Mapping[str, Any]) -> dict[str, Any]:
    """``cfg`` less the keys at their :data:`PIXEL_KEYS_NEUTRAL_AT` value (what a hash of renderer settings takes)."""
    return {k: v for k, v in cfg.items() if PIXEL_KEYS_NEUTRAL_AT.get(k, object()) != v}


def _plain(cfg) -> dict[str, Any]:
    if cfg is None:
        return {"name": "vtk"}
    return check_mapping(cfg, "renderer", "a mapping of renderer settings")


def _threads(cfg: Mapping[str, Any], threads: int | None) -> int:
    t = cfg.get("threads", 0) if threads is None else threads
    return check_integer(t or 0, "renderer.threads", 0, what="an integer >= 0 (0 = automatic)")


def _make_vtk(scene: Scene, cfg: Mapping[str, Any], threads: int):
    from .vtk import VTKRenderer

    mapper = cfg.get("mapper", "fixed_point")
    if mapper not in ("fixed_point", "gpu"):
        raise InputError(f"renderer.mapper={mapper!r}: expected 'fixed_point' or 'gpu'")
    _check_vtk_interpolation(cfg)
    return VTKRenderer(scene, mapper=mapper, threads=threads)


def _check_vtk_interpolation(cfg: Mapping[str, Any]) -> None:
    interpolation = cfg.get("interpolation", "trilinear")
    if interpolation != "trilinear":
        raise InputError(f"renderer.interpolation={interpolation!r}: renderer=vtk interpolates trilinearly only (VTK's "
                         "vtkVolumeProperty takes nearest or linear); tricubic needs renderer=numba")


def _make_numba(scene: Scene, cfg: Mapping[str, Any], threads: int):
    # the project's own compiled ray caster (VTK's scene model; casts any pixel subset)
    from .numba import NumbaRenderer

    return NumbaRenderer(scene, threads=threads, skip_empty=cfg.get("skip_empty", True),
                         interpolation=cfg.get("interpolation", "trilinear"))


# name -> factory(scene, renderer_cfg, threads); a new renderer only needs an entry here
RENDERERS: dict[str, Callable[[Scene, Mapping[str, Any], int], Any]] = {
    "vtk": _make_vtk,
    "numba": _make_numba,
}


def make_renderer(scene: Scene, renderer_cfg=None, *, threads: int | None = None):
    """Build the renderer named by ``renderer_cfg.name`` for ``scene``.

    Args:
        scene: what to render.
        renderer_cfg: the ``renderer`` config node (mapping or DictConfig); ``None`` = VTK defaults.
        threads: overrides ``renderer_cfg.threads`` (the cache sets it per worker process).

    Returns:
        A renderer with ``render(view, resolution) -> (m, m, 3) uint8`` and ``last_render_seconds``.

    Example:
        >>> r = make_renderer(scene, {"name": "vtk", "mapper": "fixed_point"})   # doctest: +SKIP
        >>> r.render([0, 0, 3, 0, 0, 0, 0, 1, 0], 64).shape                       # doctest: +SKIP
        (64, 64, 3)
    """
    cfg = _plain(renderer_cfg)
    name = cfg.get("name", "vtk")
    if name not in RENDERERS:
        raise InputError(f"renderer.name={name!r}: expected one of {sorted(RENDERERS)}")
    return RENDERERS[name](scene, cfg, _threads(cfg, threads))


# revision 2 of vtk: explicit white-ambient headlight, single-threaded normals, exact mapper image
RENDERER_REVISION = {"vtk": 2, "numba": 1}


def renderer_pixel_settings(renderer_cfg=None) -> dict[str, Any]:
    """The part of the renderer config that can change pixels (hashed into cache keys).

    Defaults are filled in so that ``{"name": "vtk"}`` and ``{"name": "vtk", "mapper":
    "fixed_point"}`` give the same key.
    """
    cfg = _plain(renderer_cfg)
    name = cfg.get("name", "vtk")
    if name not in RENDERERS:
        raise InputError(f"renderer.name={name!r}: expected one of {sorted(RENDERERS)}")
    _threads(cfg, None)  # checked here so that bad settings fail before any file is written
    if name == "vtk":
        _check_vtk_interpolation(cfg)
    elif name == "numba":
        from .numba import check_interpolation

        check_interpolation(cfg.get("interpolation", "trilinear"))
    out = {k: v for k, v in sorted(without_neutral_keys(cfg).items()) if k not in NON_PIXEL_KEYS}
    out["name"] = name
    # bumped whenever a renderer's pixels change for the same settings, so old caches are not reused
    out["revision"] = RENDERER_REVISION.get(name, 1)
    if name == "vtk":
        out.setdefault("mapper", "fixed_point")
        if out["mapper"] not in ("fixed_point", "gpu"):
            raise InputError(f"renderer.mapper={out['mapper']!r}: expected 'fixed_point' or 'gpu'")
    return out


def render_image(renderer, view, resolution: int, pixels=None):
    """``(m, m, 3)`` uint8: the full frame of ``view``, or (``pixels``: flat raster indices ``(K,)``)
    only those pixels ray-cast and every other pixel black (a cache's C-Image-only rows).

    Example:
        >>> img = render_image(renderer, view, 64, pixels=np.arange(0, 64 * 64, 2))   # doctest: +SKIP
        >>> int(img.reshape(-1, 3)[1::2].max())                                        # doctest: +SKIP
        0
    """
    if pixels is None:
        return renderer.render(view, resolution)
    m = int(resolution)
    img = np.zeros((m * m, 3), np.uint8)
    img[pixels] = renderer.render_pixels(view, m, pixels)
    return img.reshape(m, m, 3)


def renderer_version(renderer_cfg=None) -> str:
    """Version string of the rendering library (recorded in cache manifests, not hashed)."""
    name = _plain(renderer_cfg).get("name", "vtk")
    try:
        if name == "vtk":
            import vtk

            return f"vtk {vtk.vtkVersion.GetVTKVersion()}"
        if name == "numba":
            import numba

            return f"numba {numba.__version__}"
    except Exception:  # the version is informative only
        pass
    return "unknown"


__all__ = ["make_renderer", "render_image", "renderer_pixel_settings", "renderer_version", "without_neutral_keys",
           "RENDERERS", "NON_PIXEL_KEYS", "PIXEL_KEYS_NEUTRAL_AT"]
