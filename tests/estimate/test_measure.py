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

from imls_lightning.base.errors import InputError
from imls_lightning.core.patterns import downsample_pattern, foveal_pattern
from imls_lightning.estimate.measure import (ViewMeasurement, gaussian_blur, object_pixels, render_cost, silhouette_mask,
                                             upsample_c_image)
from tests.estimate.helpers import CostedRenderer

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
    return ViewMeasurement(0.0, 0.0, empty, obj, bg, n_obj, n_bg, 30.0, z, z, np.zeros(0, bool))


def test_render_cost_takes_the_fixed_cost_off_and_medians_over_views():
    views = [_view(1.0, 11.0, 2.0, 1000, 1000), _view(2.0, 22.0, 3.0, 2000, 500), _view(1.5, 9.5, 1.5, 1000, 0)]
    cost = render_cost(views)
    assert cost.fixed_ms == 1.5
    assert cost.object_ms_per_px == pytest.approx(np.median([0.01, 0.01, 0.008]))
    assert cost.background_ms_per_px == pytest.approx(np.median([0.001, 0.002]))
    assert (cost.object_px, cost.background_px) == (1000, 500)


def test_gaussian_blur_matches_a_direct_sum_and_keeps_a_constant():
    x = torch.rand(1, 1, 9, 11, dtype=torch.float64)
    sigma, r = 1.3, 4
    w = np.exp(-np.arange(-r, r + 1) ** 2 / (2 * sigma**2))
    w /= w.sum()
    a = x[0, 0].numpy()
    direct = np.zeros_like(a)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            for di in range(-r, r + 1):
                for dj in range(-r, r + 1):   # replicated edges: indices clamped
                    direct[i, j] += w[di + r] * w[dj + r] * a[min(max(i + di, 0), 8), min(max(j + dj, 0), 10)]
    np.testing.assert_allclose(gaussian_blur(x, sigma)[0, 0].numpy(), direct, atol=1e-12)
    assert torch.allclose(gaussian_blur(torch.full((1, 1, 6, 6), 0.3), 2.0), torch.full((1, 1, 6, 6), 0.3))
    assert gaussian_blur(x, 0.0) is x


def test_silhouette_mask_keeps_the_object_then_its_surroundings_then_the_floor():
    """The shape of flame_whole's trained IMS masks: the object nearly whole, the background next to it denser than
    the background far from it, every region above zero (the floor); the share is the one asked for."""
    p = downsample_pattern(128, 2)                      # 64^2 C
    yy, xx = np.divmod(np.arange(p.count), 64)
    on_object = (abs(yy - 32) < 8) & (abs(xx - 32) < 8)     # a 16^2 square: 6% of C
    dist = np.maximum(abs(yy - 32) - 8, abs(xx - 32) - 8)
    pix = silhouette_mask(on_object, 0.25, p, blur=4.0, floor=0.25)
    kept = np.isin(p.indices.numpy(), pix)
    assert abs(kept.mean() - 0.25) < 0.01
    near, far = kept[(dist >= 1) & (dist < 6)].mean(), kept[dist >= 20].mean()
    assert kept[on_object].mean() > 0.95 and near > 2 * far and far > 0.05
    sharp = np.isin(p.indices.numpy(), silhouette_mask(on_object, 0.25, p, blur=0.0, floor=0.25))
    assert sharp[(dist >= 1) & (dist < 6)].mean() < near    # the blur is what spills onto the surroundings
    with pytest.raises(InputError, match=r"on_object: expected \(4096,\) bool") as e:
        silhouette_mask(on_object[:10], 0.25, p)
    assert "\n" not in str(e.value)


def test_a_sharpened_silhouette_mask_moves_the_floor_onto_the_object():
    """sharpness = gamma: the mask a sharpened IMS makes (the head's formula on the floored importance); at the
    same share the far background keeps fewer pixels and the object more (all of it here) than at gamma = 1;
    gamma = 1 is the paper's mask, pixel for pixel."""
    p = downsample_pattern(128, 2)                      # 64^2 C
    yy, xx = np.divmod(np.arange(p.count), 64)
    on_object = (abs(yy - 32) < 12) & (abs(xx - 32) < 12)   # 14% of C, as flame_whole's object
    dist = np.maximum(abs(yy - 32) - 12, abs(xx - 32) - 12)
    idx = p.indices.numpy()
    masks = {g: np.isin(idx, silhouette_mask(on_object, 0.25, p, blur=4.0, floor=0.25, sharpness=g)) for g in (1.0, 2.0, 3.0)}
    assert np.array_equal(masks[1.0], np.isin(idx, silhouette_mask(on_object, 0.25, p, blur=4.0, floor=0.25)))
    far = dist >= 12
    for g in (1.0, 2.0, 3.0):
        assert abs(masks[g].mean() - 0.25) < 0.01
    assert masks[1.0][far].mean() > masks[2.0][far].mean() > masks[3.0][far].mean()
    assert masks[1.0][on_object].mean() <= masks[2.0][on_object].mean() <= masks[3.0][on_object].mean()
    with pytest.raises(InputError, match=r"sharpness=0.5: expected a number in \[1, 8\]"):
        silhouette_mask(on_object, 0.25, p, sharpness=0.5)


