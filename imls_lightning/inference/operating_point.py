"""The operating point an evaluation chose for an IMS checkpoint, recorded beside it.

:mod:`imls_lightning.evaluation` searches the ORP on the product path (the smallest mean value ``u``
whose IML/S + RecNN stays within ``epsilon_db`` of the RecNN alone on the validation views) and runs
IML/S there. :func:`write_operating_point` records that point in a sidecar file next to the IMS
checkpoint, ``<ims.ckpt>.orp.json`` (beside the file a symbolic link points to), so that a user who
has only the checkpoint finds it; its content names the checkpoint by the SHA-256 of its bytes.
:func:`read_operating_point` reads and checks it: a sidecar of another checkpoint (a retrained or
replaced file), an unreadable one or one of another format is ignored with a one-line warning,
never trusted.

Every consumer reads it the same way (:func:`mean_to_run`, through
:func:`~imls_lightning.inference.checkpoints.load_product`) and runs at the recorded point by default; an
explicit mean overrides it, and without a record they fall back to the trained mean, saying so in one
line on stderr: :meth:`IMLSRenderer.from_checkpoints <imls_lightning.inference.pipeline.IMLSRenderer.from_checkpoints>`
(so the desktop viewer), the browser viewer's session, and :func:`imls_lightning.inference.export.export_renderer`
(whose ``export.json`` carries the record).

Example:
    >>> p = OperatingPoint(mean=0.52, lift=False, c_share=0.393, ipr=0.098, epsilon_db=1.0)
    >>> p.describe()
    'u = 0.520, 39.3 % of C, IPR 0.098 on the validation views (within 1 dB of the RecNN alone)'
    >>> write_operating_point("ims.ckpt", p)              # doctest: +SKIP
    >>> read_operating_point("ims.ckpt", trained_mean=0.2).mean   # doctest: +SKIP
    0.52
"""
from __future__ import annotations

import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

from data_gen.errors import InputError

from ..core.importance import check_object_floor, check_sharpness

__all__ = ["SUFFIX", "OperatingPoint", "sidecar_path", "write_operating_point", "read_operating_point", "mean_to_run"]

#: appended to the checkpoint's file name
SUFFIX = ".orp.json"
KIND = "imls-operating-point"
VERSION = 1


