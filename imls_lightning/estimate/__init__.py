"""Will IML/S pay on this volume? The before-training estimate (``python -m imls_lightning.estimate``).

Before any cache or training, on a few random views of a scene at paper scale, it measures

* the ray cast of the RecNN's whole sampling pattern (what the RecNN alone renders),
* the cost per C-pixel on the object and on the background (an importance mask keeps the object),
* the render of exactly the pixels of a mask of the shape a trained IMS makes (the object's silhouette,
  blurred, with a floor) at each share of C (:func:`.measure.render_curve`); the bound takes the slower
  of it and the per-pixel model at each share (:func:`.bound.slower_render`); with ``sharpness``, the same
  for each IMS mask sharpness (``by_sharpness``),
* the latency of untrained networks of the chosen sizes (IMS, IML decoder, RecNN),
* the classical C -> FR upsampling's PSNR (bilinear; pull-push for the foveal pattern): how much
  detail lives at the pixel scale, i.e. whether a RecNN leaves error an importance mask can hide,
* with ``recnn_lead.steps > 0``, the lead over it of a RecNN trained for a few minutes on a few more
  views: whether that detail is structure a RecNN can learn or noise it cannot (:func:`.measure.recnn_lead`),

and tabulates the speed-up bound of IML/S + RecNN over the RecNN alone against the share of C
(:mod:`.bound`), with the largest share at which the goal (2x; 1.5x for FoVolNet) is reachable.

Example:
    >>> from imls_lightning.estimate import RenderCost, bound_table, share_for_speedup
    >>> cost = RenderCost(0.5, 0.01, 0.001, 30000, 35536)
    >>> share_for_speedup(bound_table(cost, c_render_ms=336.0, nets_ms=32.0, recnn_ms=16.0), 2.0)
    0.2
"""
from .bound import (SHARES, RenderCost, RenderCurve, bound_intervals, bound_table, estimate_interval, share_for_speedup,
                    sharpness_key, slower_render, speedup_at, speedup_from_estimate)
from .run import DEFAULT_TARGETS, RESULT, format_report, read_estimate, run_estimate

__all__ = ["SHARES", "RenderCost", "RenderCurve", "slower_render", "bound_table", "share_for_speedup", "sharpness_key", "speedup_at",
           "speedup_from_estimate", "estimate_interval", "bound_intervals",
           "DEFAULT_TARGETS", "RESULT", "format_report", "read_estimate", "run_estimate"]
