"""The estimate's measurements (upsampling, object pixels, render cost) and its CLI through Hydra."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from data_gen.errors import InputError
from imls_lightning.core.patterns import downsample_pattern, foveal_pattern
from imls_lightning.estimate.measure import ViewMeasurement, object_pixels, render_cost, upsample_c_image

ROOT = Path(__file__).resolve().parents[2]


def direct_bilinear(c: np.ndarray, m: int, f: int) -> np.ndarray:
    """Loop version: FR pixel i sits at C coordinate i / f (offset 0 for f = 2), edges clamped."""
    n = c.shape[-1]
    out = np.zeros(c.shape[:-2] + (m, m))
    for i in range(m):
        for j in range(m):
            y, x = min(i / f, n - 1), min(j / f, n - 1)
            y0, x0 = int(np.floor(y)), int(np.floor(x))
            y1, x1 = min(y0 + 1, n - 1), min(x0 + 1, n - 1)
            ty, tx = y - y0, x - x0
            out[..., i, j] = ((1 - ty) * (1 - tx) * c[..., y0, x0] + (1 - ty) * tx * c[..., y0, x1]
                              + ty * (1 - tx) * c[..., y1, x0] + ty * tx * c[..., y1, x1])
    return out


def test_bilinear_matches_a_direct_loop_and_keeps_the_samples():
    p = downsample_pattern(16, 2)
    c = torch.rand(1, 3, 8, 8, dtype=torch.float64)
    up, name = upsample_c_image(c, p)
    assert name == "bilinear" and up.shape == (1, 3, 16, 16)
    np.testing.assert_allclose(up.numpy(), direct_bilinear(c.numpy(), 16, 2), atol=1e-6)
    assert torch.allclose(up[..., ::2, ::2].double(), c, atol=1e-6)


def test_foveal_pattern_is_filled_at_the_fr_positions():
    p = foveal_pattern(16, 8, None)
    fr = torch.rand(1, 3, 16, 16)
    c = torch.zeros(1, 3, 8 * 8)
    c[:, :, : p.count] = fr.flatten(2)[:, :, p.indices]
    up, name = upsample_c_image(c.view(1, 3, 8, 8), p)
    assert name == "pull-push"
    assert torch.allclose(up.flatten(2)[:, :, p.indices], fr.flatten(2)[:, :, p.indices], atol=1e-6)
    assert torch.isfinite(up).all()


def test_object_pixels_against_background_colour():
    colours = np.array([[0, 0, 0], [2, 1, 0], [3, 0, 0], [255, 255, 255], [10, 10, 10]], np.uint8)
    assert object_pixels(colours, (0, 0, 0)).tolist() == [False, False, True, True, True]
    assert object_pixels(colours, (1.0, 1.0, 1.0)).tolist() == [True, True, True, False, True]


def _view(empty, obj, bg, n_obj, n_bg):
    z = np.zeros((2, 2, 3), np.uint8)
    return ViewMeasurement(0.0, 0.0, empty, obj, bg, n_obj, n_bg, 30.0, z, z)


def test_render_cost_takes_the_fixed_cost_off_and_medians_over_views():
    views = [_view(1.0, 11.0, 2.0, 1000, 1000), _view(2.0, 22.0, 3.0, 2000, 500), _view(1.5, 9.5, 1.5, 1000, 0)]
    cost = render_cost(views)
    assert cost.fixed_ms == 1.5
    assert cost.object_ms_per_px == pytest.approx(np.median([0.01, 0.01, 0.008]))
    assert cost.background_ms_per_px == pytest.approx(np.median([0.001, 0.002]))
    assert (cost.object_px, cost.background_px) == (1000, 500)


def _cli(tmp_path, *extra):
    env = dict(os.environ, IMLS_RUNS_DIR=str(tmp_path))
    args = ["scene=tiny", "resolution=32", "views=2", "repeats=1", "warmup=0", "options.half=false",
            "recnn_sizes.enhancenet.channels=4", "recnn_sizes.enhancenet.blocks=1", *extra]
    return subprocess.run([sys.executable, "-m", "imls_lightning.estimate", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def test_cli_writes_the_estimate_and_reuses_it(tmp_path):
    r = _cli(tmp_path)
    assert r.returncode == 0, r.stderr
    path = Path(r.stdout.strip().splitlines()[-1])
    est = json.loads(path.read_text())
    for key in ("c_render_ms", "nets_ms", "recnn_ms", "bilinear_db", "bound", "share_for_2x"):
        assert key in est
    assert [b["share"] for b in est["bound"]] == pytest.approx([0.1 * i for i in range(1, 11)])
    assert all(np.isfinite(b["speedup"]) and b["speedup"] > 0 for b in est["bound"])
    assert est["volume_dims"] == "32x32x32" and est["fr_size"] == 32 and est["c_size"] == 16
    assert 0 <= est["object_fraction"] <= 1 and np.isfinite(est["bilinear_db"])
    assert (path.parent / "contact_sheet.png").is_file()
    assert "speed-up" in r.stdout
    table = tmp_path / "estimates.csv"
    again = _cli(tmp_path, f"table={table}")   # the same settings: reused, and its row goes into the table
    assert again.returncode == 0 and "reusing" in again.stderr
    import csv

    rows = list(csv.DictReader(table.open()))
    assert len(rows) == 1 and rows[0]["scene"] == "tiny" and rows[0]["path"] == str(path)
    assert float(rows[0]["bound_10"]) == pytest.approx(est["bound"][0]["speedup"], rel=1e-3)
    _cli(tmp_path, f"table={table}")
    assert len(list(csv.DictReader(table.open()))) == 1   # replaced, not appended
    assert again.stdout.strip().splitlines()[-1] == str(path)


@pytest.mark.parametrize("override,match", [
    ("options.half=maybe", "options.half=maybe"),
    ("target=0.5", "target=0.5"),
    ("views=0", "views"),
    ("recnn_sizes.enhancenet.channels=0", "channels=0"),
])
def test_cli_exception_bad_settings(tmp_path, override, match):
    r = _cli(tmp_path, override)
    assert r.returncode != 0
    last = r.stderr.strip().splitlines()[-1]
    assert match in last and "Traceback" not in r.stderr


def test_cli_a_recnn_net_override_wins_over_the_default_sizes(tmp_path):
    r = _cli(tmp_path, "recnn.net.channels=6")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    assert est["settings"]["recnn"]["channels"] == 6 and est["settings"]["recnn"]["blocks"] == 1


def test_exception_update_table_refuses_a_foreign_csv(tmp_path):
    from data_gen.errors import InputError
    from imls_lightning.estimate.run import update_table

    f = tmp_path / "other.csv"
    f.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match=f"table={f}: its columns") as e:
        update_table(f, {})
    assert "\n" not in str(e.value) and f.read_text() == "a,b\n1,2\n"


def test_cli_candidates_time_more_sizes_on_the_same_render_measurements(tmp_path):
    r = _cli(tmp_path, "candidates=[{channels: 2, blocks: 0}, {channels: 8, blocks: 2, iml.depth: 2}]")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    small, big = est["candidates"]
    assert small["sizes"] == {"channels": 2, "blocks": 0} and big["sizes"]["iml.depth"] == 2
    assert all(np.isfinite(c[k]) and c[k] > 0 for c in (small, big) for k in ("recnn_ms", "nets_ms", "bound_20"))
    assert "sizes {'channels': 2, 'blocks': 0}" in r.stdout


@pytest.mark.parametrize("value, needle", [("[3]", "candidates[0]=3: expected a mapping"), ("[{}]", "candidates[0]={}: expected"),
                                           ("{channels: 8}", "expected a list of mappings")])
def test_exception_bad_candidates(value, needle):
    """The CLI prints this one line and exits 2 (``cli_errors``), before any render."""
    from omegaconf import OmegaConf

    from imls_lightning.estimate.run import check_candidates

    with pytest.raises(InputError) as e:
        check_candidates(OmegaConf.create(f"candidates: {value}"))
    assert needle in str(e.value) and "\n" not in str(e.value)
