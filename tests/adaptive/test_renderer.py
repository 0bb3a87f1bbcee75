"""imls_lightning.adaptive.renderer: the adaptive renderers against the fixed-mean ones (real tiny checkpoints)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.evaluation.timing import timed_run
from imls_lightning.adaptive import AdaptiveIMLPlusRecNN, AdaptiveIMLSRenderer, ConstantMean, scaled_pim_im
from imls_lightning.inference.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions
from imls_lightning.inference.checkpoints import load_task

CPU = NetOptions(device="cpu")


# ---- scaling the IMS's PIM' ------------------------------------------------------------------------
def test_scaled_pim_im_equals_output_to_im_at_the_trained_mean_and_grows_with_u(pim_task):
    n = pim_task.pattern.c_size
    g = torch.rand(3, 1, n, n, generator=torch.Generator().manual_seed(0)) * 2 - 1
    g[0, 0, 0, :4] = 1.0  # saturated pixels
    u0 = float(pim_task.iml.mean)
    assert torch.equal(scaled_pim_im(pim_task, g, torch.full((3,), u0)), pim_task.output_to_im(g))
    counts = [int(scaled_pim_im(pim_task, g, u).sum()) for u in (0.01, u0 / 2, u0, min(1.0, 3 * u0), 1.0)]
    assert counts == sorted(counts) and counts[0] < counts[2] < counts[-1]


def test_scaled_pim_im_lift_reaches_the_share_of_u_and_every_pixel_at_one(pim_task):
    n = pim_task.pattern.c_size
    valid = pim_task.valid.bool().view(n, n)
    k = int(valid.sum())
    g = torch.full((2, 1, n, n), -1.0)   # no importance but a saturated corner and a graded band
    g[:, 0, : n // 4, : n // 4] = 1.0
    g[:, 0, n // 2:, :] = torch.linspace(-0.9, 0.0, n)
    u0 = float(pim_task.iml.mean)
    plain = [float(scaled_pim_im(pim_task, g, u, lift=False)[0, 0][valid].float().mean()) for u in (0.9, 1.0)]
    assert plain[1] < 0.75  # the zeros stay zeros at any u
    assert not hasattr(pim_task, "lift_to_mean")  # no run-time switch: the lift is an argument
    for u in (u0, min(2 * u0, 0.5), 0.7, 0.9):
        im, im_plain = scaled_pim_im(pim_task, g, u, lift=True), scaled_pim_im(pim_task, g, u)
        share, share_plain = (float(m[0, 0][valid].float().mean()) for m in (im, im_plain))
        expected = max(u, share_plain) if u > u0 else share_plain  # at or below the trained mean: the paper's
        assert share == pytest.approx(expected, abs=0.04), u
        assert not bool((im_plain & ~im).any())  # scale first: it keeps every pixel the plain rescale samples
    full = scaled_pim_im(pim_task, g, 1.0, lift=True)
    assert int(full[0, 0][valid].sum()) == k and not bool(full[0, 0][~valid].any())
    assert torch.equal(pim_task.mask_head.threshold(g, 1.0, lift=True), full)  # the one home of the arithmetic


# ---- adaptive renderers ------------------------------------------------------------------------------
def test_adaptive_renderer_with_the_trained_mean_is_imls_renderer(pim_task, renderer, tiny_cache):
    u0 = float(pim_task.iml.mean)
    base = IMLSRenderer(renderer, pim_task.pattern, pim_task.mask_head, pim_task.decoder, pim_task.recnn, CPU)
    ada = AdaptiveIMLSRenderer(renderer, pim_task.pattern, pim_task.mask_head, pim_task.decoder, pim_task.recnn,
                               ConstantMean(u0), CPU)
    for r in tiny_cache.splits["test"][:3]:
        view = tiny_cache.views[int(r)]
        a, b = base.run(view), timed_run(ada, view)
        assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], b.info["im"])
        assert b.info["rendered_pixels"] == a.info["rendered_pixels"] and b.info["mean"] == pytest.approx(u0)
        assert set(b.timings) == {"mean", "importance", "selective_render", "decoder", "recnn", "total"}
        assert b.timings["total"] == pytest.approx(sum(v for k, v in b.timings.items() if k != "total"))


def test_adaptive_renderer_renders_more_pixels_at_a_larger_mean(pim_task, renderer, tiny_cache):
    u0 = float(pim_task.iml.mean)
    view = tiny_cache.views[int(tiny_cache.splits["test"][0])]
    counts = [AdaptiveIMLSRenderer(renderer, pim_task.pattern, pim_task.mask_head, pim_task.decoder, pim_task.recnn,
                                   ConstantMean(u), CPU).run(view).info["rendered_pixels"] for u in (0.01, u0, 1.0)]
    assert counts[0] < counts[1] < counts[2]


def test_adaptive_iml_plus_recnn_with_a_constant_mean_is_iml_plus_recnn(tiny_checkpoints, pim_task, renderer, tiny_cache):
    view = tiny_cache.views[int(tiny_cache.splits["test"][1])]
    for u in (0.05, 0.3):
        a = IMLPlusRecNN(renderer, pim_task.pattern, pim_task.iml, pim_task.recnn, CPU, mean=u).run(view)
        b = timed_run(AdaptiveIMLPlusRecNN(renderer, pim_task.pattern, pim_task.iml, pim_task.recnn, ConstantMean(u), CPU), view)
        assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], b.info["im"]) and "mean" in b.timings


def test_exception_target_im_is_refused(tiny_checkpoints, renderer):
    task = load_task(tiny_checkpoints["ims"], expect="IMSTask")
    assert task.target == "im"
    with pytest.raises(InputError, match="target=pim"):
        AdaptiveIMLSRenderer(renderer, task.pattern, task.mask_head, task.decoder, task.recnn, ConstantMean(0.1), CPU)
    with pytest.raises(InputError, match="target=pim"):
        scaled_pim_im(task, torch.zeros(1, 1, task.pattern.c_size, task.pattern.c_size), 0.1)
