"""The operating point: where the product runs, as one frozen value.

An :class:`OperatingPoint` says how the IMS's masks are made: the share of the C-Image they ray-cast (the knob a user
turns; the paper's normalization mean ``u`` is the same number, :attr:`OperatingPoint.u`: the IML normalizes the
importance to mean ``u``, so ``u`` is the expected share of C sampled), whether the masks are lifted to that share,
the share per band of camera distance (:class:`Bands`), the mask's sharpness and the floor each view's share keeps
from its own object. The ORP search finds one, the evaluation records it beside the IMS checkpoint
(:mod:`imls_lightning.inference.operating_point`), and a renderer receives it at construction
(:class:`~imls_lightning.inference.pipeline.IMLSRenderer`, :meth:`~imls_lightning.models.ims.IMSMaskHead.at`);
nothing sets it afterwards. Plain numbers only (no torch): the mask head turns it into tensors.

Example:
    >>> p = OperatingPoint(share=0.42, lift=True, sharpness=3.0)
    >>> p.u, p.lift, p.bands
    (0.42, True, None)
    >>> b = Bands(edges=[3.8], shares=[0.42, 0.3], floor_margins=[0.14, None])
    >>> OperatingPoint(share=0.42, bands=b, object_floor=(0.14, 0.2)).bands.shares
    (0.42, 0.3)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from imls_lightning.base.errors import InputError

from .importance import check_object_floor, check_sharpness

__all__ = ["OperatingPoint", "Bands", "POINT_DECODERS"]

#: what rebuilds the C-Image from the ray-cast pixels at a point: the IMS's own trained decoder, or the untrained
#: pull-push fill of the same pixels (no network: where it is as good, the cheaper product)
POINT_DECODERS = ("trained", "fill")


def _share(value, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    if isinstance(value, bool) or not math.isfinite(x) or not 0.01 <= x <= 1.0:
        raise InputError(f"{name}={value!r}: expected a share of the C-Image in [0.01, 1]")
    return x


@dataclass(frozen=True)
class Bands:
    """A share of C per band of camera distance: band ``k`` holds the views whose eye lies at a distance ``d`` with
    ``edges[k-1] <= d < edges[k]`` (the first open below, the last above) and runs at ``shares[k]``; with
    ``floor_margins``, each band its own object floor's margin (``None``: no floor there)."""

    edges: tuple[float, ...]
    shares: tuple[float, ...]
    floor_margins: tuple[float | None, ...] | None = None

    def __post_init__(self):
        edges = tuple(float(x) for x in self.edges)
        shares = tuple(_share(x, "by_distance.shares") for x in self.shares)
        if len(shares) != len(edges) + 1:
            raise InputError(f"by_distance: {len(shares)} shares for {len(edges)} band edges; expected one more share than edges")
        if not all(math.isfinite(x) for x in edges) or any(b <= a for a, b in zip(edges, edges[1:])):
            raise InputError(f"by_distance: band edges {list(edges)}: expected increasing finite distances")
        margins = self.floor_margins
        if margins is not None:
            margins = tuple(None if m is None else float(m) for m in margins)
            if len(margins) != len(shares) or any(m is not None and not 0.0 <= m <= 1.0 for m in margins):
                raise InputError(f"floor_margins={list(margins)}: expected {len(shares)} margins (one per band of camera distance), "
                                 "each in [0, 1] or null")
        object.__setattr__(self, "edges", edges)
        object.__setattr__(self, "shares", shares)
        object.__setattr__(self, "floor_margins", margins)


@dataclass(frozen=True)
class OperatingPoint:
    """Where the product runs (frozen; :meth:`replace` gives another).

    Attributes:
        share: the share of the C-Image the masks are made at, in ``[0.01, 1]``; ``None``: the share the IMS was
            trained at (its IML's mean value). With :attr:`bands` the one value that held in every band, for display.
        lift: lift the masks to the share (above the trained one: :func:`~imls_lightning.core.importance.lift_to_share`).
        bands: a share per band of camera distance (:class:`Bands`), or ``None``: ``share`` for every view.
        sharpness: the mask's sharpness ``gamma`` in ``[1, 8]`` (1: the paper's masks).
        object_floor: ``(margin, tau)``: each view's share raised to at least its object's (PIM' > ``tau``) plus
            ``margin``; ``None``: no floor. With :attr:`bands`' ``floor_margins`` each band has its own margin.
        decoder: what rebuilds the C-Image from the ray-cast pixels (:data:`POINT_DECODERS`): ``"trained"``, the IMS's own
            decoder (the paper's), or ``"fill"``, the untrained pull-push fill of the same pixels
            (:class:`~imls_lightning.models.iml.FillDecoder`), which the ORP search keeps where it runs faster
            within the same bound (``orp_decoders``).
    """

    share: float | None = None
    lift: bool = False
    bands: Bands | None = None
    sharpness: float = 1.0
    object_floor: tuple[float, float] | None = None
    decoder: str = "trained"

    def __post_init__(self):
        if self.share is not None:
            object.__setattr__(self, "share", _share(self.share, "share"))
        object.__setattr__(self, "lift", bool(self.lift))
        object.__setattr__(self, "sharpness", check_sharpness(self.sharpness))
        if self.object_floor is not None:
            object.__setattr__(self, "object_floor", tuple(check_object_floor(*self.object_floor)))
        if self.bands is not None and not isinstance(self.bands, Bands):
            raise InputError(f"bands={self.bands!r}: expected a Bands")
        if self.bands is not None and self.bands.floor_margins is not None and self.object_floor is None:
            raise InputError("bands.floor_margins: margins per band need an object_floor (its tau)")
        if self.decoder not in POINT_DECODERS:
            raise InputError(f"decoder={self.decoder!r}: expected 'trained' (the IMS's own decoder) or 'fill' "
                             "(the untrained pull-push fill of the same pixels)")

    @property
    def u(self) -> float | None:
        """The paper's normalization mean ``u``: the importance is normalized to mean ``u``, the expected share of the
        C-Image sampled, so it is :attr:`share` (``None``: the trained one)."""
        return self.share

    def replace(self, **changes) -> "OperatingPoint":
        """This point with ``changes`` (a new frozen point)."""
        return replace(self, **changes)
