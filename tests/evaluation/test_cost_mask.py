"""evaluation/cost_mask.py: the cost-aware masks' formulas against direct implementations, and one view measured
with real (tiny) networks on the numba ray caster."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.evaluation.cost_mask import (cost_at_gap, cost_aware_score, cost_fit, cost_kept, cost_on_grid,
                                                 measure_view, needed_cost, ray_costs, speedup_ceiling, summarize)


def test_cost_aware_score_divides_by_cost_to_the_alpha():
    g = torch.Generator().manual_seed(0)
    score, cost = torch.rand(1, 1, 5, 5, generator=g), torch.rand(1, 1, 5, 5, generator=g) * 50
    assert torch.equal(cost_aware_score(score, cost, 0.0), score)
    for a in (0.5, 1.0, 2.0):
        direct = torch.tensor([[s / (1 + c) ** a for s, c in zip(rs, rc)] for rs, rc in zip(score[0, 0].tolist(), cost[0, 0].tolist())])
        assert torch.allclose(cost_aware_score(score, cost, a)[0, 0], direct, rtol=1e-6)
    assert torch.isfinite(cost_aware_score(score, torch.full_like(cost, 1e30), 2.0)).all()  # no Inf at dear pixels


def test_exception_alpha_is_a_number_at_least_zero():
    with pytest.raises(InputError, match="alpha"):
        cost_aware_score(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 2, 2), -1.0)


def test_cost_kept_and_grid():
    cost = np.array([5.0, 0.0, 3.0, 2.0])
    mask = np.array([True, True, False, True])
    assert cost_kept(mask, cost) == pytest.approx(7.0 / 10.0)
    assert cost_kept(mask, np.zeros(4)) == 1.0  # nothing costs: nothing left out
    from imls_lightning.core.patterns import build_pattern

    pattern = build_pattern({"kind": "downsample", "factor": 2}, 8)
    grid = cost_on_grid(np.arange(pattern.count, dtype=float), pattern)
    assert grid.shape == (1, 1, pattern.c_size, pattern.c_size)
    assert grid.flatten()[: pattern.count].tolist() == list(range(pattern.count))


def test_ceiling_and_needed_cost_are_inverse():
    alone, pattern_ms, recnn_ms, nets = 90.0, 75.0, 15.0, 23.0
    for target in (0.8, 1.0, 1.5):
        c = needed_cost(target, alone, pattern_ms, recnn_ms, nets)
        assert speedup_ceiling(alone, pattern_ms, recnn_ms, nets, c) == pytest.approx(target)
    assert speedup_ceiling(alone, pattern_ms, recnn_ms, 0.0, 1.0) == pytest.approx(1.0)  # the whole pattern, free nets
    assert needed_cost(1.5, alone, pattern_ms, recnn_ms, nets) < 0.3  # the networks eat most of 1.5x's budget


def test_cost_at_gap_interpolates_in_order_of_cost():
    assert cost_at_gap([0.9, 0.5, 0.7], [0.5, 3.0, 1.5], 1.0) == pytest.approx(0.8)
    assert cost_at_gap([0.4, 0.6], [0.5, 0.1], 1.0) == pytest.approx(0.4)  # the cheapest already within
    assert cost_at_gap([0.4, 0.6], [3.0, 2.0], 1.0) is None


def test_cost_fit_recovers_a_line():
    x = np.linspace(10, 80, 12)
    fit = cost_fit(x, 3.0 + 0.9 * x)
    assert fit["fixed_ms"] == pytest.approx(3.0) and fit["per_unit_ms"] == pytest.approx(0.9) and fit["r2"] == pytest.approx(1.0)


def test_exception_ray_costs_need_a_caster_that_counts(blob_scene):
    from imls_lightning.render.vtk import VTKRenderer

    r = VTKRenderer(blob_scene)
    try:
        with pytest.raises(InputError, match="renderer=numba"):
            ray_costs(r, [0, 0, 3, 0, 0, 0, 0, 1, 0], 16, np.arange(10))
    finally:
        r.close()


def test_one_view_with_real_networks(tiny_checkpoints):
    """The product, the IML and the oracle masks on one view of the tiny scene: every kind measured, costs in [0, 1],
    the share-1 end keeping (nearly) the whole cost, no NaN; the summary's ceilings follow its own formulas."""
    from imls_lightning.inference.checkpoints import load_ims_nets, load_task, renderer_for
    from imls_lightning.core.operating_point import OperatingPoint
    from imls_lightning.inference.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions, RecNNAlone

    nets = load_ims_nets(tiny_checkpoints["ims_pim"])
    ray = renderer_for(nets.hparams, renderer_cfg={"name": "numba", "skip_empty": True})
    opts = NetOptions(device="cpu")
    product = IMLSRenderer.from_nets(nets, ray, opts, point=OperatingPoint(share=0.4))
    alone = RecNNAlone(ray, nets.pattern, nets.recnn, opts)
    iml = load_task(tiny_checkpoints["iml"], expect="IMLTask").iml
    view = [0.0, 0.3, 3.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    truth = ray.render(view, nets.pattern.fr_size)
    v = measure_view(0, view, truth, alone, product, {0.3: IMLPlusRecNN(ray, nets.pattern, iml, nets.recnn, opts, mean=0.3)},
                     shares=(0.2, 1.0), alphas=(0.0, 1.0))
    kinds = {r["mask"] for r in v.rows}
    assert kinds == {"product", "iml", "oracle_alpha0", "oracle_alpha1"}
    for r in v.rows:
        assert 0.0 <= r["cost_kept"] <= 1.0 and math.isfinite(r["gap_db"])
    full = [r for r in v.rows if r["mask"].startswith("oracle") and r["setting"] == 1.0]
    assert all(r["cost_kept"] > 0.95 for r in full)
    s = summarize([v], 1.0)
    assert s["masks"]["oracle_alpha1"]["curve"][0]["cost_kept"] <= s["masks"]["oracle_alpha1"]["curve"][-1]["cost_kept"]
    for m in s["masks"].values():
        if m["cost_at_epsilon"] is not None:
            assert m["speedup_at_epsilon"] == pytest.approx(speedup_ceiling(s["alone_ms"], s["pattern_ms"], s["recnn_ms"],
                                                                           s["nets_ms"], m["cost_at_epsilon"]))
