"""A baseline's operating point searched as the product's is ("beat the simplest alternative" at the same promise):
on the ORP's search views (:func:`~imls_lightning.evaluation.operating_point.search_views`), the smallest of a list of
ascending settings (the two-pass sampler's share of C, LAS's IPR) whose protocol bound
(:func:`~imls_lightning.orp.search.protocol_gap_record`: passes, bands of camera distance) stays within
``epsilon_db`` of the RecNN alone; with ``orp_by_distance``, then each band of camera distance its own
(:func:`band_values`), never above the one that held in every band. The evaluated (test) views are never looked at.

Example:
    >>> import numpy as np
    >>> from imls_lightning.evaluation.operating_point import SearchViews
    >>> v = SearchViews(None, None, "4 views", [3.0, 3.1, 5.0, 5.1], None, None, 1)
    >>> gaps = np.array([[2.0, 0.9, 0.1], [2.0, 0.9, 0.1], [0.5, 0.2, 0.0], [0.5, 0.2, 0.0]])
    >>> chosen, rows = smallest_within(v, [0.1, 0.2, 0.4], gaps * 0 + [[0.1, 0.2, 0.4]], gaps, 0.5, 1.0, None)
    >>> chosen["value"], [r["value"] for r in rows]
    (0.2, [0.1, 0.2, 0.4])
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ..core import smallest_within as grid
from ..orp import protocol_gap_record
from .operating_point import SearchViews, band_edges, split_bands

#: a searched point's knob: LAS's IPR (a share of the FR pixels) or the two-pass sampler's share of C
KNOBS = ("ipr", "share")
#: the format of a knob's value in the log lines and the report
FORMATS = {"ipr": ".1%", "share": ".0%"}


def say_value(knob: str, x: float) -> str:
    """A value of ``knob`` as the log lines and the report say it.

    Example:
        >>> say_value("ipr", 0.1234), say_value("share", 0.75)
        ('IPR 12.3%', '75% of C')
    """
    return f"IPR {x:{FORMATS[knob]}}" if knob == "ipr" else f"{x:{FORMATS[knob]}} of C"


@dataclass(frozen=True)
class SearchedPoint:
    """A baseline's operating point searched like the ORP, the small sibling of the product's
    :class:`~imls_lightning.core.operating_point.OperatingPoint`: the value of its knob it runs at and the search
    that chose it. One type for LAS at the promise (``knob="ipr"``) and the two-pass sampler (``knob="share"``, with its
    first pass ``base`` and ``floor`` in ``settings``).

    Attributes:
        knob: ``"ipr"`` or ``"share"``; ``value``: the knob's value it runs at (the largest searched, or 1 for a share,
            where none kept the bound); ``found``: whether one kept the bound; ``where``: the search views, in the
            report's words; ``epsilon_db``; ``record``: the chosen value's protocol record (None: none found); ``rows``:
            every value searched; ``by_distance``: each band of camera distance's own value (:func:`band_values`:
            ``edges``, the values near to far as ``values`` (LAS) or ``shares`` (two-pass), ...), None: ``value`` for
            every view; ``settings``: the sampler's other settings.

    Example:
        >>> p = SearchedPoint("ipr", 0.1, True, "4 views", 1.0, None)
        >>> p.value, SearchedPoint.from_dict(p.to_dict()) == p
        (0.1, True)
    """

    knob: str
    value: float
    found: bool
    where: str
    epsilon_db: float
    record: dict[str, Any] | None
    rows: list[dict[str, Any]] = field(default_factory=list)
    by_distance: dict[str, Any] | None = None
    settings: dict[str, float] = field(default_factory=dict)

    def __post_init__(self):
        if self.knob not in KNOBS:
            raise ValueError(f"knob={self.knob!r}: expected one of {list(KNOBS)}")

    @property
    def band_values(self) -> list[float] | None:
        """Each band's value, near to far (``None``: one value for every view)."""
        if not self.by_distance:
            return None
        return self.by_distance["values" if self.knob == "ipr" else "shares"]

    def values_by_distance(self):
        """The :class:`~imls_lightning.models.ims.DistanceMeans` of the bands' values (``None``: one value)."""
        if not self.by_distance:
            return None
        from ..models.ims import DistanceMeans

        return DistanceMeans(self.by_distance["edges"], self.band_values)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SearchedPoint":
        """The point :meth:`to_dict` wrote (``summary.json``'s ``las_searched`` / ``two_pass``, an interrupted run's point)."""
        knob = "ipr" if "ipr" in d else "share"
        settings = {} if knob == "ipr" else {"base": float(d["base"]), "floor": float(d["floor"])}
        return cls(knob, float(d[knob]), found=bool(d.get("found", True)), where=str(d.get("where", "")),
                   epsilon_db=float(d.get("epsilon_db", 1.0)), record=d.get("record"), rows=list(d.get("rows", [])),
                   by_distance=d.get("by_distance"), settings=settings)

    def describe(self) -> str:
        """The report's line on where the point runs and why: what runs and where its knob was searched, then the value
        chosen with its gap and bound there and, by distance, each band's own; or that none kept the bound.

        Example:
            >>> p = SearchedPoint("ipr", 0.1, True, "4 views", 1.0, {"gap_db": 0.4, "gap_bound_db": 0.9})
            >>> p.describe()[-58:]
            'within 1 dB: IPR 10.0%, gap 0.40 dB there (bound 0.90 dB).'
        """
        eps, said = self.epsilon_db, say_value(self.knob, self.value)
        if self.knob == "ipr":
            head = (f"LAS at the product's promise (what a user who chose LAS would run): its IPR searched on {self.where}, "
                    f"the smallest that keeps the bound on the gap to the RecNN alone within {eps:g} dB")
            none, bound, bands = f"none of those searched did, so it runs at the largest, {said}", "", ", never above that one"
        else:
            head = (f"Two passes + fill + RecNN (no IMS, no decoder: the simplest alternative): a blue-noise first pass of "
                    f"{self.settings['base']:.0%} of C, then the pixels whose neighbours predict them worst, pull-push "
                    f"filled; its share was searched on {self.where}")
            none = f"no share below 100% kept the bound within {eps:g} dB, so it renders all of C"
            bound, bands = f" <= {eps:g}", " share, never above that one, judged on its own search views"
        if not self.found:
            return f"{head}: {none}."
        rec = self.record
        line = f"{head}: {said}, gap {rec['gap_db']:.2f} dB there (bound {rec['gap_bound_db']:.2f}{bound} dB)"
        if not self.by_distance:
            return line + "."
        each = say_bands(self.by_distance, self.band_values, FORMATS[self.knob])
        return f"{line}; then each band of camera distance its own{bands}: {each}."

    def to_dict(self) -> dict[str, Any]:
        rows = (list(self.rows) if self.knob == "ipr" else
                [{k: r[k] for k in ("share", "c_share", "gap_db", "gap_bound_db")} for r in self.rows])
        return {**self.settings, self.knob: self.value, "found": self.found, "where": self.where,
                "epsilon_db": self.epsilon_db, "record": self.record, "by_distance": self.by_distance, "rows": rows}


