"""renderer.interpolation=tricubic: the B-spline sampler against a direct float64 reference, its exactness on
constant and linear data, the renders it gives (skipping still exact, sample counts, pixel subsets), the default
trilinear path unchanged bit for bit, the hashes of existing configs unchanged, and the errors."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.render.scene import Scene, Shading, TransferFunction
from imls_lightning.render.volume import Volume

VIEWS = [
    [0.0, 0.5, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
    [2.5, 1.0, 1.2, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0],
    [0.3, 0.2, 0.1, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],  # camera inside the volume
]
#: SHA-256 of the trilinear renders and ray-sample counts of :func:`_trilinear_digest`, computed on main at 8d223d1,
#: before the interpolation option existed: the default path must keep every pixel and every count
TRILINEAR_DIGEST = "4c0f9f91f00d7db0823cd87b610c17a57b09b7d2b945afd62f4bd58b5e4478d3"
BLOB_TF = TransferFunction([[0.0, 0.1, 0.2, 0.9], [0.5, 1.0, 0.6, 0.1], [1.0, 1.0, 1.0, 1.0]],
                           [[0.0, 0.0], [0.55, 0.0], [0.7, 0.4], [1.0, 0.9]])


def _bspline_1d(f):
    """Reference cubic B-spline weights and their derivatives for taps -1..2 (float64, from the kernel's formula)."""
    t = np.array([-1.0, 0.0, 1.0, 2.0]) - f  # tap minus sample
    a = np.abs(t)
    w = np.where(a < 1, 2 / 3 - a ** 2 + a ** 3 / 2, np.where(a < 2, (2 - a) ** 3 / 6, 0.0))
    # d/df of B(tap - f) = -B'(tap - f)
    db = np.where(a < 1, -2 * t + 1.5 * t * a, np.where(a < 2, -0.5 * np.sign(t) * (2 - a) ** 2, 0.0))
    return w, -db


def _reference(vol, u):
    """Direct 64-tap B-spline value and gradient of ``vol (nz, ny, nx)`` at voxel coordinates ``u = (x, y, z)``,
    clamp-to-edge, all in float64 numpy."""
    nz, ny, nx = vol.shape
    idx, weights, slopes = [], [], []
    for c, n in zip(u, (nx, ny, nz)):
        i = min(int(np.floor(c)), n - 2)
        w, dw = _bspline_1d(c - i)
        idx.append(np.clip(np.arange(i - 1, i + 3), 0, n - 1))
        weights.append(w)
        slopes.append(dw)
    block = vol.astype(np.float64)[np.ix_(idx[2], idx[1], idx[0])]  # (z, y, x) taps
    value = np.einsum("zyx,z,y,x->", block, weights[2], weights[1], weights[0])
    grad = (np.einsum("zyx,z,y,x->", block, weights[2], weights[1], slopes[0]),
            np.einsum("zyx,z,y,x->", block, weights[2], slopes[1], weights[0]),
            np.einsum("zyx,z,y,x->", block, slopes[2], weights[1], weights[0]))
    return value, np.array(grad)


def _points(rng, shape, count):
    nz, ny, nx = shape
    pts = rng.uniform(0, 1, (count, 3)) * [nx - 1, ny - 1, nz - 1]
    corners = np.array([[0, 0, 0], [nx - 1, ny - 1, nz - 1], [nx - 1, 0, nz - 1], [0.5, ny - 1, 0]], float)
    return np.concatenate([pts, corners])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.int16])
def test_tricubic_sample_equals_direct_bspline(dtype):
    from imls_lightning.render.numba import tricubic_gradient, tricubic_sample

    rng = np.random.default_rng(3)
    for shape in [(5, 6, 7), (2, 3, 9), (4, 4, 4)]:
        vol = (rng.uniform(-100, 100, shape) if np.dtype(dtype).kind == "f" else rng.integers(0, 120, shape)).astype(dtype)
        flat = vol.reshape(-1)
        nz, ny, nx = shape
        for u in _points(rng, shape, 40):
            value, grad = _reference(vol, u)
            scale = 1e-12 * max(1.0, float(np.abs(vol).max()))
            assert abs(tricubic_sample(flat, nx, ny, nz, *u) - value) <= scale, (shape, u)
            np.testing.assert_allclose(tricubic_gradient(flat, nx, ny, nz, *u), grad, rtol=0, atol=scale)


