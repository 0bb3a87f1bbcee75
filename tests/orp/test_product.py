"""imls_lightning.orp.product: the ORP on the product path (IML/S + RecNN against the RecNN alone), on a perfect
IMS against direct computations."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.core.patterns import plastic_rank_pattern
from imls_lightning.models.ims import IMSMaskHead
from imls_lightning.orp.product import product_orp
from imls_lightning.tasks.base import psnr_per_image
from tests.inference.test_baselines import N, _nets, _scene


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
