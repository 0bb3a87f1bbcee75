"""Untrained baselines at equal share: the share bisection, the comparison rows, the product-path ORP."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.inference.baselines import (
    equal_share_rows,
    mask_at_share,
    product_orp,
    summarize_equal_share,
)
from imls_lightning.models.enhancenet import EnhanceNet
from imls_lightning.models.iml import IMLNet
from imls_lightning.models.ims import IMSMaskHead
from imls_lightning.models.pull_push import pull_push_inpaint
from imls_lightning.core.patterns import SamplingPattern, plastic_rank_pattern
from imls_lightning.report import equal_share_markdown
from imls_lightning.tasks.base import psnr_per_image

N = 16


def _pattern(n: int = N) -> SamplingPattern:
    m = 2 * n
    ii = torch.arange(n)
    return SamplingPattern("downsample", m, n, ((2 * ii)[:, None] * m + (2 * ii)[None, :]).reshape(-1))


def _scene(b: int = 3, n: int = N):
    """C-Images with an object (a bright disc) on black background, and their 2x FR-Images."""
    yy, xx = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    c = torch.zeros(b, 3, n, n)
    for i in range(b):
        disc = ((yy - n / 2 - i) ** 2 + (xx - n / 2) ** 2) < (n / 4) ** 2
        c[i, :, disc] = torch.tensor([0.9, 0.5, 0.2])[:, None]
    fr = torch.nn.functional.interpolate(c, scale_factor=2, mode="nearest")
    return c, fr


def _nets():
    torch.manual_seed(0)
    iml = IMLNet(N, plastic_rank_pattern(N), mean=0.2, depth=2, base_channels=4).eval()
    blue = IMLNet(N, plastic_rank_pattern(N), mean=0.2, depth=2, base_channels=4, importance="uniform").eval()
    recnn = EnhanceNet(_pattern(), channels=4, blocks=1).eval()
    return iml, blue, recnn


# ---------------------------------------------------------------- mask_at_share


@pytest.mark.parametrize("share", [0.05, 0.2, 0.4, 1.0])
def test_mask_at_share_hits_the_share_against_a_direct_count(share):
    P = plastic_rank_pattern(N).view(1, 1, N, N)
    valid = torch.ones(N, N, dtype=torch.bool)
    m = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P, share, valid, 2)
    want = share * N * N
    got = m.flatten(1).sum(1)
    assert ((got - want).abs() <= 1).all(), (got, want)


def test_mask_at_share_respects_the_valid_pixels():
    valid = torch.zeros(N, N, dtype=torch.bool)
    valid[: N // 2] = True
    P = torch.rand(1, 1, N, N, generator=torch.Generator().manual_seed(0))
    m = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P, 0.5, valid, 1)
    assert m[..., N // 2:, :].sum() == 0
    assert abs(float(m.sum()) - 0.5 * valid.sum().item()) <= 1


def test_mask_at_share_exception_on_a_bad_share():
    with pytest.raises(ValueError, match="share"):
        mask_at_share(lambda u: u.view(-1, 1, 1, 1) > 0.5, 0.0, torch.ones(2, 2, dtype=torch.bool), 1)


# ---------------------------------------------------------------- equal-share rows


def test_equal_share_rows_against_a_direct_computation():
    iml, blue, recnn = _nets()
    c, fr = _scene()
    rows = equal_share_rows(c, fr, None, recnn, iml=iml, blue=blue, shares=[0.25])
    assert {(r["mask"], r["reconstruction"]) for r in rows} == {
        ("iml", "decoder"), ("iml", "fill"), ("blue_noise", "decoder"), ("blue_noise", "fill")}
    blue_fill = next(r for r in rows if r["mask"] == "blue_noise" and r["reconstruction"] == "fill")
    P = plastic_rank_pattern(N).view(1, 1, N, N)
    m = mask_at_share(lambda u: u.view(-1, 1, 1, 1) > P, 0.25, torch.ones(N, N, dtype=torch.bool), c.shape[0])
    want = psnr_per_image(recnn(pull_push_inpaint(m * c, m)), fr).numpy()
    np.testing.assert_allclose(blue_fill["psnr"], want, rtol=1e-5)
    # densities: the blue-noise mask samples background and object alike (about the share each)
    assert abs(blue_fill["density_background"] - 0.25) < 0.1 and abs(blue_fill["density_object"] - 0.25) < 0.1


def test_summary_and_markdown_smoke():
    iml, blue, recnn = _nets()
    c, fr = _scene()
    s = summarize_equal_share([equal_share_rows(c, fr, None, recnn, iml=iml, blue=blue, shares=[0.2, 0.4])] * 2)
    assert len(s) == 8 and all(r["views"] == 2 * c.shape[0] for r in s)
    text = equal_share_markdown(s)
    assert "decoder − fill" in text and "blue noise" in text and text.count("\n") == 1 + 4  # header + 2 shares x 2 masks


# ---------------------------------------------------------------- product ORP


class _ObjectGenerator(torch.nn.Module):
    """An IMS generator whose regressed PIM' is 1 on the object and 0 on background (a perfect one)."""

    def __init__(self, c: torch.Tensor):
        super().__init__()
        self.c = c

    def forward(self, views: torch.Tensor) -> torch.Tensor:
        obj = (self.c.amax(1, keepdim=True) > 0).float()
        return obj * 2 - 1  # g in {-1, 1}: PIM' = (g + 1) / 2


