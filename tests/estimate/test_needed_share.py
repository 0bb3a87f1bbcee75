"""The quality half of the estimate: the gap of the untrained masks at each share, and the share a scene needs."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.patterns import downsample_pattern
from imls_lightning.estimate.measure import upsample_c_image
from imls_lightning.estimate.needed_share import (NEEDED_SHARES, first_share_within, needed_share, share_gaps,
                                                  timed_shares)
from tests.estimate.helpers import CostedRenderer


def test_first_share_within_interpolates_between_the_shares():
    assert first_share_within([0.2, 0.4, 0.6], [3.0, 1.5, 0.5], 1.0) == pytest.approx(0.5)
    assert first_share_within([0.2, 0.4], [0.9, 0.1], 1.0) == 0.2
    assert first_share_within([0.2, 0.4], [3.0, 2.0], 1.0) is None


class _FrameRenderer:
    """The renderer's ``render_pixels`` on a stored frame (the quality half never needs a volume)."""

    def __init__(self, frame):
        self.frame = frame.reshape(-1, 3)

    def render_pixels(self, view, resolution, pixels):
        return self.frame[pixels]


def _textured_band(width: int, m: int = 64, seed: int = 0) -> np.ndarray:
    """A flat frame whose first ``width`` columns hold a texture at the C-pixel scale (bilinear from a random
    half-size image, so the C-Image predicts it exactly and nothing else does), a little noise everywhere."""
    rng = np.random.default_rng(seed)
    tex = torch.from_numpy(rng.random((1, 3, m // 2, m // 2))).float()
    up = torch.nn.functional.interpolate(tex, size=m, mode="bilinear", align_corners=True)[0].permute(1, 2, 0).numpy()
    frame = np.full((m, m, 3), 0.3)
    frame[:, :width] = up[:, :width]
    return (np.clip(frame + rng.normal(0, 1.0 / 255, frame.shape), 0, 1) * 255).astype(np.uint8)


def test_needed_share_follows_the_detailed_part_of_a_frame_and_is_zero_gap_at_the_whole_pattern():
    """The importance puts the mask on the texture: a quarter of the frame textured needs about a quarter of C,
    half of it about half; the whole pattern is the reference itself (gap 0)."""
    p = downsample_pattern(64, 2)

    def rebuild(c):
        return upsample_c_image(c, p)[0]

    out = {}
    for width in (16, 32):
        frame = _textured_band(width)
        ns = needed_share(rebuild, "bilinear", p, _FrameRenderer(frame), [None], [frame], epsilon_db=1.0,
                          repeats=1, warmup=0)
        assert ns.shares == list(NEEDED_SHARES) and len(ns.gap_db) == len(NEEDED_SHARES)
        assert ns.gap_db[-1] == pytest.approx(0.0, abs=1e-6) and ns.kept[-1] == 1.0   # every pixel: the reference
        assert all(np.isfinite(ns.gap_db)) and ns.gap_db[0] > 5.0
        timed = timed_shares(ns.kept, ns.gap_db, 1.0)   # only the masks around the needed share are ray-cast
        assert len(timed) == 2 and [j for j, r in enumerate(ns.render_ms) if r is not None] == timed
        assert all(np.isfinite(ns.render_ms[j]) and ns.render_ms[j] > 0 for j in timed)
        out[width] = ns.needed_share
        d = ns.to_dict()
        assert d["needed_share"] == ns.needed_share and len(d["rows"]) == len(NEEDED_SHARES)
    assert 0.25 <= out[16] <= 0.35 and 0.45 <= out[32] <= 0.6


def test_exception_needed_share_bad_epsilon_or_views():
    p = downsample_pattern(16, 2)
    frame = np.zeros((16, 16, 3), np.uint8)
    with pytest.raises(InputError, match="epsilon_db"):
        needed_share(lambda c: upsample_c_image(c, p)[0], "bilinear", p, _FrameRenderer(frame), [None], [frame],
                     epsilon_db=0.0)
    with pytest.raises(InputError, match="one FR frame per view"):
        needed_share(lambda c: upsample_c_image(c, p)[0], "bilinear", p, _FrameRenderer(frame), [None, None], [frame])


def test_share_gaps_with_a_first_pass_keeps_it_and_knows_less():
    """A two-pass sampler's importance (from a blue-noise base only) keeps the base in every mask and rebuilds the
    textured band no better than the importance from the whole C-Image at the same share."""
    p = downsample_pattern(64, 2)
    frame = _textured_band(16)

    def rebuild(c):
        return upsample_c_image(c, p)[0]

    shares = (0.3, 0.5)
    kept_full, gap_full = share_gaps(rebuild, p, [frame], shares)
    kept_base, gap_base = share_gaps(rebuild, p, [frame], shares, base=0.2)
    assert (kept_base >= 0.2 - 1e-6).all() and np.isfinite(gap_base).all()
    assert gap_base[0, 0] >= gap_full[0, 0] - 0.05


@pytest.mark.parametrize("shares", [NEEDED_SHARES, NEEDED_SHARES[:10]])
def test_needed_share_renders_on_each_views_own_pattern(monkeypatch, shares):
    """The masks' renders as the bound's render curve takes them: each view's times as fractions of its whole
    pattern timed in the same pass (share 1's mask, or one more render where the shares stop short of it), put on
    the pattern's time the estimate measured for that view (here 25% slower than the pass: the same pixels timed
    minutes apart) and averaged over the views. Share 1 then costs the RecNN alone's render exactly."""
    import imls_lightning.estimate.needed_share as ns_mod

    p = downsample_pattern(64, 2)
    frames = [_textured_band(16, seed=0), _textured_band(32, seed=1)]
    per_px = {0: 1.0, 1: 3.0}
    renderer = CostedRenderer(per_px)
    monkeypatch.setattr(ns_mod, "median_ms", renderer.median_ms)
    c_render = [1.25 * per_px[v] * p.count for v in (0, 1)]

    def rebuild(c):
        return upsample_c_image(c, p)[0]

    ns = needed_share(rebuild, "bilinear", p, renderer, [0, 1], frames, shares=shares, repeats=1, warmup=0,
                      c_render_ms=c_render, time_all=True)
    kept, _ = share_gaps(rebuild, p, frames, shares)
    expected = np.mean([kept[v] * c_render[v] for v in (0, 1)], axis=0)   # each view's fraction is its kept share
    np.testing.assert_allclose(ns.render_ms, expected, rtol=1e-12)
    assert renderer.calls.count(p.count) == 2   # the whole pattern once per view: share 1's mask, or one more render
    if shares[-1] == 1.0:
        assert ns.render_ms[-1] == pytest.approx(np.mean(c_render), rel=1e-12)
    # without the estimate's pattern times: on this pass's own
    own = needed_share(rebuild, "bilinear", p, renderer, [0, 1], frames, shares=shares, repeats=1, warmup=0,
                       time_all=True)
    np.testing.assert_allclose(own.render_ms, np.mean([kept[v] * per_px[v] * p.count for v in (0, 1)], axis=0),
                               rtol=1e-12)
    with pytest.raises(InputError, match="one c_render_ms per view"):
        needed_share(rebuild, "bilinear", p, renderer, [0, 1], frames, shares=shares, c_render_ms=[1.0])


def test_exception_on_own_patterns_shapes():
    from imls_lightning.estimate.measure import on_own_patterns

    with pytest.raises(InputError, match="one whole pattern and one c_render_ms per view"):
        on_own_patterns(np.ones((2, 3)), np.ones(2), [1.0])
    with pytest.raises(InputError, match="on_own_patterns"):
        on_own_patterns(np.ones(3), np.ones(3), np.ones(3))


def test_needed_share_ray_casts_only_the_masks_around_it(monkeypatch):
    """By default only the two masks around the needed share are ray-cast on each view, and the whole pattern once:
    the render at the needed share is the one every mask's renders give (it interpolates between those two)."""
    import imls_lightning.estimate.needed_share as ns_mod

    p = downsample_pattern(64, 2)
    frames = [_textured_band(16, seed=0), _textured_band(32, seed=1)]
    renderer = CostedRenderer({0: 1.0, 1: 3.0})
    monkeypatch.setattr(ns_mod, "median_ms", renderer.median_ms)
    c_render = [1.1 * p.count, 2.9 * p.count]

    def rebuild(c):
        return upsample_c_image(c, p)[0]

    every = needed_share(rebuild, "bilinear", p, renderer, [0, 1], frames, c_render_ms=c_render, time_all=True)
    renderer.calls.clear()
    around = needed_share(rebuild, "bilinear", p, renderer, [0, 1], frames, c_render_ms=c_render)
    timed = timed_shares(every.kept, every.gap_db, 1.0)
    assert around.needed_share == every.needed_share is not None and len(timed) == 2
    assert len(renderer.calls) == 2 * (len(timed) + 1) and renderer.calls.count(p.count) == 2
    assert [j for j, r in enumerate(around.render_ms) if r is not None] == timed
    assert around.render_at(around.needed_share) == pytest.approx(every.render_at(every.needed_share), rel=1e-12)
    d = around.to_dict()
    assert sum(r["render_ms"] is not None for r in d["rows"]) == 2
