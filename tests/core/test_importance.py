"""PIM normalization and rejection sampling: formulas, gradients, extremes, user errors."""
from __future__ import annotations

import math
import re

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.importance import (
    ImportanceNormalization,
    LiftToShare,
    RejectionSampling,
    hard_rejection_sample,
    lift_to_share,
    lifted_mask,
    SharpenImportance,
    check_sharpness,
    normalize_importance,
    sharpen_importance,
    soft_rejection_sample,
)


def rank_pattern(n: int, seed: int = 0) -> torch.Tensor:
    """Stand-in for the plastic rank pattern: each of 1/N, 2/N, ..., 1 once, shuffled."""
    g = torch.Generator().manual_seed(seed)
    return ((torch.randperm(n * n, generator=g) + 1).float() / (n * n)).view(n, n)


# ---------------------------------------------------------------- against a direct reimplementation


@pytest.mark.parametrize("lower", [0.0, 0.02])
def test_normalize_against_direct_formula(lower):
    pim = torch.rand(3, 1, 5, 6) * torch.tensor([1.0, 10.0, 0.01]).view(3, 1, 1, 1)
    u, delta = 0.2, 1e-7
    got = normalize_importance(pim, u, lower=lower, delta=delta)
    for b in range(3):
        mu = sum(float(v) for v in pim[b].flatten()) / pim[b].numel()
        want = lower + pim[b] * (u - lower) / (mu + delta)
        torch.testing.assert_close(got[b], want, rtol=1e-5, atol=1e-7)


def test_normalize_with_valid_uses_only_valid_pixels_for_the_mean():
    pim = torch.rand(2, 1, 4, 4)
    valid = torch.zeros(4, 4, dtype=torch.bool)
    valid.view(-1)[:11] = True  # first K raster pixels, like SamplingPattern.valid
    got = normalize_importance(pim, 0.3, valid=valid)
    for b in range(2):
        mu = pim[b, 0][valid].mean()
        torch.testing.assert_close(got[b], pim[b] * 0.3 / (mu + 1e-7))
        # the mean of PIM' over the valid pixels is u (l = 0)
        assert abs(float(got[b, 0][valid].mean()) - 0.3) < 1e-5


def test_soft_and_hard_rejection_against_direct_formula():
    pim_norm = torch.rand(2, 1, 6, 6) * 2
    P = rank_pattern(6)
    alpha = 7.5
    soft = soft_rejection_sample(pim_norm, P, alpha)
    hard = hard_rejection_sample(pim_norm, P)
    for b in range(2):
        for i in range(6):
            for j in range(6):
                d = float(pim_norm[b, 0, i, j]) - float(P[i, j])
                want = 1.0 / (1.0 + torch.exp(torch.tensor(-alpha * d, dtype=torch.float64)))
                assert abs(float(soft[b, 0, i, j]) - float(want)) < 1e-6
                assert bool(hard[b, 0, i, j]) == (d > 0)
    assert hard.dtype == torch.bool


def test_ties_are_not_important():
    P = torch.full((2, 2), 0.5)
    assert not hard_rejection_sample(torch.full((1, 1, 2, 2), 0.5), P).any()


# ---------------------------------------------------------------- gradcheck (float64)


@pytest.mark.parametrize("with_valid", [False, True])
def test_gradcheck_normalization(with_valid):
    pim = (torch.rand(2, 1, 4, 4, dtype=torch.float64) + 0.1).requires_grad_()
    valid = torch.arange(16).view(4, 4) < 13 if with_valid else None
    assert torch.autograd.gradcheck(lambda x: normalize_importance(x, 0.3, lower=0.05, valid=valid), (pim,))


def test_gradcheck_soft_rejection():
    x = (torch.rand(2, 1, 4, 4, dtype=torch.float64) * 2).requires_grad_()
    P = rank_pattern(4).double()
    assert torch.autograd.gradcheck(lambda t: soft_rejection_sample(t, P, 3.0), (x,))


