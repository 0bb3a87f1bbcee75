"""Sampling patterns S_sp of the RecNNs, blue noise, and the plastic rank pattern P.

A sampling pattern says which pixels of the ``m x m`` FR-Image a RecNN renders; compaction packs
them, in raster order, into the ``n x n`` C-Image (zero padded past the pattern's ``K`` pixels).

* :func:`downsample_pattern` - super-resolution (EnhanceNet): one pixel per ``f x f`` block; the
  C-Image *is* the low-resolution image. The paper's "4x" is ``factor=2`` (a quarter of the pixels,
  512^2 -> 256^2).
* :func:`foveal_pattern` - foveated rendering (FoVolNet): blue noise thresholded against a Gaussian
  modulation surface around a fixed centre; dense in the fovea, sparse in the periphery.
* :func:`full_pattern` - every pixel (``c_size = fr_size``), for tests and upper bounds.
* :func:`blue_noise` - void-and-cluster blue-noise ranks (Ulichney 1993), procedural and seeded
  (from :mod:`imls_lightning.core.rank_patterns`, re-exported here, like the next one).
* :func:`plastic_rank_pattern` - the LAS rank map P (R2 / plastic sequence, rank of first visit).
* :func:`build_pattern` - the above from the Hydra ``pattern`` node; :func:`c_pixels_to_fr` maps a
  C-Image mask (e.g. the IM) to the FR raster indices the selective renderer must cast.

Pixel conventions follow ``docs/ARCHITECTURE.md``: row 0 at the top, flat raster index
``row * m + col``; normalized image coordinates are ``x = (col + 0.5) / m`` (right) and
``y = (row + 0.5) / m`` (down).
"""
from __future__ import annotations

import hashlib
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_number

from .rank_patterns import PLASTIC_G, blue_noise, blue_noise_ranks, plastic_rank_pattern

log = logging.getLogger(__name__)

__all__ = [
    "SamplingPattern",
    "downsample_pattern",
    "foveal_pattern",
    "foveal_surface",
    "full_pattern",
    "blue_noise",
    "plastic_rank_pattern",
    "build_pattern",
    "c_pixels_to_fr",
    "crop_pattern",
    "FOVEAL_FORMULATIONS",
    "FOVOLNET_DEFAULT_BASE",
    "FOVOLNET_DEFAULT_SIGMA",
    "PLASTIC_G",
]


