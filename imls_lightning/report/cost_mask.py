"""The cost-aware masks' report (:mod:`imls_lightning.pipelines.cost_mask`): a Markdown table and a plot of each
mask's gap against the share of the render cost it keeps."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from .plots import new_figure, save_figure
from .writer import markdown_text, md_table

#: how each mask kind is named in the table and the plot
MASK_LABELS = {"product": "IML/S (the product, at the row's point)", "iml": "IML (sees the rendered C-Image)"}


def mask_label(kind: str) -> str:
    """``oracle_alpha1`` -> "oracle, importance / (1 + cost)^1"; the others from :data:`MASK_LABELS`."""
    if kind.startswith("oracle_alpha"):
        a = kind[len("oracle_alpha"):]
        return "oracle, pixels counted (alpha 0)" if a == "0" else f"oracle, importance / (1 + cost)^{a}"
    return MASK_LABELS.get(kind, kind)


def _x(v: Any, fmt: str = "{:.1%}") -> str:
    return "none within" if v is None else fmt.format(v)


def cost_mask_markdown(r: Mapping[str, Any]) -> str:
    """The report: the stage times, what each speed-up needs, and per mask the cost it keeps within epsilon."""
    eps = r["epsilon_db"]
    lines = [f"# Cost-aware masks: {r['row']} ({r['views']} views of seed {r['seed']}, the fastest ray caster)", "",
             f"Operating point: {r['point']}.", "",
             f"The object (C-pixels whose ray interpolated a sample) is {r['object_share']:.1%} of C and carries "
             f"{r['object_cost']:.1%} of the pattern's render cost. Times ({r.get('times', 'measured here')}): pattern "
             f"{r['pattern_ms']:.1f} ms, RecNN {r['recnn_ms']:.1f} ms (RecNN alone {r['alone_ms']:.1f} ms), IMS + decoder "
             f"{r['nets_ms']:.1f} ms" + ("" if "measured_here" not in r else
             " (here, one run each: pattern {pattern_ms:.1f}, RecNN {recnn_ms:.1f}, IMS + decoder {nets_ms:.1f} ms)".format(
                 **r["measured_here"])) + ".", "",
             f"To run 1x the RecNN alone a mask may keep {r['needed_for']['1x']:.0%} of the pattern's cost, 1.5x "
             f"{r['needed_for']['1.5x']:.0%}; with free networks 1.5x allows {r['needed_for_free_networks']['1.5x']:.0%}. "
             f"Render time against cost: {r['render_fit']['fixed_ms']:.1f} ms + {r['render_fit']['per_unit_ms']:.2f} x c, "
             f"c the view's pattern time times the share of its ray samples kept; r^2 {r['render_fit']['r2']:.3f}.", "",
             md_table(["mask", f"cost kept within {eps:g} dB", "speed-up there", "with free networks"],
                      [[mask_label(kind), _x(m["cost_at_epsilon"]), _x(m["speedup_at_epsilon"], "{:.2f}x"),
                        _x(m["free_networks_at_epsilon"], "{:.2f}x")] for kind, m in r["masks"].items()]),
             "", "Each mask's curve (means over the views): setting (share of C, or the IML's mean value), share kept, "
             "cost kept, density on the object and the background, gap to the RecNN alone.", "",
             md_table(["mask", "setting", "kept", "cost kept", "object", "background", "gap (dB)"],
                      [[mask_label(kind), f"{c['setting']:.3g}", f"{c['kept']:.1%}", f"{c['cost_kept']:.1%}",
                        f"{c['object_density']:.2f}", f"{c['background_density']:.2f}", f"{c['gap_db']:.2f}"]
                       for kind, m in r["masks"].items() for c in m["curve"]])]
    return markdown_text(lines)


def cost_mask_plot(r: Mapping[str, Any], path: str | Path) -> Path:
    """Gap to the RecNN alone against the share of the render cost kept, one line per mask kind, with the costs
    1x and 1.5x the RecNN alone allow."""
    fig = new_figure(7.5, 4.5)
    ax = fig.add_subplot(111)
    for kind, m in r["masks"].items():
        xs = [c["cost_kept"] for c in m["curve"]]
        ys = [c["gap_db"] for c in m["curve"]]
        style = dict(marker="*", markersize=14, linestyle="none") if kind == "product" else dict(marker="o", markersize=3)
        ax.plot(xs, ys, label=mask_label(kind), **style)
    ax.axhline(r["epsilon_db"], color="k", linewidth=0.8, linestyle="--")
    top = ax.get_ylim()[1]
    for k, (name, x, colour) in enumerate((("1x", r["needed_for"]["1x"], "tab:gray"), ("1.5x", r["needed_for"]["1.5x"], "tab:red"),
                                           ("1.5x, free networks", r["needed_for_free_networks"]["1.5x"], "tab:purple"))):
        if 0 < x <= 1:
            ax.axvline(x, color=colour, linewidth=0.8, linestyle=":")
            ax.text(x, top * (0.97 - 0.07 * k), f" {name}", color=colour, fontsize=7, va="top")  # staggered: never overlap
    ax.set_xlabel("share of the pattern's render cost kept (ray samples)")
    ax.set_ylabel("gap to the RecNN alone (dB)")
    ax.set_title(f"{r['row']}: what a mask must keep, fastest ray caster", fontsize=10)
    ax.legend(fontsize=7, loc="lower left")  # the curves start high on the left: that corner is empty
    ax.set_xlim(0, 1.02)
    return save_figure(fig, path)


__all__ = ["MASK_LABELS", "mask_label", "cost_mask_markdown", "cost_mask_plot"]
