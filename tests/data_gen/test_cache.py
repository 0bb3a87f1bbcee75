"""The (view, image) cache: layout, hashing, no re-rendering, crash safety (SIGKILL), errors."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

import data_gen  # noqa: F401
from data_gen.cache import LOG, ViewImageCache, cache_path_for, read_log, render_cache
from data_gen.cache_log import forget_checked
from imls_lightning.base.errors import InputError
from imls_lightning.render import make_renderer
from data_gen.scenes import build_scene
from tests.data_gen.helpers import VTK
from tests.data_gen.helpers import cache_data as _data

ROOT = Path(__file__).resolve().parents[2]


def _log_lines(path: Path) -> int:
    return len([ln for ln in (path / LOG).read_bytes().split(b"\n") if ln])


# ---- layout --------------------------------------------------------------------------------
def test_smoke_cache_layout_and_contents(tmp_path, tiny_scene):
    rep = render_cache(tiny_scene, _data(tmp_path), VTK, progress=False)
    assert rep.rendered == 16 and rep.already_done == 0
    path = rep.path
    assert path.parent == tmp_path / "cache" and path.name.startswith("tiny-") and len(path.name) == len("tiny-") + 12
    c = ViewImageCache.open(path)
    assert c.views.shape == (16, 9) and c.views.dtype == np.float32
    assert c.images.shape == (16, 24, 24, 3) and c.images.dtype == np.uint8
    assert isinstance(c.images, np.memmap) and not c.images.flags.writeable
    assert c.render_seconds.shape == (16,) and np.all(c.render_seconds > 0)
    assert np.allclose(np.load(path / "render_seconds.npy"), c.render_seconds)
    tr, va, te = (c.splits[k] for k in ("train", "val", "test"))
    assert (len(tr), len(va), len(te)) == (9, 1, 6)
    np.testing.assert_array_equal(np.sort(np.concatenate([tr, va, te])), np.arange(16))
    np.testing.assert_array_equal(te, np.arange(10, 16))
    assert all((c.images[i].max(axis=2) > 10).mean() > 0.05 for i in range(16))  # nothing empty
    m = c.manifest
    assert m["counts"] == {"train": 9, "val": 1, "test": 6, "total": 16} and m["complete"] == 16
    assert m["resolution"] == 24 and m["view_angle"] == tiny_scene.view_angle
    assert m["scene"]["volume"]["fingerprint"] == tiny_scene.volume.fingerprint()
    assert m["scene"]["transfer_function"] == tiny_scene.transfer_function.to_dict()
    assert m["renderer"]["pixel_settings"] == {"name": "vtk", "mapper": "fixed_point", "revision": 2}
    # the resolved sample distance (tiny.yaml: auto = half a voxel), in both units, keyed and recorded
    assert m["sample_distance"] == {"normalized": tiny_scene.sample_distance, "voxels": 0.5,
                                    "voxel_size_normalized": 2 * tiny_scene.sample_distance}
    assert m["settings"]["scene"]["sample_distance"] == tiny_scene.sample_distance
    assert m["settings"]["scene"]["sample_distance_voxels"] == 0.5
    assert m["renderer"]["version"].startswith("vtk ")
    assert m["runs"][-1]["rendered"] == 16
    # every entry equals a fresh render of its stored view (and can be re-rendered from the manifest)
    r = make_renderer(tiny_scene, VTK)
    for i in (0, 9, 15):
        np.testing.assert_array_equal(r.render(c.views[i], 24), c.images[i])
    np.testing.assert_array_equal(c.rerender(3), c.images[3])
    assert len(c.verify()) == 0


def test_rerun_renders_nothing(tmp_path, tiny_scene):
    d = _data(tmp_path)
    first = render_cache(tiny_scene, d, VTK, progress=False)
    lines, mtime = _log_lines(first.path), (first.path / "images.npy").stat().st_mtime_ns
    again = render_cache(tiny_scene, d, {**VTK, "threads": 1}, progress=False)  # threads: not in the key
    assert again.path == first.path and again.rendered == 0 and again.already_done == 16
    assert _log_lines(first.path) == lines
    assert (first.path / "images.npy").stat().st_mtime_ns == mtime
    assert cache_path_for(tiny_scene, d, VTK) == first.path


def test_key_changes_with_pixel_settings(tmp_path, tiny_scene):
    base = cache_path_for(tiny_scene, _data(tmp_path), VTK)
    for kw in ({"resolution": 32}, {"num_views": 11}, {"seed": 1}, {"test_views": 5}, {"val_fraction": 0.2}):
        assert cache_path_for(tiny_scene, _data(tmp_path, **kw), VTK) != base, kw
    assert cache_path_for(tiny_scene, _data(tmp_path), {**VTK, "mapper": "gpu"}) != base
    # the sample distance: auto keys by the step it resolves to, whichever way the step is given
    cfg = OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml")
    quarter = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.25}), volume=tiny_scene.volume)
    assert cache_path_for(quarter, _data(tmp_path), VTK) != base
    half = build_scene(OmegaConf.merge(cfg, {"sample_distance_voxels": 0.5}), volume=tiny_scene.volume)
    assert cache_path_for(half, _data(tmp_path), VTK) == base
    # settings that do not change pixels keep the key
    assert cache_path_for(tiny_scene, _data(tmp_path, workers=3, batch_size=99), {**VTK, "threads": 7}) == base


def test_cache_key_is_the_manifests_and_follows_the_volumes_content(tmp_path, tiny_scene):
    """``cache_key`` (what a training run records) is the key render_cache names the cache by, computed without
    rendering, and it changes when only the volume's voxels do (same name, same settings)."""
    from data_gen.cache_keys import cache_key
    from imls_lightning.render.volume import Volume

    d = _data(tmp_path)
    report = render_cache(tiny_scene, d, VTK, progress=False)
    manifest = json.loads((report.path / "manifest.json").read_text())
    assert cache_key(tiny_scene, d, VTK) == manifest["hash"] == report.path.name.rsplit("-", 1)[1]
    v = tiny_scene.volume
    cfg = OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml")
    touched = v.data.copy()
    touched[0, 0, 0] += 0.5
    other = build_scene(cfg, volume=Volume(touched, v.spacing, v.value_range, v.name, v.source, v.info))
    assert other.name == tiny_scene.name and cache_key(other, d, VTK) != manifest["hash"]


