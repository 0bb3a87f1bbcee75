"""Scenes from config: presets, raw-unit and automatic transfer functions, a real VTK render."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

import data_gen  # noqa: F401  (registers the OmegaConf resolvers)
from imls_lightning.base.errors import InputError
from data_gen.scenes import auto_transfer_function, build_scene, default_volumes_dir
from imls_lightning.render.scene import Scene, resolve_sample_distance, voxel_size
from imls_lightning.render.volume import Volume

CONF = Path(__file__).resolve().parents[2] / "conf" / "scene"
PROCEDURAL = ["tiny", "marschner_lobb", "mixing_layer", "flame", "rayleigh_taylor", "flame_sheets", "seed_shell", "rt_plumes"]
#: presets of paper-size (512^3) volumes: built at a small size in CI, streamed to a temporary directory
PAPER_SIZE = {"rayleigh_taylor", "flame_sheets", "seed_shell", "rt_plumes"}
REAL = {
    "ct_head": "ct_head_256x256x108_int16.raw",
    "mri_head": "mri_head_128x128x84_uint8.raw",
    "macaque_brain": "macaque_brain_t1.nii.gz",
    "density_1jzv": "density_1jzv_76x96x70_float32.raw",
}


def _preset(name: str, **overrides):
    cfg = OmegaConf.load(CONF / f"{name}.yaml")
    for k, v in overrides.items():
        OmegaConf.update(cfg, k, v)
    return cfg


def _front_view(scene: Scene, d: float | None = None):
    d = d or scene.camera_distance[1]
    return [0.0, -d, 0.0, 0, 0, 0, 0, 0, 1]


# ---- presets ------------------------------------------------------------------------------
def test_preset_files_cover_the_issue():
    names = {p.stem for p in CONF.glob("*.yaml")}
    assert set(PROCEDURAL) | set(REAL) | {"file"} <= names


@pytest.mark.parametrize("name", PROCEDURAL)
def test_smoke_procedural_presets_build(name, tmp_path):
    small = {"volume.size": 24, "volume.stream_to": str(tmp_path)} if name in PAPER_SIZE else {}
    s = build_scene(_preset(name, **small))
    assert s.name == name and s.sample_distance_voxels == (0.25 if name in PAPER_SIZE else 0.5)  # auto, or a quarter voxel
    if name in PAPER_SIZE:
        assert s.volume.dims == (24, 24, 24) and [p.name for p in tmp_path.iterdir()] == [f"{name}_24x24x24_float32.raw"]
    assert s.volume.source.startswith(f"procedural:{name}")
    assert s.config is not None and s.config["name"] == name
    assert float(s.transfer_function.opacity[:, 1].max()) >= 0.3


def test_flame_whole_is_flame_sheets_framed_from_twice_as_far():
    """flame_whole extends flame_sheets through Hydra's defaults list: the same volume, transfer function and
    shading, only the name and the camera's distance differ (BENCHMARKS.md, "The whole flame in view")."""
    from data_gen.scenes import preset_config

    whole = OmegaConf.to_container(preset_config("flame_whole"))
    sheets = OmegaConf.to_container(preset_config("flame_sheets"))
    assert whole.pop("name") == "flame_whole" and sheets.pop("name") == "flame_sheets"
    assert whole.pop("camera_distance") == [2 * d for d in sheets.pop("camera_distance")]
    assert whole == sheets and "defaults" not in whole
    assert preset_config("flame_whole", ["scene.camera_distance=[5,6]"]).camera_distance == [5, 6]


def test_seed_whole_is_seed_shell_framed_from_farther():
    """seed_whole extends seed_shell through Hydra's defaults list: the same volume, transfer function and shading, only
    the name and the camera's distance (about 1.5x as far) differ (BENCHMARKS.md, "seed_whole: the seed framed whole")."""
    from data_gen.scenes import preset_config

    whole = OmegaConf.to_container(preset_config("seed_whole"))
    shell = OmegaConf.to_container(preset_config("seed_shell"))
    assert whole.pop("name") == "seed_whole" and shell.pop("name") == "seed_shell"
    assert whole.pop("camera_distance") == [3.6, 5.0] and shell.pop("camera_distance") == [2.4, 3.4]
    assert whole == shell and "defaults" not in whole


def test_exception_preset_config_names_the_preset():
    from data_gen.scenes import preset_config

    with pytest.raises(InputError, match=r"scene='flame_hole': no conf/scene/flame_hole.yaml; expected one of .*flame_whole"):
        preset_config("flame_hole")
    with pytest.raises(InputError, match=r"scene=flame_whole scene.nope=1: "):
        preset_config("flame_whole", ["scene.nope=1"])


