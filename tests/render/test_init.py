"""imls_lightning.render: the renderer named by the config is built; the pixel settings hashed into cache
keys fill defaults and drop what cannot change pixels; bad settings are one-line InputErrors."""
from __future__ import annotations

import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.render.numba import NumbaRenderer
from imls_lightning.render.vtk import VTKRenderer
from imls_lightning.render import RENDERER_REVISION, make_renderer, renderer_pixel_settings, renderer_version


def test_make_renderer_builds_the_named_renderer(blob_scene):
    assert isinstance(make_renderer(blob_scene, {"name": "numba", "threads": 1}), NumbaRenderer)
    assert isinstance(make_renderer(blob_scene, {"name": "vtk", "mapper": "fixed_point"}), VTKRenderer)
    assert isinstance(make_renderer(blob_scene), VTKRenderer)  # None: VTK defaults


@pytest.mark.parametrize("cfg, needle", [({"name": "ospray"}, "renderer.name='ospray'"),
                                         ({"name": "vtk", "mapper": "x"}, "renderer.mapper='x'"),
                                         ({"name": "numba", "threads": -1}, "renderer.threads"),
                                         ("vtk", "renderer")])
def test_exception_make_renderer_bad_settings(blob_scene, cfg, needle):
    with pytest.raises(InputError, match=needle) as err:
        make_renderer(blob_scene, cfg)
    assert "\n" not in str(err.value)


def test_pixel_settings_fill_defaults_and_leave_out_threads():
    a = renderer_pixel_settings({"name": "vtk"})
    assert a == {"name": "vtk", "mapper": "fixed_point", "revision": RENDERER_REVISION["vtk"]}
    assert renderer_pixel_settings({"name": "vtk", "mapper": "fixed_point", "threads": 3}) == a
    assert renderer_pixel_settings(None) == a
    assert renderer_pixel_settings({"name": "numba", "threads": 2}) == {"name": "numba", "revision": RENDERER_REVISION["numba"]}
    # empty-space skipping changes costs, never pixels: caches are shared
    assert renderer_pixel_settings({"name": "numba", "skip_empty": False}) == renderer_pixel_settings({"name": "numba"})
    assert renderer_pixel_settings({"name": "vtk", "mapper": "gpu"}) != a
    with pytest.raises(InputError, match="renderer.threads"):
        renderer_pixel_settings({"name": "numba", "threads": "many"})
    with pytest.raises(InputError, match="renderer.mapper"):
        renderer_pixel_settings({"name": "vtk", "mapper": "cpu"})


def test_renderer_version_names_the_library():
    import numba
    import vtk

    assert renderer_version({"name": "numba"}) == f"numba {numba.__version__}"
    assert renderer_version(None) == f"vtk {vtk.vtkVersion.GetVTKVersion()}"