#: ms per pixel of the three views of :func:`_costed_views` (the close one 3x the far one)
PER_PX = {0: 1.0, 1: 3.0, 2: 2.0}


def _costed_views(monkeypatch, drift: float = 1.0):
    """A 64^2 downsampling pattern whose top quarter of C is the object, a renderer of known cost per pixel and view
    (:data:`PER_PX`) put in place of the timing, and three views measured at ``drift`` times that cost (the estimate's
    whole-pattern times, taken earlier than a render curve's pass)."""
    import imls_lightning.estimate.measure as measure

    p = downsample_pattern(64, 2)
    on_object = np.zeros(p.count, bool)
    on_object[: p.count // 4] = True
    renderer = CostedRenderer(PER_PX)
    monkeypatch.setattr(measure, "median_ms", renderer.median_ms)
    z = np.zeros((2, 2, 3), np.uint8)
    views = [ViewMeasurement(0.0, drift * PER_PX[v] * p.count, 0.0, 0.0, 0.0, p.count // 4, p.count - p.count // 4, 30.0,
                             z, z, on_object) for v in (0, 1, 2)]
    return p, on_object, renderer, views


def test_render_curve_averages_each_views_fraction_of_its_own_pattern(monkeypatch):
    """Views of unequal cost (the close one 3x the far one): each view's times as fractions of its own whole
    pattern, put on that view's pattern and averaged; a median per share jumped between views. A renderer whose
    cost is known (per pixel, per view) stands for the timing."""
    import imls_lightning.estimate.measure as measure

    p, on_object, renderer, views = _costed_views(monkeypatch)
    shares = (0.25, 0.5, 1.0)
    per_view: list = []
    curve = measure.render_curve(renderer, p, [0, 1, 2], views, shares, blur=0.0, floor=0.25, repeats=1, fixed_ms=0.0,
                                 per_view=per_view)
    kept = [len(silhouette_mask(on_object, s, p, 0.0, 0.25)) for s in shares]
    np.testing.assert_allclose(per_view, [[k / p.count for k in kept]] * 3, rtol=1e-12)   # each view's own fractions
    # every view's fraction of its pattern is kept / count, on that view's own pattern (1, 3, 2 ms per pixel), averaged
    assert curve.times_ms == pytest.approx(tuple(np.mean([1.0, 3.0, 2.0]) * k for k in kept), rel=1e-12)
    assert list(curve.times_ms) == sorted(curve.times_ms)


@pytest.mark.parametrize("shares", [(0.25, 0.5, 1.0), (0.25, 0.5)])
def test_render_curve_divides_by_the_whole_pattern_timed_in_its_own_pass(monkeypatch, shares):
    """The estimate's whole-pattern times (``c_render_ms``) were taken earlier and read 25% slow against the pass
    that renders the masks (the same pixels timed minutes apart): each fraction is of the pass's own whole pattern,
    so share 1 costs exactly the RecNN alone's render, and the bound there stays under 1x."""
    import imls_lightning.estimate.measure as measure
    from imls_lightning.estimate import RenderCost, slower_render, speedup_at

    drift = 1.25
    p, on_object, renderer, views = _costed_views(monkeypatch, drift)
    per_view: list = []
    curve = measure.render_curve(renderer, p, [0, 1, 2], views, shares, blur=0.0, floor=0.25, repeats=1, fixed_ms=0.0,
                                 per_view=per_view)
    kept = [len(silhouette_mask(on_object, s, p, 0.0, 0.25)) for s in shares]
    np.testing.assert_allclose(per_view, [[k / p.count for k in kept]] * 3, rtol=1e-12)
    c_render = drift * 2.0 * p.count      # the views' mean pattern as the estimate measured it (1, 3, 2 ms a pixel)
    assert curve.times_ms == pytest.approx(tuple(c_render * k / p.count for k in kept), rel=1e-12)
    # one extra render per view of the whole pattern only where the shares stop short of 1
    assert renderer.calls.count(p.count) == 3
    if shares[-1] == 1.0:
        assert curve.times_ms[-1] == pytest.approx(c_render, rel=1e-12)
        flat = RenderCost(fixed_ms=0.0, object_ms_per_px=0.0, background_ms_per_px=0.0, object_px=1, background_px=1)
        assert speedup_at(slower_render(curve, flat), 1.0, c_render_ms=c_render, nets_ms=10.0, recnn_ms=5.0) < 1.0


def test_render_curves_time_every_sharpness_in_one_pass_and_each_pixel_set_once(monkeypatch):
    """Two sharpnesses in one pass: each curve is the one its sharpness gets alone, and a view's whole pattern (every
    sharpness's share-1 mask) is cast once, not once per sharpness."""
    import imls_lightning.estimate.measure as measure

    p, on_object, renderer, views = _costed_views(monkeypatch)
    shares = (0.3, 0.6, 1.0)
    kw = dict(blur=2.0, floor=0.25, repeats=1, fixed_ms=0.0)
    fractions: dict = {}
    curves = measure.render_curves(renderer, p, [0, 1, 2], views, shares, sharpnesses=(1.0, 3.0), per_view=fractions, **kw)
    calls = list(renderer.calls)
    assert calls.count(p.count) == 3 and len(calls) == 3 * 5   # per view: 2 x 2 masks below share 1, the whole once
    for g in (1.0, 3.0):
        alone: list = []
        single = measure.render_curve(renderer, p, [0, 1, 2], views, shares, sharpness=g, per_view=alone, **kw)
        assert curves[g].times_ms == pytest.approx(single.times_ms, rel=1e-12)
        np.testing.assert_allclose(fractions[g], alone, rtol=1e-12)
    sharp = [len(silhouette_mask(on_object, s, p, 2.0, 0.25, 3.0)) for s in shares[:2]]
    plain = [len(silhouette_mask(on_object, s, p, 2.0, 0.25)) for s in shares[:2]]
    assert sharp != plain   # the two sharpnesses' masks differ, so both were cast


def _cli(tmp_path, *extra):
    env = dict(os.environ, IMLS_RUNS_DIR=str(tmp_path))
    # the needed share (20 masks rendered and rebuilt per view) only where a test asks for it: the suite's time
    args = ["scene=tiny", "resolution=32", "views=2", "repeats=1", "warmup=0", "options.half=false",
            "recnn_sizes.enhancenet.channels=4", "recnn_sizes.enhancenet.blocks=1", "needed_share=false", *extra]
    return subprocess.run([sys.executable, "-m", "imls_lightning.estimate", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def _cli_here(tmp_path, monkeypatch, *extra):
    """:func:`_cli` in this process (:func:`tests.cli.run_in_process`), for the documented errors of the settings."""
    from tests.cli import run_in_process

    monkeypatch.setenv("IMLS_RUNS_DIR", str(tmp_path))
    args = ["scene=tiny", "resolution=32", "views=2", "repeats=1", "warmup=0", "options.half=false",
            "recnn_sizes.enhancenet.channels=4", "recnn_sizes.enhancenet.blocks=1", "needed_share=false", *extra]
    return run_in_process("imls_lightning.estimate", args)


def test_cli_writes_the_estimate_and_reuses_it(tmp_path):
    r = _cli(tmp_path)
    assert r.returncode == 0, r.stderr
    path = Path(r.stdout.strip().splitlines()[-1])
    est = json.loads(path.read_text())
    for key in ("c_render_ms", "nets_ms", "recnn_ms", "bilinear_db", "bound", "share_for_2x"):
        assert key in est
    # the bound renders exactly a silhouette mask's pixels at each share: its speed-ups are the formula on that curve
    # (or the per-pixel model's, where that is slower)
    curve = est["render_curve"]
    assert curve["shares"] == pytest.approx([0.1 * i for i in range(1, 11)]) and all(t >= 0 for t in curve["times_ms"])
    from imls_lightning.estimate import RenderCost

    model = RenderCost(**est["render_cost"])
    alone = est["c_render_ms"] + est["recnn_ms"]
    for b, t, sil, s in zip(est["bound"], curve["times_ms"], est["silhouette_ms"], curve["shares"]):
        assert t == pytest.approx(max(sil, model.render_ms(s, est["background_density"])), rel=1e-12)
        assert b["speedup"] == pytest.approx(alone / (est["nets_ms"] + t + est["recnn_ms"]), rel=1e-9)
    assert len(est["bound_modelled"]) == len(est["bound_silhouette"]) == 10 and est["silhouette_blur"] == 4.0
    assert "per-px model" in r.stdout and "silhouette " in r.stdout
    assert "render curve: view 2/2" in r.stderr
    assert [b["share"] for b in est["bound"]] == pytest.approx([0.1 * i for i in range(1, 11)])
    assert all(np.isfinite(b["speedup"]) and b["speedup"] > 0 for b in est["bound"])
    assert est["volume_dims"] == "32x32x32" and est["fr_size"] == 32 and est["c_size"] == 16
    assert 0 <= est["object_fraction"] <= 1 and np.isfinite(est["bilinear_db"])
    assert (path.parent / "contact_sheet.png").is_file()
    assert "speed-up" in r.stdout
    # the bound's interval over the views resampled, at every share, and its line on stdout
    from imls_lightning.estimate import estimate_interval

    assert [x["share"] for x in est["bound_interval"]] == pytest.approx([0.1 * i for i in range(1, 11)])
    mid = estimate_interval(est, 0.3)
    assert mid.speedup == pytest.approx(est["bound"][2]["speedup"], rel=1e-9)
    assert (est["bound_interval"][2]["low"], est["bound_interval"][2]["high"]) == (pytest.approx(mid.low), pytest.approx(mid.high))
    assert "95% interval over the 2 views resampled" in r.stdout
    # both ray casters (both_ray_casters, default): the other one times the same pattern and masks; the bound against
    # the faster RecNN alone takes the faster render on each side, share by share
    rc = est["ray_casters"]
    assert rc["fastest_recnn"] in ("skip", "noskip") and set(rc) >= {"skip", "noskip", "vs_fastest"}
    assert rc["skip"]["c_render_ms"] == pytest.approx(est["c_render_ms"])  # the configured ray caster skips
    fastest = min(rc["skip"]["c_render_ms"], rc["noskip"]["c_render_ms"]) + est["recnn_ms"]
    for vs, sk, no, b in zip(rc["vs_fastest"], rc["skip"]["bound"], rc["noskip"]["bound"], est["bound"]):
        assert sk["speedup"] == pytest.approx(b["speedup"], rel=1e-9)
        renders = [(rc[k]["c_render_ms"] + est["recnn_ms"]) / x["speedup"] for k, x in (("skip", sk), ("noskip", no))]
        assert vs["speedup"] == pytest.approx(fastest / min(renders), rel=1e-9)
    for free, vs in zip(rc["free_networks_vs_fastest"], rc["vs_fastest"]):
        assert free["speedup"] >= vs["speedup"]  # free networks can only be faster
    assert "vs fastest" in r.stdout and "no skipping" in r.stdout and "free IMS+dec" in r.stdout
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
    ("frame_views=0", "frame_views"),
    ("recnn_sizes.enhancenet.channels=0", "channels=0"),
    ("recnn_lead.steps=-1", "recnn_lead.steps"),
    ("recnn_lead.lr=0", "recnn_lead.lr=0"),
    ("epsilon_db=0", "epsilon_db"),
    ("silhouette_blur=-1", "silhouette_blur"),
    ("background_density=2.0", "background_density=2.0"),
    ("background_density=/nonexistent/summary.json", "background_density=/nonexistent/summary.json"),
])
def test_cli_exception_bad_settings(tmp_path, monkeypatch, override, match):
    r = _cli_here(tmp_path, monkeypatch, override)
    assert r.returncode == 2 and not (tmp_path / "estimate").exists()
    last = r.stderr.strip().splitlines()[-1]
    assert match in last and "Traceback" not in r.stderr


@pytest.mark.slow  # 20-25 s of estimate CLI on 2 cores; keeps the default suite under 15 minutes
def test_cli_a_render_curve_per_mask_sharpness(tmp_path):
    """sharpness=[2]: a second render curve, of the silhouette sharpened (by_sharpness["2"]), its bound the formula
    on that curve, reported on stdout; the paper's curve and bound are the same as without it, and the default
    ([1.0]) hashes to the directory of the estimates made before the key."""
    plain = _cli(tmp_path)
    assert plain.returncode == 0, plain.stderr
    base = json.loads(Path(plain.stdout.strip().splitlines()[-1]).read_text())
    assert base["by_sharpness"] == {} and "γ = " not in plain.stdout
    r = _cli(tmp_path, "sharpness=[2]")
    assert r.returncode == 0, r.stderr
    path = Path(r.stdout.strip().splitlines()[-1])
    assert path != Path(plain.stdout.strip().splitlines()[-1])
    est = json.loads(path.read_text())
    two = est["by_sharpness"]["2"]
    assert two["sharpness"] == 2.0 and two["background_density"] == pytest.approx(0.25 ** 2)
    from imls_lightning.estimate import RenderCost, speedup_from_estimate

    model = RenderCost(**est["render_cost"])
    alone = est["c_render_ms"] + est["recnn_ms"]
    for b, t, sil, s in zip(two["bound"], two["render_curve"]["times_ms"], two["silhouette_ms"], two["render_curve"]["shares"]):
        assert t == pytest.approx(max(sil, model.render_ms(s, 0.25 ** 2)), rel=1e-12)
        assert b["speedup"] == pytest.approx(alone / (est["nets_ms"] + t + est["recnn_ms"]), rel=1e-9)
    assert speedup_from_estimate(est, 0.3, 2.0) == pytest.approx(
        alone / (est["nets_ms"] + np.interp(0.3, [0, *two["render_curve"]["shares"]],
                                            [two["render_curve"]["fixed_ms"], *two["render_curve"]["times_ms"]]) + est["recnn_ms"]))
    assert "γ = 2" in r.stdout and "render curve (and sharpness 2): view 2/2" in r.stderr
    # each view's own numbers, which the curves average: fractions of that view's pattern, per share
    assert len(est["per_view"]) == 2 and len(two["silhouette_fractions_per_view"]) == 2
    for v in est["per_view"]:
        assert len(v["silhouette_fractions"]) == len(est["render_curve"]["shares"]) and 0 <= v["object_fraction"] <= 1
        assert v["camera_distance"] > 0 and v["c_render_ms"] > 0
    # each view's fractions on its own pattern's time, averaged; the RecNN alone's render is their mean at share 1
    on_own = np.mean([np.array(v["silhouette_fractions"]) * v["c_render_ms"] for v in est["per_view"]], axis=0)
    assert est["silhouette_ms"] == pytest.approx(on_own.tolist(), rel=1e-9)
    assert est["c_render_ms"] == pytest.approx(np.mean([v["c_render_ms"] for v in est["per_view"]]), rel=1e-12)
    bad = _cli(tmp_path, "sharpness=[1,9]")
    assert bad.returncode != 0 and "sharpness=9: expected a number in [1, 8]" in bad.stderr.strip().splitlines()[-1]


def test_cli_a_recnn_net_override_wins_over_the_default_sizes(tmp_path):
    r = _cli(tmp_path, "recnn.net.channels=6")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    assert est["settings"]["recnn"]["channels"] == 6 and est["settings"]["recnn"]["blocks"] == 1


def test_background_density_from_a_trained_mask(tmp_path):
    """background_density= an evaluation's summary.json (or its folder): the trained mask's background density over
    its object density at the operating point; a number passes as it is."""
    from omegaconf import OmegaConf

    from imls_lightning.estimate.run import background_density

    (tmp_path / "summary.json").write_text(json.dumps({"mask_density": {"object_density": 0.8, "background_density": 0.1}}))
    for value in (str(tmp_path), str(tmp_path / "summary.json")):
        assert background_density(OmegaConf.create({"background_density": value})) == pytest.approx(0.125)
    assert background_density(OmegaConf.create({"background_density": 0.3})) == 0.3
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"orp": {}}))  # written before mask_density existed
    with pytest.raises(InputError, match="mask_density"):
        background_density(OmegaConf.create({"background_density": str(tmp_path / "old")}))