@dataclass(frozen=True, eq=False)
class SamplingPattern:
    """Which FR-Image pixels a RecNN renders, and how they map into the C-Image.

    Attributes:
        kind: ``"downsample"``, ``"foveal"`` or ``"full"``.
        fr_size: FR-Image side ``m``.
        c_size: C-Image side ``n``.
        indices: ``(K,)`` int64, ascending flat raster indices into ``m*m``; ``K <= n*n``.
        params: the generator's parameters as ``((name, value), ...)`` (for manifests and hashing).

    Example:
        >>> p = downsample_pattern(8, 2)
        >>> p.count, p.c_size, p.indices[:4].tolist()
        (16, 4, [0, 2, 4, 6])
    """

    kind: str
    fr_size: int
    c_size: int
    indices: torch.Tensor
    params: tuple = ()

    def __post_init__(self) -> None:
        idx = self.indices
        if idx.dtype != torch.long or idx.dim() != 1:
            raise ValueError(f"SamplingPattern.indices: expected a 1D int64 tensor, got {idx.dtype} {tuple(idx.shape)}")
        if idx.numel() > self.c_size * self.c_size:
            raise InputError(
                f"pattern '{self.kind}' has {idx.numel()} pixels, more than the C-Image holds "
                f"({self.c_size}x{self.c_size}={self.c_size * self.c_size}); raise pattern.c_size or sparsen the pattern"
            )
        if idx.numel() and (int(idx.min()) < 0 or int(idx.max()) >= self.fr_size * self.fr_size):
            raise ValueError("SamplingPattern.indices: out of range of the FR-Image")
        if idx.numel() > 1 and not bool((idx[1:] > idx[:-1]).all()):
            raise ValueError("SamplingPattern.indices: must be strictly ascending (raster order)")

    @property
    def count(self) -> int:
        """Number of pattern pixels ``K``."""
        return int(self.indices.numel())

    @property
    def mask(self) -> torch.Tensor:
        """``(m, m)`` bool: True on pattern pixels."""
        m = torch.zeros(self.fr_size * self.fr_size, dtype=torch.bool)
        m[self.indices] = True
        return m.view(self.fr_size, self.fr_size)

    @property
    def valid(self) -> torch.Tensor:
        """``(n, n)`` bool: True on the first ``K`` C-Image pixels (the rest is zero padding)."""
        v = torch.zeros(self.c_size * self.c_size, dtype=torch.bool)
        v[: self.count] = True
        return v.view(self.c_size, self.c_size)

    @property
    def fill_ratio(self) -> float:
        """``K / n^2``: share of the C-Image holding pattern pixels (1.0 = no padding)."""
        return self.count / float(self.c_size * self.c_size)

    @property
    def sampling_ratio(self) -> float:
        """``K / m^2``: share of the FR-Image the RecNN renders."""
        return self.count / float(self.fr_size * self.fr_size)

    @property
    def param_dict(self) -> dict:
        """``params`` as a dict (manifest friendly)."""
        return dict(self.params)

    def summary(self) -> str:
        """One line for logs and reports, e.g. ``foveal 512->256: K=65536 (100.0% of C, 25.0% of FR), ...``."""
        extra = ", ".join(f"{k}={v}" for k, v in self.params)
        return (
            f"{self.kind} {self.fr_size}->{self.c_size}: K={self.count} "
            f"({100 * self.fill_ratio:.1f}% of C, {100 * self.sampling_ratio:.1f}% of FR)" + (f", {extra}" if extra else "")
        )

    def fingerprint(self) -> str:
        h = hashlib.sha256(repr((self.kind, self.fr_size, self.c_size, self.params)).encode())
        h.update(self.indices.numpy().tobytes())
        return h.hexdigest()[:16]


# --------------------------------------------------------------------------------------------
# full and downsampling patterns
# --------------------------------------------------------------------------------------------


def full_pattern(fr_size: int) -> SamplingPattern:
    """Every FR pixel; the C-Image is the FR-Image itself (``c_size = fr_size``).

    Example:
        >>> full_pattern(4).count
        16
    """
    m = check_integer(fr_size, "fr_size", 1, strict=True)
    return SamplingPattern("full", m, m, torch.arange(m * m, dtype=torch.long), ())


def downsample_pattern(fr_size: int, factor: int) -> SamplingPattern:
    """Super-resolution pattern: one pixel of every ``factor x factor`` block.

    The C-Image is the ``(m / factor)^2`` low-resolution image. Within each block the pixel at
    offset ``o = (factor - 1) // 2`` (row and column) is sampled:

    * odd factors: the block centre, which is exactly where a low-resolution render through its
      own pixel centres samples the image (low-res pixel ``j`` is FR position ``j*f + (f-1)/2``);
    * even factors: no FR pixel sits on that centre (it falls between four); we take the upper-left
      of the four, half an FR pixel from it (the other three are no closer). For ``factor=2`` this
      makes the C-Image exactly ``fr[..., ::2, ::2]``, the usual strided downsampling.

    Args:
        fr_size: FR-Image side ``m``; must be divisible by ``factor``.
        factor: downsampling factor per axis (the paper's "4x" = a quarter of the pixels = 2).

    Returns:
        pattern with ``c_size = m // factor`` and ``K = c_size^2`` (no padding).

    Example:
        >>> downsample_pattern(6, 3).indices.tolist()
        [7, 10, 25, 28]
    """
    m = check_integer(fr_size, "fr_size", 1, strict=True)
    f = check_integer(factor, "pattern.factor", 1, strict=True)
    if m % f:
        raise InputError(f"pattern.factor={f}: the FR size {m} is not divisible by it (choose a factor that divides {m})")
    n = m // f
    o = (f - 1) // 2
    rows = torch.arange(n, dtype=torch.long) * f + o
    idx = (rows[:, None] * m + rows[None, :]).reshape(-1)  # raster order: already ascending
    return SamplingPattern("downsample", m, n, idx, (("factor", f), ("offset", o)))




