"""`python -m data_gen` end to end through Hydra, in a subprocess: output contract and every
documented user error (exit != 0, one line on stderr, no traceback, nothing half-written)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def run_cli(*overrides, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "data_gen", *overrides], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})


def test_smoke_cli_renders_cache_and_contact_sheet(tmp_path):
    cache_dir = tmp_path / "cache"
    p = run_cli("scene=tiny", "data=tiny", "data.num_views=12", "data.resolution=24", f"data.cache_dir={cache_dir}",
                "contact_sheet=true", "contact_sheet_views=8", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.strip().splitlines()
    path = Path(lines[-1])  # the cache directory is the last line
    assert path.parent == cache_dir and path.name.startswith("tiny-")
    assert (path / "manifest.json").is_file() and "render tiny 24x24" in p.stderr  # progress bar
    assert any(ln.startswith("contact sheet: ") for ln in lines[:-1])
    from PIL import Image

    sheet = np.asarray(Image.open(path / "contact_sheet.png"))
    assert sheet.ndim == 3 and sheet.std() > 5
    from data_gen.cache import ViewImageCache

    c = ViewImageCache.open(path)
    assert c.images.shape == (24, 24, 24, 3) and len(c.splits["test"]) == 12
    # Hydra leaves nothing in the working directory
    assert sorted(q.name for q in tmp_path.iterdir()) == ["cache"]
    again = run_cli("scene=tiny", "data=tiny", "data.num_views=12", "data.resolution=24", f"data.cache_dir={cache_dir}", cwd=tmp_path)
    assert again.returncode == 0 and again.stdout.strip().splitlines()[-1] == str(path)
    assert "nothing to render" in again.stderr


def _write_inputs(d: Path) -> dict[str, str]:
    d.mkdir()
    z, y, x = np.mgrid[-1:1:6j, -1:1:6j, -1:1:6j]
    good = (x * x + y * y + z * z).astype(np.float32)
    good.tofile(d / "good_6x6x6_float32.raw")
    good[:3].tofile(d / "short_6x6x6_float32.raw")
    good.tofile(d / "odd_6x6x6_float17.raw")
    good.tofile(d / "vol.xyz")
    nan = good.copy()
    nan[2, 3, 4] = np.nan
    nan.tofile(d / "nan_6x6x6_float32.raw")
    np.full(216, 7, np.float32).tofile(d / "flat_6x6x6_float32.raw")
    np.savetxt(d / "views.txt", np.array([[0, 0, 3, 0, 0, 0, 0, 1, 0], [0, 0, 3, 0, 0, 0, 0, 0, 1]], float))
    (d / "a_file").write_text("x")
    names = {"good": "good_6x6x6_float32.raw", "short": "short_6x6x6_float32.raw", "odd": "odd_6x6x6_float17.raw",
             "xyz": "vol.xyz", "nan": "nan_6x6x6_float32.raw", "flat": "flat_6x6x6_float32.raw", "views": "views.txt",
             "a_file": "a_file"}
    return {k: str(d / v) for k, v in names.items()}


ERRORS = [
    ("missing file", ["scene=file", "scene.volume.path={tmp}/nope_6x6x6_uint8.raw"], "file not found"),
    ("wrong file size", ["scene=file", "scene.volume.path={short}"], "bytes"),
    ("unknown dtype", ["scene=file", "scene.volume.path={odd}"], "dtype"),
    ("unknown extension", ["scene=file", "scene.volume.path={xyz}"], "extension"),
    ("NaN voxels", ["scene=file", "scene.volume.path={nan}"], "nan_to"),
    ("constant volume", ["scene=file", "scene.volume.path={flat}"], "constant"),
    ("degenerate view", ["scene=tiny", "data.test_trajectory={views}"], "parallel"),
    ("resolution 0", ["scene=tiny", "data.resolution=0"], "data.resolution=0"),
    ("negative resolution", ["scene=tiny", "data.resolution=-8"], "data.resolution=-8"),
    ("unwritable cache dir", ["scene=tiny", "data.cache_dir={a_file}/sub"], "not writable"),
    ("bad camera distance", ["scene=tiny", "scene.camera_distance=[0,0]"], "camera_distance"),
    # issue 17, 8: Hydra's 15-line message before
    ("unknown scene", ["scene=no_such_scene"], "scene=no_such_scene: no such scene; expected one of ct_head, "),
    ("bad sample distance", ["scene=tiny", "scene.sample_distance=fine"], "scene.sample_distance='fine'"),
    ("bad sample distance in voxels", ["scene=tiny", "scene.sample_distance_voxels=-1"], "scene.sample_distance_voxels=-1"),
]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_inputs")
    return d, _write_inputs(d / "in")


@pytest.mark.parametrize("what, overrides, match", ERRORS, ids=[e[0] for e in ERRORS])
def test_exception_cli_one_line_errors(inputs, tmp_path, what, overrides, match):
    base, files = inputs
    ov = [o.format(tmp=base, **files) for o in overrides]
    if not any(o.startswith("data.cache_dir=") for o in ov):
        ov.append(f"data.cache_dir={tmp_path / 'cache'}")
    p = run_cli("data=tiny", *ov, cwd=tmp_path)
    assert p.returncode == 2, (what, p.stdout, p.stderr)
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), p.stderr
    assert match in err[0] and "Traceback" not in p.stderr + p.stdout
    assert p.stdout.strip() == ""
    assert not (tmp_path / "cache").exists()  # nothing half-written


def test_exception_cli_manifest_of_other_settings(tmp_path):
    target = tmp_path / "exact"
    ok = run_cli("scene=tiny", "data=tiny", "data.num_views=4", "data.test_views=2", f"data.cache_path={target}", cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    before = {q.name: q.read_bytes() for q in target.iterdir() if q.is_file()}
    p = run_cli("scene=tiny", "data=tiny", "data.num_views=4", "data.test_views=2", "data.resolution=16",
                f"data.cache_path={target}", cwd=tmp_path)
    assert p.returncode == 2
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and "belongs to other settings" in err[0] and "Traceback" not in p.stderr
    assert {q.name: q.read_bytes() for q in target.iterdir() if q.is_file()} == before


def test_exception_cli_refuses_a_folder_of_mine(tmp_path):
    """The user's own views.npy / images.npy / done.log were overwritten without a word (issue 17, 1)."""
    mine = tmp_path / "mine"
    mine.mkdir()
    files = {"views.npy": b"my views", "images.npy": b"my images", "done.log": b"my notes\n"}
    for name, data in files.items():
        (mine / name).write_bytes(data)
    p = run_cli("scene=tiny", "data=tiny", f"data.cache_path={mine}", cwd=tmp_path)
    assert p.returncode == 2, p.stderr
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: data.cache_path={mine}: ") and "not a cache made by this tool" in err[0]
    assert {q.name: q.read_bytes() for q in mine.iterdir()} == files


def test_cli_volume_path_with_non_ascii_characters(tmp_path):
    """volumes_é/... ended in Hydra's lexer traceback (issue 17, 13); spaces work too."""
    for folder in ("volumes_é", "my volumes"):
        d = tmp_path / folder
        d.mkdir()
        (np.arange(216) % 250).astype(np.uint8).tofile(d / "v_6x6x6_uint8.raw")
        p = run_cli("scene=file", f"scene.volume.path={d / 'v_6x6x6_uint8.raw'}", "data=tiny", "data.num_views=4",
                    "data.test_views=2", "data.resolution=16", f"data.cache_dir={tmp_path / 'cache'}", "progress=false", cwd=tmp_path)
        assert p.returncode == 0, p.stderr
        assert Path(p.stdout.strip().splitlines()[-1]).parent == tmp_path / "cache"