def test_committed_row_gives_the_estimate_its_density():
    from omegaconf import OmegaConf

    from imls_lightning.estimate.run import background_density

    row = Path(__file__).resolve().parents[2] / "benchmarks" / "rows" / "seed_whole" / "point"
    md = json.loads((row / "summary.json").read_text())["mask_density"]
    assert background_density(OmegaConf.create({"background_density": str(row)})) == pytest.approx(
        md["background_density"] / md["object_density"])


def test_table_row_has_the_bound_against_the_fastest(tmp_path):
    """The estimates table's columns against the fastest RecNN alone, from the committed seed_whole estimate; an older
    table (without them) is extended, its rows keeping the new columns empty."""
    import csv

    from imls_lightning.estimate.run import TABLE_COLUMNS, table_row, update_table

    est = json.loads((Path(__file__).resolve().parents[2] / "benchmarks" / "seed_whole" / "estimate_fastest.json").read_text())
    row = table_row(est, tmp_path / "estimate.json")
    rc = est["ray_casters"]
    assert row["vs_fastest_best"] == pytest.approx(max(r["speedup"] for r in rc["vs_fastest"]), rel=1e-3)
    assert row["vs_fastest_at_needed"] == pytest.approx(rc["speedup_vs_fastest_at_needed"], rel=1e-3)
    free = {r["share"]: r["speedup"] for r in rc["free_networks_vs_fastest"]}
    lo, hi = 0.2, 0.3  # the needed share (24%) lies between them
    t = (est["needed_share"] - lo) / (hi - lo)
    assert row["free_networks_vs_fastest_at_needed"] == pytest.approx(free[lo] + t * (free[hi] - free[lo]), rel=1e-3)
    old = tmp_path / "old.csv"
    old_cols = TABLE_COLUMNS[:TABLE_COLUMNS.index("path") + 1]
    old.write_text(",".join(old_cols) + "\n" + ",".join("ct_head" if c == "scene" else "enhancenet" if c == "recnn" else "1"
                                                       for c in old_cols) + "\n")
    update_table(old, row)
    rows = list(csv.DictReader(old.open()))
    assert [r["scene"] for r in rows] == ["ct_head", "seed_whole"] and rows[0]["vs_fastest_best"] == ""


