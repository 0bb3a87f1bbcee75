"""Shared test doubles of the estimate's tests."""
from __future__ import annotations


class CostedRenderer:
    """A renderer whose cost is known (ms per pixel, per view: ``per_px[view]``) and a ``median_ms`` that reads it,
    put in place of the timing; ``calls`` records each render's pixel count."""

    def __init__(self, per_px):
        self.per_px, self.cost, self.calls = per_px, 0.0, []

    def render_pixels(self, view, resolution, pixels):
        self.cost = self.per_px[int(view)] * len(pixels)
        self.calls.append(len(pixels))

    def median_ms(self, fn, repeats, warmup=0):
        fn()
        return self.cost