@pytest.mark.parametrize("name", sorted(PAPER_SIZE))
def test_paper_size_presets_default_to_512_streamed(name, monkeypatch, tmp_path):
    """The preset asks for the generator's 512^3 default and streams it to the cache directory."""
    from data_gen.procedural import PROCEDURAL_GENERATORS

    monkeypatch.setenv("IMLS_CACHE_DIR", str(tmp_path))
    cfg = _preset(name)
    assert cfg.volume.kind == "procedural" and cfg.volume.generator == name and cfg.volume.size is None
    assert PROCEDURAL_GENERATORS[name].default_size == (512, 512, 512)
    assert cfg.volume.stream_to == f"{tmp_path}/volumes"


@pytest.mark.real_volume
@pytest.mark.parametrize("name", sorted(REAL))
def test_smoke_real_presets_build_and_show_structure(name, volumes_dir):
    s = build_scene(_preset(name, **{"volume.path": str(volumes_dir / REAL[name])}))
    tf = s.transfer_function
    # the background (lowest values) is clear, something is nearly opaque
    assert tf.alpha(0.0) == 0.0 and tf.opacity[:, 1].max() >= 0.8
    if name == "ct_head":
        hu = lambda v: (v - s.volume.value_range[0]) / (s.volume.value_range[1] - s.volume.value_range[0])  # noqa: E731
        assert tf.alpha(hu(-1000)) == 0 and tf.alpha(hu(40)) == 0       # air and soft tissue clear
        assert 0.05 < tf.alpha(hu(-400)) < 0.6                          # skin: translucent
        assert tf.alpha(hu(1000)) > 0.7                                 # bone: nearly opaque


def test_volumes_dir_resolver_follows_env(monkeypatch, tmp_path):
    monkeypatch.setenv("IMLS_VOLUMES_DIR", str(tmp_path))
    cfg = _preset("ct_head")
    assert cfg.volume.path == f"{tmp_path}/ct_head_256x256x108_int16.raw"
    monkeypatch.delenv("IMLS_VOLUMES_DIR")
    assert default_volumes_dir().endswith("shared/volumes")


def test_file_preset_names_scene_after_file(tmp_path):
    cfg = OmegaConf.create({"scene": OmegaConf.load(CONF / "file.yaml")})
    OmegaConf.update(cfg, "scene.volume.path", str(tmp_path / "engine_8x8x8_uint8.raw"))
    assert cfg.scene.name == "engine"
    OmegaConf.update(cfg, "scene.volume.name", "mine")
    assert cfg.scene.name == "mine"


def test_smoke_file_preset_auto_tf(tmp_path):
    z, y, x = np.mgrid[-1:1:20j, -1:1:24j, -1:1:28j]
    d = (200 * np.exp(-4 * (x * x + y * y + z * z))).astype(np.uint8)
    d.tofile(tmp_path / "ball_28x24x20_uint8.raw")
    cfg = OmegaConf.create({"scene": OmegaConf.load(CONF / "file.yaml")})
    OmegaConf.update(cfg, "scene.volume.path", str(tmp_path / "ball_28x24x20_uint8.raw"))
    s = build_scene(cfg.scene)
    assert s.name == "ball" and s.volume.dims == (28, 24, 20)


# ---- transfer functions ---------------------------------------------------------------------
def test_raw_units_against_direct_interpolation(blob_volume):
    """Raw-unit points are re-expressed over [0, 1]; compare with interpolating in raw units."""
    lo, hi = blob_volume.value_range
    color = [[lo - 1.0, 0, 0, 0], [lo + 0.3 * (hi - lo), 1, 0.5, 0], [hi + 2.0, 1, 1, 1]]
    opacity = [[lo - 5.0, 0.0], [lo + 0.5 * (hi - lo), 0.2], [lo + 0.8 * (hi - lo), 0.9], [hi + 1.0, 1.0]]
    s = build_scene({"name": "b", "transfer_function": {"units": "raw", "color": color, "opacity": opacity}}, volume=blob_volume)
    xs = np.linspace(0, 1, 101)
    raw = lo + xs * (hi - lo)
    op = np.asarray(opacity)
    np.testing.assert_allclose(s.transfer_function.alpha(xs), np.interp(raw, op[:, 0], op[:, 1]), atol=1e-12)
    col = np.asarray(color)
    np.testing.assert_allclose(s.transfer_function.rgb(xs)[:, 0], np.interp(raw, col[:, 0], col[:, 1]), atol=1e-12)