def test_gradcheck_normalization_then_soft_rejection():
    pim = (torch.rand(1, 1, 4, 4, dtype=torch.float64) + 0.05).requires_grad_()
    P = rank_pattern(4).double()
    fn = lambda x: soft_rejection_sample(normalize_importance(x, 0.5), P, 2.0)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (pim,))


# ---------------------------------------------------------------- extremes


def _finite_grad(fn, x):
    x = x.clone().requires_grad_()
    y = fn(x)
    (y * torch.linspace(0.5, 1.5, y.numel()).view_as(y)).sum().backward()
    return y, x.grad


@pytest.mark.parametrize("mean", [0.01, 1.0])
@pytest.mark.parametrize("alpha", [1.0, 50.0, 1e4])
@pytest.mark.parametrize("kind", ["zero", "huge", "tiny", "one_hot_huge", "random"])
@pytest.mark.parametrize("autocast", [False, True])
def test_stability_grid_finite_values_and_gradients(mean, alpha, kind, autocast):
    n = 8
    pim = {
        "zero": torch.zeros(2, 1, n, n),
        "huge": torch.full((2, 1, n, n), 1e30),
        "tiny": torch.full((2, 1, n, n), 1e-30),
        "one_hot_huge": torch.zeros(2, 1, n, n).index_fill_(3, torch.tensor([3]), 1e30),
        "random": torch.rand(2, 1, n, n),
    }[kind]
    P = rank_pattern(n)

    def fn(x):
        return soft_rejection_sample(normalize_importance(x, mean), P, alpha)

    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=autocast):
        y, g = _finite_grad(fn, pim.to(torch.bfloat16) if autocast else pim)
        hard = hard_rejection_sample(normalize_importance(pim, mean), P)
    assert y.dtype == torch.float32
    assert torch.isfinite(y).all() and torch.isfinite(g).all()
    assert ((y >= 0) & (y <= 1)).all()
    if kind == "zero":
        # mean(PIM) = 0: delta keeps it finite, PIM' = l = 0, so nothing is important
        assert not hard.any()
        assert torch.equal(normalize_importance(pim, mean), torch.zeros_like(pim))


def test_constant_pim_is_normalized_to_the_mean():
    for c in (1e-3, 1.0, 1e6):
        out = normalize_importance(torch.full((1, 1, 4, 4), c), 0.25)
        # exactly u up to the delta bias c / (c + delta)
        torch.testing.assert_close(out, torch.full_like(out, 0.25 * c / (c + 1e-7)), rtol=1e-6, atol=0)


def test_all_invalid_image_gives_lower_not_nan():
    out = normalize_importance(torch.rand(1, 1, 3, 3), 0.5, lower=0.1, valid=torch.zeros(3, 3, dtype=torch.bool))
    assert torch.isfinite(out).all()


def test_bf16_autocast_matches_float32_computation():
    pim = torch.rand(2, 1, 8, 8).to(torch.bfloat16).float()  # bf16-representable values
    P = rank_pattern(8)
    ref = soft_rejection_sample(normalize_importance(pim, 0.1), P, 50.0)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = soft_rejection_sample(normalize_importance(pim.to(torch.bfloat16), 0.1), P, 50.0)
    assert got.dtype == torch.float32
    torch.testing.assert_close(got, ref)


@pytest.mark.parametrize("alpha", [1e3, 1e5])
def test_soft_mask_tends_to_hard_mask_for_large_alpha(alpha):
    pim_norm = torch.rand(4, 1, 16, 16) * 1.5
    P = rank_pattern(16)
    soft = soft_rejection_sample(pim_norm, P, alpha)
    hard = hard_rejection_sample(pim_norm, P).float()
    eps = 1e-2
    away = (pim_norm - P).abs() > eps
    bound = torch.sigmoid(torch.tensor(-alpha * eps)).item()
    assert ((soft - hard).abs()[away] <= bound + 1e-7).all()


# ---------------------------------------------------------------- modules