# ---- crash safety ---------------------------------------------------------------------------
def test_half_written_entry_without_marker_is_rerendered(tmp_path, tiny_scene):
    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    ref = np.array(ViewImageCache.open(path).images)
    # simulate a crash while view 7 was being written: its log line is gone (or torn) and its
    # pixels are garbage; view 3's line is corrupted (bad checksum)
    lines = (path / LOG).read_bytes().split(b"\n")
    keep = [ln for ln in lines if ln and not ln.startswith(b"7 ") and not ln.startswith(b"3 ")]
    line3 = next(ln for ln in lines if ln.startswith(b"3 "))
    bad3 = line3[:-1] + (b"0" if line3[-1:] != b"0" else b"1")
    (path / LOG).write_bytes(b"\n".join(keep + [bad3]) + b"\n7 1234ab")  # torn tail, no newline
    with open(path / "images.npy", "r+b") as f:
        f.seek(-(16 - 7) * 24 * 24 * 3, os.SEEK_END)
        f.write(b"\xff" * 100)
    done, _, _ = read_log(path / LOG, 16)
    assert not done[7] and not done[3] and done.sum() == 14
    with pytest.raises(InputError, match="only 14 of 16"):
        ViewImageCache.open(path)
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.rendered == 2 and rep.already_done == 14
    c = ViewImageCache.open(path)
    np.testing.assert_array_equal(np.asarray(c.images), ref)
    assert len(c.verify()) == 0


# ---- trust: changed, truncated and foreign files (issue 17) ---------------------------------
def test_changed_pixels_refused_on_open_and_rerendered(tmp_path, tiny_scene, capsys):
    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    ref = np.array(ViewImageCache.open(path).images)
    a = np.load(path / "images.npy", mmap_mode="r+")
    a[1] = 255
    a.flush()
    del a
    forget_checked()  # as a new process would
    with pytest.raises(InputError, match=r"pixels of 1 view\(s\) do not match their checksums \(rows 1;") as e:
        ViewImageCache.open(path)
    assert "\n" not in str(e.value)
    capsys.readouterr()
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    err = capsys.readouterr().err
    assert rep.rendered == 1 and rep.already_done == 15
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "do not match their checksums (rows 1)" in warnings[0]
    forget_checked()
    np.testing.assert_array_equal(np.asarray(ViewImageCache.open(path).images), ref)


def test_pixel_check_costs_far_less_than_rendering_a_view(tmp_path, tiny_scene):
    from data_gen.cache import bad_views

    path = render_cache(tiny_scene, _data(tmp_path, resolution=128, num_views=4, test_views=0), VTK, progress=False).path
    c = ViewImageCache.open(path)
    t0 = time.perf_counter()
    for _ in range(20):
        assert len(bad_views(c.images, np.arange(4), c.crc)) == 0
    check = (time.perf_counter() - t0) / 80
    assert check < 0.05 * float(np.median(c.render_seconds)), (check, np.median(c.render_seconds))


