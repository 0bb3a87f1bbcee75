"""imls_lightning.adaptive.predictor: MeanPredictor and train_predictor on synthetic data."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.adaptive import MeanPredictor, train_predictor


# ---- the predictor -------------------------------------------------------------------------------
def _synthetic(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    eye = torch.randn(n, 3, generator=g)
    eye = eye / eye.norm(dim=1, keepdim=True) * (3 + 1.5 * torch.rand(n, 1, generator=g))
    views = torch.cat([eye, torch.zeros(n, 3), torch.tensor([[0.0, 1.0, 0.0]]).expand(n, 3)], 1)
    u = torch.exp(-1.0 - 2.0 * (eye[:, 0] / eye.norm(dim=1)).clamp(-1, 1))  # in [e^-3, e^1] -> clamp
    return views, u.clamp(0.01, 1.0)


def test_predictor_trains_is_deterministic_and_in_range():
    views, u = _synthetic(64)
    vv, vu = _synthetic(32, seed=1)
    p1, h1 = train_predictor(views, u, val=(vv, vu), epochs=300, hidden=16, seed=3)
    p2, h2 = train_predictor(views, u, val=(vv, vu), epochs=300, hidden=16, seed=3)
    with torch.no_grad():
        a, b = p1(vv), p2(vv)
    assert torch.equal(a, b) and h1["train_l1"] == h2["train_l1"]
    assert h1["train_l1"] < 0.5 * h1["constant_l1"] and h1["val_l1"] < h1["val_constant_l1"]
    assert a.shape == (32,) and bool(((a >= 0.01) & (a <= 1.0)).all())
    p1.margin = 2.0
    with torch.no_grad():
        assert torch.allclose(p1(vv), (2 * a).clamp(0.01, 1.0))


def test_predictor_keeps_the_epoch_with_the_lowest_validation_l1():
    views, u = _synthetic(24)
    vv, vu = _synthetic(16, seed=1)
    vu = vu.flip(0)  # unrelated validation labels: training longer makes the validation L1 worse
    p, h = train_predictor(views, u, val=(vv, vu), epochs=200, hidden=16, seed=0)
    assert 1 <= h["best_epoch"] < 200
    # the same seed trained for exactly best_epoch steps without validation is the kept model
    q, hq = train_predictor(views, u, epochs=h["best_epoch"], hidden=16, seed=0)
    assert hq["best_epoch"] == h["best_epoch"]
    with torch.no_grad():
        assert torch.allclose(p(vv), q(vv), atol=1e-6)
    for epochs in (h["best_epoch"] + 1, 200):
        r, _ = train_predictor(views, u, epochs=epochs, hidden=16, seed=0)
        with torch.no_grad():
            l1 = float((r.log_mean(vv) - vu.clamp(0.01, 1).log()).abs().mean())
        assert l1 >= h["val_l1"] - 1e-6


def test_predictor_gradients_are_finite_at_extreme_inputs():
    p = MeanPredictor(hidden=8, layers=2)
    p.fit_normalization(_synthetic(16)[0])
    views = torch.tensor([[1e6] * 9, [-1e6] * 9, [0.0] * 9, [1.0, 2, 3, 1, 2, 3, 0, 1, 0]], requires_grad=True)
    u = p(views)
    assert bool(((u >= 0.01) & (u <= 1.0)).all())
    p.log_mean(views).sum().backward()
    assert torch.isfinite(views.grad).all()
    assert all(torch.isfinite(q.grad).all() for q in p.parameters())


def test_predictor_save_load_roundtrip(tmp_path):
    p, _ = train_predictor(*_synthetic(16), epochs=5, hidden=8)
    q = MeanPredictor.load(p.save(tmp_path / "p.pt"), margin=1.5)
    v = _synthetic(4, 2)[0]
    with torch.no_grad():
        assert torch.allclose(q(v), (1.5 * torch.exp(p.log_mean(v))).clamp(0.01, 1))
    with pytest.raises(InputError, match="margin"):
        MeanPredictor(margin=0)
    with pytest.raises(InputError, match="predictor="):
        MeanPredictor.load(tmp_path / "missing.pt")
