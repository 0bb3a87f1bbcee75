"""An evaluation that resumes: what a run has measured so far, kept in ``<output_dir>/partial/`` until its report is
written, so that an interrupted evaluation (a session's end, a killed job) loses at most the view it was measuring.

- ``point.json``: the operating point once searched (the ORP's summary, the mean value IML/S runs at, whether the masks
  are lifted, the two-pass sampler's share, the notes so far). A later run restores it instead of searching again.
- ``views.jsonl``: one line per measured view, its metric rows, sweep rows and the other processes' load while it was
  timed; its image-grid images beside it (``grid-<view>.npz``), written first. The line is written last and fsynced, so
  a view counts only once it is whole.

The folder's name already holds the hash of the checkpoints' bytes and of every setting that changes the results, so a
run that finds ``partial/`` there is one of the same inputs; the record is still checked before it is trusted (its
format, its views, each line's rows), and what does not hold is dropped with one line and measured again.
``resume=false`` starts over. The report says how many views an earlier sitting measured.

Example:
    >>> import tempfile
    >>> out = Path(tempfile.mkdtemp())
    >>> progress = EvaluationProgress(out, positions=[0, 5], timed=[0])
    >>> progress.save_point({"orp": None, "imls_mean": None, "lift": False, "notes": []})
    >>> progress.add_view(0, [{"view": 0, "method": "recnn", "psnr": 30.0}], [], None, None)
    >>> again = EvaluationProgress(out, positions=[0, 5], timed=[0])
    >>> sorted(again.views), again.point["lift"]
    ([0], False)
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from imls_lightning.base.atomic import atomic_json, atomic_write, atomic_write_text, fsync_dir

#: the record's layout; a record of another is started over
FORMAT = 1


def plain(o: Any) -> Any:
    """A JSON value for what :func:`json.dumps` cannot write itself: NumPy scalars and arrays, tuples' items, tensors.

    Example:
        >>> plain(np.int64(3)), plain(np.float32(0.5)), plain(np.array([1, 2])), plain(np.bool_(True))
        (3, 0.5, [1, 2], True)
    """
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if hasattr(o, "tolist"):  # arrays and tensors
        return o.tolist()
    raise TypeError(f"{type(o).__name__} is not JSON serializable")


def _log(msg: str) -> None:
    print(f"[evaluate] {msg}", file=sys.stderr, flush=True)


class EvaluationProgress:
    """The partial results of one evaluation folder (see the module's docstring).

    Args:
        out: the evaluation's folder.
        positions: the evaluated positions on the trajectory, in order (a record of other views is started over).
        timed: the timed positions (likewise).
        resume: ``False``: discard any record and start over.

    Attributes:
        point: the saved operating point (``{}`` before it is searched).
        views: ``{position: {"rows", "sweep_rows", "load", "grid", "sitting"}}`` of the views already measured.
        sitting: this run's number (1 for a fresh evaluation, one more for each resume).
    """

    def __init__(self, out: str | Path, positions: Iterable[int], timed: Iterable[int], resume: bool = True):
        self.dir = Path(out) / "partial"
        self.positions = [int(p) for p in positions]
        self.timed = sorted(int(p) for p in timed)
        if not resume and self.dir.exists():
            shutil.rmtree(self.dir)
            _log(f"resume=false: the partial results in {self.dir} were discarded")
        self.point = self._read_point()
        self.views = self._read_views() if self.point else {}
        self.sitting = 1 + max((v["sitting"] for v in self.views.values()), default=0 if not self.point else
                               int(self.point.get("sitting", 1)))
        if self.views:
            _log(f"resuming: {len(self.views)} of the {len(self.positions)} views already measured in {self.dir} "
                 "(resume=false starts over)")
        elif self.point:
            _log(f"resuming: the operating point searched earlier is restored from {self.dir / 'point.json'}")

    # the operating point -------------------------------------------------------------------------------------------
    def _start_over(self, why: str) -> dict:
        _log(f"{self.dir}: {why}; this evaluation starts over")
        shutil.rmtree(self.dir, ignore_errors=True)
        return {}

    def _read_point(self) -> dict[str, Any]:
        path = self.dir / "point.json"
        if not path.is_file():
            if self.dir.exists():  # views without their point cannot be trusted
                shutil.rmtree(self.dir, ignore_errors=True)
            return {}
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            return self._start_over(f"point.json is unreadable ({type(err).__name__})")
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            return self._start_over(f"point.json is not a format-{FORMAT} record")
        if d.get("positions") != self.positions or d.get("timed") != self.timed:
            return self._start_over("point.json was measured on other views")
        if not {"orp", "imls_mean", "lift", "notes"} <= set(d):
            return self._start_over("point.json lacks some of orp, imls_mean, lift, notes")
        return d

    def save_point(self, point: Mapping[str, Any]) -> None:
        """Keep the operating point (``orp`` summary | None, ``imls_mean``, ``lift``, ``notes``, optional ``two_pass``)."""
        self.point = {**point, "format": FORMAT, "positions": self.positions, "timed": self.timed,
                      "sitting": self.point.get("sitting", self.sitting) if self.point else 1}
        atomic_json(self.dir / "point.json", self.point, default=plain)

    # the views -----------------------------------------------------------------------------------------------------
    def _grid_path(self, p: int) -> Path:
        return self.dir / f"grid-{int(p)}.npz"

    def _valid(self, rec: Any) -> str | None:
        """Why a views.jsonl record cannot be trusted (None: it can)."""
        if not isinstance(rec, dict) or not isinstance(rec.get("view"), int):
            return "not a view record"
        p = rec["view"]
        if p not in self.positions:
            return f"view {p} is not evaluated"
        rows = rec.get("rows")
        if not isinstance(rows, list) or not rows or any(not isinstance(r, dict) or r.get("view") != p or "method" not in r
                                                         for r in rows):
            return f"view {p}'s rows are malformed"
        if not isinstance(rec.get("sweep_rows"), list):
            return f"view {p}'s sweep rows are malformed"
        if rec.get("grid") and not self._grid_path(p).is_file():
            return f"view {p}'s grid images are missing"
        return None

    def _read_views(self) -> dict[int, dict[str, Any]]:
        path = self.dir / "views.jsonl"
        if not path.is_file():
            return {}
        views, bad, lines = {}, [], path.read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            try:
                rec = json.loads(line)
            except ValueError:
                rec = None
            why = "an unreadable line (an interrupted write)" if rec is None else self._valid(rec)
            if why is None:
                views[rec["view"]] = {"rows": rec["rows"], "sweep_rows": rec["sweep_rows"], "load": rec.get("load"),
                                      "grid": bool(rec.get("grid")), "sitting": int(rec.get("sitting", 1))}
            else:
                bad.append(f"line {i + 1}: {why}")
        if bad:  # repair: keep the lines that hold, measure the rest again
            _log(f"{path}: {len(bad)} record(s) dropped and measured again ({'; '.join(bad[:3])})")
            text = "".join(json.dumps({"view": p, **v}, default=plain) + "\n" for p, v in views.items())
            atomic_write_text(path, text)
        return views

    def add_view(self, p: int, rows: list[dict[str, Any]], sweep_rows: list[dict[str, Any]], load: dict[str, Any] | None,
                 grid: Mapping[str, Any] | None) -> None:
        """Keep one measured view: its grid images first, then its line (fsynced), so it counts only once whole."""
        if not self.point:
            raise RuntimeError("EvaluationProgress.add_view before save_point: the views belong to an operating point")
        if grid is not None:
            arrays = {k: np.asarray(v.cpu().numpy() if hasattr(v, "cpu") else v) for k, v in grid.items() if v is not None}
            atomic_write(self._grid_path(p), lambda f: np.savez(f, **arrays))
        rec = {"view": int(p), "rows": rows, "sweep_rows": sweep_rows, "load": load, "grid": grid is not None,
               "sitting": self.sitting}
        path = self.dir / "views.jsonl"
        new = not path.exists()
        with open(path, "a", encoding="utf-8") as f:
            f.write(json.dumps(rec, default=plain) + "\n")
            f.flush()
            os.fsync(f.fileno())
        if new:
            fsync_dir(self.dir)
        self.views[int(p)] = {k: rec[k] for k in ("rows", "sweep_rows", "load", "grid", "sitting")}

    def grid(self, p: int) -> dict[str, np.ndarray]:
        """The image-grid images kept for view ``p``."""
        with np.load(self._grid_path(p), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}

    def note(self) -> str | None:
        """The report's line on the sittings (None when one sitting measured every view)."""
        earlier = sum(v["sitting"] < self.sitting for v in self.views.values())
        if not earlier and self.sitting == 1:
            return None
        return (f"Resumed evaluation (sitting {self.sitting}): {earlier} of the {len(self.positions)} views were measured "
                "in an earlier sitting and kept (partial/); each view's methods ran in one schedule, but stage times of "
                "views from different sittings can differ with the machine's state.")

    def finish(self) -> None:
        """The report is written: the partial results are no longer needed."""
        shutil.rmtree(self.dir, ignore_errors=True)
