"""The adaptive CLI's report: ``adaptive.md`` (:func:`markdown`, :func:`tradeoff_markdown`), the
per-view CSVs (:func:`write_csv`) and the plots (:func:`plot_per_view`, :func:`plot_tradeoff`).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..core.importance import MEAN_RANGE
from ..inference.pipeline import pick_device
from ..report import fmt, md_table, new_figure, save_figure
from ..report import write_csv as report_csv
from .settings import Settings
from .tradeoff import TradeoffPoint


def reference_method(name: str, reference: str) -> str:
    """The method whose per-view PSNR ``name`` must stay within epsilon of.

    Example:
        >>> reference_method("imls_adaptive", "recnn"), reference_method("imls_adaptive", "iml")
        ('recnn', 'imls_fixed')
        >>> reference_method("iml_orp", "iml"), reference_method("recnn", "iml")
        ('iml_fixed', 'recnn')
    """
    if reference == "recnn" or name == "recnn":
        return "recnn"
    return "iml_fixed" if name.startswith("iml_") else "imls_fixed"


LABELS = {
    "recnn": "RecNN alone",
    "imls_fixed": "IML/S, fixed u (trained)",
    "imls_orp": "IML/S, fixed u (ORP)",
    "imls_matched": "IML/S, fixed u (IPR-matched)",
    "imls_adaptive": "IML/S, adaptive u",
    "imls_oracle": "IML/S, oracle u (labels)",
    "iml_fixed": "IML + RecNN, fixed u (trained)",
    "iml_orp": "IML + RecNN, fixed u (ORP)",
    "iml_adaptive": "IML + RecNN, adaptive u",
    "iml_oracle": "IML + RecNN, oracle u (labels)",
}


def write_csv(path: Path, rows: list[dict[str, Any]]) -> Path:
    """``rows`` as a CSV at ``path`` (columns: the union of the rows' keys, first-seen order; floats to 6 digits); atomic."""
    return report_csv(path, rows, cell=lambda v: f"{v:.6g}" if isinstance(v, float) else v)


def plot_per_view(path: Path, per_view: list[dict[str, Any]], eps: float, reference: str = "recnn") -> None:
    """``adaptive.png``: label and predicted ``u`` vs view complexity, IPR vs complexity, gap per view."""
    fig = new_figure(13.0, 4.0)
    cx = np.array([r["complexity"] for r in per_view])
    ax1, ax2, ax3 = fig.add_subplot(131), fig.add_subplot(132), fig.add_subplot(133)
    ax1.scatter(cx, [r["u_label"] for r in per_view], s=12, label="label u (oracle)", alpha=0.7)
    ax1.scatter(cx, [r["u_pred"] for r in per_view], s=12, marker="x", label="predicted u")
    ax1.axhline(per_view[0]["u_fixed"], color="gray", ls="--", lw=1, label="trained u")
    ax1.axhline(per_view[0]["u_orp"], color="k", ls=":", lw=1, label="ORP u")
    ax1.set_yscale("log")
    ax1.set_xlabel("view complexity (non-background share)")
    ax1.set_ylabel("mean value u")
    ax1.legend(fontsize=7)
    for name, mk in (("imls_fixed", "o"), ("imls_matched", "s"), ("imls_adaptive", "x")):
        ax2.scatter(cx, [r[f"ipr_{name}"] for r in per_view], s=12, marker=mk, label=LABELS[name], alpha=0.8)
    ax2.set_xlabel("view complexity (non-background share)")
    ax2.set_ylabel("IPR (rendered / FR pixels)")
    ax2.legend(fontsize=7)
    x = np.arange(len(per_view))
    for name in ("imls_fixed", "imls_matched", "imls_adaptive"):
        ax3.plot(x, [r[f"psnr_{reference_method(name, reference)}"] - r[f"psnr_{name}"] for r in per_view], lw=1, label=LABELS[name])
    ax3.axhline(eps, color="k", ls=":", lw=1, label=f"epsilon {eps:g} dB")
    ax3.set_xlabel("view along the trajectory")
    ax3.set_ylabel("PSNR gap to the reference (dB)" if reference != "recnn" else "PSNR gap to RecNN alone (dB)")
    ax3.legend(fontsize=7)
    save_figure(fig, path)


def plot_tradeoff(path: Path, curve: list[dict[str, float]], points: list[TradeoffPoint], eps: float, source: str) -> None:
    """``tradeoff.png``: average PSNR and within-epsilon share vs average IPR, fixed-mean curve vs adaptive margins."""
    fig = new_figure(10.0, 4.0)
    ax1, ax2 = fig.add_subplot(121), fig.add_subplot(122)
    path_name = "IML/S + RecNN" if source == "ims" else "IML + RecNN"
    for ax, key, label in ((ax1, "psnr", "average PSNR (dB)"), (ax2, "within", f"views within {eps:g} dB of the reference")):
        ax.plot([r["ipr"] for r in curve], [r[key] for r in curve], "o-", ms=3, color="gray", label="fixed u (sweep)")
        ad = [p for p in points if p.name.startswith("adaptive")]
        ax.plot([p.ipr for p in ad], [getattr(p, key) for p in ad], "x-", ms=6, color="C1", label="adaptive u (margins)")
        for p in ad:
            ax.annotate(p.name.split(" ", 1)[1], (p.ipr, getattr(p, key)), fontsize=7, xytext=(3, -9), textcoords="offset points")
        for p in points:
            if p.name.startswith("oracle"):
                ax.plot([p.ipr], [getattr(p, key)], "*", ms=10, color="C2", label="oracle u (labels)")
            elif p.name.startswith("by camera distance"):
                ax.plot([p.ipr], [getattr(p, key)], "s", ms=6, color="C0", label="u by camera distance (the ORP's bands)")
        ax.set_xlabel("average IPR (rendered / FR pixels)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{path_name}: per-view mean vs one fixed mean", fontsize=9)
    save_figure(fig, path)


def markdown(s: Settings, cfg, ims, cache, summ, per_view, hist, timing, labels, u_train, u_orp, orp_res, u_match,
              adaptive_ipr_est, out: Path, command: str, trade: dict[str, Any] | None = None) -> str:
    """The text of ``adaptive.md``: settings, labels, predictor, summary table, adaptive vs fixed, latency, notes."""
    eps = s.epsilon_db
    n = len(per_view)
    L: list[str] = []
    bracket = (MEAN_RANGE[0], MEAN_RANGE[1] if s.reference == "recnn" else u_train)
    L.append(f"# Adaptive mean value vs fixed mean (scene {cfg.scene.get('name')}, {n} {s.views} views, epsilon {eps:g} dB)\n")
    L.append(f"Command: `{command}`\n")
    L.append(f"- IMS checkpoint: `{s.ims}` (target=pim; IML trained at u = {u_train:g}); RecNN: "
             f"`{s.recnn or 'the one in the IMS checkpoint'}`; cache `{cache.path}`; device {pick_device(s.device)}"
             f"{', bfloat16/float16 autocast' if s.options.half else ''}.")
    L.append("- IML/S masks at u: " + ("above the trained mean lifted to u's share of C (ims_lift=true: scale first, then a blue-noise floor)."
                                       if s.ims_lift else "the paper's rescale, PIM' x u / u_train (ims_lift=false)."))
    ref_text = "RecNN alone" if s.reference == "recnn" else f"IML + RecNN at the trained u = {u_train:g}"
    path_name = "IML/S + RecNN" if s.label_source == "ims" else "IML + RecNN"
    orp_ref_text = (f"RecNN alone on the product path (IML/S + RecNN{', lifted masks' if s.ims_lift else ''}: the evaluation's ORP)"
                    if s.orp_path == "product" else f"{ref_text} on the IML + RecNN path")
    if s.reference != "recnn":
        ref_text = f"{path_name} at the trained u = {u_train:g}"
    L.append(f"- Labels: per view, smallest u in [{bracket[0]:g}, {bracket[1]:g}] with PSNR({path_name} at u) >= PSNR({ref_text}) - {eps:g} dB "
             f"(reference={s.reference}, label_source={s.label_source}), {s.steps} bisection steps in log u (+2 end checks); views that fail even at "
             f"u = {bracket[1]:g}: " + ("the smallest u within epsilon of their gap there (unreachable=best)." if s.unreachable == "best"
                                      else f"u = {bracket[1]:g} (unreachable=hi)."))
    for split, lab in labels.items():
        L.append(f"  - {split}: {len(lab)} views, u median {np.median(lab.u):.4f} (min {lab.u.min():.4f}, max {lab.u.max():.4f}), "
                 f"{int((~lab.met).sum())} views fail even at u = {bracket[1]:g}; "
                 f"{'reused' if timing.get(f'labels_{split}_reused') else 'computed'} in {timing.get(f'labels_{split}_s', 0):.1f} s"
                 f" (compute time recorded: {lab.meta.get('seconds', 0):.1f} s).")
    L.append(f"- Predictor: MLP {hist['views']} train views, {hist['epochs']} full-batch epochs in {hist['seconds']:.1f} s "
             f"(kept epoch {hist.get('best_epoch', hist['epochs'])}: lowest validation L1); "
             f"L1(log u) train {hist['train_l1']:.3f} / val {fmt(hist['val_l1'], 3)} vs constant (median) "
             f"{hist['constant_l1']:.3f} / {fmt(hist['val_constant_l1'], 3)}; margin x{s.predictor['margin']:g}.")
    ul = np.array([r["u_label"] for r in per_view])
    up = np.array([r["u_pred"] for r in per_view])
    cx = np.array([r["complexity"] for r in per_view])
    corr = float(np.corrcoef(np.log(ul), np.log(up))[0, 1]) if n > 2 and ul.std() > 0 and up.std() > 0 else float("nan")
    ccx = float(np.corrcoef(cx, np.log(ul))[0, 1]) if n > 2 and ul.std() > 0 and cx.std() > 0 else float("nan")
    L.append(f"- On the {s.views} views: corr(log label u, log predicted u) = {fmt(corr, 3)}; "
             f"corr(complexity, log label u) = {fmt(ccx, 3)}; L1(log u) = {float(np.abs(np.log(ul) - np.log(up)).mean()):.3f}.")
    L.append(f"- Fixed means compared: trained u = {u_train:g}; ORP u = {u_orp:.5g} (ORP search on the validation views against the "
             f"{orp_ref_text}, inference-time u, {orp_res.jobs} evaluations, {'found' if orp_res.found else 'NOT found: u = 1 used'}); "
             f"IPR-matched u = {u_match:.5g} (IML/S average IPR {adaptive_ipr_est:.4f} of the adaptive one).")
    L.append(f"- Time: labels {sum(v for k, v in timing.items() if k.startswith('labels_') and k.endswith('_s')):.1f} s, "
             f"predictor {timing['train_predictor_s']:.1f} s, ORP search {timing['orp_search_s']:.1f} s, "
             f"evaluation {timing['evaluate_s']:.1f} s, total {timing['total_s']:.1f} s.\n")

    L.append("## Summary\n")
    if s.reference != "recnn":
        L.append(f"Reference of each method (gap to reference, within epsilon): its own family at the trained mean "
                 f"(IML/S rows: IML/S fixed u = {u_train:g}; IML + RecNN rows: IML + RecNN fixed u = {u_train:g}).\n")
    L.append(md_table(["method", "avg IPR", "IPR min–max", "avg PSNR (dB)", "avg gap to RecNN (dB)", "avg gap to reference (dB)",
                       "max gap to reference", "views within epsilon of reference", "latency (ms)"],
                      [[LABELS.get(name, name), f"{v['ipr']:.4f}", f"{v['ipr_min']:.4f}–{v['ipr_max']:.4f}", f"{v['psnr']:.2f}",
                        f"{v['gap']:.3f}", f"{v['gap_ref']:.3f}", f"{v['max_gap_ref']:.3f}", f"{100 * v['within']:.0f} %",
                        fmt(v.get("latency_ms", {}).get("total"), 1)] for name, v in summ.items()], tight_rule=True))
    a, f_m, f_o, f_t = summ["imls_adaptive"], summ["imls_matched"], summ["imls_orp"], summ["imls_fixed"]
    L.append("")
    L.append("## Adaptive vs fixed (IML/S, the product)\n")
    L.append(f"- At the same average IPR ({f_m['ipr']:.4f} fixed vs {a['ipr']:.4f} adaptive): average PSNR "
             f"{f_m['psnr']:.2f} vs {a['psnr']:.2f} dB, i.e. the fixed mean is {f_m['psnr'] - a['psnr']:+.3f} dB vs adaptive; "
             f"views within epsilon {100 * f_m['within']:.0f} % vs {100 * a['within']:.0f} %.")
    L.append(f"- Against the fixed-mean ORP (u = {u_orp:.4g}): average IPR {f_o['ipr']:.4f} vs {a['ipr']:.4f} adaptive "
             f"({100 * (a['ipr'] / f_o['ipr'] - 1) if f_o['ipr'] > 0 else float('nan'):+.1f} %), PSNR gap to the reference "
             f"{f_o['gap_ref']:.3f} vs {a['gap_ref']:.3f} dB, within epsilon {100 * f_o['within']:.0f} % vs {100 * a['within']:.0f} %.")
    L.append(f"- Against the trained mean (u = {u_train:g}): average IPR {f_t['ipr']:.4f} vs {a['ipr']:.4f}, PSNR "
             f"{f_t['psnr']:.2f} vs {a['psnr']:.2f} dB.")
    i_a, i_o = summ["iml_adaptive"], summ["iml_orp"]
    L.append(f"- Upper bound (IML + RecNN, importance from the rendered C-Image): ORP IPR {i_o['ipr']:.4f} / gap {i_o['gap_ref']:.3f} dB / "
             f"within {100 * i_o['within']:.0f} %; adaptive IPR {i_a['ipr']:.4f} / gap {i_a['gap_ref']:.3f} dB / within "
             f"{100 * i_a['within']:.0f} %; oracle (labels) IPR {summ['iml_oracle']['ipr']:.4f} / within {100 * summ['iml_oracle']['within']:.0f} %.")
    if trade is not None:
        L.extend(tradeoff_markdown(trade, s, path_name, len(per_view)))
    lat_a, lat_f = a.get("latency_ms"), f_t.get("latency_ms")
    if lat_a and lat_f:
        stages = [k for k in ("mean", "importance", "selective_render", "decoder", "recnn", "total") if k in lat_a or k in lat_f]
        L.append("")
        L.append(f"## Latency (ms, median of {s.repeats} runs per view, mean over {min(s.timing_views, n)} views)\n")
        L.append(md_table(["method", *stages], [[LABELS[name], *(fmt(summ[name].get("latency_ms", {}).get(k), 2) for k in stages)]
                                                for name in ("recnn", "imls_fixed", "imls_adaptive")], tight_rule=True))
        if s.repeats < 10:
            L.append(f"\n(repeats={s.repeats} < 10: indicative timings only.)")
    L.append("")
    L.append("## Notes\n")
    L.append("- The adaptive IML/S scales the IMS's PIM' (normalized to the trained mean) by u_v / u_train before "
             "thresholding against P: exact for pixels below saturation; pixels the IMS saturated (g = 1, PIM' >= 1) are "
             "kept for u_v >= u_train and compared at their lower bound below it.")
    L.append("- Labels assume the gap falls as u grows; the paper notes that means far above the trained one need not "
             "improve quality, so a view can fail at u = 1 although it passed at a smaller u (bisection then returns one "
             "crossing). PSNRs here are on the uint8 images of the real selective renderer; labels use the float images.")
    L.append("- Files: `adaptive.csv` (per view), `adaptive.png` (u and IPR vs complexity, gap per view), "
             "`tradeoff.csv` / `tradeoff.png` (the curve), `mean_predictor.pt`, `adaptive.json`.\n")
    L.append("![adaptive](adaptive.png)\n")
    return "\n".join(L) + "\n"


def tradeoff_markdown(trade: dict[str, Any], s: Settings, path_name: str, n: int) -> list[str]:
    """The lines of ``adaptive.md``'s trade-off section (the table of settings against the fixed-mean curve)."""
    eps = s.epsilon_db
    curve, points = trade["curve"], trade["points"]
    ref = "the RecNN alone" if s.reference == "recnn" else f"{path_name} at the trained mean"
    L = ["", f"## Trade-off: adaptive vs the whole fixed-mean curve ({path_name})\n",
         f"One fixed mean is one point; a fair comparison is against the curve of all of them. {len(curve)} fixed means "
         f"(log-spaced in [0.05, 1]) and the predictor at margins {', '.join(f'x{m:g}' for m in s.tradeoff_margins)} "
         f"on the {n} {s.views} views, float pipeline (cached images, no uint8 rounding), computed in {trade['seconds']:.1f} s. "
         f"'fixed at same IPR': the curve's average PSNR / within-epsilon share at the setting's average IPR; "
         f"'fixed IPR for same PSNR': the fewest pixels with which some fixed mean reaches the setting's average PSNR. "
         f"Within epsilon: PSNR at most {eps:g} dB below {ref}.\n",
         md_table(["setting", "avg IPR", "avg PSNR (dB)", "within epsilon", "fixed at same IPR: PSNR / within", "ΔPSNR (dB)",
                   "fixed IPR for same PSNR", "Δ pixels"],
                  [[p.name, f"{p.ipr:.4f}", f"{p.psnr:.2f}", f"{100 * p.within:.0f} %",
                    "–" if p.fixed_psnr is None else f"{p.fixed_psnr:.2f} / {100 * p.fixed_within:.0f} %", fmt(p.d_psnr, spec="+.2f"),
                    fmt(p.fixed_ipr, 4), "–" if p.d_ipr is None else f"{100 * p.d_ipr:+.1f} %"] for p in points], tight_rule=True)]
    ad = [p for p in points if p.name.startswith("adaptive") and p.d_psnr is not None]
    if ad:
        best = max(ad, key=lambda p: p.d_psnr)
        L.append("")
        L.append(f"- Adaptive beats the fixed-mean curve at {sum(p.d_psnr > 0 for p in ad)} of {len(ad)} margins inside its range; "
                 f"largest gain {best.d_psnr:+.2f} dB at IPR {best.ipr:.4f} ({best.name}); "
                 + ", ".join(f"{p.name}: {'–' if p.d_ipr is None else f'{100 * p.d_ipr:+.1f} %'} pixels for the same PSNR" for p in ad) + ".")
    bands = next((p for p in points if p.name.startswith("by camera distance")), None)
    if bands is not None and ad:
        # the untrained per-view alternative: the evaluation's mean value per band of camera distance
        near = min(ad, key=lambda p: abs(p.ipr - bands.ipr))
        L.append(f"- Against the evaluation's bands by camera distance (IPR {bands.ipr:.4f}, {bands.psnr:.2f} dB, "
                 f"{100 * bands.within:.0f} % of views within epsilon): the predictor at the nearest IPR ({near.name}, "
                 f"{near.ipr:.4f}) scores {near.psnr - bands.psnr:+.2f} dB.")
    top = max(curve, key=lambda r: r["psnr"])
    L.append(f"- The fixed-mean curve tops out at {top['psnr']:.2f} dB (u = {top['u']:.3g}, IPR {top['ipr']:.4f}); a setting "
             f"above it has '–' as fixed IPR. See `tradeoff.png`, `tradeoff.csv`.\n")
    L.append("![trade-off](tradeoff.png)")
    return L


def read_results(out: str | Path) -> tuple[dict[str, Any] | None, str | None]:
    """A finished run's ``adaptive.json`` in ``out``, checked by its content (a summary with the
    adaptive method): ``(data, None)``, or ``(None, why not)`` as a short phrase."""
    import json

    try:
        data = json.loads((Path(out) / "adaptive.json").read_text())
    except (OSError, ValueError) as err:
        return None, f"cannot read the adaptive run's results ({err})"
    if not isinstance(data, dict) or "imls_adaptive" not in (data.get("summary") or {}):
        return None, "not an adaptive run's results (no 'imls_adaptive')"
    return data, None