# --------------------------------------------------------------------------------------------
# foveal pattern
# --------------------------------------------------------------------------------------------

FOVEAL_FORMULATIONS = ("fovolnet", "paper")
# FoVolNet's public render app (VIDILabs/open-volume-renderer, apps/main_app.cpp) starts with
# focus_scale (sigma) = 0.06 and base_noise (b) = 0.07; sigma there is in units of image width.
FOVOLNET_DEFAULT_SIGMA = 0.06
FOVOLNET_DEFAULT_BASE = 0.07
_SIGMA_DIGITS = 6  # solved sigmas are rounded to 6 significant digits: stable reprs/fingerprints


def _check_formulation(formulation: str) -> str:
    if formulation not in FOVEAL_FORMULATIONS:
        raise InputError(f"pattern.formulation={formulation!r}: expected one of {', '.join(FOVEAL_FORMULATIONS)}")
    return formulation


def _resolve_base(base, formulation: str) -> float:
    if base is None:  # the formulation's own default: FoVolNet's 0.07, the paper's surface has none
        return FOVOLNET_DEFAULT_BASE if formulation == "fovolnet" else 0.0
    return check_number(base, "pattern.base", 0.0, 1.0)


def _check_center(center) -> tuple[float, float]:
    if not isinstance(center, (Sequence, np.ndarray, torch.Tensor)) or isinstance(center, str) or len(center) != 2:
        raise InputError(f"pattern.center={center!r}: expected two numbers [x, y] in [0, 1] (image width/height units)")
    return (check_number(center[0], "pattern.center[0]", 0.0, 1.0), check_number(center[1], "pattern.center[1]", 0.0, 1.0))


def _radius2(m: int, center: tuple[float, float]) -> np.ndarray:
    # squared distance of every pixel centre to the fovea centre, in image-width units
    c = (np.arange(m, dtype=np.float64) + 0.5) / m
    fx = c[None, :] - center[0]
    fy = c[:, None] - center[1]
    return (fx * fx + fy * fy).reshape(-1)


def _surface(r2: np.ndarray, sigma: float, formulation: str, base: float) -> np.ndarray:
    if formulation == "fovolnet":
        e = np.exp(-0.5 * r2 / (sigma * sigma))
    else:
        e = np.exp(-0.5 * r2 * sigma)
    return base + (1.0 - base) * e