def test_exception_update_table_refuses_a_foreign_csv(tmp_path):
    from imls_lightning.base.errors import InputError
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


def _edge_frames(count: int, m: int = 32, seed: int = 0) -> list[np.ndarray]:
    """Frames of six soft straight edges (about a pixel wide) at random angles: structure a C-Image gives a
    network to complete."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:m, 0:m] + 0.5
    frames = []
    for _ in range(count):
        img = np.zeros((m, m, 3))
        for _ in range(6):
            a, c = rng.uniform(0, np.pi), rng.uniform(0.1, 0.9) * m
            t = (np.cos(a) * (x - m / 2) + np.sin(a) * (y - m / 2) + m / 2 - c) / 0.7
            img += rng.uniform(0.05, 0.15, 3) / (1 + np.exp(-t))[..., None]
        frames.append((np.clip(img, 0, 1) * 255).astype(np.uint8))
    return frames


def test_recnn_lead_grows_with_training_on_edges_and_not_on_noise():
    """The quick RecNN of the third bar: on soft edges, training adds clearly to the lead over bilinear that the
    untrained net's bicubic skip already has; on pixel noise (which no C-Image predicts) it can only learn the
    mean, a lead far below the edges'."""
    from imls_lightning.estimate.measure import recnn_lead
    from imls_lightning.models.enhancenet import EnhanceNet

    p = downsample_pattern(32, 2)

    def lead(frames, steps):
        torch.manual_seed(0)
        return recnn_lead(EnhanceNet(p, channels=8, blocks=1), p, frames[:6], frames[6:], steps=steps, crop=16, batch=8,
                          lr=3e-3)

    untrained, edges = lead(_edge_frames(8), 0), lead(_edge_frames(8), 200)
    noise = lead([(np.random.default_rng(i).random((32, 32, 3)) * 255).astype(np.uint8) for i in range(8)], 200)
    assert all(np.isfinite(v) for v in edges.to_dict().values())
    assert edges.steps == 200 and edges.train_views == 6 and edges.upsampled_db == untrained.upsampled_db
    assert edges.lead_db > untrained.lead_db + 1.0 and edges.lead_db > noise.lead_db + 2.0


