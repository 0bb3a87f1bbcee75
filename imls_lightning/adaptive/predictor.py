"""The mean predictor: view ``(B, 9)`` -> mean value ``u`` ``(B,)`` (:class:`MeanPredictor`, trained by
:func:`train_predictor`), and the fixed and table "predictors" it is compared with
(:class:`ConstantMean`, :class:`TableMean`).
"""
from __future__ import annotations

import copy
import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from imls_lightning.base.errors import InputError, finite_number
from imls_lightning.render.camera import view_tensor

from ..core.importance import MEAN_RANGE
from .checks import check_integer, clamp_mean


class MeanPredictor(nn.Module):
    """View ``(B, 9)`` -> mean value ``u`` ``(B,)`` in ``[lo, hi]`` (default ``[0.01, 1]``).

    Features: the 9 view floats, the unit view direction ``lookAt - eye`` and the camera distance
    (13 numbers), standardized with statistics fitted on the training views
    (:meth:`fit_normalization`, stored as buffers). An MLP (``layers`` hidden layers of ``hidden``
    units, SiLU) gives ``z``; ``log u = log lo + (log hi - log lo) sigmoid(z)`` (:meth:`log_mean`,
    what training fits), and ``forward`` returns ``clamp(margin * exp(log u), lo, hi)``: a
    ``margin > 1`` renders a few more pixels than predicted, a safety factor against
    under-prediction. Gradients stay finite for any finite view (the sigmoid saturates, the
    direction is divided by ``max(distance, 1e-6)``).

    Example:
        >>> p = MeanPredictor(hidden=8, layers=1)
        >>> u = p(torch.tensor([[0, 0, 3.0, 0, 0, 0, 0, 1, 0]]))
        >>> u.shape, bool((u >= 0.01).all() and (u <= 1).all())
        (torch.Size([1]), True)
    """

    FEATURES = 13

    def __init__(self, hidden: int = 64, layers: int = 2, margin: float = 1.0, bracket: Sequence[float] = MEAN_RANGE):
        super().__init__()
        hidden = check_integer(hidden, "predictor.hidden", 1, 4096)
        layers = check_integer(layers, "predictor.layers", 0, 16)
        lo, hi = (finite_number(x, "predictor.bracket", "two numbers in [0.01, 1]") for x in bracket)
        if not MEAN_RANGE[0] <= lo < hi <= MEAN_RANGE[1]:
            raise InputError(f"predictor.bracket=[{lo}, {hi}]: expected {MEAN_RANGE[0]} <= lo < hi <= {MEAN_RANGE[1]}")
        self.hidden, self.layers, self.bracket = hidden, layers, (lo, hi)
        self.margin = margin
        mods: list[nn.Module] = []
        width = self.FEATURES
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        mods.append(nn.Linear(width, 1))
        self.mlp = nn.Sequential(*mods)
        self.register_buffer("feat_mean", torch.zeros(self.FEATURES))
        self.register_buffer("feat_std", torch.ones(self.FEATURES))

    @property
    def margin(self) -> float:
        return self._margin

    @margin.setter
    def margin(self, value: float) -> None:
        m = finite_number(value, "predictor.margin", "a number in (0, 10]")
        if not 0 < m <= 10:
            raise InputError(f"predictor.margin={value!r}: expected a number in (0, 10] (1: no margin)")
        self._margin = m

    def hparams(self) -> dict[str, Any]:
        return {"hidden": self.hidden, "layers": self.layers, "margin": self.margin, "bracket": list(self.bracket)}

    @staticmethod
    def features(view: torch.Tensor) -> torch.Tensor:
        """``(B, 9)`` -> ``(B, 13)``: view, unit direction ``lookAt - eye``, distance."""
        v = view_tensor(view)
        d = v[:, 3:6] - v[:, 0:3]
        dist = d.norm(dim=1, keepdim=True)
        return torch.cat([v, d / dist.clamp_min(1e-6), dist], dim=1)

    @torch.no_grad()
    def fit_normalization(self, views: torch.Tensor) -> None:
        """Standardize the features with the mean/std of these training views ``(N, 9)``."""
        f = self.features(views)
        if f.shape[0] < 1:
            raise InputError("views: expected at least one training view")
        std = f.std(0, unbiased=False) if f.shape[0] > 1 else torch.ones(self.FEATURES)
        self.feat_mean.copy_(f.mean(0))
        self.feat_std.copy_(torch.where(std < 1e-6, torch.ones_like(std), std))

    def log_mean(self, view: torch.Tensor) -> torch.Tensor:
        """``log u`` ``(B,)`` before the margin, in ``[log lo, log hi]`` (the quantity trained)."""
        f = self.features(view).to(self.feat_mean.device)
        z = self.mlp((f - self.feat_mean) / self.feat_std)[:, 0]
        lo, hi = math.log(self.bracket[0]), math.log(self.bracket[1])
        return lo + (hi - lo) * torch.sigmoid(z)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        u = torch.exp(self.log_mean(view)) * self.margin
        return u.clamp(self.bracket[0], self.bracket[1])

    def save(self, path: str | Path) -> Path:
        """State dict + hyperparameters, loadable with ``torch.load(weights_only=True)``; atomic."""
        from imls_lightning.base.atomic import atomic_write

        return atomic_write(path, lambda f: torch.save({"hparams": self.hparams(), "state_dict": self.state_dict()}, f), unique=True)

    @classmethod
    def load(cls, path: str | Path, margin: float | None = None) -> "MeanPredictor":
        try:
            d = torch.load(Path(path), map_location="cpu", weights_only=True)
            hp = dict(d["hparams"])
            if margin is not None:
                hp["margin"] = margin
            p = cls(**hp)
            p.load_state_dict(d["state_dict"])
        except (OSError, KeyError, RuntimeError, TypeError) as err:
            raise InputError(f"predictor={path}: not a MeanPredictor file ({type(err).__name__}: {str(err)[:120]})") from None
        return p.eval()