def test_rejection_sampling_module_soft_in_training_hard_in_eval():
    P = rank_pattern(6)
    rs = RejectionSampling(P, alpha=5.0)
    x = torch.rand(2, 1, 6, 6)
    soft = rs.train()(x)
    torch.testing.assert_close(soft, soft_rejection_sample(x, P, 5.0))
    hard = rs.eval()(x)
    assert hard.dtype == torch.float32
    assert torch.equal(hard, hard_rejection_sample(x, P).float())
    assert torch.equal(rs.eval()(x, hard=False), soft)  # override
    assert torch.equal(rs.train()(x, hard=True), hard)
    assert torch.equal(rs.state_dict()["P"], P)  # the checkpoint carries P


def test_importance_normalization_module():
    norm = ImportanceNormalization(mean=0.1)
    x = torch.rand(3, 1, 5, 5)
    torch.testing.assert_close(norm(x), normalize_importance(x, 0.1))
    norm.mean = 0.5
    torch.testing.assert_close(norm(x), normalize_importance(x, 0.5))
    with pytest.raises(InputError):
        norm.mean = 2.0
    assert norm.mean == 0.5


# ---------------------------------------------------------------- exceptions


@pytest.mark.parametrize("mean", [0.0, 0.009, 1.01, -1.0, float("nan"), "abc"])
def test_invalid_mean_is_refused(mean):
    with pytest.raises(InputError, match="mean") as err:
        normalize_importance(torch.rand(1, 1, 2, 2), mean)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="mean"):
        ImportanceNormalization(mean)


@pytest.mark.parametrize("alpha", [0.0, -1.0, float("inf"), float("nan")])
def test_invalid_alpha_is_refused(alpha):
    with pytest.raises(InputError, match="alpha") as err:
        soft_rejection_sample(torch.rand(1, 1, 2, 2), torch.rand(2, 2), alpha)
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="alpha"):
        RejectionSampling(torch.rand(2, 2), alpha)


def test_invalid_lower_delta_and_P_are_refused():
    with pytest.raises(InputError, match="lower"):
        normalize_importance(torch.rand(1, 1, 2, 2), 0.1, lower=0.1)
    with pytest.raises(InputError, match="delta"):
        normalize_importance(torch.rand(1, 1, 2, 2), 0.1, delta=0.0)
    with pytest.raises(InputError, match="P"):
        RejectionSampling(torch.rand(2, 2, 2))
    with pytest.raises(InputError, match="P"):
        RejectionSampling(torch.full((2, 2), 2.0))


def test_rejection_sampling_window_smoke_crop_uses_the_top_left_of_p():
    P = torch.rand(8, 8)
    rs = RejectionSampling(P, alpha=5.0)
    assert rs.window(8, 8) is rs.P
    x = torch.rand(2, 1, 4, 4)
    torch.testing.assert_close(rs(x, hard=False), torch.sigmoid(5.0 * (x - P[:4, :4])))
    assert torch.equal(rs(x, hard=True).bool(), x > P[:4, :4])


def test_rejection_sampling_window_exception_larger_than_p():
    with pytest.raises(ValueError, match="larger than the rank pattern"):
        RejectionSampling(torch.rand(4, 4))(torch.rand(1, 1, 8, 8))


# ---- lift_to_share ----------------------------------------------------------------------------------
def _share(x: torch.Tensor, m: float, f: float) -> float:
    """Expected share of the lifted importance, computed directly: min(max(m x, f), 1) (m x = [x > 0] at m = inf)."""
    x = x.double()
    scaled = (x > 0).double() if math.isinf(m) else x * m
    return float(torch.clamp(torch.maximum(scaled, torch.full_like(x, f)), max=1.0).mean())


def test_lift_smoke_scales_first_then_floors():
    pim = torch.tensor([[[[0.0, 0.1, 0.3, 2.0]]]])
    assert [v.item() for v in lift_to_share(pim, 0.3)] == [1.0, 0.0]
    m, f = lift_to_share(pim, 0.5)
    assert m.item() == pytest.approx(2.5) and f.item() == 0.0
    assert [v.item() for v in lift_to_share(pim, 1.0)] == [math.inf, 1.0]