def foveal_surface(
    fr_size: int,
    sigma: float,
    *,
    formulation: str = "fovolnet",
    base: float | None = None,
    center: Sequence[float] = (0.5, 0.5),
) -> torch.Tensor:
    """The sampling probability ``p = b + (1 - b) * E`` of a foveal pattern.

    ``fx, fy`` are the pixel-centre offsets from ``center`` in image-size units (``x`` right,
    ``y`` down); ``r^2 = fx^2 + fy^2``.

    * ``formulation="fovolnet"`` (default): ``E = exp(-0.5 r^2 / sigma^2)``, as in FoVolNet's public
      mask code (``generate_mask.cu``), where ``sigma`` is the fovea's std in image widths and
      ``b`` (default 0.07) keeps a thin blue-noise sampling of the periphery.
    * ``formulation="paper"``: ``E = exp(-0.5 r^2 sigma)``, as printed in the IML/S paper (sigma
      multiplies: larger sigma = smaller fovea); default ``b = 0`` gives the paper's surface exactly.

    FoVolNet additionally divides ``fy`` by the aspect ratio; FR-Images here are square, so that
    is a no-op. FoVolNet uses ``x / W`` (pixel corners); we use pixel centres so that the surface
    is symmetric about the image centre.

    Returns:
        ``(m, m)`` float64 in ``[b, 1]``.

    Example:
        >>> p = foveal_surface(64, 0.1)
        >>> bool(p[32, 32] > 0.99), bool(abs(float(p[0, 0]) - 0.07) < 1e-6)
        (True, True)
    """
    m = check_integer(fr_size, "fr_size", 1, strict=True)
    formulation = _check_formulation(formulation)
    sigma = check_number(sigma, "pattern.sigma", 0.0, lo_open=True)
    b = _resolve_base(base, formulation)
    p = _surface(_radius2(m, _check_center(center)), sigma, formulation, b)
    return torch.from_numpy(p.reshape(m, m))


def _round_sigma(sigma: float, up: bool) -> list[float]:
    # candidates on the 6-significant-digit grid nearest sigma, in the preferred direction first
    e = math.floor(math.log10(sigma)) - (_SIGMA_DIGITS - 1)
    q = sigma / 10.0**e
    lo, hi = math.floor(q), math.ceil(q)
    grid = [float(f"{v * 10.0**e:.{_SIGMA_DIGITS}g}") for v in ((hi, lo) if up else (lo, hi))]
    return grid