def test_truncated_images_are_repaired(tmp_path, tiny_scene, capsys):
    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    ref = np.array(ViewImageCache.open(path).images)
    size = (path / "images.npy").stat().st_size
    os.truncate(path / "images.npy", size - 6 * 24 * 24 * 3)  # views 10..15 lose their pixels
    forget_checked()
    with pytest.raises(InputError, match="damaged or unreadable") as e:
        ViewImageCache.open(path)
    assert "\n" not in str(e.value)
    capsys.readouterr()
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.rendered == 6 and rep.already_done == 10
    assert "images.npy is truncated" in capsys.readouterr().err
    np.testing.assert_array_equal(np.asarray(ViewImageCache.open(path).images), ref)
    # a header cut short: everything is checked, and re-rendered
    os.truncate(path / "images.npy", 40)
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.rendered == 16
    np.testing.assert_array_equal(np.asarray(ViewImageCache.open(path).images), ref)


@pytest.mark.parametrize("damage", ["truncate", "delete"])
def test_truncated_or_deleted_views_are_repaired(tmp_path, tiny_scene, capsys, damage):
    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    views = np.load(path / "views.npy")
    if damage == "truncate":
        os.truncate(path / "views.npy", 200)
    else:
        (path / "views.npy").unlink()
    with pytest.raises(InputError, match="damaged or unreadable") as e:
        ViewImageCache.open(path)
    assert "\n" not in str(e.value)
    capsys.readouterr()
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.rendered == 0
    assert "views.npy is missing, truncated or changed" in capsys.readouterr().err
    np.testing.assert_array_equal(ViewImageCache.open(path).views, views)