class _FakeIMS(IMSMaskHead):
    """The mask head of a perfect IMS (trained at u = 0.2): what product_orp takes."""

    def __init__(self, c: torch.Tensor):
        super().__init__(_ObjectGenerator(c), plastic_rank_pattern(N), torch.ones(N, N, dtype=torch.bool), "pim",
                         trained_mean=0.2)

    def output_to_im_at(self, g, mean):
        return self.threshold(g, mean)


def test_product_orp_finds_the_smallest_mean_within_epsilon():
    _, _, recnn = _nets()
    c, fr = _scene()
    ims = _FakeIMS(c)
    batches = [{"c": c, "fr": fr, "view": torch.zeros(c.shape[0], 9)}]
    exact = type("Exact", (torch.nn.Module,), {"forward": lambda self, v, m: v * m})()  # no fill: needs every pixel
    res = product_orp(ims, exact, recnn, batches, epsilon_db=0.5)
    assert res.found
    rec = res.best.record
    assert rec["gap_db"] <= 0.5 and 0 < rec["c_share"] <= 1
    # every evaluation below the ORP fails epsilon (the gap falls as u grows)
    assert all(e.gap_db > 0.5 for e in res.evaluations if e.u < res.mean and e.gap_db is not None)


def test_product_orp_with_a_confidence_margin_keeps_the_bound_within_epsilon():
    """confidence > 0.5: the bound on the mean per-view gap (not the mean) meets epsilon, so the ORP can only move up;
    the record keeps the mean gap, its spread and the bound, computed from the per-view gaps at that mean."""
    from imls_lightning.orp import gap_upper_bound

    _, _, recnn = _nets()
    c, fr = _scene(b=4)
    ims = _FakeIMS(c)
    batches = [{"c": c, "fr": fr, "view": torch.zeros(4, 9)}]  # the fake generator answers for all of c at once
    exact = type("Exact", (torch.nn.Module,), {"forward": lambda self, v, m: v * m})()
    plain = product_orp(ims, exact, recnn, batches, epsilon_db=0.5)
    safe = product_orp(ims, exact, recnn, batches, epsilon_db=0.5, confidence=0.95)
    assert plain.found and safe.found and safe.mean >= plain.mean
    rec = safe.best.record
    assert rec["views"] == 4 and rec["confidence"] == 0.95 and rec["gap_bound_db"] <= 0.5
    # direct: the per-view gaps at the chosen mean
    im = ims.output_to_im_at(ims.generator(None), torch.full((4,), safe.mean)).float()
    gaps = (psnr_per_image(recnn(c), fr) - psnr_per_image(recnn(exact(im * c, im)), fr)).tolist()
    b = gap_upper_bound(gaps, 0.95)
    assert rec["gap_db"] == pytest.approx(b.mean, abs=1e-5) and rec["gap_bound_db"] == pytest.approx(b.bound, abs=1e-5)
    assert plain.best.record["gap_bound_db"] == pytest.approx(plain.best.record["gap_db"])  # confidence 0.5: the mean


def test_product_orp_with_path_passes_bounds_the_pass_means_for_one_new_path():
    """Views along camera paths (passes): the bound is the pass bound for one new path, never below the views' own,
    so the ORP can only move up; the record says how many passes it counted."""
    from imls_lightning.orp import pass_gap_bound

    _, _, recnn = _nets()
    c, fr = _scene(b=4)
    ims = _FakeIMS(c)
    batches = [{"c": c, "fr": fr, "view": torch.zeros(4, 9)}]
    exact = type("Exact", (torch.nn.Module,), {"forward": lambda self, v, m: v * m})()
    views = product_orp(ims, exact, recnn, batches, epsilon_db=0.5, confidence=0.95, future_views=4)
    passes = [0, 0, 1, 1]  # two paths of two views, each one pass
    by_pass = product_orp(ims, exact, recnn, batches, epsilon_db=0.5, confidence=0.95, future_views=4, passes=passes, paths=2)
    assert by_pass.found and by_pass.mean >= views.mean
    rec = by_pass.best.record
    assert rec["passes"] == 2 and rec["gap_bound_db"] <= 0.5
    im = ims.output_to_im_at(ims.generator(None), torch.full((4,), by_pass.mean)).float()
    gaps = (psnr_per_image(recnn(c), fr) - psnr_per_image(recnn(exact(im * c, im)), fr)).tolist()
    assert rec["gap_bound_db"] == pytest.approx(pass_gap_bound(gaps, passes, 0.95, 1).bound, abs=1e-5)
    with pytest.raises(InputError, match="product_orp: 3 pass labels for 4 views"):
        product_orp(ims, exact, recnn, batches, passes=[0, 0, 1])