def test_auto_tf_background_clear_structures_visible():
    rng = np.random.default_rng(0)
    # air (mostly ~0) + a shell of medium values + a dense core
    z, y, x = np.mgrid[-1:1:40j, -1:1:40j, -1:1:40j]
    r = np.sqrt(x * x + y * y + z * z)
    d = np.where(r < 0.8, 300.0, 0.0) + np.where(r < 0.4, 900.0, 0.0) + rng.normal(0, 5, r.shape)
    v = Volume(d.astype(np.float32), (1, 1, 1), (float(d.min()), float(d.max())), "layers", "test")
    tf = auto_transfer_function(v)
    air, shell, core = (v.normalize(np.array([a]))[0] for a in (0.0, 300.0, 1200.0))
    assert tf.alpha(air) == 0.0
    assert 0 < tf.alpha(shell) < tf.alpha(core)
    assert tf.alpha(core) > 0.5
    # colours are distinct for distinct structures
    assert np.abs(tf.rgb(shell) - tf.rgb(core)).max() > 0.1


def test_auto_tf_on_smooth_volume(blob_volume):
    tf = auto_transfer_function(blob_volume, colormap="viridis")
    assert tf.opacity[:, 1].max() > 0.5 and tf.alpha(0.0) == 0.0


@pytest.mark.parametrize("tf, match", [
    ({"auto": False}, "color: missing"),
    ({"units": "kelvin", "color": [[0, 0, 0, 0], [1, 1, 1, 1]], "opacity": [[0, 0], [1, 1]]}, "units"),
    ({"units": "raw", "color": [[0, 0, 0, 0], [1, 1, 1, 1]], "opacity": [[1e9, 0], [2e9, 1]]}, "opacity"),
    ({"auto": True, "colormap": "no_such_map"}, "colormap"),
])
def test_exception_bad_transfer_function(blob_volume, tf, match):
    with pytest.raises(InputError, match=match):
        build_scene({"name": "b", "transfer_function": tf}, volume=blob_volume)


def test_exception_bad_scene_values(blob_volume):
    with pytest.raises(InputError, match="shading"):
        build_scene({"transfer_function": {"auto": True}, "shading": {"shine": 1}}, volume=blob_volume)
    with pytest.raises(InputError, match="camera_distance"):
        build_scene({"transfer_function": {"auto": True}, "camera_distance": [3, 2]}, volume=blob_volume)
    with pytest.raises(InputError, match="scene.volume"):
        build_scene({"name": "x"})


# ---- sample distance ------------------------------------------------------------------------
def _half_voxel(dims_xyz, spacing_xyz) -> float:
    """Direct computation: half the smallest spacing, in the space where the longest axis spans 2."""
    extent = [(d - 1) * s for d, s in zip(dims_xyz, spacing_xyz)]
    return 0.5 * min(spacing_xyz) * 2.0 / max(extent)


def test_every_scene_preset_defaults_to_auto_sample_distance():
    from data_gen.scenes import preset_config

    for p in sorted(CONF.glob("*.yaml")):
        cfg = preset_config(p.stem)
        assert cfg.sample_distance == "auto", p.name
        # the paper-regime scenes step a quarter voxel: at half-voxel steps their thin opaque shells drew wood-grain rings
        paper_size = cfg.volume.get("generator") in PAPER_SIZE
        assert cfg.sample_distance_voxels == (0.25 if paper_size else None), p.name
        if "defaults" not in OmegaConf.load(p):  # a preset that extends another states the units there
            assert "normalized" in p.read_text() and "voxel" in p.read_text(), f"{p.name}: the config must state the units"


def test_auto_sample_distance_is_half_the_smallest_voxel(blob_volume):
    # the blob is anisotropic: 40 x 32 x 24 voxels, spacing (1, 1, 1.5): x spans 39, z 34.5
    s = build_scene({"name": "b", "transfer_function": {"auto": True}, "sample_distance": "auto"}, volume=blob_volume)
    assert s.sample_distance == pytest.approx(_half_voxel((40, 32, 24), (1.0, 1.0, 1.5)), rel=1e-12)
    assert s.sample_distance_voxels == 0.5
    assert voxel_size(blob_volume) == pytest.approx(2 * _half_voxel((40, 32, 24), (1.0, 1.0, 1.5)), rel=1e-12)
    # the default of a Scene built in code, and of a config without the key, is auto too
    assert Scene("b", blob_volume, s.transfer_function).sample_distance == s.sample_distance
    assert build_scene({"name": "b", "transfer_function": {"auto": True}}, volume=blob_volume).sample_distance == s.sample_distance
    # the smallest spacing decides, whichever axis it is on and however the box is shaped
    v = Volume(np.zeros((10, 50, 20), np.float32), (2.0, 0.5, 0.8), (0.0, 1.0), "v", "test")
    assert resolve_sample_distance(v) == pytest.approx(_half_voxel((20, 50, 10), (2.0, 0.5, 0.8)), rel=1e-12)


