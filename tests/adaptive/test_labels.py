"""Adaptive mean value (``imls_lightning.adaptive``): labels, predictor, adaptive renderers, CLI.

Real components: the ``tiny_checkpoints`` fixture (conftest.py) gives a RecNN, an end-to-end IML and
an IMS (``target="im"``) on ``scene=tiny data=tiny``; the IMS checkpoint is copied once with
``target="pim"`` (same weights: the generator's output is then read as PIM'), which is what the
adaptive renderer needs. The bisection is checked against synthetic monotone gaps with a known answer.
"""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.adaptive import (
    MeanLabels,
    bisect_mean,
    compute_labels,
    im_at_means,
    iml_pim,
    quality_at_means,
    view_complexity,
)
from imls_lightning.inference.checkpoints import load_task


def _c_fr(cache, rows, pattern):
    from imls_lightning.core.compaction import compact

    img = torch.from_numpy(np.array(cache.images[rows])).permute(0, 3, 1, 2).float() / 255
    return compact(img, pattern.indices, pattern.c_size), img


# ---- bisection ---------------------------------------------------------------------------------
def test_bisect_mean_finds_the_known_answer_of_a_monotone_gap():
    # gap(u) = 20 log10(t / u) for u < t (0 beyond): the smallest u with gap <= eps is t * 10^(-eps/20)
    t = torch.tensor([0.005, 0.05, 0.3, 0.99, 5.0], dtype=torch.float64)
    eps, steps = 1.0, 10
    res = bisect_mean(lambda u: (20 * torch.log10(t / u)).clamp(min=0), len(t), eps, steps)
    answer = t * 10 ** (-eps / 20)
    tol = math.log(100) / 2**steps + 1e-12
    assert res.met.tolist() == [True, True, True, True, False]
    assert res.u[0] == 0.01                      # passes at the lower end already
    assert res.u[4] == 1.0                       # nothing in [0.01, 1] meets epsilon
    for i in (1, 2, 3):
        assert answer[i] <= res.u[i] <= answer[i] * math.exp(tol)  # never below the answer, within one step
        assert res.gap[i] <= eps
    assert res.evaluations == steps + 2


def test_bisect_mean_treats_nan_as_failing_and_is_vectorized():
    calls = []

    def gap(u):
        calls.append(u.clone())
        return torch.where(u > 0.2, torch.zeros_like(u), torch.full_like(u, float("nan")))

    res = bisect_mean(gap, 4, 0.5, steps=6)
    assert len(calls) == 8 and all(c.shape == (4,) for c in calls)
    assert torch.all(res.u > 0.2) and torch.all(res.u < 0.2 * 100 ** (1 / 64) + 1e-9) and res.met.all()


def test_bisect_mean_unreachable_best_labels_within_epsilon_of_the_best_gap():
    # gap(u) = max(floor, 20 log10(t / u)): views with floor > eps never meet epsilon; "best" gives the
    # smallest u with gap <= floor + eps (= t * 10^(-(floor + eps)/20) where that is inside the bracket)
    t = torch.tensor([0.05, 0.5, 0.5, 0.5], dtype=torch.float64)
    floor = torch.tensor([0.0, 0.0, 3.0, 50.0], dtype=torch.float64)
    eps, steps = 1.0, 12

    def gap(u):
        return torch.maximum(floor, 20 * torch.log10(t / u))

    hi = bisect_mean(gap, 4, eps, steps, unreachable="hi")
    best = bisect_mean(gap, 4, eps, steps, unreachable="best")
    assert hi.met.tolist() == best.met.tolist() == [True, True, False, False]
    assert torch.equal(hi.u[:2], best.u[:2])                  # reachable views: the same labels
    assert hi.u[2] == hi.u[3] == 1.0
    tol = math.log(100) / 2**steps + 1e-12
    answer = 0.5 * 10 ** (-(3.0 + eps) / 20)
    assert answer <= best.u[2] <= answer * math.exp(tol) and best.gap[2] <= 3.0 + eps
    assert best.u[3] == 0.01                                   # flat at 50 dB: the bracket's bottom is as good
    with pytest.raises(InputError, match="unreachable"):
        bisect_mean(gap, 4, eps, unreachable="nope")


def test_exception_bad_steps_and_bracket():
    with pytest.raises(InputError, match="steps"):
        bisect_mean(lambda u: u * 0, 2, 1.0, steps=0)
    with pytest.raises(InputError, match="bracket"):
        bisect_mean(lambda u: u * 0, 2, 1.0, bracket=(0.5, 0.1))