def foveal_pattern(
    fr_size: int,
    c_size: int,
    sigma: float | None = None,
    *,
    formulation: str = "fovolnet",
    base: float | None = None,
    center: Sequence[float] = (0.5, 0.5),
    seed: int = 0,
) -> SamplingPattern:
    """Foveal pattern: blue noise thresholded against a Gaussian modulation surface.

    A pixel is in the pattern iff ``P < p``, where ``P`` is :func:`blue_noise` (uniform ranks in
    ``[0, 1)``) and ``p`` is :func:`foveal_surface`. So the expected local density *is* ``p``:
    1 at the fovea centre, falling to the base level ``b`` in the periphery.

    Direction of the inequality: the paper prints ``FP = 1 if P > E``; with ``E = 1`` at the centre
    that would leave the fovea *empty* and sample the periphery, the opposite of foveated rendering
    and of the paper's own figures. FoVolNet's code samples where ``noise < p``; we follow it.

    The count ``K`` must fit the C-Image (``K <= n^2``):

    * ``sigma=None`` (default) solves, by bisection on sigma (the count is monotone in sigma), for
      the densest pattern that fits; the solved sigma is rounded to 6 significant digits (on the
      side that still fits) and the resulting fill ratio ``K / n^2`` is logged and available as
      ``pattern.fill_ratio``.
    * a given sigma whose ``K`` exceeds ``n^2`` raises :class:`InputError` naming the largest
      (fovolnet) or smallest (paper) sigma that would fit.

    Args:
        fr_size: FR-Image side ``m``.
        c_size: C-Image side ``n``.
        sigma: fovea size (see :func:`foveal_surface`), or None to solve for it.
        formulation: ``"fovolnet"`` (default) or ``"paper"``.
        base: periphery level ``b`` in ``[0, 1]``; None = formulation default (0.07 / 0.0).
        center: fovea centre ``(x, y)`` in image-size units; default the image centre.
        seed: blue-noise seed.

    Returns:
        pattern with ``params = (("formulation", ..), ("sigma", ..), ("base", ..), ("center", ..),
        ("seed", ..))``, the effective values: passing the solved sigma back in (or the default
        base explicitly) reproduces the same pattern and fingerprint.

    Example:
        >>> p = foveal_pattern(64, 32)
        >>> p.count <= 32 * 32, p.fill_ratio > 0.99
        (True, True)
    """
    m = check_integer(fr_size, "fr_size", 1, strict=True)
    n = check_integer(c_size, "pattern.c_size", 1, strict=True)
    formulation = _check_formulation(formulation)
    b = _resolve_base(base, formulation)
    ctr = _check_center(center)
    seed = check_integer(seed, "pattern.seed", 0, strict=True)
    cap = n * n
    u = blue_noise_ranks(m, m, seed).reshape(-1).astype(np.float64) / float(m * m)
    r2 = _radius2(m, ctr)
    grows = formulation == "fovolnet"  # K grows with sigma (fovolnet) or shrinks (paper)

    def select(s: float) -> np.ndarray:
        return u < _surface(r2, s, formulation, b)

    def count(s: float) -> int:
        return int(np.count_nonzero(select(s)))

    solved = sigma is None
    if solved:
        # bracket: the sparsest end keeps only the base level (and an exact-centre pixel)
        sparse_end, dense_end = (1e-6, 1e3) if grows else (1e9, 1e-6)
        k_min = count(sparse_end)
        if k_min > cap:
            raise InputError(
                f"pattern.base={b}: the base level alone puts {k_min} pixels in the pattern, more than the "
                f"C-Image holds ({n}x{n}={cap}); lower pattern.base or raise pattern.c_size"
            )
        if count(dense_end) <= cap:
            s = dense_end  # everything fits: the whole FR-Image
        else:
            fit, over = math.log(sparse_end), math.log(dense_end)
            for _ in range(80):  # bisection in log sigma; K(sigma) is a monotone step function
                mid = 0.5 * (fit + over)
                if count(math.exp(mid)) <= cap:
                    fit = mid
                else:
                    over = mid
            s = math.exp(fit)
            for cand in _round_sigma(s, up=not grows):  # prefer the rounding that shrinks K
                if count(cand) <= cap:
                    s = cand
                    break
        sig = s
    else:
        sig = check_number(sigma, "pattern.sigma", 0.0, lo_open=True)
        k = count(sig)
        if k > cap:
            hint = foveal_pattern(m, n, None, formulation=formulation, base=b, center=ctr, seed=seed).param_dict["sigma"]
            side = "<=" if grows else ">="
            raise InputError(
                f"pattern.sigma={sig}: the foveal pattern has {k} pixels, more than the C-Image holds "
                f"({n}x{n}={cap}); use sigma {side} {hint}, sigma=null to solve for it, or raise pattern.c_size"
            )
    idx = torch.from_numpy(np.flatnonzero(select(sig)).astype(np.int64))
    params = (
        ("formulation", formulation),
        ("sigma", sig),  # the effective sigma, solved or given: same pattern, same fingerprint
        ("base", b),
        ("center", ctr),
        ("seed", seed),
    )
    pat = SamplingPattern("foveal", m, n, idx, params)
    if solved:
        log.info("foveal pattern: sigma solved for the densest fit: %s", pat.summary())
    return pat




# --------------------------------------------------------------------------------------------
# config and helpers
# --------------------------------------------------------------------------------------------

_KINDS = ("downsample", "foveal", "full")