@pytest.mark.parametrize("seed", range(5))
def test_lift_against_direct_share_with_valid_pixels_and_per_image_means(seed):
    g = torch.Generator().manual_seed(seed)
    pim = torch.rand(4, 1, 9, 11, generator=g) ** 3 * 3 * (torch.rand(4, 1, 9, 11, generator=g) > 0.4)
    valid = torch.rand(9, 11, generator=g) > 0.3
    u = torch.rand(4, generator=g) * 0.99 + 0.01
    m, f = lift_to_share(pim, u, valid)
    assert m.shape == f.shape == (4, 1, 1, 1) and m.dtype == torch.float64
    for b in range(4):
        x = pim[b, 0][valid]
        plain = float(x.double().clamp(max=1).mean())
        mb, fb = float(m[b]), float(f[b])
        assert mb >= 1.0 and 0.0 <= fb <= 1.0
        assert _share(x, mb, fb) == pytest.approx(max(plain, float(u[b])), abs=1e-9)
        if fb > 0:
            assert math.isinf(mb)  # the floor only once every pixel with importance is taken
        elif mb > 1.0:
            assert _share(x, mb * (1 - 1e-6), 0.0) < float(u[b])  # the smallest multiplier


def test_lifted_mask_reaches_the_share_against_the_rank_pattern():
    n = 64
    P = rank_pattern(n, seed=1)
    pim = torch.zeros(1, 1, n, n)
    pim[..., n // 2:, :] = torch.linspace(0.05, 3.0, n)  # graded importance on half the image, saturating
    plain = float(pim.clamp(max=1).mean())  # 0.42: the plain mask's share
    for u in (0.3, 0.45, 0.6, 0.9, 1.0):
        im = lifted_mask(pim, *lift_to_share(pim, u), P)
        assert float(im.float().mean()) == pytest.approx(max(u, plain), abs=0.02), u
        assert not bool((hard_rejection_sample(pim, P) & ~im).any())  # keeps what the plain mask samples
    assert bool(lifted_mask(pim, *lift_to_share(pim, 1.0), P).all())


def test_lift_extremes_all_zero_and_all_saturated_are_finite():
    zero, full = torch.zeros(2, 1, 8, 8), torch.full((2, 1, 8, 8), 1e30)
    m, f = lift_to_share(zero, 0.01)
    assert m.isinf().all() and f.flatten().tolist() == pytest.approx([0.01, 0.01])
    assert [v.flatten().tolist() for v in lift_to_share(full, 1.0)] == [[1.0, 1.0], [0.0, 0.0]]
    assert [v.flatten().tolist() for v in lift_to_share(zero, 0.5, torch.zeros(8, 8, dtype=torch.bool))] == [[1.0, 1.0], [0.0, 0.0]]
    tiny = torch.full((1, 1, 8, 8), 1e-30)
    m, f = lift_to_share(tiny, 0.5)
    assert torch.isfinite(m).all() and _share(tiny.flatten(), float(m), float(f)) == pytest.approx(0.5)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan")])
def test_lift_exception_mean_out_of_range(bad):
    with pytest.raises(InputError, match="mean"):
        lift_to_share(torch.rand(1, 1, 4, 4), bad)


def test_lift_exception_shapes():
    with pytest.raises(ValueError, match="pim_norm"):
        lift_to_share(torch.rand(4, 4), 0.5)
    with pytest.raises(ValueError, match="mean"):
        lift_to_share(torch.rand(2, 1, 4, 4), torch.tensor([0.1, 0.2, 0.3]))


def test_lift_module_smoke_equals_the_functions():
    g = torch.Generator().manual_seed(3)
    pim = torch.rand(2, 1, 16, 16, generator=g) ** 4 * 4
    P, valid = rank_pattern(16, seed=2), torch.rand(16, 16, generator=g) > 0.2
    u = torch.tensor([0.5, 0.9])
    expected = lifted_mask(pim, *lift_to_share(pim, u, valid), P)
    assert torch.equal(LiftToShare()(pim, u, P, valid), expected) and expected.dtype == torch.bool


@pytest.mark.parametrize("valid_kind", ["none", "shared", "per_image"])
def test_lift_equals_the_per_image_solution_bit_for_bit(valid_kind):
    """The vectorized (traceable) lift gives the multipliers and floors the per-image solution gave
    (frozen in tests/models/helpers.py), bit for bit: batches, ties, zeros, saturation, u = 1."""
    from tests.models.helpers import reference_lift_to_share

    g = torch.Generator().manual_seed(7)
    for trial in range(40):
        b, n = int(torch.randint(1, 5, (1,), generator=g)), int(torch.randint(2, 12, (1,), generator=g))
        x = torch.rand(b, 1, n, n, generator=g) * float(torch.rand(1, generator=g) * 3)
        x[torch.rand(b, 1, n, n, generator=g) < 0.4] = 0
        if trial % 3 == 0:
            x = (x * 4).round() / 4
        u = torch.rand(b, generator=g)
        if trial % 7 == 0:
            u[:] = 1.0
        valid = {"none": None, "shared": torch.rand(n, n, generator=g) < 0.8,
                 "per_image": torch.rand(b, 1, n, n, generator=g) < 0.8}[valid_kind]
        got, want = lift_to_share(x, u, valid), reference_lift_to_share(x, u, valid)
        assert torch.equal(got[0], want[0]) and torch.equal(got[1], want[1]), trial


# ---------------------------------------------------------------- sharpening (the IMS mask's sharpness)


@pytest.mark.parametrize("gamma", [1.5, 2.0, 8.0])
@pytest.mark.parametrize("with_valid", [False, True])
def test_sharpen_against_direct_formula(gamma, with_valid):
    """S = PIM'^gamma mean(PIM') / (mean(PIM'^gamma) + delta), means per image over the valid pixels; the mean is kept,
    the order of the pixels too, and the high ones gain at the low ones' expense."""
    gen = torch.Generator().manual_seed(3)
    pim = torch.rand(3, 1, 5, 6, generator=gen) * torch.tensor([1.0, 3.0, 0.05]).view(3, 1, 1, 1)
    valid = (torch.rand(5, 6, generator=gen) > 0.3) if with_valid else None
    got = sharpen_importance(pim, gamma, valid)
    keep = valid.flatten() if with_valid else torch.ones(30, dtype=torch.bool)
    for b in range(3):
        x = [float(v) for v, k in zip(pim[b].flatten(), keep) if k]
        mean_x = sum(x) / len(x)
        top = max(x)
        mean_s = sum((v / top) ** gamma for v in x) / len(x)
        want = (pim[b] / top) ** gamma * mean_x / (mean_s + 1e-7)
        torch.testing.assert_close(got[b], want, rtol=1e-5, atol=1e-8)
        kept = got[b].flatten()[keep]
        assert float(kept.mean()) == pytest.approx(mean_x, rel=1e-4)
        order = torch.argsort(pim[b].flatten()[keep])
        assert bool((kept[order].diff() >= -1e-7).all())
        assert float(kept.max()) > float(pim[b].flatten()[keep].max())


def test_sharpen_at_one_is_the_identity_and_the_module_binds_gamma():
    pim = torch.rand(2, 1, 4, 4)
    assert sharpen_importance(pim, 1.0) is pim
    assert torch.equal(SharpenImportance(2.5)(pim), sharpen_importance(pim, 2.5))
    assert "sharpness=2.5" in repr(SharpenImportance(2.5))


@pytest.mark.parametrize("with_valid", [False, True])
def test_gradcheck_sharpen(with_valid):
    pim = (torch.rand(2, 1, 4, 5, dtype=torch.float64) + 0.05).requires_grad_()
    valid = (torch.arange(20).view(4, 5) % 3 != 0) if with_valid else None
    assert torch.autograd.gradcheck(lambda x: sharpen_importance(x, 2.5, valid), (pim,))


def test_sharpen_extremes_stay_finite():
    """All zero, one hot, tiny, huge, negative values (read as 0), gamma at its bound 8: finite values and gradients."""
    x = torch.zeros(6, 1, 8, 8)
    x[1, 0, 3, 3] = 1.0
    x[2] = 1e-12
    x[3] = torch.rand(8, 8) * 1e6
    x[4] = -torch.rand(8, 8)
    x[5] = torch.rand(8, 8)
    x.requires_grad_()
    for gamma in (1.5, 8.0):
        y = sharpen_importance(x, gamma)
        y.sum().backward()
        assert bool(torch.isfinite(y).all()) and bool(torch.isfinite(x.grad).all())
        assert float(y[0].abs().max()) == 0.0 and float(y[4].abs().max()) == 0.0
        x.grad = None


def test_sharpness_errors_are_one_line():
    for bad in (0.5, 9, float("nan"), "soft", True):
        with pytest.raises(InputError, match=r"^sharpness=.*: expected a number in \[1, 8\]|^sharpness=.*expected"):
            check_sharpness(bad)
    with pytest.raises(ValueError, match="expected a \\(B, C, H, W\\) tensor"):
        sharpen_importance(torch.rand(4, 4), 2.0)


# ---- the object floor: a view's mean value raised to its object's share plus a margin ---------------------------------
def test_object_fraction_against_a_direct_count():
    """The share of each image's valid pixels whose importance exceeds tau, counted pixel by pixel; padding does not
    count, an image with no valid pixel gets 0 (not NaN), and bfloat16 input is counted in float32."""
    from imls_lightning.core.importance import object_fraction

    g = torch.Generator().manual_seed(3)
    pim = torch.rand(3, 1, 7, 9, generator=g)
    valid = torch.rand(7, 9, generator=g) > 0.3
    for tau in (0.05, 0.2, 0.9):
        want = [sum(float(pim[b, 0, i, j]) > tau for i in range(7) for j in range(9) if valid[i, j]) / int(valid.sum())
                for b in range(3)]
        assert object_fraction(pim, valid, tau).tolist() == pytest.approx(want, abs=1e-7)
    assert object_fraction(pim.bfloat16(), valid, 0.2).dtype == torch.float32
    none = object_fraction(pim, torch.zeros(7, 9, dtype=torch.bool))
    assert torch.equal(none, torch.zeros(3))


def test_floored_mean_is_the_larger_of_u_and_the_object_plus_margin_at_most_one():
    from imls_lightning.core.importance import floored_mean

    u, f = torch.tensor([0.3, 0.6, 0.2, 0.01]), torch.tensor([0.35, 0.35, 0.95, 0.0])
    want = [max(a, min(1.0, b + 0.1)) for a, b in zip(u.tolist(), f.tolist())]
    assert floored_mean(u, f, 0.1).tolist() == pytest.approx(want)
    assert torch.equal(floored_mean(u, f, 0.0), torch.maximum(u, f))
    assert floored_mean(u, f, 1.0).tolist() == [1.0] * 4
    # one margin per view (a band's; -1: no floor for that view), against the direct formula
    m = torch.tensor([0.1, -1.0, 0.0, 0.5])
    want = [a if c < 0 else max(a, min(1.0, b + c)) for a, b, c in zip(u.tolist(), f.tolist(), m.tolist())]
    assert floored_mean(u, f, m).tolist() == pytest.approx(want)


def test_object_floor_errors_are_one_line():
    from imls_lightning.core.importance import check_object_floor

    for margin, tau, msg in ((-0.1, 0.2, "object_floor.margin=-0.1: expected a share of the C-Image in [0, 1]"),
                             (1.5, 0.2, "object_floor.margin=1.5"), (float("nan"), 0.2, "object_floor.margin=nan"),
                             (0.1, 0.0, "object_floor.tau=0.0: expected an importance in (0, 1)"),
                             (0.1, 1.0, "object_floor.tau=1.0"), (True, 0.2, "object_floor.margin=True")):
        with pytest.raises(InputError, match=re.escape(msg)) as e:
            check_object_floor(margin, tau)
        assert "\n" not in str(e.value)
