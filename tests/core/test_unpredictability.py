"""The untrained importance (:mod:`imls_lightning.core.unpredictability`): against direct implementations."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.patterns import downsample_pattern, foveal_pattern
from imls_lightning.core.rank_patterns import blue_noise
from imls_lightning.core.unpredictability import base_unpredictability, importance_mask, two_pass_mask, unpredictability
from imls_lightning.core.pull_push import pull_push_inpaint


def test_unpredictability_is_the_fill_error_from_the_other_half():
    """Direct form: each pixel filled by pull-push from the blue-noise half it is not in."""
    p = downsample_pattern(32, 2)
    c = torch.rand(2, 3, 16, 16)
    score = unpredictability(c, p, seed=3)
    half = blue_noise(16, 3) < 0.5
    for known in (half, ~half):
        m = known[None, None].float().expand(2, 1, 16, 16)
        err = (pull_push_inpaint(c * m, m) - c).abs().sum(1, keepdim=True)
        assert torch.allclose(score[..., ~known], err[..., ~known], atol=1e-6)
    assert score.shape == (2, 1, 16, 16) and (score >= 0).all()


def test_unpredictability_is_zero_on_a_flat_image_and_large_on_noise():
    p = downsample_pattern(32, 2)
    flat = torch.full((1, 3, 16, 16), 0.4)
    assert float(unpredictability(flat, p).abs().max()) < 1e-6
    assert float(unpredictability(torch.rand(1, 3, 16, 16), p).mean()) > 0.3


def test_unpredictability_scores_nothing_past_a_foveal_pattern():
    p = foveal_pattern(32, 16)
    c = torch.rand(1, 3, 16, 16) * p.valid
    score = unpredictability(c, p)
    assert (score[0, 0][~p.valid] == 0).all() and torch.isfinite(score).all()


@pytest.mark.parametrize("share", [0.05, 0.3, 0.7, 1.0])
def test_masks_keep_the_share_and_prefer_the_important_pixels(share):
    p = downsample_pattern(64, 2)
    score = torch.zeros(1, 1, 32, 32)
    score[..., :, :8] = 1.0        # a quarter of the image is important
    mask = importance_mask(score, share, p)
    assert mask.dtype == torch.bool and abs(float(mask.float().mean()) - share) < 0.03
    left, right = mask[..., :, :8].float().mean(), mask[..., :, 8:].float().mean()
    assert left >= right and (share > 0.25 or right == 0)   # the important quarter first, the rest only past it


def test_exception_masks_bad_share():
    p = downsample_pattern(16, 2)
    with pytest.raises(InputError, match="share") as e:
        importance_mask(torch.ones(1, 1, 8, 8), 0.0, p)
    assert "\n" not in str(e.value)


def test_base_unpredictability_scores_the_base_against_itself_and_spreads_it():
    """Direct form: the base's two blue-noise halves filled from each other, then the base's scores filled everywhere."""
    p = downsample_pattern(32, 2)
    c = torch.rand(1, 3, 16, 16)
    score, first = base_unpredictability(c, p, 0.3, seed=2)
    ranks = blue_noise(16, 2)
    assert torch.equal(first, ranks < 0.3)
    half, other = ranks < 0.15, (ranks >= 0.15) & (ranks < 0.3)
    err = torch.zeros(1, 1, 16, 16)
    for known, unknown in ((half, other), (other, half)):
        m = known[None, None].float()
        err[..., unknown] = (pull_push_inpaint(c * m, m) - c).abs().sum(1, keepdim=True)[..., unknown]
    m = first[None, None].float()
    assert torch.allclose(score, pull_push_inpaint(err * m, m), atol=1e-6)
    # only the base is read: the other pixels may be anything (a two-pass renderer has not cast them)
    c2 = torch.where(first, c, torch.rand_like(c))
    assert torch.allclose(base_unpredictability(c2, p, 0.3, seed=2)[0], score, atol=1e-6)


@pytest.mark.parametrize("base", [0.0, 1.0, -0.1])
def test_exception_base_share(base):
    with pytest.raises(InputError, match="base=") as e:
        base_unpredictability(torch.rand(1, 3, 8, 8), downsample_pattern(16, 2), base)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("share", [0.1, 0.3, 0.6, 1.0])
def test_two_pass_mask_keeps_the_first_pass_and_reaches_the_share(share):
    p = downsample_pattern(64, 2)
    c = torch.rand(1, 3, 32, 32)
    score, first = base_unpredictability(c, p, 0.2)
    m = two_pass_mask(score, first, share, p, floor=0.25)
    assert m.shape == (1, 1, 32, 32) and m[0, 0][first].all()
    assert abs(m.float().mean().item() - max(share, first.float().mean().item())) < 0.02
    among = importance_mask(score, 0.5, p, among=~first)            # the second pass alone never repeats the first
    assert not among[0, 0][first].any()


def test_importance_mask_extremes_stay_finite_and_the_floor_samples_flat_regions():
    p = downsample_pattern(64, 2)
    zero = torch.zeros(1, 1, 32, 32)
    assert importance_mask(zero, 1.0, p).all()                  # the whole pattern, even with no importance at all
    assert abs(importance_mask(zero, 0.2, p, floor=0.25).float().mean().item() - 0.2) < 0.02  # the floor alone, evenly
    huge = torch.zeros(1, 1, 32, 32)
    huge[..., 0, 0] = 1e30
    m = importance_mask(huge, 0.1, p, floor=0.25)
    assert m[0, 0, 0, 0] and abs(m.float().mean().item() - 0.1) < 0.02


def test_importance_mask_sharpness_is_the_heads_formula_on_the_floored_importance():
    """sharpness = gamma: the floored importance sharpened (core.importance.sharpen_importance, the IMS head's
    formula) before the rescale, the same pixels as sharpening it by hand; gamma = 1 is the unsharpened mask; the
    extremes stay a mask of the asked share."""
    from imls_lightning.core.importance import sharpen_importance

    p = downsample_pattern(64, 2)
    g = torch.Generator().manual_seed(0)
    score = torch.rand(2, 1, 32, 32, generator=g) ** 3
    valid = p.valid
    mean = (score * valid).sum(dim=(1, 2, 3), keepdim=True) / valid.sum()
    by_hand = sharpen_importance(score + 0.25 * mean, 2.0, valid=valid)
    assert torch.equal(importance_mask(score, 0.3, p, 0.25, sharpness=2.0), importance_mask(by_hand, 0.3, p, 0.0))
    assert torch.equal(importance_mask(score, 0.3, p, 0.25, sharpness=1.0), importance_mask(score, 0.3, p, 0.25))
    for extreme in (torch.zeros(1, 1, 32, 32), torch.full((1, 1, 32, 32), 1e-12), torch.full((1, 1, 32, 32), 1e6)):
        m = importance_mask(extreme, 0.2, p, 0.25, sharpness=8.0)
        assert abs(m.float().sum().item() / p.count - 0.2) < 0.02
    with pytest.raises(InputError, match="sharpness=0.5"):
        importance_mask(score, 0.3, p, 0.25, sharpness=0.5)


def test_module_doctest():
    import doctest

    import imls_lightning.core.unpredictability as mod

    result = doctest.testmod(mod)
    assert result.attempted > 0 and result.failed == 0, result
