"""Timing a method by its stages, from outside it: the product and every baseline time nothing themselves.

A method's forward pass (:meth:`Method.steps <imls_lightning.inference.pipeline.Method.steps>`) names each stage as it
starts it (``importance``, ``selective_render``, ``decoder``, ``recnn``, ...; ``None``: a step no stage counts);
:func:`timed_run` runs those steps and times each stage: wall time from its start to the next step's, synchronized on
CUDA so GPU work is counted, a stage that occurs twice summed, ``total`` the sum of the stages. :func:`timed` wraps a
method so that its ``run`` / ``render`` return those times (the viewers' latency bars); :func:`time_method` and
:func:`time_methods` take the median over repeated runs (the evaluation's per-stage breakdown, its CSV columns).

Example:
    >>> from imls_lightning.inference.pipeline import FullRayCast
    >>> # image, med, info = time_method(FullRayCast(renderer, 512), view)   # med: {"render": s, "total": s}
"""
from __future__ import annotations

import time
from typing import Any, Mapping

import numpy as np
import torch

from imls_lightning.render.camera import validate_view
from imls_lightning.base.errors import InputError

from ..inference.pipeline import Method, RenderResult

__all__ = ["StageTimer", "timed_run", "Timed", "timed", "time_method", "time_methods", "TIMING_ORDERS"]

#: the clock every stage is read with (a test may put a scripted one here)
clock = time.perf_counter


class StageTimer:
    """Seconds per stage of one run: :meth:`run` drives a method's steps, reading the clock at each stage boundary
    (after a CUDA synchronization on a CUDA ``device``, so work queued on the GPU counts in its stage)."""

    def __init__(self, device: torch.device | str = "cpu"):
        self.device = torch.device(device)
        self.times: dict[str, float] = {}

    def _now(self) -> float:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return clock()

    def run(self, steps) -> RenderResult:
        """Run the steps generator ``steps`` to its end; its :class:`RenderResult` (its ``timings`` are :meth:`result`)."""
        try:
            stage = next(steps)  # what comes before the first stage is no stage's
        except StopIteration as stop:
            return stop.value
        while True:
            t0 = self._now()
            try:
                following = next(steps)
            except StopIteration as stop:
                self._add(stage, self._now() - t0)
                out = stop.value
                out.timings = self.result()
                return out
            self._add(stage, self._now() - t0)
            stage = following

    def _add(self, stage: str | None, seconds: float) -> None:
        if stage is not None:
            self.times[stage] = self.times.get(stage, 0.0) + seconds

    def result(self) -> dict[str, float]:
        out = dict(self.times)
        out["total"] = float(sum(self.times.values()))
        return out


def timed_run(method: Method, view, **run_args: Any) -> RenderResult:
    """``method.run(view, **run_args)`` (a validated view) with ``timings``: seconds per stage plus ``total``."""
    return StageTimer(method.device).run(method.steps(view, **run_args))


class Timed:
    """A method whose runs are timed by stage (:func:`timed`); every other attribute is the method's."""

    def __init__(self, method: Method):
        self.method = method

    def __getattr__(self, name: str):
        return getattr(self.method, name)

    def run(self, view, **run_args: Any) -> RenderResult:
        return timed_run(self.method, view, **run_args)

    @torch.inference_mode()
    def render(self, view) -> tuple[np.ndarray, dict[str, float]]:
        """Render one view: ``(m, m, 3)`` uint8 image and seconds per stage (plus ``total``)."""
        r = self.run(validate_view(view))
        return r.image, r.timings


def timed(method: Method) -> Timed:
    """``method`` timed by stage: its ``run`` returns a :class:`RenderResult` with ``timings``, its ``render``
    ``(image, timings)`` (a method already timed is returned as it is).

    Example:
        >>> # image, timings = timed(IMLSRenderer.from_checkpoints("ims.ckpt")).render(view)
    """
    return method if isinstance(method, Timed) else Timed(method)


def time_method(method: Method, view, repeats: int = 10, warmup: int = 1,
                **run_args: Any) -> tuple[np.ndarray, dict[str, float], dict[str, Any]]:
    """Render a view ``warmup + repeats`` times; per-stage medians over the repeats. ``run_args`` go to
    each run (e.g. an oracle ``im`` for :class:`~imls_lightning.inference.pipeline.IMLSRenderer`, an ``ipr`` for
    :class:`~imls_lightning.inference.pipeline.LASMethod`).

    Returns the last image ``(m, m, 3)`` uint8, ``{stage: median seconds}`` (``total`` is the median
    of the per-run totals, not the sum of the stage medians), and the method's info of the last run.

    Raises:
        InputError: ``repeats`` < 1, ``warmup`` < 0, or a bad view.
    """
    return time_methods({"method": method}, view, repeats, warmup, run_args={"method": run_args})["method"]


#: how :func:`time_methods` orders the runs of several methods on one view
TIMING_ORDERS = ("interleaved", "blocked")


def time_methods(methods: Mapping[str, Method], view, repeats: int = 10, warmup: int = 1, order: str = "interleaved",
                 run_args: Mapping[str, Mapping[str, Any]] | None = None
                 ) -> dict[str, tuple[np.ndarray, dict[str, float], dict[str, Any]]]:
    """Time several methods on one view, ``warmup + repeats`` runs each: ``{name: (image, medians, info)}`` as
    :func:`time_method` returns them.

    ``order="interleaved"`` runs them in rounds, each method once per round (a load that comes and goes
    for a few seconds then slows every method alike, so their ratio holds); ``"blocked"`` runs each method's
    runs back to back (its working set stays in the CPU's caches, as from one frame to the next of one
    renderer). ``run_args``: per method name, the keyword arguments of each of its runs.

    Example:
        >>> # timed = time_methods({"full": FullRayCast(renderer, 512), "alone": RecNNAlone(...)}, view)
        >>> # timed["full"][1]["total"] / timed["alone"][1]["total"]   # the ratio of one run's medians

    Raises:
        InputError: ``repeats`` < 1, ``warmup`` < 0, an unknown ``order``, no method, or a bad view.
    """
    if isinstance(repeats, bool) or not isinstance(repeats, (int, np.integer)) or repeats < 1:
        raise InputError(f"repeats={repeats}: expected an integer >= 1")
    if isinstance(warmup, bool) or not isinstance(warmup, (int, np.integer)) or warmup < 0:
        raise InputError(f"warmup={warmup}: expected an integer >= 0")
    if order not in TIMING_ORDERS:
        raise InputError(f"timing={order!r}: expected one of {list(TIMING_ORDERS)}")
    if not methods:
        raise InputError("methods: expected at least one method to time")
    v = validate_view(view)
    args = {name: dict((run_args or {}).get(name) or {}) for name in methods}
    n = warmup + repeats
    schedule = ([(i, name) for i in range(n) for name in methods] if order == "interleaved" else
                [(i, name) for name in methods for i in range(n)])
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in methods}
    last: dict[str, RenderResult] = {}
    with torch.inference_mode():
        for i, name in schedule:
            last[name] = timed(methods[name]).run(v, **args[name])
            if i >= warmup:
                runs[name].append(last[name].timings)
    out = {}
    for name in methods:
        keys = runs[name][0].keys()
        med = {k: float(np.median([r[k] for r in runs[name]])) for k in keys}
        out[name] = (last[name].image, med, last[name].info)
    return out
