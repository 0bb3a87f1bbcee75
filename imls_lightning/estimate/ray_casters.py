"""The estimate on both ray casters: the bound against the **fastest** RecNN alone (DESIGN.md, "The fastest baseline").

The estimate measures a scene on its configured ray caster (:func:`~imls_lightning.estimate.run.measure`). Here the
other one (``renderer.skip_empty`` flipped: the same pixels, other costs) times the same views' whole pattern and the
same masks, so that the bound can take, at each share, the faster ray caster on each side:
``(min C render + RecNN) / (networks + min mask render + RecNN)``. With empty-space skipping a background pixel is nearly
free, so IML/S pays there only by skipping object pixels: this table says how far that goes.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import numpy as np

from .bound import RenderCurve
from .measure import PassTimer, median_ms, render_curves


def label(skip_empty: bool) -> str:
    """``skip`` / ``noskip``, the key a ray caster has in the estimate and the CSV columns."""
    return "skip" if skip_empty else "noskip"


def other_ray_caster_curve(other, pattern, views: Sequence, measured: Sequence, shares: Sequence[float], *, blur: float,
                           floor: float, repeats: int, fixed_ms: float, progress: Callable[[str], None] | None = None
                           ) -> tuple[float, RenderCurve]:
    """``(mean C pattern ms, render curve)`` of ``other``: its whole pattern per view (median of ``repeats``, after one
    untimed cast that compiles and pages the volume in), then the same silhouette masks the estimate timed, put on
    its own whole pattern's time."""
    all_pix = pattern.indices.numpy()
    other.render_pixels(views[0], pattern.fr_size, all_pix)  # compile, page in: never timed
    own = [median_ms(lambda v=v: other.render_pixels(v, pattern.fr_size, all_pix), repeats) for v in views]
    relabelled = [dataclasses.replace(m, c_render_ms=float(c)) for m, c in zip(measured, own)]
    curve = render_curves(other, pattern, views, relabelled, shares, blur=blur, floor=floor, repeats=repeats,
                          fixed_ms=fixed_ms, progress=progress)[1.0]
    return float(np.mean(own)), curve


def fastest_bounds(main_skip: bool, main_c_ms: float, main_curve, other_c_ms: float, other_curve: RenderCurve, *,
                   nets_ms: float, recnn_ms: float, shares: Sequence[float], needed_share: float | None = None,
                   needed_render_ms: float | None = None) -> dict[str, Any]:
    """``estimate.json``'s ``ray_casters``: each ray caster's C pattern and bound, and the bound against the fastest
    RecNN alone at each share (IML/S on its faster ray caster at that share), at the needed share too.

    Example:
        >>> c = RenderCurve((0.5, 1.0), (60.0, 100.0))
        >>> slow = RenderCurve((0.5, 1.0), (500.0, 1000.0))
        >>> r = fastest_bounds(True, 100.0, c, 1000.0, slow, nets_ms=20.0, recnn_ms=20.0, shares=[0.5, 1.0])
        >>> [round(x["speedup"], 3) for x in r["vs_fastest"]], round(r["noskip"]["bound"][0]["speedup"], 3)
        ([1.2, 0.857], 1.889)
    """
    curves = {main_skip: (float(main_c_ms), main_curve), (not main_skip): (float(other_c_ms), other_curve)}
    fastest_alone = min(c for c, _ in curves.values()) + float(recnn_ms)
    out: dict[str, Any] = {}
    for skip, (c_ms, curve) in curves.items():
        alone = c_ms + float(recnn_ms)
        out[label(skip)] = {"c_render_ms": c_ms, "bound": [
            {"share": float(s), "speedup": alone / (float(nets_ms) + curve.render_ms(s) + float(recnn_ms))} for s in shares]}

    def best(s: float, measured: float | None = None) -> float:
        renders = [curve.render_ms(s) for _, curve in curves.values()] + ([measured] if measured is not None else [])
        return fastest_alone / (float(nets_ms) + min(renders) + float(recnn_ms))

    out["fastest_recnn"] = label(min(curves, key=lambda k: curves[k][0]))
    out["vs_fastest"] = [{"share": float(s), "speedup": best(float(s))} for s in shares]
    # the same with the IMS and the decoder free (the RecNN still runs on both sides): what no smaller network can beat
    out["free_networks_vs_fastest"] = [
        {"share": float(s), "speedup": fastest_alone / (min(c.render_ms(float(s)) for _, c in curves.values()) + float(recnn_ms))}
        for s in shares]
    # at the needed share the main ray caster's render of exactly the untrained mask's pixels is measured: a candidate
    out["speedup_vs_fastest_at_needed"] = best(float(needed_share), needed_render_ms) if needed_share is not None else None
    return out


def report_lines(est: dict[str, Any]) -> list[str]:
    """The estimate's lines on both ray casters (nothing when only one was measured)."""
    rc = est.get("ray_casters")
    if not rc:
        return []
    lines = [f"  C pattern: {rc['skip']['c_render_ms']:.1f} ms with empty-space skipping, {rc['noskip']['c_render_ms']:.1f} ms "
             f"marching every sample (the fastest RecNN alone: {rc['fastest_recnn']})",
             "  vs fastest   " + " ".join(f"{r['speedup']:>5.2f}" for r in rc["vs_fastest"])
             + "  (IML/S on its faster ray caster against the faster RecNN alone)",
             "  no skipping  " + " ".join(f"{r['speedup']:>5.2f}" for r in rc["noskip"]["bound"])
             + "  (both marching every sample, as the CUDA volumeRender sample does)"]
    if rc.get("speedup_vs_fastest_at_needed") is not None:
        lines.append(f"  at the needed share: {rc['speedup_vs_fastest_at_needed']:.2f}x the fastest RecNN alone")
    if rc.get("free_networks_vs_fastest"):
        lines.append("  free IMS+dec " + " ".join(f"{r['speedup']:>5.2f}" for r in rc["free_networks_vs_fastest"])
                     + "  (against the fastest, the IMS and decoder costing nothing: the limit smaller networks approach)")
    best = max(rc["vs_fastest"], key=lambda r: r["speedup"])
    lines.append(f"  against the fastest baseline the bound peaks at {best['speedup']:.2f}x ({best['share']:.0%} of C)")
    return lines