def _log(msg: str) -> None:
    print(f"[orp] {msg}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class OperatingPoint:
    """An evaluation's operating point for one IMS checkpoint.

    Attributes:
        mean: the mean value ``u`` IML/S runs at (``None``: the search found no ORP within
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
            (``None``: no floor there), which :meth:`distance_means` carries; ``margin`` is then the largest, for
            consumers that take one.
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

    @property
    def found(self) -> bool:
        return self.mean is not None

    def distance_means(self):
        """The :class:`~imls_lightning.models.ims.DistanceMeans` of a by-distance point (``None``: one mean
        value for every view)."""
        if not self.found or not self.by_distance:
            return None
        from ..models.ims import DistanceMeans

        margins = (self.object_floor or {}).get("band_margins")
        return DistanceMeans(self.by_distance["edges"], self.by_distance["means"], margins)

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
    from ..config import file_hash

    return file_hash(Path(ims_checkpoint).expanduser(), length=64)


def write_operating_point(ims_checkpoint: str | Path, point: OperatingPoint) -> Path:
    """Record ``point`` for ``ims_checkpoint`` in its sidecar (atomically; replaces an older one).

    Returns the sidecar's path. Raises ``OSError`` where the checkpoint's folder is not writable.
    """
    from data_gen.atomic import atomic_json

    record = {"kind": KIND, "version": VERSION, "ims_checkpoint": str(Path(ims_checkpoint).expanduser().resolve()),
              "ims_checkpoint_sha256": _checkpoint_hash(ims_checkpoint), **asdict(point)}
    return atomic_json(sidecar_path(ims_checkpoint), record)


def _check(record: Any, sha: str) -> tuple[OperatingPoint | None, str | None]:
    """``(point, None)`` for a record of this checkpoint, else ``(None, why)``."""
    if not isinstance(record, dict) or record.get("kind") != KIND or record.get("version") != VERSION:
        return None, "not an operating-point record of this version"
    if record.get("ims_checkpoint_sha256") != sha:
        return None, (f"it belongs to another checkpoint (SHA-256 {str(record.get('ims_checkpoint_sha256'))[:12]}..., "
                      f"this one is {sha[:12]}...)")
    try:
        mean = record["mean"]
        mean = None if mean is None else float(mean)
        if mean is not None and not 0.01 <= mean <= 1.0:
            raise ValueError(f"mean={mean} outside [0.01, 1]")
        opt = lambda k, f=float: None if record.get(k) is None else f(record[k])  # noqa: E731
        point = OperatingPoint(mean=mean, lift=bool(record["lift"]), c_share=opt("c_share"), ipr=opt("ipr"),
                               epsilon_db=float(record["epsilon_db"]), gap_db=opt("gap_db"), views=opt("views", int),
                               scene=opt("scene", str), report=opt("report", str),
                               by_distance=_by_distance(record.get("by_distance")),
                               sharpness=check_sharpness(record.get("sharpness", 1.0)),
                               object_floor=_object_floor(record.get("object_floor")))
        if (point.object_floor or {}).get("band_margins") is not None and not point.by_distance:
            raise ValueError("object_floor.band_margins without by_distance bands to hold them")
        point.distance_means()  # the bands are checked as a renderer will read them
    except (KeyError, TypeError, ValueError, InputError) as err:
        return None, f"malformed ({type(err).__name__}: {err})"
    return point, None


def _object_floor(value: Any) -> dict | None:
    """A record's ``object_floor`` checked (``margin`` in [0, 1], ``tau`` in (0, 1)), its other numbers as floats;
    ``None`` stays ``None``."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise TypeError(f"object_floor is a {type(value).__name__}, expected a mapping")
    margin, tau = check_object_floor(value["margin"], value["tau"])
    out: dict[str, Any] = {"margin": margin, "tau": tau}
    if value.get("band_margins") is not None:  # one per band of by_distance: distance_means() checks the count
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
                         log: Callable[[str], None] | None = _log) -> OperatingPoint | None:
    """The operating point recorded for ``ims_checkpoint`` (checked against its bytes), or ``None``.

    Says in one line (``log``, by default stderr; ``None``: silent) which point a renderer built from
    the checkpoint runs at: the recorded one, or the trained mean ``trained_mean`` because there is
    no sidecar, the sidecar is ignored (another checkpoint's, unreadable, another format: a
    warning) or the evaluation found no ORP. ``None`` is returned in each of those cases.
    """
    say = log or (lambda _msg: None)
    side = sidecar_path(ims_checkpoint)
    fallback = "the trained mean" + ("" if trained_mean is None else f" u = {float(trained_mean):.3f}")
    if not side.is_file():
        say(f"no recorded operating point for {ims_checkpoint} (python -m imls_lightning.evaluate records one "
            f"in {side.name}): running at {fallback}")
        return None
    try:
        point, why = _check(json.loads(side.read_text()), _checkpoint_hash(ims_checkpoint))
    except (OSError, ValueError) as err:
        point, why = None, f"unreadable ({type(err).__name__})"
    if point is None:
        say(f"warning: {side} ignored: {why}; running at {fallback}")
        return None
    if not point.found:
        say(f"{side.name}: the evaluation found {point.describe()}; running at {fallback}")
        return None
    say(f"running at the evaluation's operating point {point.describe()} ({side.name})")
    return point


def mean_to_run(ims_checkpoint: str | Path, mean: float | str | None = None, *, target: str = "pim",
                trained_mean: float | None = None, log: Callable[[str], None] | None = _log
                ) -> tuple[float | None, bool, OperatingPoint | None]:
    """The mean value a renderer of the IMS checkpoint ``ims_checkpoint`` runs at, whether its masks are
    lifted, and the recorded point they came from: ``(mean or None for the trained one, lift, point or None)``.

    ``mean``: ``None``: the recorded operating point (its mean and lift), else the trained mean (one
    line says which, see :func:`read_operating_point`); a number in ``[0.01, 1]``: that mean value (the
    paper's rescale; nothing is read); ``"trained"``: the trained mean. An IMS trained with
    ``target="im"`` (``target``) has only its trained mean: nothing is read. ``trained_mean`` names
    the fallback in the message.

    Raises:
        InputError: a ``mean`` that is neither of those.

    Example:
        >>> mean_to_run("ims.ckpt", 0.4), mean_to_run("ims.ckpt", "trained")
        ((0.4, False, None), (None, False, None))
    """
    from data_gen.errors import finite_number

    if isinstance(mean, str) and mean == "trained":
        return None, False, None
    if mean is not None:
        u = finite_number(mean, "mean", "a number in [0.01, 1], 'trained' or null (the recorded operating point)")
        if not 0.01 <= u <= 1.0:
            raise InputError(f"mean={mean}: expected a number in [0.01, 1], 'trained' or null (the recorded operating point)")
        return u, False, None
    if str(target) != "pim":
        return None, False, None
    point = read_operating_point(ims_checkpoint, trained_mean, log=log)
    return (None, False, None) if point is None else (point.mean, point.lifted, point)
