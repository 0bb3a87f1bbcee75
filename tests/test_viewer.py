"""The interactive viewer (imls_lightning.viewer): headless screenshot CLI, event handling, errors."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
FIGSIZE, DPI = (8.0, 4.5), 80  # small figure: fast to draw, still every panel readable


def _run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    # one torch thread: on a shared 2-core machine two spinning OpenMP threads slow every conv down
    e = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", **(env or {}))
    return subprocess.run([sys.executable, "-m", "imls_lightning.viewer", *args], cwd=ROOT, env=e,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def renderer(tiny_checkpoints):
    import torch

    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as OMP_NUM_THREADS=1 in the subprocesses (shared 2-core machine)
    yield IMLSRenderer.from_checkpoints(str(tiny_checkpoints["ims"]), opts=NetOptions(device="cpu"))
    torch.set_num_threads(threads)


def _compose(*overrides: str):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_viewer"):
        return compose("viewer", overrides=list(overrides))


@pytest.fixture()
def viewer(renderer):
    from imls_lightning.viewer import Viewer

    return Viewer(renderer, azimuth=30, elevation=20, figsize=FIGSIZE, dpi=DPI, warmup=0)


def _mouse(v, name, x, y, button=1, step=0):
    from matplotlib.backend_bases import MouseEvent

    ev = MouseEvent(name, v.fig.canvas, x, y, button=button, step=step)
    v.fig.canvas.callbacks.process(name, ev)  # through the connections, as a GUI would deliver it


def _key(v, key):
    from matplotlib.backend_bases import KeyEvent

    v.fig.canvas.callbacks.process("key_press_event", KeyEvent("key_press_event", v.fig.canvas, key, 100, 100))


def test_smoke_orbit_view_camera_conventions():
    from imls_lightning.render.camera import camera_basis
    from imls_lightning.viewer import orbit_view

    v = orbit_view(90, 30, 3.0)
    assert np.isclose(np.linalg.norm(v[:3]), 3.0) and np.allclose(v[3:6], 0)
    assert np.isclose(np.degrees(np.arcsin(v[2] / 3.0)), 30) and v[1] > 0 and abs(v[0]) < 1e-12
    _, f, _, up = camera_basis(v)
    assert abs(f @ v[6:9]) < 1e-12 and v[8] > 0 and np.isclose(np.linalg.norm(v[6:9]), 1)


def test_smoke_screenshot_cli_writes_png_with_both_panels(tiny_checkpoints, viewer, tmp_path):
    import matplotlib.image as mpimg

    out = tmp_path / "shots" / "viewer.png"
    r = _run(f"ims_checkpoint={tiny_checkpoints['ims_pim']}", f"screenshot={out}", "azimuth=30", "elevation=20",
             f"figsize=[{FIGSIZE[0]},{FIGSIZE[1]}]", f"dpi={DPI}", "options.device=cpu")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == str(out)
    assert out.is_file() and not [p for p in out.parent.iterdir() if p != out]  # no temporary left behind
    png = mpimg.imread(out)[..., :3]
    assert png.shape[:2] == (round(FIGSIZE[1] * DPI), round(FIGSIZE[0] * DPI))
    crops = {}
    for name in ("imls", "truth", "mask"):
        r0, r1, c0, c1 = viewer.panel_box(name)  # same figsize/dpi/layout in this process
        crop = png[r0 + 2:r1 - 2, c0 + 2:c1 - 2]
        assert crop.size > 0
        crops[name] = crop
        # the figure background is white: a panel shows an image (the mask may be empty for this IMS)
        assert np.mean(np.all(crop > 0.98, axis=-1)) < 0.5, name
    # the volume is drawn in both frames, with structure (the tiny scene's background is black)
    for name in ("imls", "truth"):
        assert crops[name].mean(axis=-1).std() > 0.02, name
        assert np.mean(crops[name].max(axis=-1) > 0.15) > 0.02, name
    # the IML/S frame is the viewer's own render, not a copy of the ray cast
    h = min(crops["imls"].shape[0], crops["truth"].shape[0])
    w = min(crops["imls"].shape[1], crops["truth"].shape[1])
    assert np.abs(crops["imls"][:h, :w] - crops["truth"][:h, :w]).mean() > 1e-3


def test_smoke_viewer_events_change_view_and_rerender(viewer, tmp_path):
    from imls_lightning.viewer import IMLS_STAGES, RAY_CAST

    v = viewer
    assert v.frames == 1 and v.ray_casts == 1 and not v.truth_stale
    assert v.imls.image.shape == v.truth.image.shape == (v.renderer.fr_size, v.renderer.fr_size, 3)
    text = v.latency_text()
    for stage in (*IMLS_STAGES, RAY_CAST, "IPR", "PSNR"):
        assert stage in text, stage
    # (the fast_dev_run IMS of the fixture may select no pixel at all: IPR 0 is legal)
    assert np.isfinite(v.psnr) and 0 <= v.imls.info["ipr"] <= 1
    assert v.imls.info["rendered_pixels"] == int(v.imls.info["im"].sum())
    view0, truth0 = v.view().copy(), v.truth.image.copy()
    assert np.array_equal(v.imls_view, view0) and np.array_equal(v.truth_view, view0)

    # left drag: each motion renders the IML/S frame only; the release ray-casts the final view
    _mouse(v, "button_press_event", 200, 150)
    _mouse(v, "motion_notify_event", 230, 150)
    _mouse(v, "motion_notify_event", 260, 170)
    assert v.frames == 3 and v.ray_casts == 1 and v.truth_stale
    assert "release to update" in v.latency_text()
    assert v.azimuth == pytest.approx(30 - 0.4 * 60) and v.elevation == pytest.approx(20 - 0.4 * 20)
    assert not np.allclose(v.view(), view0)
    assert np.array_equal(v.imls_view, v.view())  # the IML/S frame is of the new camera
    _mouse(v, "button_release_event", 260, 170)
    assert v.ray_casts == 2 and not v.truth_stale and "release" not in v.latency_text()
    assert np.array_equal(v.truth_view, v.view()) and not np.array_equal(v.truth.image, truth0)  # the volume turned
    # a drag with another button, or motion without a press, does nothing
    _mouse(v, "button_press_event", 200, 150, button=3)
    _mouse(v, "motion_notify_event", 250, 190, button=3)
    _mouse(v, "button_release_event", 250, 190, button=3)
    assert v.frames == 4 and v.azimuth == pytest.approx(6.0)

    # scroll: zoom in, clamped to the scene's camera distance range
    d0 = v.distance
    _mouse(v, "scroll_event", 200, 150, button="up", step=1)
    assert v.distance == pytest.approx(max(d0 * 0.9, v.distance_range[0])) and v.ray_casts == 3
    for _ in range(30):
        v.zoom(-1)
    assert v.distance == v.distance_range[1]

    # keys: arrows orbit, m toggles the mask panel, r resets
    az = v.azimuth
    _key(v, "left")
    assert v.azimuth == pytest.approx(az + 10)
    assert v.axes["mask"].get_visible()
    _key(v, "m")
    assert not v.axes["mask"].get_visible() and not v.show_mask
    _key(v, "r")
    assert (v.azimuth, v.elevation, v.distance) == v.home and np.allclose(v.view(), view0)
    for _ in range(20):
        v.orbit(0, 10)
    assert v.elevation == 89.0  # clamped: the up vector never becomes parallel to the view
    v.update()
    assert v.save_screenshot(tmp_path / "s.png").is_file()


def test_exception_bad_checkpoint_path_names_ims_checkpoint(tmp_path):
    r = _run(f"ims_checkpoint={tmp_path / 'missing.ckpt'}", f"screenshot={tmp_path / 'x.png'}")
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "ims_checkpoint" in err[0], r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "x.png").exists()


def test_exception_no_display_without_screenshot(tiny_checkpoints):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MPLBACKEND")}
    r = subprocess.run([sys.executable, "-m", "imls_lightning.viewer", f"ims_checkpoint={tiny_checkpoints['ims']}"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode != 0
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and "screenshot=" in err[0] and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("arg, name", [("elevation=95", "elevation"), ("elevation=-90", "elevation"),
                                       ("azimuth=abc", "azimuth"), ("screenshot=out.jpg", "screenshot"),
                                       ("mask=maybe", "mask")])
def test_exception_bad_arguments_fail_before_loading(tmp_path, arg, name):
    from imls_lightning.base.errors import InputError
    from imls_lightning.viewer import viewer

    args = [f"ims_checkpoint={tmp_path / 'never_read.ckpt'}", arg]
    if not arg.startswith("screenshot"):
        args.append(f"screenshot={tmp_path / 'x.png'}")
    with pytest.raises(InputError, match=f"^{name}="):
        viewer(_compose(*args))
    with pytest.raises(InputError, match="^ims_checkpoint: required"):
        viewer(_compose(f"screenshot={tmp_path / 'x.png'}"))


def test_exception_unwritable_screenshot_path_fails_before_loading(tmp_path):
    """An unwritable screenshot= path failed with a PermissionError after all the work (issue 17, 12)."""
    from imls_lightning.base.errors import InputError
    from imls_lightning.viewer import viewer

    (tmp_path / "a_file").write_text("x")
    (tmp_path / "dir.png").mkdir()
    for shot, needle in ((tmp_path / "a_file" / "sub" / "x.png", "is not a directory"),
                         (tmp_path / "dir.png", "is a directory"),
                         (Path("/proc/imls_no_such/x.png"), "cannot write into /proc")):
        with pytest.raises(InputError, match=f"^screenshot={shot}: .*{needle}") as e:
            viewer(_compose(f"ims_checkpoint={tmp_path / 'never_read.ckpt'}", f"screenshot={shot}"))
        assert "\n" not in str(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "dir.png"]  # no probe left behind


def test_exception_viewer_distance_outside_scene_range(renderer):
    from imls_lightning.base.errors import InputError
    from imls_lightning.viewer import Viewer, orbit_view

    hi = renderer.renderer.scene.camera_distance[1]
    with pytest.raises(InputError, match="distance="):
        Viewer(renderer, distance=hi + 1.0, figsize=FIGSIZE, dpi=DPI, warmup=0)
    with pytest.raises(InputError, match="elevation="):
        orbit_view(0, -90, 3.0)


def test_the_viewer_opens_at_the_recorded_operating_point(tiny_checkpoints, tmp_path, capsys):
    """The desktop viewer's renderer comes from IMLSRenderer.from_checkpoints: it runs at the
    evaluation's record beside the IMS checkpoint, and the IML/S panel's title says at which u."""
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions
    from imls_lightning.viewer import Viewer

    ckpt = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ckpt)
    write_operating_point(ckpt, ORPRecord(mean=0.45, lift=False, c_share=0.3, ipr=0.08, epsilon_db=1.0))
    r = IMLSRenderer.from_checkpoints(str(ckpt), opts=NetOptions(device="cpu"))
    v = Viewer(r, figsize=FIGSIZE, dpi=DPI, warmup=0)
    assert r.mean == 0.45 and v.axes["imls"].get_title() == "IML/S + RecNN (share of C 0.45)"
    assert "running at the evaluation's operating point u = 0.450" in capsys.readouterr().err
    assert _compose(f"ims_checkpoint={ckpt}").share is None  # the viewer's default: the recorded point
    assert _compose(f"ims_checkpoint={ckpt}", "share=0.3").share == 0.3  # the documented key (mean: its older name)
    v.close()
