"""The operating point an evaluation chose for an IMS checkpoint, recorded beside it.

:mod:`imls_lightning.evaluation` searches the ORP on the product path (the smallest mean value ``u``
whose IML/S + RecNN stays within ``epsilon_db`` of the RecNN alone on the validation views) and runs
IML/S there. :func:`write_operating_point` records that point in a sidecar file next to the IMS
checkpoint, ``<ims.ckpt>.orp.json`` (beside the file a symbolic link points to), so that a user who
has only the checkpoint finds it; its content names the checkpoint by the SHA-256 of its bytes and
carries a digest of itself keyed with that hash (:func:`record_digest`: SHA-256 over its canonical JSON,
without the digest, then the checkpoint's hash), so that an edit of any number shows.
:func:`read_operating_point` reads and checks it, and trusts it only when it is what the evaluation
wrote: a sidecar of another checkpoint (a retrained or replaced file), an unreadable one, one of another
format, one without a digest (written before records carried one) or whose digest does not match, one
whose share of C is not what its own search measured at its mean value (within the search's recorded
relative ``tolerance``), and one that disagrees with its evaluation's ``summary.json`` (beside the
``report`` it names, when that file is at hand) is ignored with a one-line warning, never trusted; the
trained mean is used, and ``mean=<u>`` runs at a point of the user's choice.

An :class:`ORPRecord` is the search's account: the frozen
:class:`~imls_lightning.core.operating_point.OperatingPoint` it chose (:attr:`ORPRecord.point`: share, lift, bands,
sharpness, object floor), with what it measured there (the share of C and IPR, the gap, the views, the search's
points). The file keeps its format (``mean`` is the point's share as the paper's mean value ``u``, ``by_distance``
its bands, ``object_floor`` its floor), so records written before read the same.

Every consumer reads it the same way (:func:`point_to_run`, through
:func:`~imls_lightning.inference.checkpoints.load_product`) and runs at the recorded point by default; an
explicit share overrides it, and without a record they fall back to the trained share, saying so in one
line on stderr: :meth:`IMLSRenderer.from_checkpoints <imls_lightning.inference.pipeline.IMLSRenderer.from_checkpoints>`
(so the desktop viewer), the browser viewer's session, and :func:`imls_lightning.inference.export.export_renderer`
(whose ``export.json`` carries the record).

Example:
    >>> r = ORPRecord(mean=0.52, lift=False, c_share=0.393, ipr=0.098, epsilon_db=1.0)
    >>> r.describe()
    'u = 0.520, 39.3 % of C, IPR 0.098 on the validation views (within 1 dB of the RecNN alone)'
    >>> r.point
    OperatingPoint(share=0.52, lift=False, bands=None, sharpness=1.0, object_floor=None, decoder='trained')
    >>> write_operating_point("ims.ckpt", r)              # doctest: +SKIP
    >>> read_operating_point("ims.ckpt", trained_mean=0.2).point.share   # doctest: +SKIP
    0.52
"""
from __future__ import annotations

import hashlib
import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from imls_lightning.base.errors import InputError

from ..core.importance import check_object_floor, check_sharpness
from ..core.operating_point import Bands, OperatingPoint

__all__ = ["SUFFIX", "ORPRecord", "sidecar_path", "write_operating_point", "read_operating_point", "point_to_run",
           "share_setting", "record_digest", "SEARCH_TOLERANCE"]

#: appended to the checkpoint's file name
SUFFIX = ".orp.json"
KIND = "imls-operating-point"
VERSION = 1
#: the record's field holding :func:`record_digest` (records written before it have none: not trusted)
DIGEST = "digest"
#: the ORP search's relative tolerance on the mean value (:func:`~imls_lightning.orp.product.product_orp`):
#: a record's share of C may differ from the share its search measured at its mean value by this fraction
SEARCH_TOLERANCE = 0.05