def test_exception_recnn_lead_needs_a_regular_grid():
    from imls_lightning.estimate.measure import recnn_lead

    p = foveal_pattern(32, 16)
    with pytest.raises(InputError, match="recnn_lead.steps=5: .*foveal pattern has none") as e:
        recnn_lead(torch.nn.Identity(), p, _edge_frames(1), _edge_frames(1), steps=5)
    assert "\n" not in str(e.value)


@pytest.mark.slow  # 20-25 s of estimate CLI on 2 cores; keeps the default suite under 15 minutes
def test_cli_candidates_get_their_own_quick_recnn_lead(tmp_path):
    """The size table's quality half: each candidate's quick RecNN trains on the chosen size's frames from the same
    seed, so a candidate of the chosen sizes reproduces the chosen lead, and another size gets its own."""
    r = _cli(tmp_path, "recnn_lead.steps=3", "recnn_lead.train_views=1", "recnn_lead.crop=16", "recnn_lead.batch=2",
             "candidates=[{channels: 4, blocks: 1}, {channels: 8, blocks: 2}]")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    same, other = (c["recnn_lead"] for c in est["candidates"])
    assert same == pytest.approx({**est["recnn_lead"], "seconds": same["seconds"]})
    assert np.isfinite(other["lead_db"]) and other["recnn_db"] != same["recnn_db"]
    assert other["upsampled_db"] == pytest.approx(est["bilinear_db"], abs=1e-4)  # scored on the estimate's views
    assert "its quick RecNN" in r.stdout and "candidate {'channels': 8, 'blocks': 2}: RecNN lead" in r.stderr + r.stdout


