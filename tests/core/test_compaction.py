"""Compaction / decompaction: against the paper's dense C and D matrices, round trips, gradcheck,
batch/channel handling, and the errors a user can hit."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.compaction import Compaction, Decompaction, compact, decompact
from imls_lightning.core.patterns import SamplingPattern, downsample_pattern, foveal_pattern


def _random_pattern(m: int = 10, n: int = 8, k: int = 41, seed: int = 0) -> SamplingPattern:
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(m * m, generator=g)[:k].sort().values
    return SamplingPattern("random", m, n, idx, (("seed", seed),))


PATTERNS = {
    "downsample": lambda: downsample_pattern(8, 2),  # K = n^2, no padding
    "foveal": lambda: foveal_pattern(12, 5, 0.1, seed=1),  # fixed sigma: padded C-Image
    "random_padded": lambda: _random_pattern(),
}


@pytest.fixture(params=sorted(PATTERNS))
def pattern(request) -> SamplingPattern:
    return PATTERNS[request.param]()


def _dense_c(p: SamplingPattern) -> torch.Tensor:
    """The paper's m^2 x n^2 compaction matrix: C-Image (row vector) = PR-Image (row vector) @ C."""
    c = torch.zeros(p.fr_size**2, p.c_size**2, dtype=torch.float64)
    c[p.indices, torch.arange(p.count)] = 1.0
    return c


# --- against a direct reimplementation: the dense matrices -------------------------------------


def test_compact_equals_dense_c_matrix(pattern):
    m, n = pattern.fr_size, pattern.c_size
    x = torch.rand(2, 3, m, m, dtype=torch.float64)
    want = (x.reshape(2, 3, m * m) @ _dense_c(pattern)).reshape(2, 3, n, n)
    assert torch.equal(compact(x, pattern.indices, n), want)


def test_decompact_equals_dense_d_matrix(pattern):
    m, n = pattern.fr_size, pattern.c_size
    c_mat = _dense_c(pattern)
    d_mat = torch.linalg.pinv(c_mat)  # the paper's D = C^-1 (pseudo-inverse when padded)
    assert torch.allclose(d_mat, c_mat.T, atol=1e-12)  # a selection matrix: D = C^T
    c_img = torch.rand(2, 3, n, n, dtype=torch.float64)
    want = (c_img.reshape(2, 3, n * n) @ d_mat).reshape(2, 3, m, m)
    assert torch.allclose(decompact(c_img, pattern.indices, m), want, atol=1e-12)


def test_dense_matrices_compose_to_the_masks(pattern):
    c_mat = _dense_c(pattern)
    assert torch.equal(c_mat @ c_mat.T, torch.diag(pattern.mask.reshape(-1).double()))
    assert torch.equal(c_mat.T @ c_mat, torch.diag(pattern.valid.reshape(-1).double()))


# --- round trips ---------------------------------------------------------------------------------


def test_decompact_compact_is_identity_on_pattern_and_zero_elsewhere(pattern):
    m, n = pattern.fr_size, pattern.c_size
    x = torch.rand(2, 3, m, m) + 1.0  # strictly positive: a zero outside the pattern is meaningful
    back = decompact(compact(x, pattern.indices, n), pattern.indices, m)
    mask = pattern.mask
    assert torch.equal(back[..., mask], x[..., mask])
    assert torch.count_nonzero(back[..., ~mask]) == 0


def test_compact_pads_with_zeros_and_decompact_ignores_padding(pattern):
    m, n = pattern.fr_size, pattern.c_size
    c = compact(torch.rand(1, 2, m, m) + 1.0, pattern.indices, n)
    assert torch.count_nonzero(c[..., ~pattern.valid]) == 0
    assert torch.count_nonzero(c[..., pattern.valid]) == 2 * pattern.count
    garbage = torch.rand(1, 2, n, n) * ~pattern.valid  # only on the padding
    assert torch.count_nonzero(decompact(c + garbage, pattern.indices, m) - decompact(c, pattern.indices, m)) == 0


# --- gradients -----------------------------------------------------------------------------------


def test_gradcheck_compact_float64(pattern):
    x = torch.rand(2, 2, pattern.fr_size, pattern.fr_size, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: compact(t, pattern.indices, pattern.c_size), (x,))


def test_gradcheck_decompact_float64(pattern):
    c = torch.rand(2, 2, pattern.c_size, pattern.c_size, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: decompact(t, pattern.indices, pattern.fr_size), (c,))


def test_backward_of_compaction_is_decompaction(pattern):
    x = torch.rand(1, 1, pattern.fr_size, pattern.fr_size, requires_grad=True)
    g = torch.rand(1, 1, pattern.c_size, pattern.c_size)
    compact(x, pattern.indices, pattern.c_size).backward(g)
    assert torch.equal(x.grad, decompact(g, pattern.indices, pattern.fr_size))