def test_tricubic_gradient_is_the_fields_derivative():
    """The kernel's slope weights against central differences of its own field (interior points)."""
    from imls_lightning.render.numba import tricubic_gradient, tricubic_sample

    rng = np.random.default_rng(5)
    vol = rng.normal(size=(6, 7, 8))
    flat, h = vol.reshape(-1), 1e-5
    for u in rng.uniform(1.2, 4.8, (20, 3)):
        g = tricubic_gradient(flat, 8, 7, 6, *u)
        for a in range(3):
            e = np.eye(3)[a] * h
            fd = (tricubic_sample(flat, 8, 7, 6, *(u + e)) - tricubic_sample(flat, 8, 7, 6, *(u - e))) / (2 * h)
            assert abs(g[a] - fd) < 1e-6


def test_tricubic_reproduces_constant_and_linear_data():
    from imls_lightning.render.numba import tricubic_gradient, tricubic_sample

    rng = np.random.default_rng(7)
    nz, ny, nx = 6, 7, 9
    const = np.full((nz, ny, nx), 37, np.uint8).reshape(-1)
    for u in _points(rng, (nz, ny, nx), 30):  # everywhere, faces and corners included
        assert tricubic_sample(const, nx, ny, nz, *u) == pytest.approx(37.0, abs=1e-12)
        assert np.abs(tricubic_gradient(const, nx, ny, nz, *u)).max() < 1e-12
    z, y, x = np.mgrid[0:nz, 0:ny, 0:nx].astype(np.float64)
    ramp = (0.5 + 2.0 * x - 3.0 * y + 0.25 * z).reshape(-1)
    for u in [[1.0, 1.0, 1.0]] + rng.uniform([1, 1, 1], [nx - 2, ny - 2, nz - 2], (30, 3)).tolist():
        # every tap inside the volume: the B-spline reproduces the linear function and its slope
        assert tricubic_sample(ramp, nx, ny, nz, *u) == pytest.approx(0.5 + 2.0 * u[0] - 3.0 * u[1] + 0.25 * u[2], abs=1e-12)
        np.testing.assert_allclose(tricubic_gradient(ramp, nx, ny, nz, *u), [2.0, -3.0, 0.25], atol=1e-12)


def _trilinear_digest() -> str:
    """Renders (float32 and uint8 data, shaded or not, skipping on and off) and their ray-sample counts, hashed."""
    from imls_lightning.render.numba import NumbaRenderer

    z, y, x = np.mgrid[-1:1:24j, -1:1:32j, -1:1:40j]
    d = (np.exp(-3 * (x * x + y * y + z * z)) + 0.25 * np.sin(6 * x) * np.cos(5 * y)).astype(np.float32)
    h = hashlib.sha256()
    for data in (d, np.round((d - d.min()) / (d.max() - d.min()) * 255).astype(np.uint8)):
        vol = Volume(data, (1.0, 1.0, 1.5), (float(data.min()), float(data.max())), "blob", "test:blob")
        for shading in (Shading(), Shading(enabled=False)):
            for skip in (True, False):
                r = NumbaRenderer(Scene("blob", vol, BLOB_TF, shading=shading), threads=1, skip_empty=skip)
                for view in VIEWS:
                    h.update(r.render(view, 32).tobytes())
                    h.update(r.last_ray_samples.tobytes())
    return h.hexdigest()


def test_trilinear_default_renders_as_before():
    assert _trilinear_digest() == TRILINEAR_DIGEST


@pytest.fixture(scope="module")
def tricubic_pair(blob_scene):
    from imls_lightning.render.numba import NumbaRenderer

    return NumbaRenderer(blob_scene, interpolation="tricubic"), NumbaRenderer(blob_scene)


def test_tricubic_render_close_to_trilinear_and_subsets_exact(tricubic_pair):
    from tests.data_gen.helpers import psnr

    cubic, linear = tricubic_pair
    for view in VIEWS:
        a, b = cubic.render(view, 40), linear.render(view, 40)
        assert not np.array_equal(a, b)  # another picture ...
        assert psnr(a, b) > 20.0, view  # ... of the same scene
        px = np.array([0, 17, 820, 821, 1599])
        assert np.array_equal(cubic.render_pixels(view, 40, px), a.reshape(-1, 3)[px])


def test_tricubic_counts_the_same_samples_as_trilinear(blob_volume):
    """With skipping off and a transfer function too faint to end a ray, every ray interpolates every sample of
    its segment whatever the filter: the counts agree ray by ray."""
    from imls_lightning.render.numba import NumbaRenderer

    faint = Scene("faint", blob_volume, TransferFunction([[0, 1, 1, 1], [1, 1, 1, 1]], [[0.0, 0.0], [1.0, 0.002]]))
    view = [3.0, 2.0, 4.0, 0.6, 0.4, 0.3, 0.0, 1.0, 0.0]
    counts = []
    for interpolation in ("trilinear", "tricubic"):
        r = NumbaRenderer(faint, skip_empty=False, interpolation=interpolation)
        r.render(view, 32)
        counts.append(r.last_ray_samples.copy())
    assert counts[0].max() > 10 and np.array_equal(counts[0], counts[1])