def test_cli_recnn_lead_reported_and_tabled(tmp_path):
    table = tmp_path / "estimates.csv"
    table.write_text("scene,recnn,volume_dims\nold,enhancenet,8x8x8\n")  # an older table with fewer columns is extended
    r = _cli(tmp_path, "recnn_lead.steps=3", "recnn_lead.train_views=1", "recnn_lead.crop=16", "recnn_lead.batch=2",
             f"table={table}", "needed_share=true")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    lead = est["recnn_lead"]
    assert lead["steps"] == 3 and lead["train_views"] == 1 and np.isfinite(lead["lead_db"])
    assert lead["upsampled_db"] == pytest.approx(est["bilinear_db"], abs=1e-4)  # scored on the estimate's own views
    assert "a RecNN trained 3 steps on 1 views" in r.stdout
    # the quality half: the untrained masks rebuilt by that quick RecNN, every share's gap finite, 0 at the whole pattern
    need = est["needed"]
    assert need["reference"] == "recnn (3 steps)" and len(need["rows"]) == 20
    assert all(np.isfinite(row["gap_db"]) for row in need["rows"])
    assert 1 <= sum(row["render_ms"] is not None and row["render_ms"] >= 0 for row in need["rows"]) <= 2  # around it
    assert need["rows"][-1]["kept"] == 1.0 and need["rows"][-1]["gap_db"] == pytest.approx(0.0, abs=1e-6)
    assert est["needed_share"] is not None and 0.05 <= est["needed_share"] <= 1.0
    assert est["speedup_at_needed"] > 0 and est["bound_at_needed"] > 0 and "needed share within 1 dB" in r.stdout
    import csv

    rows = {row["scene"]: row for row in csv.DictReader(table.open())}
    assert rows["old"]["recnn_lead_db"] == "" and float(rows["tiny"]["recnn_lead_db"]) == pytest.approx(lead["lead_db"], abs=1e-3)
    assert float(rows["tiny"]["needed_share"]) == pytest.approx(est["needed_share"], rel=1e-3) and rows["old"]["needed_share"] == ""


@pytest.mark.slow  # 20-25 s of estimate CLI on 2 cores; keeps the default suite under 15 minutes
def test_cli_needed_share_off_or_without_a_quick_recnn(tmp_path):
    """Without recnn_lead the masks are rebuilt by the classical upsampling; needed_share=false measures nothing."""
    r = _cli(tmp_path, "needed_share=true")
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    assert est["needed"]["reference"] == "bilinear" and len(est["needed"]["rows"]) == 20
    views = [line for line in r.stderr.splitlines() if "needed share: view" in line]   # progress, a line per view
    assert len(views) == est["settings"]["views"] and "20 masks" in views[-1]
    off = _cli(tmp_path, "needed_share=false")
    assert off.returncode == 0, off.stderr
    est = json.loads(Path(off.stdout.strip().splitlines()[-1]).read_text())
    assert est["needed"] is None and est["needed_share"] is None and est["speedup_at_needed"] is None