# --- batch, channels, dtypes, modules --------------------------------------------------------------


@pytest.mark.parametrize("lead", [(), (3,), (2, 3), (2, 1, 4)])
def test_any_leading_dims_match_per_slice_results(lead):
    p = _random_pattern()
    x = torch.rand(*lead, p.fr_size, p.fr_size)
    c = compact(x, p.indices, p.c_size)
    assert c.shape == (*lead, p.c_size, p.c_size)
    ref = compact(x.reshape(-1, 1, p.fr_size, p.fr_size), p.indices, p.c_size).reshape(c.shape)
    assert torch.equal(c, ref)
    assert decompact(c, p.indices, p.fr_size).shape == x.shape


@pytest.mark.parametrize("dtype", [torch.uint8, torch.bool, torch.float16, torch.int64])
def test_integer_bool_and_half_images(dtype):
    p = _random_pattern()
    x = (torch.rand(2, 3, p.fr_size, p.fr_size) * 200 + 1).to(dtype)
    c = compact(x, p.indices, p.c_size)
    assert c.dtype == dtype
    back = decompact(c, p.indices, p.fr_size)
    assert torch.equal(back[..., p.mask], x[..., p.mask])
    assert not back[..., ~p.mask].any()


def test_modules_from_pattern_match_functions_and_keep_no_state():
    p = foveal_pattern(12, 5, 0.1, seed=1)
    comp, decomp = Compaction.from_pattern(p), Decompaction.from_pattern(p)
    x = torch.rand(2, 3, 12, 12)
    assert torch.equal(comp(x), compact(x, p.indices, p.c_size))
    assert torch.equal(decomp(comp(x)), decompact(compact(x, p.indices, 5), p.indices, 12))
    assert comp.state_dict() == {} and decomp.state_dict() == {}  # rebuilt from the pattern config
    assert f"K={p.count}" in repr(comp)


def test_modules_follow_the_input_device_and_dtype():
    p = downsample_pattern(8, 2)
    net = torch.nn.Sequential(Compaction.from_pattern(p), Decompaction.from_pattern(p)).double()
    x = torch.rand(1, 3, 8, 8, dtype=torch.float64)
    assert net(x).dtype == torch.float64
    assert net[0].indices.dtype == torch.long  # .double() leaves the index buffers alone


# --- exceptions ----------------------------------------------------------------------------------


def test_too_many_pattern_pixels_are_refused_clearly():
    idx = torch.arange(17)
    with pytest.raises(InputError, match=r"17 pixels, more than the C-Image holds \(4x4=16\)"):
        compact(torch.rand(1, 1, 8, 8), idx, 4)
    with pytest.raises(InputError, match="more than the C-Image holds"):
        decompact(torch.rand(1, 1, 4, 4), idx, 8)
    with pytest.raises(InputError, match="more than the C-Image holds"):
        Compaction(idx, 4)
    with pytest.raises(InputError, match="pattern.c_size"):
        SamplingPattern("random", 8, 4, idx)


@pytest.mark.parametrize(
    "shape, fr_size, match",
    [
        ((1, 3, 8, 9), None, r"expected a tensor of shape \(B, C, m, m\)"),
        ((8,), None, r"expected a tensor of shape"),
        ((1, 3, 6, 6), 8, r"expected a tensor of shape \(B, C, 8, 8\).*got \(1, 3, 6, 6\)"),
    ],
)
def test_compact_shape_errors_name_the_expected_shape(shape, fr_size, match):
    p = downsample_pattern(8, 2)
    with pytest.raises(ValueError, match=match):
        compact(torch.rand(*shape), p.indices, p.c_size, fr_size)


def test_compaction_module_rejects_a_wrong_resolution():
    p = downsample_pattern(8, 2)
    with pytest.raises(ValueError, match=r"\(B, C, 8, 8\)"):
        Compaction.from_pattern(p)(torch.rand(1, 3, 16, 16))
    with pytest.raises(ValueError, match=r"\(B, C, 4, 4\)"):
        Decompaction.from_pattern(p)(torch.rand(1, 3, 5, 5))


def test_bare_compact_detects_an_image_smaller_than_the_pattern():
    p = downsample_pattern(8, 2)
    with pytest.raises(ValueError, match="wrong resolution"):
        compact(torch.rand(1, 3, 4, 4), p.indices, p.c_size)


def test_bad_indices_are_rejected():
    with pytest.raises(ValueError, match="1D int64"):
        compact(torch.rand(1, 1, 4, 4), torch.tensor([0.0, 1.0]), 2)
    with pytest.raises(ValueError, match="1D int64"):
        decompact(torch.rand(1, 1, 2, 2), torch.tensor([[0, 1]]), 4)
