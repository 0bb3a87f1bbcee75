"""imls_lightning.core.pull_push: pull-push inpainting against direct loops, gradcheck."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.models.las import pull_push_inpaint


def ref_pull_push(mask: np.ndarray, data: np.ndarray):
    """Loop transcription of LAS ``fastInpaintFractional`` (renderer/inpainting_fast.cu).

    mask (B, H, W), data (B, C, H, W), float64. Returns (mask_out, data_out)."""
    B, C, H, W = data.shape
    if H <= 1 or W <= 1:
        return mask, data
    oH, oW = H // 2, W // 2
    mL = np.zeros((B, oH, oW))
    dL = np.zeros((B, C, oH, oW))
    for b in range(B):
        for i in range(oH):
            for j in range(oW):
                n1, n2, d = 0.0, 0.0, np.zeros(C)
                for ii in range(math.floor(i * H / oH), math.ceil((i + 1) * H / oH)):
                    for jj in range(math.floor(j * W / oW), math.ceil((j + 1) * W / oW)):
                        n1 += mask[b, ii, jj]
                        n2 = max(n2, mask[b, ii, jj])
                        d += mask[b, ii, jj] * data[b, :, ii, jj]
                mL[b, i, j] = n2
                dL[b, :, i, j] = d / n1 if n1 > 0 else 0.0
    mL, dL = ref_pull_push(mL, dL)
    mH = np.zeros_like(mask)
    dH = np.zeros_like(data)
    for b in range(B):
        for i in range(H):
            for j in range(W):
                io = -1 if i % 2 == 0 else 1
                jo = -1 if j % 2 == 0 else 1
                wsum, n, d = 0.0, 0.0, np.zeros(C)
                for ii, jj, w in ((i // 2, j // 2, 0.75 * 0.75), (i // 2 + io, j // 2, 0.25 * 0.75),
                                  (i // 2, j // 2 + jo, 0.25 * 0.75), (i // 2 + io, j // 2 + jo, 0.25 * 0.25)):
                    if 0 <= ii < oH and 0 <= jj < oW:
                        wsum += w
                        n += w * mL[b, ii, jj]
                        d += w * mL[b, ii, jj] * dL[b, :, ii, jj]
                m = mask[b, i, j]
                mH[b, i, j] = m + ((1 - m) * (n / wsum) if n > 0 else 0.0)
                dH[b, :, i, j] = m * data[b, :, i, j] + (1 - m) * (d / n if n > 0 else 0.0)
    return mH, dH


@pytest.mark.parametrize("shape", [(8, 8), (6, 5), (7, 3), (1, 4), (16, 16), (12, 9)])  # even sides pool in 2x2 blocks
@pytest.mark.parametrize("kind", ["binary", "soft"])
def test_pull_push_against_direct_loops(shape, kind):
    g = torch.Generator().manual_seed(shape[0] * 10 + shape[1] + (kind == "soft"))
    data = torch.rand(2, 3, *shape, generator=g, dtype=torch.float64)
    if kind == "binary":
        mask = (torch.rand(2, *shape, generator=g, dtype=torch.float64) < 0.3).double()
    else:
        mask = torch.rand(2, *shape, generator=g, dtype=torch.float64) ** 3
    got = pull_push_inpaint(data, mask)
    _, want = ref_pull_push(mask.numpy(), data.numpy())
    np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-12)


def test_pull_push_keeps_samples_and_fills_everything():
    data = torch.rand(1, 3, 16, 16)
    mask = torch.zeros(1, 1, 16, 16)
    mask[0, 0, 3, 5] = mask[0, 0, 12, 9] = 1.0
    out = pull_push_inpaint(data * mask, mask)
    assert torch.equal(out[mask.expand_as(out) > 0], data[mask.expand_as(data) > 0])
    # every pixel is a convex combination of the two samples: inside their colour box, no zeros
    lo = torch.minimum(data[0, :, 3, 5], data[0, :, 12, 9]).view(3, 1, 1)
    hi = torch.maximum(data[0, :, 3, 5], data[0, :, 12, 9]).view(3, 1, 1)
    assert bool(((out[0] >= lo - 1e-6) & (out[0] <= hi + 1e-6)).all())
    assert torch.equal(pull_push_inpaint(data, torch.zeros(1, 1, 16, 16)), torch.zeros_like(data))


def test_pull_push_gradcheck():
    data = torch.rand(1, 2, 5, 4, dtype=torch.float64, requires_grad=True)
    mask = (torch.rand(1, 1, 5, 4, dtype=torch.float64) * 0.9 + 0.05).requires_grad_(True)
    assert torch.autograd.gradcheck(pull_push_inpaint, (data, mask))


# ---- fill_c_image: the fill where the C-Image's neighbours are the picture's ------------------------
def _smooth_fr(m: int) -> torch.Tensor:
    y, x = torch.meshgrid(torch.linspace(0, 1, m, dtype=torch.float64), torch.linspace(0, 1, m, dtype=torch.float64), indexing="ij")
    return torch.stack([x, y, 0.5 * (x + y)])[None]  # (1, 3, m, m): a ramp, which pull-push rebuilds closely


def test_fill_c_image_grid_pattern_is_the_plain_fill():
    from imls_lightning.core.patterns import downsample_pattern
    from imls_lightning.core.pull_push import fill_c_image

    v, m = torch.rand(2, 3, 8, 8), (torch.rand(2, 1, 8, 8) > 0.6).float()
    for pattern in (None, downsample_pattern(16, 2)):
        assert torch.equal(fill_c_image(v, m, pattern), pull_push_inpaint(v, m))


def test_fill_c_image_foveal_against_a_direct_scatter_fill_gather():
    """A foveal C-Image is filled at its samples' FR positions: against a direct loop over the pattern's pixels."""
    from imls_lightning.core.patterns import foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    p = foveal_pattern(24, 8, None)
    k, n, fr = p.count, p.c_size, p.fr_size
    torch.manual_seed(0)
    v = torch.rand(1, 3, n, n, dtype=torch.float64)
    mask = (torch.rand(1, 1, n, n) > 0.5).double()
    got = fill_c_image(v, mask, p)
    fr_v, fr_m = torch.zeros(1, 3, fr, fr, dtype=torch.float64), torch.zeros(1, 1, fr, fr, dtype=torch.float64)
    for j in range(k):  # pixel j of the C-Image sits at FR raster index indices[j]
        y, x = divmod(int(p.indices[j]), fr)
        fr_v[0, :, y, x] = v[0, :, j // n, j % n] * mask[0, 0, j // n, j % n]
        fr_m[0, 0, y, x] = mask[0, 0, j // n, j % n]
    filled = pull_push_inpaint(fr_v, fr_m)
    want = torch.zeros_like(v)
    for j in range(k):
        y, x = divmod(int(p.indices[j]), fr)
        want[0, :, j // n, j % n] = filled[0, :, y, x]
    assert torch.allclose(got, want, atol=1e-12)
    keep = mask.bool().expand_as(v)
    assert torch.equal(got[keep], v[keep])  # sampled pixels unchanged


def test_fill_c_image_foveal_beats_the_fill_in_memory_order():
    """The reason for the function: on a smooth picture the C-Image's memory neighbours are not its
    picture neighbours, and filling among them is several times worse."""
    from imls_lightning.core.compaction import compact
    from imls_lightning.core.patterns import foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    p = foveal_pattern(64, 24, None)
    c = compact(_smooth_fr(p.fr_size), p.indices, p.c_size)
    torch.manual_seed(1)
    mask = (torch.rand(1, 1, p.c_size, p.c_size, dtype=torch.float64) > 0.7).double()
    valid = compact(torch.ones(1, 1, p.fr_size, p.fr_size, dtype=torch.float64), p.indices, p.c_size).bool()
    err_fr = (fill_c_image(c, mask, p) - c).abs()[valid.expand_as(c)].mean()
    err_c = (pull_push_inpaint(c, mask) - c).abs()[valid.expand_as(c)].mean()
    assert err_fr < 0.5 * err_c, (float(err_fr), float(err_c))


def test_fill_c_image_gradcheck():
    from imls_lightning.core.patterns import foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    p = foveal_pattern(12, 5, None)
    v = torch.rand(1, 2, 5, 5, dtype=torch.float64, requires_grad=True)
    m = (torch.rand(1, 1, 5, 5, dtype=torch.float64) * 0.9 + 0.05).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, b: fill_c_image(a, b, p), (v, m))


def test_exception_fill_c_image_mask_shape():
    from imls_lightning.core.patterns import foveal_pattern
    from imls_lightning.core.pull_push import fill_c_image

    p = foveal_pattern(12, 5, None)
    with pytest.raises((ValueError, RuntimeError)):
        fill_c_image(torch.rand(1, 3, 5, 5), torch.ones(1, 1, 4, 4), p)


def test_in_layout_of_keeps_a_channels_last_layout_and_nothing_else():
    from imls_lightning.core.pull_push import fill_c_image, in_layout_of

    c = torch.rand(1, 6, 6, 3).permute(0, 3, 1, 2)
    m = (torch.rand(1, 1, 6, 6) > 0.5).float()
    out = in_layout_of(fill_c_image(c * m, m), c)
    assert out.is_contiguous(memory_format=torch.channels_last) and not out.is_contiguous()
    assert torch.equal(out, fill_c_image(c * m, m))                 # the same values, another layout
    plain = torch.rand(2, 3, 6, 6)
    assert in_layout_of(plain, plain) is plain                      # a plain contiguous layout stays as it is
    assert in_layout_of(c.contiguous(), plain).is_contiguous()