def test_tricubic_skipping_is_exact_next_to_a_brick_face():
    """A bright voxel just past a brick's last voxel: the B-spline's tail reaches into the brick before it, whose
    own voxels are all zero, so skipping must count the spline's extra voxel per side (the bricks' halo)."""
    from imls_lightning.render.numba import BRICK, NumbaRenderer

    d = np.zeros((20, 20, 28), np.float32)
    d[8:11, 8:11, BRICK + 1] = 1.0  # in brick 1 only (brick 0's voxels are x = 0..BRICK)
    vol = Volume(d, (1.0, 1.0, 1.0), (0.0, 1.0), "dot", "test:dot")
    scene = Scene("dot", vol, TransferFunction([[0, 1, 1, 1], [1, 1, 1, 1]], [[0.0, 0.0], [1.0, 1.0]]))
    view = [-3.0, 0.05, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]  # looking along +x: rays cross brick 0 first
    skip, every = (NumbaRenderer(scene, interpolation="tricubic", skip_empty=s) for s in (True, False))
    a, b = skip.render(view, 48), every.render(view, 48)
    assert (b > 0).any() and np.array_equal(a, b)
    assert (skip.last_ray_samples <= every.last_ray_samples).all() and skip.last_ray_samples.sum() < every.last_ray_samples.sum()


def test_exception_unknown_interpolation(blob_scene):
    from imls_lightning.render import make_renderer, renderer_pixel_settings
    from imls_lightning.render.numba import NumbaRenderer

    for bad in ("cubic", "", None, 3):
        with pytest.raises(InputError, match=r"renderer\.interpolation=.*expected one of trilinear, tricubic"):
            NumbaRenderer(blob_scene, warmup=False, interpolation=bad)
    with pytest.raises(InputError, match=r"renderer\.interpolation='nearest'.*trilinear, tricubic"):
        renderer_pixel_settings({"name": "numba", "interpolation": "nearest"})
    with pytest.raises(InputError, match=r"renderer=vtk interpolates trilinearly only"):
        make_renderer(blob_scene, {"name": "vtk", "interpolation": "tricubic"})
    with pytest.raises(InputError, match=r"renderer=vtk interpolates trilinearly only"):
        renderer_pixel_settings({"name": "vtk", "interpolation": "tricubic"})


def test_trilinear_key_leaves_hashes_unchanged():
    """Caches, run hashes and estimates made before the key existed keep their names; tricubic gets its own."""
    from omegaconf import OmegaConf

    from imls_lightning.base.config import KEYS_NEUTRAL_AT, settings_hash
    from imls_lightning.render import PIXEL_KEYS_NEUTRAL_AT, renderer_pixel_settings

    before = {"name": "numba", "threads": 0, "skip_empty": True}
    conf = OmegaConf.to_container(OmegaConf.load("conf/renderer/numba.yaml"))
    assert conf["interpolation"] == "trilinear" and set(conf) == set(before) | {"interpolation"}
    assert renderer_pixel_settings(conf) == renderer_pixel_settings(before)
    assert renderer_pixel_settings({**conf, "interpolation": "tricubic"}) != renderer_pixel_settings(before)
    assert settings_hash({"renderer": conf}) == settings_hash({"renderer": before})
    assert settings_hash({"renderer": {**conf, "interpolation": "tricubic"}}) != settings_hash({"renderer": before})
    assert all(KEYS_NEUTRAL_AT[k] == v for k, v in PIXEL_KEYS_NEUTRAL_AT.items())  # the two lists agree


def test_trilinear_key_leaves_estimate_hash_unchanged():
    """An estimate's output directory hashes the whole renderer node: the new key must not enter it at its default."""
    from pathlib import Path

    from hydra import compose, initialize_config_dir

    from data_gen.scenes import register_resolvers
    from imls_lightning.estimate.run import estimate_settings

    register_resolvers()
    with initialize_config_dir(config_dir=str(Path("conf").resolve()), version_base=None):
        cfg = compose(config_name="estimate", overrides=["scene=tiny", "renderer=numba"])
        cubic = compose(config_name="estimate", overrides=["scene=tiny", "renderer=numba", "renderer.interpolation=tricubic"])
    assert cfg.renderer.interpolation == "trilinear"
    assert estimate_settings(cfg)["renderer"] == {"name": "numba", "threads": 0, "skip_empty": True}
    assert estimate_settings(cubic)["renderer"]["interpolation"] == "tricubic"