class ConstantMean(nn.Module):
    """The fixed-mean "predictor": ``u`` for every view, ``(B,)`` float32.

    Example:
        >>> ConstantMean(0.2)(torch.zeros(2, 9)).tolist() == [torch.tensor(0.2).item()] * 2
        True
    """

    def __init__(self, u: float):
        super().__init__()
        u = finite_number(u, "u", f"a number in [{MEAN_RANGE[0]}, {MEAN_RANGE[1]}]")
        if not MEAN_RANGE[0] <= u <= MEAN_RANGE[1]:
            raise InputError(f"u={u}: expected a number in [{MEAN_RANGE[0]}, {MEAN_RANGE[1]}]")
        self.u = u

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        return torch.full((view.shape[0],), self.u, dtype=torch.float32, device=view.device)

    def extra_repr(self) -> str:
        return f"u={self.u}"


class TableMean(nn.Module):
    """Looks a view's mean value up in a table (the per-view labels: the oracle predictor)."""

    def __init__(self, views: np.ndarray, u: np.ndarray):
        super().__init__()
        self.views = np.asarray(views, np.float32)
        self.u = np.asarray(u, np.float64)

    def forward(self, view: torch.Tensor) -> torch.Tensor:
        v = view.detach().float().cpu().numpy()
        idx = [int(np.argmin(np.abs(self.views - x[None]).sum(1))) for x in v]
        return torch.tensor([clamp_mean(self.u[i]) for i in idx], dtype=torch.float32, device=view.device)