def smallest_within(v: SearchViews, values: Sequence[float], kept: np.ndarray, gaps: np.ndarray, confidence: float,
                    epsilon_db: float, future_views: int | None) -> tuple[dict[str, Any] | None, list[dict[str, Any]]]:
    """The smallest of ``values`` (ascending) whose protocol bound on ``v``'s views stays within ``epsilon_db``:
    ``(its record or None, every value's record)``. ``kept`` and ``gaps`` are ``(views, len(values))``: the share
    each view kept at each value and its PSNR gap to the RecNN alone. A record is
    :func:`~imls_lightning.orp.search.protocol_gap_record`'s plus ``value`` and ``kept`` (the mean kept share)."""
    rows = []
    for j, value in enumerate(values):
        rec = protocol_gap_record(gaps[:, j].tolist(), confidence, future_views, v.strata, v.passes, v.paths)
        rec.update(value=float(value), kept=float(kept[:, j].mean()))
        rows.append(rec)
    return grid.smallest_within(rows, epsilon_db, gap=_bound).item, rows


def _bound(rec: dict[str, Any]) -> float:
    """A protocol record's bound, what a search compares with epsilon."""
    return rec["gap_bound_db"]


def band_values(v: SearchViews, values: list[float], kept: np.ndarray, gaps: np.ndarray, confidence: float,
                epsilon_db: float, future_views: int | None, what: str = "the two-pass sampler",
                say: Callable[[float], str] = lambda x: say_value("share", x)) -> dict[str, Any] | None:
    """Each band of camera distance's own value, as the product's ORP gets a mean value per band: the smallest of
    ``values`` (ascending; the last is the value that held in every band, which a band keeps where none below it
    holds) whose bound on the band's own search views, for its share of ``future_views`` and counting its passes
    (:func:`~imls_lightning.orp.search.protocol_gap_record`), stays within ``epsilon_db``. ``kept`` and ``gaps``:
    ``(views, len(values))`` or wider, as measured on ``v``'s views, so no view is rebuilt again. ``what`` and
    ``say`` word the log lines.

    Returns ``edges`` (:func:`~imls_lightning.evaluation.operating_point.band_edges`), and per band near to far
    ``values``, ``kept``, ``gaps_db``, ``bounds_db``, ``views``, ``lo``, ``hi``; ``None`` (one line says so)
    where the views' distances do not separate the bands.
    """
    bands = split_bands(v.strata, future_views, v.passes)
    out: dict[str, list] = {k: [] for k in ("values", "kept", "gaps_db", "bounds_db", "views", "lo", "hi")}
    for band in bands:
        k, idx = band.label, band.idx
        records = (protocol_gap_record(gaps[idx, j].tolist(), confidence, band.future_views, None, band.passes, v.paths)
                   for j in range(len(values)))  # read up to the first within only
        pick = grid.smallest_within(records, epsilon_db, gap=_bound, otherwise="last")
        j, rec, value = pick.index, pick.item, values[pick.index]
        d = [v.distances[i] for i in idx]
        for key, x in (("values", value), ("kept", kept[idx, j].mean()), ("gaps_db", rec["gap_db"]),
                       ("bounds_db", rec["gap_bound_db"]), ("lo", min(d)), ("hi", max(d))):
            out[key].append(float(x))
        out["views"].append(len(idx))
        print(f"[evaluate] {what} by distance: band {k + 1} of {len(bands)} ({min(d):.2f}-{max(d):.2f}): "
              f"{say(value)}, gap {rec['gap_db']:.2f} dB (bound {rec['gap_bound_db']:.2f})", file=sys.stderr, flush=True)
    out["edges"] = band_edges(out["lo"], out["hi"])
    if out["edges"] is None:
        print(f"[evaluate] warning: {what} by distance: the search views' camera distances do not separate "
              f"the bands; every view runs at {say(values[-1])}", file=sys.stderr, flush=True)
        return None
    return out