@pytest.mark.slow  # two estimate CLI runs; keeps the default suite under 15 minutes on 2 cores
def test_cli_an_estimate_timed_beside_other_jobs_says_so_when_reused(tmp_path):
    """The estimate records how many cores other jobs kept busy before it timed; reused, such a file warns in one line."""
    first = _cli(tmp_path)
    assert first.returncode == 0, first.stderr
    path = Path(first.stdout.strip().splitlines()[-1])
    est = json.loads(path.read_text())
    assert est["busy_cores"] is None or 0.0 <= est["busy_cores"] <= os.cpu_count()
    path.write_text(json.dumps({**est, "busy_cores": 1.5}))
    again = _cli(tmp_path)
    assert again.returncode == 0 and "reusing" in again.stderr
    warning = [line for line in again.stderr.splitlines() if "cores busy" in line]
    assert len(warning) == 1 and "1.50 cores busy" in warning[0] and f"delete {path.parent}" in warning[0]
    # a job that started during the timing: the reading before it was quiet, the one around it was not
    assert est["timing_busy_cores"] is None or 0.0 <= est["timing_busy_cores"] <= os.cpu_count()
    path.write_text(json.dumps({**est, "busy_cores": 0.0, "timing_busy_cores": 1.2}))
    late = [line for line in _cli(tmp_path).stderr.splitlines() if "cores busy" in line]
    assert len(late) == 1 and "1.20 cores busy" in late[0]


def test_the_busiest_reading_around_an_estimate_is_the_one_judged():
    from imls_lightning.estimate.run import _busiest

    assert _busiest({"busy_cores": 0.02, "timing_busy_cores": 0.9}) == 0.9  # a job started during the timing
    assert _busiest({"busy_cores": 1.1, "timing_busy_cores": 0.1}) == 1.1
    assert _busiest({"busy_cores": 0.3}) == 0.3  # an estimate from before the reading during it
    assert _busiest({"busy_cores": None, "timing_busy_cores": None}) is None


def test_cli_an_estimate_is_measured_again_when_the_volume_changed(tmp_path):
    """Reuse is by content: a volume replaced at the same path is not served its old estimate."""
    z, y, x = np.mgrid[-1:1:16j, -1:1:16j, -1:1:16j]
    vol = tmp_path / "ball_16x16x16_uint8.raw"
    (200 * np.exp(-4 * (x * x + y * y + z * z))).astype(np.uint8).tofile(vol)
    args = ("scene=file", f"scene.volume.path={vol}", "resolution=16")
    first = _cli(tmp_path, *args)
    assert first.returncode == 0, first.stderr
    assert "reusing" in _cli(tmp_path, *args).stderr
    (200 * np.exp(-9 * (x * x + y * y + z * z))).astype(np.uint8).tofile(vol)  # another volume, same name
    again = _cli(tmp_path, *args)
    assert again.returncode == 0 and "reusing" not in again.stderr
    assert again.stdout.strip().splitlines()[-1] != first.stdout.strip().splitlines()[-1]


def _tiny_networks():
    """A 64^2 FR / 32^2 C downsampling pattern and untrained networks of small sizes for it (:func:`build_networks`)."""
    from imls_lightning.estimate.measure import build_networks

    pattern = downsample_pattern(64, 2)
    return pattern, build_networks(pattern, {"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4,
                                             "blocks": 1},
                                   {"depth": 2, "base_channels": 4}, {"layers": 5, "base_channels": 8, "max_channels": 32})


def test_network_ms_times_the_products_mask_head(monkeypatch):
    """The IMS's stage is timed as the product runs it at a lifted ORP: the generator, then the mask head's sharpen,
    rescale and lift (at the share and the sharpness asked), not a plain threshold; every time is finite."""
    from imls_lightning.estimate.measure import network_ms
    from imls_lightning.inference.pipeline import NetOptions
    from imls_lightning.models.ims import IMSMaskHead

    pattern, nets = _tiny_networks()
    calls = []
    real = IMSMaskHead.threshold

    def spy(self, g, mean=None, lift=False):
        im = real(self, g, mean, lift)
        calls.append((self.sharpness, self.trained_mean, mean, lift, float(im.float().mean())))
        return im

    monkeypatch.setattr(IMSMaskHead, "threshold", spy)
    out = network_ms(nets, pattern, NetOptions(device="cpu"), repeats=3, warmup=1, share=0.25, sharpness=3.0)
    assert set(out) == {"ims_ms", "decoder_ms", "recnn_ms"} and all(np.isfinite(v) and v > 0 for v in out.values())
    assert len(calls) == 4 and {c[:4] for c in calls} == {(3.0, 0.2, 0.25, True)}  # 1 warm-up + 3 timed runs


def test_median_ms_runs_before_untimed_before_every_run():
    """``before`` (the product's ray cast between two network calls) runs ahead of each warm-up and timed run, and its
    time is not counted."""
    import time as _time

    from imls_lightning.estimate.measure import median_ms

    log = []
    ms = median_ms(lambda: log.append("fn"), 3, 2, before=lambda: (_time.sleep(0.03), log.append("before")))
    assert log == ["before", "fn"] * 5
    assert 0.0 <= ms < 10.0  # 30 ms of sleep before each run, none of it timed


