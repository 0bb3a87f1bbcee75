"""The VTK renderer of record: determinism, the scene model it must honour, pixel subsets, errors.

No timing is asserted here: performance was measured by ``scripts/bench_selective.py``, removed after its result was
committed (``git show 97cc83f:scripts/bench_selective.py``; BENCHMARKS.md).
"""
from __future__ import annotations


import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.render.scene import Scene, Shading

from tests.data_gen.helpers import SAMPLE_DISTANCE_VIEWS, check_images_alike_across_sample_distances, psnr

VIEW = [0.0, 0.5, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
OBLIQUE = [2.5, 1.0, 1.2, 0.1, 0.0, 0.0, 0.0, 0.0, 1.0]



@pytest.fixture(scope="module")
def vtk_renderer(blob_scene):
    from imls_lightning.render.vtk import VTKRenderer

    return VTKRenderer(blob_scene)


def _with(scene: Scene, **kw) -> Scene:
    fields = dict(shading=scene.shading, background=scene.background, sample_distance=scene.sample_distance)
    fields.update(kw)
    return Scene(scene.name, scene.volume, scene.transfer_function, **fields)


# ---- smoke -------------------------------------------------------------------------------------
def test_smoke_render_deterministic(vtk_renderer):
    a = vtk_renderer.render(VIEW, 48)
    b = vtk_renderer.render(VIEW, 48)
    assert a.shape == (48, 48, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert (a != 0).any(axis=2).mean() > 0.1
    assert vtk_renderer.last_render_seconds > 0


def test_smoke_resolution_changes(vtk_renderer):
    assert vtk_renderer.render(VIEW, 20).shape == (20, 20, 3)
    assert vtk_renderer.render(VIEW, 33).shape == (33, 33, 3)


# ---- the scene model ----------------------------------------------------------------------------
def test_ambient_term_is_honoured(blob_scene):
    """VTK's automatic light has a black ambient colour; ours is white, so ambient=1 alone gives
    the unshaded colours (D = 1 everywhere) instead of a black image."""
    from imls_lightning.render.vtk import VTKRenderer

    amb = VTKRenderer(_with(blob_scene, shading=Shading(True, 1.0, 0.0, 0.0, 10.0))).render(OBLIQUE, 40)
    flat = VTKRenderer(_with(blob_scene, shading=Shading(enabled=False))).render(OBLIQUE, 40)
    assert amb.max() > 100
    assert psnr(amb, flat) > 50.0


def test_thread_count_does_not_change_pixels(blob_scene):
    """VTK computes normals in one z slab per thread with one-sided differences at every slab
    boundary; the renderer computes them single-threaded, so the picture is thread-independent."""
    from imls_lightning.render.vtk import VTKRenderer

    one = VTKRenderer(blob_scene, threads=1).render(OBLIQUE, 40)
    three = VTKRenderer(blob_scene, threads=3).render(OBLIQUE, 40)
    assert np.array_equal(one, three)


def test_exact_pixels_versus_displayed_window(blob_scene):
    """The ray-cast image (one ray per pixel centre) is what VTK shows, up to VTK's texture
    resampling: close, not equal; both agree exactly on the background far from the volume."""
    from imls_lightning.render.vtk import VTKRenderer

    bg = (0.2, 0.4, 0.6)
    scene = _with(blob_scene, background=bg)
    exact = VTKRenderer(scene).render(VIEW, 48)
    shown = VTKRenderer(scene, exact_pixels=False).render(VIEW, 48)
    assert 30.0 < psnr(exact, shown) < 80.0
    corner = np.round(np.array(bg) * 255).astype(np.uint8)
    assert (exact[0, 0] == corner).all() and (shown[0, 0] == corner).all()


@pytest.mark.parametrize("away", [[6.0, 0.0, 0.0, 7.0, 0.0, 0.0, 0.0, 1.0, 0.0],   # volume behind the camera
                                  [0.0, 0.0, 3.0, 3.0, 0.0, 3.0, 0.0, 1.0, 0.0]])  # volume beside the view
def test_volume_outside_the_view_gives_background(blob_scene, away):
    """VTK culls the volume (or gives up on the frame) and keeps its previous ray-cast image;
    the renderer must return the background, not that stale frame."""
    from imls_lightning.render.numba import NumbaRenderer
    from imls_lightning.render.vtk import VTKRenderer

    bg = (0.1, 0.2, 0.3)
    scene = _with(blob_scene, background=bg)
    r = VTKRenderer(scene)
    r.render(VIEW, 24)  # a frame with the volume in it first
    img = r.render(away, 24)
    assert (img == np.floor(np.array(bg) * 255 + 0.5).astype(np.uint8)).all()
    assert np.array_equal(img, NumbaRenderer(scene).render(away, 24))


# ---- selective rendering (opaque points in front of the volume) -----------------------------------
def test_render_pixels_equal_full_frame(vtk_renderer, blob_scene):
    """Requested rays are cast exactly as in the full frame (observed: bit-identical); the
    tolerance only guards against VTK versions that change the pipeline."""
    from imls_lightning.render.numba import ray_hit_mask

    m = 48
    full = vtk_renderer.render(OBLIQUE, m).reshape(-1, 3)
    rng = np.random.default_rng(1)
    pix = rng.choice(m * m, 400, replace=False)
    got = vtk_renderer.render_pixels(OBLIQUE, m, pix)
    err = np.abs(got.astype(int) - full[pix])
    assert err.max() <= 1 and psnr(got, full[pix]) >= 40.0
    hits = ray_hit_mask(OBLIQUE, m, blob_scene.view_angle, blob_scene.volume.bounds)
    hits[pix] = False
    assert vtk_renderer.last_blocked_pixels == int(hits.sum()) > 0


def test_render_pixels_leave_full_frames_unchanged(vtk_renderer):
    before = vtk_renderer.render(VIEW, 40)
    vtk_renderer.render_pixels(VIEW, 40, np.arange(0, 1600, 7))
    assert np.array_equal(vtk_renderer.render(VIEW, 40), before)


def test_render_pixels_empty(vtk_renderer):
    out = vtk_renderer.render_pixels(VIEW, 64, np.array([], np.int64))
    assert out.shape == (0, 3) and out.dtype == np.uint8
    assert vtk_renderer.last_render_seconds == 0.0 and vtk_renderer.last_blocked_pixels == 0


# ---- errors -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("pixels", [np.array([0.5]), np.array([64]), np.array([[1, 2]])])
def test_exception_invalid_pixels(vtk_renderer, pixels):
    with pytest.raises(InputError, match="pixels") as e:
        vtk_renderer.render_pixels(VIEW, 8, pixels)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("resolution", [0, -1, 3.0])
def test_exception_invalid_resolution(vtk_renderer, resolution):
    with pytest.raises(InputError, match="resolution"):
        vtk_renderer.render(VIEW, resolution)


def test_exception_unknown_mapper(blob_scene):
    from imls_lightning.render.vtk import VTKRenderer

    with pytest.raises(InputError, match="renderer.mapper"):
        VTKRenderer(blob_scene, mapper="magic")


@pytest.mark.parametrize("view", SAMPLE_DISTANCE_VIEWS)
def test_images_alike_across_sample_distances(view):
    from imls_lightning.render.vtk import VTKRenderer

    check_images_alike_across_sample_distances(VTKRenderer, view)