def choose(v: SearchViews, s, values: list[float], kept: np.ndarray, gaps: np.ndarray, future_views: int | None,
           what: str, say: Callable[[float], str]) -> tuple[dict[str, Any] | None, list[dict[str, Any]], dict[str, Any] | None]:
    """A baseline's point from its measured ``kept`` and ``gaps`` on the search views ``v`` (``values`` ascending):
    :func:`smallest_within` at ``s.orp_confidence`` and ``s.epsilon_db``, then, with ``s.orp_by_distance`` and bands
    on ``v``, each band's own (:func:`band_values`, never above the chosen). ``what`` and ``say`` word the log lines.

    Returns ``(chosen, rows, by_distance)`` as :func:`smallest_within` and :func:`band_values` give them (``None``
    for none found, or no bands).
    """
    chosen, rows = smallest_within(v, values, kept, gaps, s.orp_confidence, s.epsilon_db, future_views)
    by_distance = None
    if chosen is None:
        print(f"[evaluate] {what}: none of the values searched kept the bound", file=sys.stderr, flush=True)
        return chosen, rows, by_distance
    print(f"[evaluate] {what}: {say(chosen['value'])}, gap {chosen['gap_db']:.2f} dB (bound {chosen['gap_bound_db']:.2f})",
          file=sys.stderr, flush=True)
    if s.orp_by_distance and v.strata is not None:
        by_distance = band_values(v, values[:values.index(chosen["value"]) + 1], kept, gaps, s.orp_confidence, s.epsilon_db,
                                  future_views, what=what, say=say)
    return chosen, rows, by_distance


def say_bands(b: dict[str, Any], values: Sequence[float], fmt: str) -> str:
    """A point's bands of camera distance as its report line says them, near to far: ``lo-hi: value (bound x dB)``
    (``b``: :func:`band_values`' output; ``values``: the bands' values; ``fmt``: their format).

    Example:
        >>> say_bands({"lo": [1.0, 2.5], "hi": [2.0, 3.5], "bounds_db": [0.4, 0.9]}, [0.1, 0.25], ".0%")
        '1.00-2.00: 10% (bound 0.40 dB); 2.50-3.50: 25% (bound 0.90 dB)'
    """
    return "; ".join(f"{lo:.2f}-{hi:.2f}: {x:{fmt}} (bound {bd:.2f} dB)" for lo, hi, x, bd in zip(b["lo"], b["hi"], values, b["bounds_db"]))


__all__ = ["FORMATS", "KNOBS", "SearchedPoint", "say_value", "smallest_within", "band_values", "choose", "say_bands"]