def _log(msg: str) -> None:
    print(f"[orp] {msg}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class ORPRecord:
    """An evaluation's operating point for one IMS checkpoint, as recorded: the point (:attr:`point`) and what its
    search measured there. Its fields are the record file's.

    Attributes:
        mean: the share of C IML/S runs at, as the paper's mean value ``u`` (``None``: the search found no ORP within
            ``epsilon_db``; the evaluation ran at the trained mean).
        lift: whether the IMS's masks were lifted to their mean value (the evaluation's ``ims_lift``;
            the ``lift`` argument of :class:`~imls_lightning.models.ims.IMSMaskHead`).
        c_share, ipr: the share of the C-Image and of the FR-Image ray-cast at ``mean``, averaged
            over the validation views the search ran on.
        epsilon_db: the search's bound; ``gap_db``: the RecNN alone's PSNR minus IML/S's there.
        views: the number of validation views searched; ``scene``: the scene evaluated;
            ``report``: the evaluation's ``report.md``.
        by_distance: the evaluation's ``orp_by_distance`` point, ``None`` without: ``edges`` (``K - 1``
            camera distances between the bands), ``means`` (``K`` mean values, near to far), and per band
            the search's ``c_shares``, ``gaps_db`` and ``views``. Renderers then run each view at its
            band's mean value (:class:`~imls_lightning.models.ims.DistanceMeans`); ``mean`` stays the one
            value that met the bound in every band, for consumers that take a single one.
        sharpness: the IMS mask's sharpness ``gamma`` the point was searched at (the evaluation's
            ``ims_sharpness``; 1: the paper's masks; :meth:`~imls_lightning.models.ims.IMSMaskHead.with_sharpness`).
            Records written before it read as 1.
        object_floor: the floor on each view's mean value from the object its IMS sees (the evaluation's
            ``orp_object_floor``, chosen on the cache's validation views after the search): ``{"margin", "tau"}`` and
            what chose it (``c_share``, ``gap_db`` and ``gap_bound_db`` there, ``views``), or ``None``: no floor
            (:meth:`~imls_lightning.models.ims.IMSMaskHead.with_object_floor`). Records written before it read as ``None``.
            With ``band_margins`` (``orp_object_floor_by_band``) each band of ``by_distance`` has its own margin
            (``None``: no floor there), which :attr:`point` carries in its bands; ``margin`` is then the largest, for
            consumers that take one.
        points: ``[u, c_share]`` of every mean value the search tried (the share of C it measured there), so the record
            says which share its ``mean`` implies; ``None``: not recorded (then that check is skipped).
        tolerance: the search's relative tolerance (``SEARCH_TOLERANCE``): how far ``c_share`` may be from the share
            ``points`` imply at ``mean``.
        decoder: what rebuilds the C-Image at the point (``"trained"``: the IMS's own decoder; ``"fill"``: the
            untrained pull-push fill, which the search kept as the faster within the bound; the evaluation's
            ``orp_decoders``). Records written before it read as ``"trained"``, and a ``"trained"`` record is written
            without the field, so its bytes are what they were.
    """

    mean: float | None
    lift: bool
    c_share: float | None
    ipr: float | None
    epsilon_db: float
    gap_db: float | None = None
    views: int | None = None
    scene: str | None = None
    report: str | None = None
    by_distance: dict | None = None
    sharpness: float = 1.0
    object_floor: dict | None = None
    points: list | None = None
    tolerance: float = SEARCH_TOLERANCE
    decoder: str = "trained"

    @property
    def found(self) -> bool:
        return self.mean is not None

    @property
    def point(self) -> OperatingPoint | None:
        """The :class:`~imls_lightning.core.operating_point.OperatingPoint` recorded (``None``: the search found none):
        the share, lift, bands, sharpness and object floor renderers run at."""
        if not self.found:
            return None
        bands = None
        if self.by_distance:
            bands = Bands(self.by_distance["edges"], self.by_distance["means"], (self.object_floor or {}).get("band_margins"))
        return OperatingPoint(share=self.mean, lift=self.lift, bands=bands, sharpness=self.sharpness, object_floor=self.floor,
                              decoder=self.decoder)

    def describe(self) -> str:
        """One line: the mean value, the share and IPR it gave, and the bound."""
        if not self.found:
            return f"no ORP within {self.epsilon_db:g} dB of the RecNN alone on the validation views"
        share = "" if self.c_share is None else f", {100 * self.c_share:.1f} % of C"
        ipr = "" if self.ipr is None else f", IPR {self.ipr:.3f}"
        bands = ""
        if self.by_distance:
            b = self.by_distance
            bands = "; by camera distance, near to far: u = " + " / ".join(f"{u:.3f}" for u in b["means"])
            if b.get("c_shares"):
                bands += " (" + " / ".join(f"{100 * c:.0f}" for c in b["c_shares"]) + " % of C)"
            bands += " split at " + ", ".join(f"{e:.2f}" for e in b["edges"])
        sharp = "" if self.sharpness == 1.0 else f", sharpness {self.sharpness:g}"
        sharp += "" if self.decoder == "trained" else ", the pull-push fill as decoder"
        floor = ""
        if self.object_floor:
            f = self.object_floor
            margin = (f"{f['margin']:g}" if not f.get("band_margins") else
                      "(near to far) " + " / ".join("none" if m is None else f"{m:g}" for m in f["band_margins"]))
            floor = f"; each view at least its object (PIM' > {f['tau']:g}) + {margin} of C"
        return (f"u = {self.mean:.3f}{' (masks lifted)' if self.lift else ''}{sharp}{share}{ipr} on the validation views "
                f"(within {self.epsilon_db:g} dB of the RecNN alone){bands}{floor}")

    @property
    def floor(self) -> tuple[float, float] | None:
        """``(margin, tau)`` of the recorded object floor, for :meth:`~imls_lightning.models.ims.IMSMaskHead.with_object_floor`;
        ``None``: none."""
        if not self.found or not self.object_floor:
            return None
        return float(self.object_floor["margin"]), float(self.object_floor["tau"])

    @property
    def lifted(self) -> bool:
        """Whether masks made at this point are lifted (the evaluation lifted them and found a point)."""
        return bool(self.lift) if self.found else False


def sidecar_path(ims_checkpoint: str | Path) -> Path:
    """``<ims.ckpt>.orp.json`` beside the checkpoint's file (a symbolic link is followed)."""
    p = Path(ims_checkpoint).expanduser().resolve()
    return p.with_name(p.name + SUFFIX)


def _checkpoint_hash(ims_checkpoint: str | Path) -> str:
    from ..base.config import file_hash

    return file_hash(Path(ims_checkpoint).expanduser(), length=64)


def _canonical(record: Any) -> bytes:
    """The record's canonical JSON (sorted keys, compact separators), its digest left out."""
    body = {k: v for k, v in record.items() if k != DIGEST}
    return json.dumps(body, sort_keys=True, separators=(",", ":"), default=str).encode()


def record_digest(record: Any, checkpoint_sha256: str) -> str:
    """The digest an operating-point record carries: SHA-256 over its canonical JSON (sorted keys, compact separators,
    without the ``digest`` field) followed by the IMS checkpoint's SHA-256 (hex), so an edit of any number, or the
    record moved to another checkpoint, breaks it. Not a signature: it tells what the evaluation wrote from an edit.

    Example:
        >>> rec = {"kind": KIND, "version": VERSION, "mean": 0.5}
        >>> record_digest(rec, "ab" * 32) == record_digest({**rec, DIGEST: "x"}, "ab" * 32) != record_digest(rec, "cd" * 32)
        True
    """
    h = hashlib.sha256(_canonical(record))
    h.update(str(checkpoint_sha256).encode())
    return h.hexdigest()


def write_operating_point(ims_checkpoint: str | Path, point: ORPRecord) -> Path:
    """Record ``point`` for ``ims_checkpoint`` in its sidecar (atomically; replaces an older one), with its
    :func:`record_digest`.

    Returns the sidecar's path. Raises ``OSError`` where the checkpoint's folder is not writable.
    """
    from imls_lightning.base.atomic import atomic_json

    sha = _checkpoint_hash(ims_checkpoint)
    record = {"kind": KIND, "version": VERSION, "ims_checkpoint": str(Path(ims_checkpoint).expanduser().resolve()),
              "ims_checkpoint_sha256": sha, **asdict(point)}
    if record["decoder"] == "trained":  # the paper's decoder: written as before the field existed
        del record["decoder"]
    record = json.loads(json.dumps(record, default=str))  # as it reads back (tuples as lists, NumPy numbers as text)
    record[DIGEST] = record_digest(record, sha)
    return atomic_json(sidecar_path(ims_checkpoint), record)


def _check(record: Any, sha: str) -> tuple[ORPRecord | None, str | None]:
    """``(point, None)`` for a record of this checkpoint, as the evaluation wrote it, else ``(None, why)``."""
    if not isinstance(record, dict) or record.get("kind") != KIND or record.get("version") != VERSION:
        return None, "not an operating-point record of this version"
    if record.get("ims_checkpoint_sha256") != sha:
        return None, (f"it belongs to another checkpoint (SHA-256 {str(record.get('ims_checkpoint_sha256'))[:12]}..., "
                      f"this one is {sha[:12]}...)")
    if DIGEST not in record:
        return None, ("it carries no digest of its content (written before records carried one, or by hand), so "
                      "whether the evaluation wrote these numbers cannot be told; python -m imls_lightning.evaluate "
                      "records it again")
    if record[DIGEST] != record_digest(record, sha):
        return None, "its digest does not match its content (it was edited after the evaluation wrote it)"
    try:
        mean = record["mean"]
        mean = None if mean is None else float(mean)
        if mean is not None and not 0.01 <= mean <= 1.0:
            raise ValueError(f"mean={mean} outside [0.01, 1]")
        opt = lambda k, f=float: None if record.get(k) is None else f(record[k])  # noqa: E731
        point = ORPRecord(mean=mean, lift=bool(record["lift"]), c_share=opt("c_share"), ipr=opt("ipr"),
                               epsilon_db=float(record["epsilon_db"]), gap_db=opt("gap_db"), views=opt("views", int),
                               scene=opt("scene", str), report=opt("report", str),
                               by_distance=_by_distance(record.get("by_distance")),
                               sharpness=check_sharpness(record.get("sharpness", 1.0)),
                               object_floor=_object_floor(record.get("object_floor")),
                               points=_points(record.get("points")),
                               tolerance=float(record.get("tolerance", SEARCH_TOLERANCE)),
                               decoder=str(record.get("decoder", "trained")))
        if (point.object_floor or {}).get("band_margins") is not None and not point.by_distance:
            raise ValueError("object_floor.band_margins without by_distance bands to hold them")
        if not 0.0 <= point.tolerance <= 1.0:
            raise ValueError(f"tolerance={point.tolerance} outside [0, 1]")
        point.point  # the point is checked as a renderer will read it (its bands, floor and share)
    except (KeyError, TypeError, ValueError, InputError) as err:
        return None, f"malformed ({type(err).__name__}: {err})"
    why = _inconsistency(point)
    return (None, why) if why else (point, None)


def _points(value: Any) -> list | None:
    """A record's ``points``: ``[u, c_share]`` pairs as floats (``None`` stays ``None``)."""
    if value is None:
        return None
    out = [[float(u), float(c)] for u, c in value]
    if any(not (math.isfinite(u) and math.isfinite(c)) for u, c in out):
        raise ValueError("points: expected finite [u, c_share] pairs")
    return out


def _inconsistency(point: ORPRecord) -> str | None:
    """Why ``point``'s share of C is not the one its mean value implies (the share its search measured there,
    interpolated between the mean values it tried), beyond its relative tolerance; ``None`` when it is, or when the
    record does not say (no ``points``, no share, no point found)."""
    if not point.found or point.c_share is None or not point.points:
        return None
    pts = sorted(point.points)
    us, shares = [u for u, _ in pts], [c for _, c in pts]
    tol = point.tolerance
    if not us[0] * (1 - tol) <= point.mean <= us[-1] * (1 + tol):
        return (f"not self-consistent: u = {point.mean:.3f} lies outside the mean values its search tried "
                f"({us[0]:.3f}-{us[-1]:.3f})")
    implied = float(np.interp(point.mean, us, shares))
    if abs(point.c_share - implied) > tol * max(implied, 1e-3) + 1e-9:
        return (f"not self-consistent: {100 * point.c_share:.1f} % of C at u = {point.mean:.3f}, where its search "
                f"measured {100 * implied:.1f} % (tolerance {tol:.0%})")
    return None


def _summary_disagreement(point: ORPRecord, sha: str) -> str | None:
    """Why ``point`` is not what its evaluation's ``summary.json`` (beside the report it names) says, or ``None``: it
    agrees, or that file is not at hand (an evaluation folder moved or deleted, a record written without a report)."""
    if not point.report:
        return None
    path = Path(point.report).expanduser().parent / "summary.json"
    if not path.is_file():
        return None
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
        orp = summary["orp"]
        if not isinstance(orp, dict):
            raise TypeError("orp is not a mapping")
    except (OSError, ValueError, KeyError, TypeError) as err:
        return f"its evaluation's {path} is unreadable or has no operating point ({type(err).__name__})"
    theirs = (summary.get("checkpoints_sha256") or {}).get("ims") if isinstance(summary.get("checkpoints_sha256"), dict) else None
    if theirs and not sha.startswith(str(theirs)):
        return f"its evaluation's {path} evaluated another IMS checkpoint (SHA-256 {str(theirs)[:12]}...)"
    ours: dict[str, Any] = {"found": point.found, "mean": point.mean, "lift": point.lift, "c_share": point.c_share,
                            "ipr": point.ipr, "epsilon_db": point.epsilon_db, "gap_db": point.gap_db,
                            "sharpness": point.sharpness, "decoder": point.decoder}
    there: dict[str, Any] = {"found": bool(orp.get("found")), "mean": orp.get("mean") if orp.get("found") else None,
                             "lift": bool(orp.get("lift")), "c_share": orp.get("c_share"), "ipr": orp.get("ipr"),
                             "epsilon_db": orp.get("epsilon_db"), "gap_db": orp.get("gap_db"),
                             "sharpness": orp.get("sharpness", 1.0), "decoder": orp.get("decoder", "trained")}
    if point.by_distance:
        bands = orp.get("by_distance") or {}
        for key in ("means", "edges"):
            ours[f"by_distance.{key}"], there[f"by_distance.{key}"] = point.by_distance.get(key), bands.get(key)
    if point.object_floor:
        chosen = (orp.get("object_floor") or {}).get("chosen") or {}
        for key in ("margin", "tau"):
            ours[f"object_floor.{key}"], there[f"object_floor.{key}"] = point.object_floor.get(key), chosen.get(key)
    for key, mine in ours.items():
        if not _same(mine, there[key]):
            return f"it disagrees with its evaluation's {path} ({key} {_shown(mine)} here, {_shown(there[key])} there)"
    return None


def _same(a: Any, b: Any) -> bool:
    """Equal values, numbers (and lists of them) to a relative 1e-6."""
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return (isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b)
                and all(_same(x, y) for x, y in zip(a, b)))
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None:
        return a == b
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9)
    except (TypeError, ValueError):
        return a == b