def train_predictor(views: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor, *,
                    val: tuple[Any, Any] | None = None, hidden: int = 64, layers: int = 2, epochs: int = 600,
                    lr: float = 3e-3, weight_decay: float = 1e-4, seed: int = 0, margin: float = 1.0,
                    progress: bool = False) -> tuple[MeanPredictor, dict[str, Any]]:
    """Fit a :class:`MeanPredictor` to per-view labels: L1 on ``log u``, full-batch Adam on the CPU.

    Deterministic for a given ``seed`` (the global RNG is left as it was).

    Args:
        views: ``(N, 9)`` training views; ``u``: ``(N,)`` labels in ``[0.01, 1]``.
        val: optional ``(views, u)``: the validation L1 is reported and the epoch where it is lowest
            is kept (early stopping by model selection).
        hidden, layers, margin: :class:`MeanPredictor` settings; ``epochs``: full-batch steps.

    Returns:
        ``(predictor in eval mode, history)`` with ``train_l1``, ``val_l1`` (``log u``; None without
        ``val``), ``constant_l1`` (the best constant, the median label: the baseline to beat),
        ``seconds``, ``epochs``, ``best_epoch`` (the kept epoch; ``epochs`` without ``val``).

    Example:
        >>> v = torch.randn(32, 9); y = torch.exp(-2 + v[:, 0].clamp(-1, 1))
        >>> p, h = train_predictor(v, y, epochs=200, hidden=16)
        >>> h["train_l1"] < h["constant_l1"]
        True
    """
    x = view_tensor(views)
    y = torch.as_tensor(np.asarray(u, np.float64)).float().reshape(-1)
    if x.dim() != 2 or x.shape[1] != 9 or x.shape[0] < 1 or x.shape[0] != y.shape[0]:
        raise InputError(f"views/u: expected (N, 9) views and (N,) labels with N >= 1, got {tuple(x.shape)} and {tuple(y.shape)}")
    if not bool(torch.isfinite(y).all()) or float(y.min()) <= 0:
        raise InputError("u: expected positive finite labels in [0.01, 1]")
    epochs = check_integer(epochs, "predictor.epochs", 1, 1_000_000)
    lr = finite_number(lr, "predictor.lr", "a positive learning rate")
    wd = finite_number(weight_decay, "predictor.weight_decay", "a number >= 0")
    if lr <= 0 or wd < 0:
        raise InputError(f"predictor.lr={lr}, predictor.weight_decay={wd}: expected lr > 0 and weight_decay >= 0")
    target = y.clamp(*MEAN_RANGE).log()
    t0 = time.perf_counter()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        model = MeanPredictor(hidden=hidden, layers=layers, margin=margin)
        model.fit_normalization(x)
        opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=wd)
        has_val = val is not None and len(val[0]) > 0
        if has_val:
            vx = torch.as_tensor(np.asarray(val[0], np.float32))
            vy = torch.as_tensor(np.asarray(val[1], np.float64)).float().clamp(*MEAN_RANGE).log()
        # With validation labels the epoch with the lowest validation L1 is kept: a few hundred views
        # are easily memorized by the MLP (train L1 falls far below a validation L1 that rises).
        best_l1, best_epoch, best_state = math.inf, epochs, None
        with torch.enable_grad():
            for epoch in range(1, epochs + 1):
                model.train()
                loss = (model.log_mean(x) - target).abs().mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                if has_val:
                    model.eval()
                    with torch.no_grad():
                        v_l1 = float((model.log_mean(vx) - vy).abs().mean())
                    if v_l1 < best_l1:
                        best_l1, best_epoch, best_state = v_l1, epoch, copy.deepcopy(model.state_dict())
        if best_state is not None:
            model.load_state_dict(best_state)
    model.eval()
    with torch.no_grad():
        train_l1 = float((model.log_mean(x) - target).abs().mean())
        const = float((target - target.median()).abs().mean())
        val_l1 = None
        val_const = None
        if has_val:
            val_l1 = float((model.log_mean(vx) - vy).abs().mean())
            val_const = float((vy - target.median()).abs().mean())
    return model, {"train_l1": train_l1, "val_l1": val_l1, "constant_l1": const, "val_constant_l1": val_const,
                   "seconds": time.perf_counter() - t0, "epochs": epochs, "best_epoch": best_epoch,
                   "views": int(x.shape[0])}

