"""Untrained baselines at equal share: the share bisection, the comparison rows (the product-path ORP:
``tests/orp/test_product.py``)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from imls_lightning.inference.baselines import (
    equal_share_rows,
    mask_at_share,
    summarize_equal_share,
)
from imls_lightning.models.enhancenet import EnhanceNet
from imls_lightning.models.iml import IMLNet
from imls_lightning.core.pull_push import pull_push_inpaint
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
