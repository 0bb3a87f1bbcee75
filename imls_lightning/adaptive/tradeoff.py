"""The trade-off measurement: quality and IPR of the IML/S (or IML) + RecNN path at given per-view
means (:func:`quality_at_means`), per-view settings against the whole curve of fixed means
(:func:`tradeoff`, :class:`TradeoffPoint`), and the fixed mean of a given average IPR (:func:`mean_for_ipr`).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np
import torch
from torch import nn

from imls_lightning.base.errors import InputError

from ..core.importance import MEAN_RANGE
from ..core.metrics import psnr_per_image
from ..core.smallest_within import bisect_monotone
from ..inference.pipeline import pick_device
from .checks import check_epsilon, check_integer
from .labels import check_source, mask_function


def quality_at_means(cache, rows: np.ndarray, pattern, iml: nn.Module, recnn: nn.Module, means: Mapping[str, Any], *,
                     source: str = "ims", ims=None, lift: bool = False, batch_size: int = 16, device: str | torch.device = "cpu",
                     progress: bool = False, desc: str = "trade-off") -> dict[str, dict[str, np.ndarray]]:
    """Per-view PSNR and IPR of the IML/S (``source="ims"``) or IML (``"iml"``) + RecNN path at given means.

    One pass over the cache ``rows``: per batch the RecNN alone, the importance network (once) and,
    for every entry of ``means``, the mask at that entry's per-view ``u``, the decoder and the RecNN
    on the float images of the cache (the selective render of the masked pixels gives those same
    pixels, up to the uint8 rounding of the real renderer).

    Args:
        means: ``name -> u``: a number (one fixed mean) or an ``(N,)`` array (one mean per row).
        source, ims, lift: as :func:`compute_labels`.

    Returns:
        ``name -> {"psnr": (N,), "ipr": (N,)}`` plus ``"recnn" -> {"psnr": (N,)}`` (the RecNN alone);
        IPR is rendered pixels / FR pixels.

    Example (shapes only; see ``tests/adaptive/test_tradeoff.py``)::

        q = quality_at_means(cache, rows, pattern, iml, recnn, {"fixed": 0.3, "adaptive": u_pred}, ims=ims)
        q["adaptive"]["psnr"].mean(), q["adaptive"]["ipr"].mean()
    """
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from ..data.datamodule import ViewImageDataset

    check_source(source, ims)
    bs = check_integer(batch_size, "batch_size", 1)
    rows = np.asarray(rows, np.int64)
    n_rows = len(rows)
    table: dict[str, np.ndarray] = {}
    for name, u in means.items():
        arr = np.asarray(u, np.float64)
        arr = np.full(n_rows, float(arr)) if arr.ndim == 0 else arr.reshape(-1)
        if arr.shape[0] != n_rows or not np.isfinite(arr).all() or (arr <= 0).any():
            raise InputError(f"means[{name!r}]: expected a positive mean or {n_rows} positive means, got shape {np.shape(u)}")
        table[name] = np.clip(arr, *MEAN_RANGE)
    dev = pick_device(device)
    for net in (iml, recnn) + ((ims,) if ims is not None else ()):
        net.to(dev).eval()
    fr_pixels = float(pattern.fr_size) ** 2
    out: dict[str, dict[str, list[np.ndarray]]] = {k: {"psnr": [], "ipr": []} for k in table}
    out["recnn"] = {"psnr": []}
    ds = ViewImageDataset(cache.path, rows, pattern, fields=("view", "fr", "c"))
    loader = DataLoader(ds, batch_size=bs, shuffle=False, num_workers=0)
    start = 0
    with torch.inference_mode():
        for batch in tqdm(loader, total=len(loader), desc=desc, unit="batch", file=sys.stderr, disable=not progress,
                          dynamic_ncols=True):
            c, fr = batch["c"].to(dev), batch["fr"].to(dev)
            sl = slice(start, start + c.shape[0])
            start += c.shape[0]
            out["recnn"]["psnr"].append(psnr_per_image(recnn(c), fr).double().cpu().numpy())
            mask_at = mask_function(source, iml, ims, c, batch["view"].to(dev), lift)
            for name, u in table.items():
                im = mask_at(torch.as_tensor(u[sl]))
                out[name]["psnr"].append(psnr_per_image(recnn(iml.decode(im * c, im)), fr).double().cpu().numpy())
                out[name]["ipr"].append(im.flatten(1).sum(1).double().cpu().numpy() / fr_pixels)
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return {name: {k: cat(v) for k, v in d.items()} for name, d in out.items()}


@dataclass
class TradeoffPoint:
    """One setting on the IPR / quality plane, compared with the fixed-mean curve.

    ``ipr``, ``psnr``: averages over the views; ``within``: share of views within epsilon of the
    reference; ``fixed_psnr``: the fixed-mean curve's average PSNR at this average IPR (linear
    between the curve's points; None outside its IPR range); ``fixed_ipr``: the smallest average
    IPR at which the fixed-mean curve reaches this average PSNR (None: no fixed mean does);
    ``fixed_within``: the curve's within-epsilon share at this IPR.
    """

    name: str
    ipr: float
    psnr: float
    within: float
    fixed_psnr: float | None
    fixed_within: float | None
    fixed_ipr: float | None

    @property
    def d_psnr(self) -> float | None:
        """dB gained over the fixed mean at the same average IPR."""
        return None if self.fixed_psnr is None else self.psnr - self.fixed_psnr

    @property
    def d_ipr(self) -> float | None:
        """Relative change of the pixels rendered vs the fixed mean at the same average PSNR (< 0: fewer)."""
        return None if not self.fixed_ipr else self.ipr / self.fixed_ipr - 1.0


def tradeoff(reference: np.ndarray, fixed: Mapping[float, Mapping[str, np.ndarray]],
             points: Mapping[str, Mapping[str, np.ndarray]], epsilon_db: float = 1.0) -> tuple[list[dict[str, float]], list[TradeoffPoint]]:
    """Compare per-view settings with the curve of fixed means on the (average IPR, average PSNR) plane.

    Args:
        reference: ``(N,)`` per-view reference PSNR (a view is "within" when its PSNR is at most
            ``epsilon_db`` below it).
        fixed: ``u -> {"psnr": (N,), "ipr": (N,)}`` for several fixed means (the curve).
        points: ``name -> {"psnr": (N,), "ipr": (N,)}``: the settings compared (adaptive, oracle).

    Returns:
        ``(curve, compared)``: the curve as ``{"u", "ipr", "psnr", "within"}`` rows sorted by IPR, and
        one :class:`TradeoffPoint` per entry of ``points``.

    Example:
        >>> ref = np.array([30.0, 30.0])
        >>> fixed = {u: {"psnr": np.array([20 + 10 * u, 20 + 10 * u]), "ipr": np.array([u, u])} for u in (0.1, 0.5, 1.0)}
        >>> _, (p,) = tradeoff(ref, fixed, {"a": {"psnr": np.array([25.0, 27.0]), "ipr": np.array([0.2, 0.4])}})
        >>> round(p.d_psnr, 3), round(p.d_ipr, 3)          # +3 dB at IPR 0.3; the curve needs 0.6 for 26 dB
        (3.0, -0.5)
    """
    eps = check_epsilon(epsilon_db)
    ref = np.asarray(reference, np.float64)

    def summary(d: Mapping[str, np.ndarray]) -> tuple[float, float, float]:
        ps = np.asarray(d["psnr"], np.float64)
        if ps.shape != ref.shape:
            raise InputError(f"tradeoff: expected {ref.shape[0]} per-view PSNRs, got shape {ps.shape}")
        return float(np.mean(d["ipr"])), float(ps.mean()), float((ref - ps <= eps + 1e-9).mean())

    curve = sorted(({"u": float(u), **dict(zip(("ipr", "psnr", "within"), summary(d)))} for u, d in fixed.items()),
                   key=lambda r: (r["ipr"], r["u"]))
    if not curve:
        raise InputError("tradeoff: expected at least one fixed mean")
    ci = np.array([r["ipr"] for r in curve])
    cp = np.array([r["psnr"] for r in curve])
    cw = np.array([r["within"] for r in curve])
    env = np.maximum.accumulate(cp)  # best PSNR reachable with at most this IPR

    def fixed_ipr_for(psnr: float) -> float | None:
        if psnr > env[-1]:
            return None
        k = int(np.argmax(env >= psnr))  # first point reaching it; env[k - 1] < psnr <= env[k]
        if k == 0:
            return float(ci[0])
        t = (psnr - env[k - 1]) / (env[k] - env[k - 1])
        return float(ci[k - 1] + t * (ci[k] - ci[k - 1]))

    compared = []
    for name, d in points.items():
        ip, ps, w = summary(d)
        inside = len(ci) > 1 and ci[0] - 1e-12 <= ip <= ci[-1] + 1e-12
        compared.append(TradeoffPoint(name, ip, ps, w, float(np.interp(ip, ci, cp)) if inside else None,
                                      float(np.interp(ip, ci, cw)) if inside else None, fixed_ipr_for(ps)))
    return curve, compared


def mean_for_ipr(ipr_of: Callable[[float], float], target: float, steps: int = 30) -> float:
    """The fixed mean value ``u`` in ``[0.01, 1]`` whose average IPR ``ipr_of(u)`` is closest to ``target``.

    Bisection in ``log u`` (``ipr_of`` non-decreasing in ``u``:
    :func:`~imls_lightning.core.smallest_within.bisect_monotone`); returns the closest ``u`` seen, the ends
    included (the earliest seen on a tie: ``hi``, ``lo``, then the midpoints in order).

    Example:
        >>> round(mean_for_ipr(lambda u: 0.5 * u, 0.05), 4)
        0.1
    """
    lo, hi = MEAN_RANGE
    seen = [(hi, ipr_of(hi)), (lo, ipr_of(lo))]
    seen += bisect_monotone(ipr_of, target, lo, hi, steps).trace
    return float(min(seen, key=lambda point: abs(point[1] - target))[0])