def test_auto_sample_distance_of_presets(volumes_dir):
    tiny = build_scene(_preset("tiny"))
    assert tiny.sample_distance == pytest.approx(_half_voxel((32, 32, 32), (1, 1, 1)), rel=1e-12)
    ct = build_scene(_preset("ct_head", **{"volume.path": str(volumes_dir / REAL["ct_head"])}))
    assert ct.sample_distance == pytest.approx(_half_voxel((256, 256, 108), (0.957, 0.957, 1.5)), rel=1e-12)
    assert 0.0039 < ct.sample_distance < 0.00393   # the old default 0.02 was 2.55 voxels


def test_explicit_sample_distance_in_voxels_or_normalized_units(blob_volume):
    base = {"name": "b", "transfer_function": {"auto": True}}
    vs = voxel_size(blob_volume)
    s = build_scene({**base, "sample_distance_voxels": 0.25}, volume=blob_volume)
    assert s.sample_distance == pytest.approx(0.25 * vs, rel=1e-12) and s.sample_distance_voxels == 0.25
    s = build_scene({**base, "sample_distance": "auto", "sample_distance_voxels": 2}, volume=blob_volume)
    assert s.sample_distance == pytest.approx(2 * vs, rel=1e-12)
    s = build_scene({**base, "sample_distance": 0.02}, volume=blob_volume)   # normalized units, as before
    assert s.sample_distance == 0.02 and s.sample_distance_voxels == pytest.approx(0.02 / vs)
    settings = s.pixel_settings()
    assert settings["sample_distance"] == 0.02 and settings["sample_distance_voxels"] == s.sample_distance_voxels
    # through Hydra's override of the preset
    assert build_scene(_preset("tiny", sample_distance_voxels=0.25)).sample_distance_voxels == 0.25


@pytest.mark.parametrize("key, value, match", [
    ("sample_distance", "fine", "scene.sample_distance='fine'"),
    ("sample_distance", 0, "scene.sample_distance=0:"),
    ("sample_distance", -0.01, "scene.sample_distance=-0.01"),
    ("sample_distance", float("nan"), "scene.sample_distance=nan"),
    ("sample_distance", float("inf"), "scene.sample_distance=inf"),
    ("sample_distance", True, "scene.sample_distance=True"),
    ("sample_distance", [0.1], r"scene.sample_distance=\[0.1\]"),
    ("sample_distance", 1e-6, "finer than 0.01 voxel"),
    ("sample_distance_voxels", "half", "scene.sample_distance_voxels='half'"),
    ("sample_distance_voxels", 0, "scene.sample_distance_voxels=0:"),
    ("sample_distance_voxels", -1, "scene.sample_distance_voxels=-1"),
    ("sample_distance_voxels", 0.001, "scene.sample_distance_voxels=0.001: finer than 0.01 voxel"),
])
def test_exception_bad_sample_distance(blob_volume, key, value, match):
    with pytest.raises(InputError, match=match) as err:
        build_scene({"name": "b", "transfer_function": {"auto": True}, key: value}, volume=blob_volume)
    assert "\n" not in str(err.value)


def test_exception_sample_distance_given_twice(blob_volume):
    with pytest.raises(InputError, match="scene.sample_distance=0.02 and scene.sample_distance_voxels=0.5: give only one"):
        build_scene({"name": "b", "transfer_function": {"auto": True}, "sample_distance": 0.02,
                     "sample_distance_voxels": 0.5}, volume=blob_volume)
    with pytest.raises(InputError, match="scene.opacity_unit_distance"):
        build_scene({"name": "b", "transfer_function": {"auto": True}, "opacity_unit_distance": "x"}, volume=blob_volume)


# ---- a real VTK render ----------------------------------------------------------------------
def test_smoke_vtk_render_tiny_nonempty_deterministic():
    from imls_lightning.render import make_renderer

    scene = build_scene(_preset("tiny"))
    view = _front_view(scene, scene.camera_distance[0])
    a = make_renderer(scene, {"name": "vtk"}, threads=1).render(view, 48)
    b = make_renderer(scene, {"name": "vtk"}, threads=2).render(view, 48)
    assert a.shape == (48, 48, 3) and a.dtype == np.uint8
    lit = (a.max(axis=2) > 10).mean()
    assert 0.1 < lit < 0.95  # the volume is in frame and framed with some background
    np.testing.assert_array_equal(a, b)


@pytest.mark.real_volume
def test_smoke_vtk_render_ct_head_fills_frame(volumes_dir):
    from imls_lightning.render import make_renderer

    scene = build_scene(_preset("ct_head", **{"volume.path": str(volumes_dir / REAL["ct_head"])}))
    img = make_renderer(scene, {"name": "vtk"}).render(_front_view(scene), 64)
    lit = img.max(axis=2) > 20
    assert 0.3 < lit.mean() < 0.9
    # lit structure (skin over skull), not just a faint haze
    assert (img.max(axis=2) > 150).mean() > 0.05