def _shown(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _object_floor(value: Any) -> dict | None:
    """A record's ``object_floor`` checked (``margin`` in [0, 1], ``tau`` in (0, 1)), its other numbers as floats;
    ``None`` stays ``None``."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise TypeError(f"object_floor is a {type(value).__name__}, expected a mapping")
    margin, tau = check_object_floor(value["margin"], value["tau"])
    out: dict[str, Any] = {"margin": margin, "tau": tau}
    if value.get("band_margins") is not None:  # one per band of by_distance: the point's Bands check the count
        from ..models.ims import check_band_margins

        out["band_margins"] = check_band_margins(value["band_margins"], name="object_floor.band_margins")
    for key in ("c_share", "gap_db", "gap_bound_db"):
        if value.get(key) is not None:
            out[key] = float(value[key])
    if value.get("views") is not None:
        out["views"] = int(value["views"])
    return out


def _by_distance(value: Any) -> dict | None:
    """A record's ``by_distance`` as floats (``None`` stays ``None``); ``edges`` and ``means`` are required."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise TypeError(f"by_distance is a {type(value).__name__}, expected a mapping")
    out = {"edges": [float(x) for x in value["edges"]], "means": [float(x) for x in value["means"]]}
    for key in ("c_shares", "gaps_db"):
        if value.get(key) is not None:
            out[key] = [float(x) for x in value[key]]
    if value.get("views") is not None:
        out["views"] = [int(x) for x in value["views"]]
    return out


def read_operating_point(ims_checkpoint: str | Path, trained_mean: float | None = None, *,
                         log: Callable[[str], None] | None = _log, warn: Any = "log") -> ORPRecord | None:
    """The operating point recorded for ``ims_checkpoint`` (checked against its bytes, its digest, its own search
    and its evaluation's ``summary.json``), or ``None``; every consumer reads the record through this function.

    Says in one line (``log``, by default stderr; ``None``: silent) which point a renderer built from
    the checkpoint runs at: the recorded one, or the trained mean ``trained_mean`` because there is
    no sidecar or the evaluation found no ORP. A sidecar that is ignored (another checkpoint's, unreadable, another
    format, without or with a wrong digest, not self-consistent, disagreeing with its evaluation's summary) is one
    warning line saying why on ``warn`` (by default ``log``, and stderr where ``log`` is silent; ``None``: silent).
    ``None`` is returned in each of those cases.
    """
    say = log or (lambda _msg: None)
    if warn == "log":
        warn = log or _log
    warn = warn or (lambda _msg: None)
    side = sidecar_path(ims_checkpoint)
    fallback = "the trained mean" + ("" if trained_mean is None else f" u = {float(trained_mean):.3f}")
    if not side.is_file():
        say(f"no recorded operating point for {ims_checkpoint} (python -m imls_lightning.evaluate records one "
            f"in {side.name}): running at {fallback}")
        return None
    sha = _checkpoint_hash(ims_checkpoint)
    try:
        point, why = _check(json.loads(side.read_text()), sha)
    except (OSError, ValueError) as err:
        point, why = None, f"unreadable ({type(err).__name__})"
    if point is not None:
        why = _summary_disagreement(point, sha)
        point = None if why else point
    if point is None:
        warn(f"warning: {side} ignored: {why}; running at {fallback}")
        return None
    if not point.found:
        say(f"{side.name}: the evaluation found {point.describe()}; running at {fallback}")
        return None
    say(f"running at the evaluation's operating point {point.describe()} ({side.name})")
    return point


def point_to_run(ims_checkpoint: str | Path, share: float | str | None = None, *, target: str = "pim",
                 trained_mean: float | None = None, log: Callable[[str], None] | None = _log, key: str = "share"
                 ) -> tuple[OperatingPoint | None, ORPRecord | None]:
    """The operating point a renderer of the IMS checkpoint ``ims_checkpoint`` runs at and the record it came from:
    ``(point or None for the trained share, record or None)``.

    ``share``: ``None``: the recorded operating point (its share, lift, bands, sharpness and floor), else the trained
    share (one line says which, see :func:`read_operating_point`); a number in ``[0.01, 1]``: that share of the
    C-Image (the paper's rescale to that mean value; nothing is read); ``"trained"``: the trained share. An IMS
    trained with ``target="im"`` (``target``) has only its trained share: nothing is read. ``trained_mean`` names the
    fallback in the message; ``key`` the setting ``share`` came from, for messages (``mean`` where users type that).

    Raises:
        InputError: a ``share`` that is neither of those.

    Example:
        >>> point_to_run("ims.ckpt", 0.4), point_to_run("ims.ckpt", "trained")
        ((OperatingPoint(share=0.4, lift=False, bands=None, sharpness=1.0, object_floor=None, decoder='trained'), None), (None, None))
    """
    from imls_lightning.base.errors import finite_number

    if isinstance(share, str) and share == "trained":
        return None, None
    if share is not None:
        what = "a number in [0.01, 1] (a share of the C-Image), 'trained' or null (the recorded operating point)"
        u = finite_number(share, key, what)
        if not 0.01 <= u <= 1.0:
            raise InputError(f"{key}={share}: expected {what}")
        return OperatingPoint(share=u), None
    if str(target) != "pim":
        return None, None
    record = read_operating_point(ims_checkpoint, trained_mean, log=log)
    return (None, None) if record is None else (record.point, record)


def share_setting(settings: Any) -> tuple[Any, str]:
    """The share of the C-Image a user asked a viewer or the export for, and the key they typed it as: ``share`` (the
    documented name) or ``mean`` (its older name, still read); ``(None, "share")`` when neither is set.

    Raises:
        InputError: both are set.

    Example:
        >>> share_setting({"share": 0.4, "mean": None}), share_setting({"mean": "trained"}), share_setting({})
        ((0.4, 'share'), ('trained', 'mean'), (None, 'share'))
    """
    share, mean = settings.get("share"), settings.get("mean")
    if share is not None and mean is not None:
        raise InputError(f"share={share} and mean={mean}: set one (mean is share's older name)")
    return (mean, "mean") if share is None and mean is not None else (share, "share")