def build_pattern(cfg: Mapping, fr_size: int) -> SamplingPattern:
    """Build the pattern of the Hydra ``pattern`` group node.

    ``conf/pattern/downsample.yaml``: ``kind: downsample``, ``factor``.
    ``conf/pattern/foveal.yaml``: ``kind: foveal``, ``c_size`` (or ``c_size_ratio`` of ``fr_size``),
    ``sigma`` (null = solve), ``formulation``, ``base`` (null = formulation default), ``center``,
    ``seed``. ``kind: full`` takes no parameters.

    Args:
        cfg: the ``pattern`` node (DictConfig or any mapping).
        fr_size: FR-Image side ``m`` (from the data config).

    Example:
        >>> build_pattern({"kind": "downsample", "factor": 2}, 16).c_size
        8
    """
    if not isinstance(cfg, Mapping) and not hasattr(cfg, "get"):
        raise InputError(f"pattern={cfg!r}: expected a config node with a 'kind' key")
    kind = cfg.get("kind")
    m = check_integer(fr_size, "fr_size", 1, strict=True)
    if kind == "full":
        return full_pattern(m)
    if kind == "downsample":
        return downsample_pattern(m, cfg.get("factor", 2))
    if kind == "foveal":
        c_size = cfg.get("c_size")
        if c_size is None:
            ratio = check_number(cfg.get("c_size_ratio", 0.5), "pattern.c_size_ratio", 0.0, lo_open=True)
            c_size = max(1, int(round(m * ratio)))
        center = cfg.get("center", (0.5, 0.5))
        if center is not None and not isinstance(center, (Sequence, np.ndarray, torch.Tensor)):
            center = list(center)  # omegaconf ListConfig
        return foveal_pattern(
            m,
            c_size,
            cfg.get("sigma"),
            formulation=cfg.get("formulation", "fovolnet"),
            base=cfg.get("base"),
            center=center,
            seed=cfg.get("seed", 0),
        )
    raise InputError(f"pattern.kind={kind!r}: expected one of {', '.join(_KINDS)}")


def crop_pattern(pattern: SamplingPattern, crop: int) -> SamplingPattern:
    """The pattern of a ``crop x crop`` window of the FR-Image, for patch training (``data.crop``).

    Only shift-invariant patterns have one pattern for every window: the full pattern, and the
    downsampling pattern for windows that start on its grid (multiples of the factor) with a side
    divisible by the factor. The foveal pattern's density depends on the position, so a crop of it
    is not the same pattern: refused.

    Example:
        >>> crop_pattern(downsample_pattern(16, 2), 8).summary()
        'downsample 8->4: K=16 (100.0% of C, 25.0% of FR), factor=2, offset=0'
    """
    c = check_integer(crop, "data.crop", 1, strict=True)
    if c > pattern.fr_size:
        raise InputError(f"data.crop={c}: larger than the FR-Image ({pattern.fr_size}^2); choose a crop <= {pattern.fr_size} or null")
    if pattern.kind == "full":
        return full_pattern(c)
    if pattern.kind == "downsample":
        f = int(pattern.param_dict["factor"])
        if c % f:
            raise InputError(f"data.crop={c}: not a multiple of the downsampling factor {f}")
        return downsample_pattern(c, f)
    raise InputError(f"data.crop={c}: the {pattern.kind} pattern changes with the position in the image, so its crops are "
                     "not the same pattern; train it on whole images (data.crop=null)")


def c_pixels_to_fr(pattern: SamplingPattern, c_mask: torch.Tensor) -> torch.Tensor:
    """FR raster indices of the C-Image pixels selected by ``c_mask`` (e.g. the IM).

    Padding pixels (``k >= K``) are ignored, so a mask that is True on the padding is harmless.

    Args:
        pattern: the sampling pattern.
        c_mask: ``(n, n)`` bool (or 0/1 numbers; nonzero = selected).

    Returns:
        ``(S,)`` int64 ascending FR raster indices, ready for ``render_pixels``.

    Example:
        >>> p = downsample_pattern(4, 2)
        >>> c_pixels_to_fr(p, torch.tensor([[True, False], [False, True]])).tolist()
        [0, 10]
    """
    n = pattern.c_size
    if not isinstance(c_mask, torch.Tensor) or tuple(c_mask.shape) != (n, n):
        got = tuple(c_mask.shape) if isinstance(c_mask, torch.Tensor) else type(c_mask).__name__
        raise ValueError(f"c_mask: expected a tensor of shape ({n}, {n}), got {got}")
    sel = c_mask.reshape(-1)[: pattern.count].to("cpu")
    sel = sel if sel.dtype == torch.bool else sel != 0
    return pattern.indices[sel]
