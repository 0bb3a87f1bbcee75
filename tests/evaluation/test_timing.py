"""Timing a method by its stages from outside it (imls_lightning.evaluation.timing): the stages its steps name, the
medians over repeated runs, the order of several methods' runs. Real methods are timed in tests/inference/test_pipeline.py."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.evaluation import timing
from imls_lightning.evaluation.timing import StageTimer, time_method, time_methods, timed, timed_run
from imls_lightning.inference.pipeline import Method, NetOptions, RenderResult

CPU = NetOptions(device="cpu")
VIEW = [0, 0, 3, 0, 0, 0, 0, 1, 0]


class Clock:
    """A scripted clock: a stage takes what its step adds."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(autouse=True)
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(timing, "clock", c)
    return c


class Scripted(Method):
    """A method whose stage times are known: run i takes i seconds to "render", 100 - i in the RecNN, and an untimed
    step of 1000 s; run 7 renders 50 s longer (an outlier)."""

    name = "scripted"

    def __init__(self, clock: Clock):
        super().__init__(None, 4, CPU)
        self.clock = clock
        self.calls = 0

    def steps(self, view):
        i = self.calls
        self.calls += 1
        yield "render"
        self.clock.now += i + (50.0 if i == 7 else 0.0)
        yield "recnn"
        self.clock.now += 100.0 - i
        yield None
        self.clock.now += 1000.0  # in no stage
        return RenderResult(np.full((4, 4, 3), i, np.uint8), {}, {"run": i})


def test_the_stages_a_method_names_are_timed_from_outside_it(clock):
    s = Scripted(clock)
    plain = s.run(VIEW)
    assert plain.timings == {} and plain.info == {"run": 0}  # the forward pass times nothing
    res = timed_run(s, VIEW)
    assert res.timings == {"render": 1.0, "recnn": 99.0, "total": 100.0} and res.info == {"run": 1}
    image, timings = timed(s).render(VIEW)
    assert timings == {"render": 2.0, "recnn": 98.0, "total": 100.0} and int(image[0, 0, 0]) == 2
    assert timed(s).name == "scripted" and timed(timed(s)).method is s


def test_a_stage_named_twice_is_summed(clock):
    def steps():
        yield "importance"
        clock.now += 1.0
        yield "decoder"
        clock.now += 2.0
        yield "importance"
        clock.now += 4.0
        return RenderResult(np.zeros((1, 1, 3), np.uint8), {})

    assert StageTimer("cpu").run(steps()).timings == {"importance": 5.0, "decoder": 2.0, "total": 7.0}


def test_time_method_returns_medians_over_the_repeats(clock):
    s = Scripted(clock)
    image, med, info = time_method(s, VIEW, repeats=6, warmup=2)
    assert s.calls == 8
    # runs 2..7 are timed: medians of (2..6, 57) and (98..93); the outlier moves the mean, not the median
    assert med == {"render": 4.5, "recnn": 95.5, "total": 100.0}
    assert info == {"run": 7} and int(image[0, 0, 0]) == 7


class Logged(Scripted):
    """A :class:`Scripted` method that writes its name into a shared log at every run (tests the schedule)."""

    def __init__(self, name, log, clock):
        super().__init__(clock)
        self.name, self.log = name, log

    def steps(self, view):
        self.log.append(self.name)
        return (yield from super().steps(view))


@pytest.mark.parametrize("order,expected", [
    ("interleaved", ["a", "b"] * 4),
    ("blocked", ["a"] * 4 + ["b"] * 4),
])
def test_time_methods_schedule(order, expected, clock):
    log = []
    methods = {"a": Logged("a", log, clock), "b": Logged("b", log, clock)}
    out = time_methods(methods, VIEW, repeats=3, warmup=1, order=order)
    assert log == expected
    # each method's own runs 1..3 are timed, whatever the order: the same medians as time_method's
    for name in "ab":
        image, med, info = out[name]
        assert med == {"render": 2.0, "recnn": 98.0, "total": 100.0} and info == {"run": 3} and int(image[0, 0, 0]) == 3
    alone = time_method(Scripted(clock), VIEW, repeats=3, warmup=1)
    assert alone[1] == out["a"][1]


@pytest.mark.parametrize("kw,needle", [
    ({"order": "shuffled"}, "timing='shuffled'"),
    ({"repeats": 0}, "repeats"),
    ({"warmup": -1}, "warmup"),
])
def test_exception_time_methods_bad_arguments(kw, needle, clock):
    with pytest.raises(InputError, match=needle):
        time_methods({"a": Scripted(clock)}, VIEW, **kw)


def test_exception_time_methods_none():
    with pytest.raises(InputError, match="at least one method"):
        time_methods({}, VIEW)


@pytest.mark.parametrize("kw,needle", [
    ({"repeats": 0}, "repeats"),
    ({"repeats": 2.5}, "repeats"),
    ({"warmup": -1}, "warmup"),
])
def test_exception_time_method_bad_counts(kw, needle, clock):
    with pytest.raises(InputError, match=needle):
        time_method(Scripted(clock), VIEW, **kw)


def test_cuda_stage_boundaries_synchronize(monkeypatch, clock):
    """On a CUDA device every boundary waits for the GPU, so queued work counts in its own stage."""
    calls = []
    monkeypatch.setattr(torch.cuda, "synchronize", lambda device=None: calls.append(device))
    timer = StageTimer.__new__(StageTimer)
    timer.device, timer.times = torch.device("cuda"), {}
    timer.run(Scripted(clock).steps(VIEW))
    assert len(calls) == 6  # a start and an end for each of the three steps