# ---- the IML path at per-view means --------------------------------------------------------------
def test_im_at_means_is_the_imls_own_path_at_each_mean(tiny_checkpoints, tiny_cache):
    iml = load_task(tiny_checkpoints["iml"], expect="IMLTask")
    c, _ = _c_fr(tiny_cache, tiny_cache.splits["train"][:3], iml.pattern)
    means = [0.01, 0.137, 1.0]
    with torch.inference_mode():
        got = im_at_means(iml.iml, iml_pim(iml.iml, c), means)
        for b, u in enumerate(means):
            net = copy.deepcopy(iml.iml)
            net.mean = u
            assert torch.equal(got[b:b + 1], net.importance(c[b:b + 1], hard=True)), u
    counts = got.flatten(1).sum(1)
    assert counts[0] <= counts[1] <= counts[2]


def test_labels_on_tiny_are_in_range_and_consistent(tiny_checkpoints, tiny_cache, pim_task, tmp_path):
    rows = tiny_cache.splits["train"][:6]
    lab = compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn,
                         epsilon_db=1.0, steps=4, batch_size=4, device="cpu", progress=False)
    assert len(lab) == 6 and lab.views.shape == (6, 9)
    assert np.all((lab.u >= 0.01) & (lab.u <= 1.0))
    assert np.all(lab.gap_db[lab.met] <= 1.0) and np.all(np.isfinite(lab.psnr_ref))
    assert np.all(lab.u[~lab.met] == 1.0)
    assert np.all((lab.complexity >= 0) & (lab.complexity <= 1))
    back = MeanLabels.load(lab.save(tmp_path / "l.npz"))
    assert np.array_equal(back.u, lab.u) and back.meta["steps"] == 4


def test_view_complexity_counts_non_background_pixels():
    img = np.zeros((2, 4, 4, 3), np.uint8)
    img[0, 0, :2] = 255
    img[1] = 255
    assert view_complexity(img).tolist() == [2 / 16, 1.0]
    assert view_complexity(img, background=(1.0, 1.0, 1.0)).tolist() == [14 / 16, 0.0]
    with pytest.raises(InputError, match="images"):
        view_complexity(np.zeros((4, 4, 3), np.uint8))


def test_labels_with_the_iml_reference_stay_below_the_trained_mean(tiny_cache, pim_task):
    u0 = float(pim_task.iml.mean)
    rows = tiny_cache.splits["train"][:4]
    lab = compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn, epsilon_db=0.5,
                         steps=4, batch_size=4, device="cpu", progress=False, reference="iml", bracket=(0.01, u0))
    # the trained mean is the reference itself: every view meets epsilon at or below it
    assert lab.met.all() and np.all((lab.u >= 0.01) & (lab.u <= u0 + 1e-12)) and np.all(lab.gap_db <= 0.5)
    with pytest.raises(InputError, match="reference"):
        compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn, reference="x")


def test_labels_on_the_imls_path_meet_epsilon_there(tiny_cache, pim_task):
    rows = tiny_cache.splits["train"][:6]
    args = (tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn)
    lab = compute_labels(*args, epsilon_db=1.0, steps=5, batch_size=4, progress=False, source="ims", ims=pim_task,
                         unreachable="best")
    assert lab.meta["source"] == "ims" and np.all((lab.u >= 0.01) & (lab.u <= 1.0))
    # re-measure each view at its own label with the independent quality_at_means: the gap is the one bisected
    q = quality_at_means(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, {"label": lab.u, "top": 1.0},
                         source="ims", ims=pim_task)
    gap = q["recnn"]["psnr"] - q["label"]["psnr"]
    np.testing.assert_allclose(gap, lab.gap_db, atol=1e-4)
    thr = np.where(lab.met, 1.0, (q["recnn"]["psnr"] - q["top"]["psnr"]) + 1.0)
    assert np.all(gap <= thr + 1e-4)
    # the trained mean as the reference: every view meets epsilon at or below it
    u0 = float(pim_task.iml.mean)
    lab2 = compute_labels(*args, epsilon_db=0.5, steps=4, progress=False, source="ims", ims=pim_task, reference="iml",
                          bracket=(0.01, u0))
    assert lab2.met.all() and np.all(lab2.u <= u0 + 1e-12)
    with pytest.raises(InputError, match="label_source"):
        compute_labels(*args, source="ims", ims=None)