def test_network_ms_runs_each_stage_after_before(monkeypatch):
    """Every stage's every call (warm-up and timed) follows a call of ``before``, as in the product each stage follows
    a ray cast; without it nothing runs in between."""
    from imls_lightning.estimate.measure import network_ms
    from imls_lightning.inference.pipeline import NetOptions
    from imls_lightning.models.ims import IMSMaskHead

    pattern, nets = _tiny_networks()
    log = []
    real = IMSMaskHead.threshold

    def spy(self, g, mean=None, lift=False):
        log.append("ims")
        return real(self, g, mean, lift)

    monkeypatch.setattr(IMSMaskHead, "threshold", spy)
    out = network_ms(nets, pattern, NetOptions(device="cpu"), repeats=3, warmup=1, before=lambda: log.append("cast"))
    assert all(np.isfinite(v) and v > 0 for v in out.values())
    assert log[:8] == ["cast", "ims"] * 4 and log[8:] == ["cast"] * 8  # the IMS's 4 calls, then 4 each of the others
    log.clear()
    network_ms(nets, pattern, NetOptions(device="cpu"), repeats=3, warmup=1)
    assert log == ["ims"] * 4


def test_exception_cli_mask_repeats_must_be_positive(tmp_path):
    """``mask_repeats`` (timed runs of each mask's render) below 1: one line naming it, exit 2, nothing written."""
    r = _cli(tmp_path, "mask_repeats=0")
    assert r.returncode == 2 and "mask_repeats" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "estimate").exists()


def _tiny_scene_and_renderer():
    from hydra import compose, initialize_config_dir

    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene, register_resolvers

    register_resolvers()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        cfg = compose(config_name="estimate", overrides=["scene=tiny"])
    scene = build_scene(cfg.scene)
    return scene, make_renderer(scene, cfg.renderer)


class _FrameCounter:
    """The renderer, counting its full-frame renders."""

    def __init__(self, renderer):
        self.renderer, self.frames = renderer, 0

    def render(self, view, resolution):
        self.frames += 1
        return self.renderer.render(view, resolution)

    def render_pixels(self, view, resolution, pixels):
        return self.renderer.render_pixels(view, resolution, pixels)


def test_a_view_timed_without_its_frame_finds_the_same_object_pixels_from_its_pattern():
    """full_frame=False: no FR render; the pattern's own run gives the object pixels the frame gives, and nothing
    is scored (no frame, no PSNR); its object and background are timed apart as a frame view's are."""
    from data_gen.views import sample_training_views
    from imls_lightning.estimate.measure import measure_view

    scene, renderer = _tiny_scene_and_renderer()
    p = downsample_pattern(32, 2)
    view = sample_training_views(1, scene.camera_distance, seed=3)[0]
    spy = _FrameCounter(renderer)
    framed = measure_view(spy, p, view, scene.background, repeats=1, warmup=0)
    assert spy.frames == 1 and framed.fr.shape == (32, 32, 3) and np.isfinite(framed.bilinear_db)
    timed = measure_view(spy, p, view, scene.background, repeats=2, warmup=1, full_frame=False)
    assert spy.frames == 1   # not rendered again
    assert timed.fr is None and timed.upsampled is None and timed.full_ms is None and timed.bilinear_db is None
    assert 0 < timed.object_px < p.count and np.array_equal(timed.on_object, framed.on_object)
    assert (timed.object_px, timed.background_px) == (framed.object_px, framed.background_px)
    assert timed.c_render_ms > 0 and timed.object_ms > 0 and timed.background_ms > 0


def test_cli_frames_only_on_a_subset_spread_over_the_distances(tmp_path):
    """views=3 frame_views=1: every view is timed (the bound, its interval), one renders its frame (the PSNR, the
    contact sheet, the needed share): the view of the middle distance."""
    from PIL import Image

    r = _cli(tmp_path, "views=3", "frame_views=1", "needed_share=true")
    assert r.returncode == 0, r.stderr
    path = Path(r.stdout.strip().splitlines()[-1])
    est = json.loads(path.read_text())
    per_view = est["per_view"]
    assert len(per_view) == 3 and est["settings"]["frame_views"] == 1
    assert [v["full_ms"] is not None for v in per_view].count(True) == 1
    distances = [v["camera_distance"] for v in per_view]
    middle = sorted(range(3), key=distances.__getitem__)[1]
    assert est["frame_view_indices"] == [middle] and per_view[middle]["full_ms"] > 0
    assert len(est["bilinear_db_per_view"]) == 1 and est["bilinear_db"] == est["bilinear_db_per_view"][0]
    assert est["full_frame_ms"] == per_view[middle]["full_ms"]
    assert Image.open(path.parent / "contact_sheet.png").size == (3 * 256, 256)   # one view's row
    assert [line for line in r.stderr.splitlines() if "needed share: view" in line][-1].count("view 1/1") == 1
    assert "95% interval over the 3 views resampled" in r.stdout
    assert all(np.isfinite(b["speedup"]) for b in est["bound"]) and np.isfinite(est["bilinear_db"])