def test_foreign_folder_with_cache_file_names_is_refused_untouched(tmp_path, tiny_scene):
    """A user's folder holding files named like the cache's own: refused, nothing written (issue 17, 1)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    files = {"views.npy": b"my views", "images.npy": b"my images", "done.log": b"my log\n"}
    for name, data in files.items():
        (mine / name).write_bytes(data)
    with pytest.raises(InputError, match=r"data.cache_path=.*not a cache made by this tool .* choose an empty or new directory") as e:
        render_cache(tiny_scene, _data(tmp_path, cache_path=str(mine)), VTK, progress=False)
    assert "\n" not in str(e.value)
    assert {p.name: p.read_bytes() for p in mine.iterdir()} == files  # untouched, not even a .lock


def test_empty_folder_is_used_and_interrupted_initialisation_redone(tmp_path, tiny_scene):
    mine = tmp_path / "mine"
    mine.mkdir()
    d = _data(tmp_path, cache_path=str(mine))
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.rendered == 16 and (mine / ".imls-cache").is_file()
    # an initialisation cut short (the marker is there, the manifest not yet): redone
    (mine / "manifest.json").unlink()
    assert render_cache(tiny_scene, d, VTK, progress=False).rendered == 16


def test_failed_run_in_empty_folder_leaves_it_empty(tmp_path, tiny_scene, monkeypatch):
    from data_gen import cache as cache_mod

    mine = tmp_path / "mine"
    mine.mkdir()

    def boom(*a, **k):
        raise InputError("boom")

    monkeypatch.setattr(cache_mod, "_initialise", boom)
    with pytest.raises(InputError, match="boom"):
        render_cache(tiny_scene, _data(tmp_path, cache_path=str(mine)), VTK, progress=False)
    assert list(mine.iterdir()) == []


def test_complete_cache_on_read_only_mount_is_read_without_writing(tmp_path, tiny_scene, monkeypatch):
    from data_gen import cache as cache_mod

    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    before = {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in path.iterdir()}
    monkeypatch.setattr(cache_mod, "_dir_writable", lambda p: False)  # root ignores chmod: as on a ro mount
    monkeypatch.setattr(cache_mod, "_prepare_dir", lambda *a: pytest.fail("wrote into a read-only cache"))
    forget_checked()
    rep = render_cache(tiny_scene, d, VTK, progress=False)
    assert rep.path == path and rep.rendered == 0 and rep.already_done == 16
    assert {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in path.iterdir()} == before


def test_resume_after_sigkill(tmp_path):
    """Kill a real parallel run with SIGKILL mid-way; the re-run renders only the rest, and every
    entry equals an uninterrupted render."""
    cache_dir = tmp_path / "cache"
    args = [sys.executable, "-m", "data_gen", "scene=tiny", "data.num_views=300", "data.test_views=20",
            "data.resolution=64", "data.workers=2", f"data.cache_dir={cache_dir}", "progress=false"]
    proc = subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    log = None
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            logs = list(cache_dir.glob("tiny-*/" + LOG))
            if logs and _log_lines(logs[0].parent) >= 20:
                log = logs[0]
                break
            time.sleep(0.005)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # parent and its render workers, mid-run
        proc.communicate(timeout=30)
    assert log is not None, "the run ended before it could be killed"
    path = log.parent
    done_before, _, _ = read_log(path / LOG, 320)
    assert 20 <= done_before.sum() < 320
    scene = build_scene(OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml"))
    d = {"num_views": 300, "test_views": 20, "resolution": 64, "workers": 0, "cache_dir": str(cache_dir)}
    rep = render_cache(scene, d, VTK, progress=False)
    assert rep.path == path
    assert rep.already_done == done_before.sum() and rep.rendered == 320 - done_before.sum()
    ref = render_cache(scene, {**d, "cache_path": str(tmp_path / "ref")}, VTK, progress=False)
    np.testing.assert_array_equal(np.asarray(ViewImageCache.open(path).images), np.asarray(ViewImageCache.open(ref.path).images))


def test_lock_serialises_concurrent_runs(tmp_path, tiny_scene):
    from filelock import FileLock

    d = _data(tmp_path)
    path = render_cache(tiny_scene, d, VTK, progress=False).path
    out = {}
    lock = FileLock(str(path / ".lock"))
    lock.acquire()
    t = threading.Thread(target=lambda: out.setdefault("rep", render_cache(tiny_scene, d, VTK, progress=False)))
    t.start()
    time.sleep(0.5)
    assert t.is_alive()  # waits for the lock holder
    lock.release()
    t.join(timeout=30)
    assert out["rep"].rendered == 0


# ---- errors -------------------------------------------------------------------------------
def test_exception_manifest_of_other_settings(tmp_path, tiny_scene):
    path = render_cache(tiny_scene, _data(tmp_path, cache_path=str(tmp_path / "mine")), VTK, progress=False).path
    before = (path / "manifest.json").read_bytes()
    with pytest.raises(InputError, match=r"belongs to other settings \(differs in resolution\)") as e:
        render_cache(tiny_scene, _data(tmp_path, cache_path=str(path), resolution=16), VTK, progress=False)
    assert "\n" not in str(e.value)
    assert (path / "manifest.json").read_bytes() == before  # untouched


def test_exception_hash_dir_with_foreign_manifest(tmp_path, tiny_scene):
    d = _data(tmp_path)
    path = cache_path_for(tiny_scene, d, VTK)
    path.mkdir(parents=True)
    (path / "manifest.json").write_text(json.dumps({"settings": {"other": 1}}))
    with pytest.raises(InputError, match="other settings"):
        render_cache(tiny_scene, d, VTK, progress=False)


def test_exception_not_a_cache_directory(tmp_path, tiny_scene):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "thesis.tex").write_text("precious")
    with pytest.raises(InputError, match="not a cache"):
        render_cache(tiny_scene, _data(tmp_path, cache_path=str(tmp_path / "notes")), VTK, progress=False)
    assert sorted(p.name for p in (tmp_path / "notes").iterdir()) == ["thesis.tex"]  # not even a .lock


def test_exception_unwritable_cache_dir(tmp_path, tiny_scene):
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match=r"data.cache_dir=.*not writable"):
        render_cache(tiny_scene, _data(tmp_path, cache_dir=str(tmp_path / "file" / "sub")), VTK, progress=False)


@pytest.mark.parametrize("kw, match", [
    ({"resolution": 0}, "data.resolution=0"),
    ({"resolution": -3}, "data.resolution=-3"),
    ({"num_views": 0}, "data.num_views"),
    ({"val_fraction": 1.5}, "data.val_fraction"),
    ({"workers": -1}, "data.workers"),
])
def test_exception_bad_data_settings_write_nothing(tmp_path, tiny_scene, kw, match):
    with pytest.raises(InputError, match=match):
        render_cache(tiny_scene, _data(tmp_path, **kw), VTK, progress=False)
    assert not (tmp_path / "cache").exists()


def test_exception_unknown_renderer_writes_nothing(tmp_path, tiny_scene):
    for r, match in (({"name": "povray"}, "renderer.name"), ({"name": "vtk", "mapper": "magic"}, "renderer.mapper")):
        with pytest.raises(InputError, match=match):
            render_cache(tiny_scene, _data(tmp_path), r, progress=False)
    assert not (tmp_path / "cache").exists()
