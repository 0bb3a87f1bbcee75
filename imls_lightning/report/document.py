"""``report.md``: :class:`ReportContext` (everything the evaluation measured) and :func:`write_report`
(the plots, the image grid and, last, the Markdown text of :func:`render_markdown`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from .front import front_markdown, front_verdict
from .metrics_csv import summarize_rows
from .names import METHOD_LABELS, METHOD_ORDER
from .plots import plot_front, plot_image_grid, plot_latency_vs_psnr, plot_options, plot_psnr_per_view, plot_stage_breakdown
from .tables import (
    equal_share_markdown,
    latency_table,
    options_table,
    quality_table,
    speedup_table,
    sweep_label,
    sweep_points,
    sweep_table,
)
from .writer import fmt, fmt_pct, md_table, write_markdown


@dataclass
class ReportContext:
    """Everything :func:`write_report` formats (filled by :func:`imls_lightning.evaluation.evaluate`).

    ``rows`` / ``sweep_rows`` / ``option_rows`` are the rows of metrics.csv / sweep.csv / options.csv;
    ``grid`` is :func:`plot_image_grid`'s input; ``order`` the evaluated methods in table order.
    """

    out: Path
    scene: str
    recnn_name: str
    resolution: int
    c_size: int
    pattern: str
    renderer: str
    views: str
    positions: list[int]
    trajectory_len: int
    repeats: int
    warmup: int
    options: dict[str, Any]
    device: str
    checkpoints: dict[str, str]
    iml_mean: float
    rows: list[dict[str, Any]]
    sweep_rows: list[dict[str, Any]] = field(default_factory=list)
    option_rows: list[dict[str, Any]] = field(default_factory=list)
    order: list[str] = field(default_factory=lambda: list(METHOD_ORDER))
    sweep_positions: list[int] = field(default_factory=list)
    grid: dict[int, dict[str, Any]] = field(default_factory=dict)
    pattern_obj: Any = None
    notes: list[str] = field(default_factory=list)
    timing: str = "blocked"   # the order of a timed view's runs (evaluation.timing.time_methods)
    las_ipr: float | None = None
    machine: dict[str, str] = field(default_factory=dict)
    command: str = ""
    cache: str = ""
    orp: dict[str, Any] | None = None
    equal_share: list[dict[str, Any]] = field(default_factory=list)
    #: the speed-quality front's points on ``sweep_positions`` (:func:`~imls_lightning.report.front.front_points`)
    front: list[dict[str, Any]] = field(default_factory=list)
    #: the two-pass sampler's search and its gap on the evaluated views (``summary.json``'s ``two_pass``; None: not measured)
    two_pass: dict[str, Any] | None = None
    #: the report's last line: whether IML/S pays here against the fastest RecNN alone (:func:`verdict_line`)
    verdict: str | None = None


def _latency_points(ctx: ReportContext, summ, points) -> tuple[dict, dict, float | None]:
    curves: dict[str, list[tuple[float, float, str]]] = {}
    for (method, value), s in sorted(points.items(), key=lambda kv: kv[0][1]):
        label = METHOD_LABELS.get(method, method) + (" (sweep)" if method == "las" else "")
        note = sweep_label(method, s["setting"], value)
        if method == "iml_selective":
            note = f"{note}, IPR {fmt_pct(s['ipr'])}"
        curves.setdefault(label, []).append((s["latency_ms"].get("total", math.nan), s["psnr"], note))
    pts = {}
    for m in ctx.order:
        if m == "full":
            continue
        s = summ[m]
        extra = f" (u={ctx.iml_mean:g})" if m == "iml" else (f" (IPR {fmt_pct(s['ipr'])})" if m in ("imls", "las", "las_searched") else "")
        pts[f"{s['label']}{extra}"] = (s["latency_ms"].get("total", math.nan), s["psnr"])
    full = summ["full"]["latency_ms"].get("total") if "full" in summ else None
    return curves, pts, full


def _md_image(name: str, alt: str) -> str:
    return f"![{alt}]({name})"


def write_report(ctx: ReportContext) -> Path:
    """Write the plots, the image grid and (last, atomically) ``report.md`` into ``ctx.out``.

    Files: ``stage_breakdown.png``, ``psnr_per_view.png``, ``latency_vs_psnr.png`` (with sweep rows),
    ``speed_quality_front.png`` (with front points),
    ``options.png`` (with option rows), ``image_grid.png`` (with grid views), ``report.md``.
    Returns the path of ``report.md``.
    """
    out = Path(ctx.out)
    out.mkdir(parents=True, exist_ok=True)
    if not ctx.rows:
        raise ValueError("write_report: no metric rows")
    summ = summarize_rows(ctx.rows)
    order = [m for m in ctx.order if m in summ]
    figures: list[tuple[str, str]] = []

    plot_stage_breakdown(summ, order, out / "stage_breakdown.png")
    figures.append(("stage_breakdown.png", "Time breakdown per method"))
    approx = [m for m in order if m != "full"]  # the full ray cast is the ground truth
    plot_psnr_per_view(ctx.rows, approx, out / "psnr_per_view.png")
    figures.append(("psnr_per_view.png", "PSNR per view"))
    points = sweep_points(ctx.sweep_rows) if ctx.sweep_rows else {}
    curves, pts, full_ms = _latency_points(ctx, summ, points)
    plot_latency_vs_psnr(curves, pts, full_ms, out / "latency_vs_psnr.png")
    figures.append(("latency_vs_psnr.png", "Latency vs PSNR"))
    if ctx.front:  # shown in its own section, not again under Figures
        plot_front(ctx.front, out / "speed_quality_front.png", title=f"Speed-quality front: {ctx.scene}, {ctx.recnn_name}")
    if ctx.option_rows:
        ok = [r for r in ctx.option_rows if not r.get("error")]
        if ok:
            plot_options(ok, out / "options.png")
            figures.append(("options.png", "IML/S network stages per inference option"))
    if ctx.grid:
        plot_image_grid(ctx.grid, order, out / "image_grid.png", ctx.pattern_obj, ctx.resolution)
        figures.append(("image_grid.png", "Image grid: ground truth, each method, error maps"))

    text = render_markdown(ctx, summ, order, points, figures)
    return write_markdown(out / "report.md", text)


def render_markdown(ctx: ReportContext, summ, order: Sequence[str], points, figures: Sequence[tuple[str, str]]) -> str:
    """The text of report.md (paper-style tables; see :func:`write_report`), section by section."""
    L: list[str] = []
    L.append(f"# IML/S evaluation: {ctx.scene}, {ctx.recnn_name}")
    L.append("")
    L.extend(_header_lines(ctx))
    L.append("## Average latency per method and stage (ms)")
    L.append("")
    L.append(latency_table(summ, order, reference="recnn"))
    L.append("")
    L.append("IPR: ray-cast important pixels / FR pixels (the RecNN alone and IML + RecNN ray-cast their whole "
             "pattern; IML + RecNN's IPR is the IML mask it keeps). C-Image share: important / pattern pixels. "
             "Total: median of the per-run sums of the stages.")
    L.append("")

    if ctx.orp is not None:
        L.extend(_orp_lines(ctx.orp, ctx.views))
    if ctx.two_pass is not None:
        L.extend(_two_pass_lines(ctx.two_pass, ctx.views))

    if ctx.front:
        L.extend(_front_lines(ctx))

    if "imls" in summ:
        L.append("## Speed-up of IML/S + RecNN")
        L.append("")
        L.append(speedup_table(summ, rows=ctx.rows))
        L.append("")
        L.append("The interval resamples the timed views, a view's methods together (a percentile bootstrap): how far the "
                 "ratio moves with the views drawn. It does not cover a machine whose ray caster runs at another speed "
                 "in another sitting.")
        L.append("")

    L.append("## Average image quality")
    L.append("")
    L.append(quality_table(ctx.rows, summ, order))
    L.append("")
    if "full" in summ:
        L.append("Ground truth = the cache's full ray cast by the same renderer, so the full ray cast scores "
                 "100 dB (identical images; the PSNR is capped there) unless the renderer is not deterministic.")
        L.append("")

    L.extend(_sweep_and_option_lines(ctx, points))
    L.extend(_notes_lines(ctx, figures))
    if ctx.verdict:
        L += ["", ctx.verdict]
    return "\n".join(L)


def verdict_line(rc: dict[str, Any] | None, gap_db: float | None, epsilon_db: float = 1.0) -> str | None:
    """One line: does IML/S pay on this scene against the fastest RecNN alone (``summary.json``'s ``ray_casters``), and
    where to see a scene where it does (``make reproduce``). None without both ray casters timed.

    Example:
        >>> verdict_line({"speedup_vs_fastest": 0.8, "speedup_noskip": 1.9, "fastest_recnn": "skip"}, 0.4).split("**")[1]
        'Verdict: IML/S does not pay here'
    """
    if not rc:
        return None
    vs, noskip = float(rc["speedup_vs_fastest"]), float(rc["speedup_noskip"])
    within = gap_db is not None and gap_db <= epsilon_db
    pays = vs > 1.0 and within
    head = "**Verdict: IML/S pays here**" if pays else "**Verdict: IML/S does not pay here**"
    fastest = "empty-space skipping" if rc.get("fastest_recnn") == "skip" else "every sample marched"
    return (f"{head}: {vs:.2f}x the fastest RecNN alone (its ray caster: {fastest}) at a {gap_db if gap_db is not None else float('nan'):.2f} dB "
            f"gap; {noskip:.2f}x where both march every sample. The scene where it pays most is re-measured from "
            "committed networks by `make reproduce ROW=seed_whole` (README, \"Where it pays\").")


def _header_lines(ctx: ReportContext) -> list[str]:
    """The table of what was evaluated, how, where and with which checkpoints."""
    L: list[str] = []
    n_views = len(ctx.positions)
    opts = ", ".join(f"{k}={v}" for k, v in ctx.options.items())
    mach = ctx.machine or {}
    machine = ", ".join(f"{k} {v}" for k, v in mach.items() if k not in ("device",))
    header = [
        ("scene", ctx.scene),
        ("RecNN", ctx.recnn_name),
        ("resolution (FR-Image)", f"{ctx.resolution}×{ctx.resolution}"),
        ("C-Image size", f"{ctx.c_size}×{ctx.c_size}"),
        ("sampling pattern", ctx.pattern),
        ("renderer", ctx.renderer),
        ("views", f"{n_views} of the {ctx.trajectory_len} '{ctx.views}' views"
                  + (" (the test trajectory)" if ctx.views == "test" else "")),
        ("timing", f"per view and stage: median of {ctx.repeats} runs after {ctx.warmup} warm-up run(s), "
                   + ("the methods interleaved run by run" if ctx.timing == "interleaved" else "each method's runs back to back")
                   + "; tables: mean over views"),
        ("device (networks)", mach.get("device", ctx.device)),
        ("inference options", opts),
        ("machine", machine or "–"),
        ("command", f"`{ctx.command}`" if ctx.command else "–"),
        ("cache", f"`{ctx.cache}`" if ctx.cache else "–"),
    ]
    header += [(f"checkpoint: {k}", f"`{v}`" if v and v != "–" else "–") for k, v in ctx.checkpoints.items()]
    header.append(("IML mean u (as trained)", fmt(ctx.iml_mean, 4)))
    if ctx.las_ipr is not None:
        header.append(("LAS IPR", fmt_pct(ctx.las_ipr, 2)))
    L.append(md_table(["", ""], [(k, str(v).replace("|", "\\|")) for k, v in header], "ll"))
    L.append("")
    return L


def _orp_lines(o: dict[str, Any], views: str) -> list[str]:
    """The section ``ORP on the product path``: the rule, the point found, its gaps and the search's points."""
    L: list[str] = []
    L.append("## ORP on the product path")
    L.append("")
    conf, m = o.get("confidence"), o.get("future_views")
    where = o.get("where") or "the validation views"
    if conf is not None and conf > 0.5 and o.get("passes"):
        rule = (f"the one-sided {fmt_pct(conf, 0)} upper bound on the mean gap of the passes one new trajectory makes, "
                f"over the {o['passes']} search passes' mean gaps (a pass: one path's run of views within a band of camera "
                "distance, one observation; mean + z·std·√(1/P + 1/P′))")
    elif conf is not None and conf > 0.5 and m:
        rule = (f"the one-sided {fmt_pct(conf, 0)} upper bound on the mean gap the {m} evaluated views will show "
                "(mean + z·std·√(1/n + 1/m) over the n search views' per-view gaps: a margin for views it was not chosen on)")
    elif conf is not None and conf > 0.5:
        rule = (f"the one-sided {fmt_pct(conf, 0)} upper confidence bound on its mean per-view gap (mean + z·std/√n over "
                "the n search views: a margin for views it was not chosen on)")
    else:
        rule = "its mean gap"
    if o["found"]:
        L.append(f"The smallest mean value u whose IML/S + RecNN (IMS mask from the view, exactly those pixels "
                 f"ray-cast, IML decoder, RecNN) stays within ε = {fmt(o['epsilon_db'], 2)} dB of the RecNN alone on "
                 f"{where}, judged by {rule}: **u = {fmt(o['mean'], 4)}**, C-share {fmt_pct(o['c_share'])}, IPR "
                 f"{fmt_pct(o['ipr'], 2)}, gap {fmt(o['gap_db'], 2)} dB (bound {fmt(o.get('gap_bound_db'), 2)} dB; "
                 f"{o['evaluations']} means tried). IML/S + RecNN "
                 "and IML + RecNN below run at this u (one IMS regressing PIM', rescaled to u"
                 + (", lifted so that its share of C reaches u)." if o.get("lift") else ", not lifted).") )
    else:
        L.append(f"No mean value in [0.01, 1] keeps IML/S + RecNN within ε = {fmt(o['epsilon_db'], 2)} dB of the RecNN "
                 f"alone on {where}, judged by {rule}; IML/S runs at its trained mean.")
    L.append("")
    if o.get("sharpness_candidates"):
        cands = o["sharpness_candidates"]
        timed = any(c.get("ms") is not None for c in cands)
        rule = ("whose product ran fastest on the search views (each found point's IMS mask, exactly its pixels "
                "ray-cast, decoder, RecNN; the candidates interleaved run by run)" if timed else
                "that ray-casts the smallest share of C on the search views")
        decoders = len({c.get("decoder", "trained") for c in cands}) > 1
        kept = f"**γ = {fmt(o.get('sharpness', 1.0), 2)}**" + (f", **decoder {o.get('decoder', 'trained')}**" if decoders else "")
        L.append(f"**Candidates** (`ims_sharpness`" + (", `orp_decoders`" if decoders else "") + "): the search above ran "
                 "at each sharpness γ (the IMS's PIM' raised to γ per image at the same mean before the rescale)"
                 + (" with each decoder (trained: the IMS's own; fill: the pull-push fill of the same pixels)" if decoders else "")
                 + f", and the point {rule} was kept: {kept}.")
        L.append("")
        L.append(md_table(["γ", "decoder", "ORP found", "u", "C-share (search views)", "lifted", "product (ms, search views)"],
                          [[fmt(c["sharpness"], 2), c.get("decoder", "trained"), "yes" if c["found"] else "no",
                            fmt(c["mean"], 4) if c["found"] else "–",
                            fmt_pct(c["c_share"]) if c["found"] else "–", "yes" if c.get("lift") else "no",
                            fmt(c["ms"], 1) if c.get("ms") is not None else "–"]
                           for c in cands], "rlrrrrr"))
        L.append("")
    if o["found"] and o.get("by_distance"):
        b = o["by_distance"]
        L.append(f"**By camera distance** (`orp_by_distance`): each of the {len(b['means'])} bands then searched on its own "
                 f"search views, judged by the same rule on its share of the new views; a band keeps u = {fmt(o['mean'], 4)} "
                 "where its own search finds nothing smaller. IML/S + RecNN below runs each view at its band's u (split "
                 "at the midpoints between the bands); IML + RecNN at the one u above.")
        L.append("")
        L.append(md_table(["band (search views' distance)", "up to", "views", "u", "C-share", "gap (dB)", "gap bound (dB)"],
                          [[f"{fmt(lo, 2)}-{fmt(hi, 2)}", fmt(e, 3) if e is not None else "–", str(n), fmt(u, 4), fmt_pct(c),
                            fmt(g, 2), fmt(bd, 2)]
                           for lo, hi, e, n, u, c, g, bd in zip(b["lo"], b["hi"], [*b["edges"], None], b["views"], b["means"],
                                                                 b["c_shares"], b["gaps_db"], b["bounds_db"])], "lrrrrrr"))
        L.append("")
    if o["found"] and o.get("object_floor"):
        L.extend(_object_floor_lines(o["object_floor"], o["epsilon_db"]))
    L.extend(_gap_lines(o, views))
    L.append(md_table(["u", "gap (dB)", "gap bound (dB)", "C-share"],
                      [[fmt(u, 4), fmt(g, 2), fmt(b[0] if b else None, 2), fmt_pct(c)] for u, g, c, *b in o["points"]], "rrrr"))
    L.append("")
    if o.get("rescale_points"):
        L.append("The paper's rescale (`ims_lift=false`) found no ORP first: its share of C saturates. Its search:")
        L.append("")
        L.append(md_table(["u", "gap (dB)", "gap bound (dB)", "C-share"],
                          [[fmt(u, 4), fmt(g, 2), fmt(b[0] if b else None, 2), fmt_pct(c)] for u, g, c, *b in o["rescale_points"]],
                          "rrrr"))
        L.append("")
    return L


def _sweep_and_option_lines(ctx: ReportContext, points) -> list[str]:
    """The sections ``Learned parts against untrained baselines``, ``Latency / PSNR sweep`` and ``Inference options``."""
    L: list[str] = []
    if ctx.equal_share:
        L.append("## Learned parts against untrained baselines, at equal share")
        L.append("")
        L.append("Each mask is brought to the target share of the C-Image per view (bisection on u, no ground truth); "
                 "its pixels are rebuilt by the decoder trained for that mask or by the untrained pull-push fill, then "
                 "by the same RecNN. PSNR after the RecNN, mean over the evaluated views. \"decoder − fill\": what the "
                 "trained decoder adds on the same pixels; \"mask − blue noise\": what the learned mask adds over the "
                 "blue-noise mask of the same share, each through its own trained decoder. Density: share of the empty "
                 "background (ground truth black) and of the object that the mask samples.")
        L.append("")
        L.append(equal_share_markdown(ctx.equal_share))
        L.append("")

    if points:
        L.append("## Latency / PSNR sweep")
        L.append("")
        L.append(f"On {len(ctx.sweep_positions)} view(s) (positions {_positions(ctx.sweep_positions)}). "
                 "IML + RecNN at each inference mean u; \"IML IM, selectively rendered\": the IML/S pipeline "
                 "with the IML's mask of that u in place of the IMS output (the latency IML/S would have if "
                 "its IMS reproduced that mask)"
                 + ("; LAS at each IPR." if any(k[0] == "las" for k in points) else "."))
        L.append("")
        L.append(sweep_table(points))
        L.append("")

    if ctx.option_rows:
        L.append("## Inference options (IML/S network stages)")
        L.append("")
        L.append(options_table(ctx.option_rows))
        L.append("")
    return L


def _notes_lines(ctx: ReportContext, figures: Sequence[tuple[str, str]]) -> list[str]:
    """The sections ``Notes`` and ``Figures``."""
    L: list[str] = []
    L.append("## Notes")
    L.append("")
    for note in ctx.notes:
        L.append(f"- {note}")
    L.append("- Selective rendering is real: the renderer ray-casts only the chosen pixels, so its stage time "
             "falls with the IPR; IML + RecNN renders the whole pattern (its importance comes from the "
             "rendered C-Image), so it bounds quality, not speed.")
    L.append(f"- Evaluated view positions: {_positions(ctx.positions)}.")
    L.append("- Files: `metrics.csv` (view × method), `sweep.csv`"
             + (", `options.csv`" if ctx.option_rows else "") + ", `config.yaml`.")
    L.append("")

    L.append("## Figures")
    L.append("")
    for name, alt in figures:
        L.append(f"### {alt}")
        L.append("")
        L.append(_md_image(name, alt))
        L.append("")
    return L


def _object_floor_lines(f: dict, epsilon_db: float) -> list[str]:
    """The object floor's choice (``orp_object_floor``): each candidate margin on the validation views, and the one kept."""
    c = f.get("chosen")
    kept = ("no floor (the operating point alone was the cheapest that held)" if c is None else
            f"**each view at least its object + {fmt(c['margin'], 2)} of C**" if not c.get("band_margins") else
            "**each view at least its object + its band's margin (below)**")
    L = [f"**Object floor** (`orp_object_floor`): each view's u raised to its object's share of C (the pixels whose IMS "
         f"PIM', from the view alone, exceeds {fmt(f['tau'], 2)}) plus a margin, judged on the cache's {f['views']} validation "
         f"views (not the search's, where the operating point holds by construction; never the test trajectory) by the "
         f"same bound within ε = {fmt(epsilon_db, 2)} dB; the cheapest that held was kept: {kept}. IML/S + RecNN below "
         "runs with it.", ""]
    L.append(md_table(["margin", "C-share", "gap (dB)", "gap bound (dB)", "gap by band (dB)", f"views over {fmt(epsilon_db, 2)} dB"],
                      [["no floor" if x["margin"] is None else fmt(x["margin"], 2), fmt_pct(x["c_share"]), fmt(x["gap_db"], 2),
                        fmt(x["gap_bound_db"], 2), " / ".join(fmt(g, 2) for g in (x.get("strata_gap_db") or [])) or "–",
                        str(x["views_over_epsilon"])] for x in f["candidates"]], "lrrrlr"))
    if f.get("by_band"):
        bands = c["band_margins"] if c else None
        L.append(f"**By band** (`orp_object_floor_by_band`): each band of camera distance kept its own cheapest margin "
                 f"that held on its own validation views (its bound within ε, at most {fmt_pct(f.get('tail', 1.0))} of them "
                 "over ε): near to far " + (" / ".join("no floor" if m is None else fmt(m, 2) for m in bands) if bands
                                            else "no floor in any") + ".")
        L.append("")
        L.append(md_table(["margin", "C-share by band", "bound by band (dB)", f"views over {fmt(epsilon_db, 2)} dB by band"],
                          [["no floor" if x["margin"] is None else fmt(x["margin"], 2),
                            " / ".join(fmt_pct(v) if v is not None else "–" for v in x["band_c_shares"]),
                            " / ".join(fmt(v, 2) if v is not None else "–" for v in x["band_bounds_db"]),
                            " / ".join(str(v) for v in x["band_views_over_epsilon"])] for x in f["candidates"]], "lllr"))
    L.append("")
    return L


def _gap_lines(o: dict[str, Any], split: str = "test") -> list[str]:
    """The ORP's gap on the validation views (where it was chosen) beside its gap on the evaluated views."""
    t = o.get("test")
    if not o.get("found"):
        return []
    eps = float(o["epsilon_db"])
    within = lambda g: "–" if g is None or not math.isfinite(float(g)) else ("yes" if float(g) <= eps else "**no**")  # noqa: E731
    rows = [[f"{o.get('where') or 'validation views'} (the ORP is chosen here)", o.get("views") or "–", fmt(o.get("psnr_recnn"), 2), fmt(o.get("psnr_imls"), 2),
             fmt(o["gap_db"], 2), fmt(o.get("gap_std_db"), 2), fmt(o.get("gap_bound_db"), 2), within(o["gap_db"])]]
    if t:
        what = "the test trajectory" if split == "test" else f"the '{split}' views"
        rows.append([f"{what}, evaluated (never tuned on)", t["views"], fmt(t["psnr_recnn"], 2), fmt(t["psnr_imls"], 2),
                     fmt(t["gap_db"], 2), fmt(t["gap_std_db"], 2), "–", within(t["gap_db"])])
    L = ["The same operating point on the views it was chosen on and on the evaluated views:", "",
         md_table(["views", "n", "RecNN alone PSNR", "IML/S PSNR", "mean gap (dB)", "gap std (dB)", "gap bound (dB)",
                   f"within ε = {fmt(eps, 2)} dB"], rows, "lrrrrrrr"), ""]
    bins = o.get("test_by_distance") or []
    if t and len(bins) > 1:
        L += ["Its gap on the evaluated views by camera distance (equal-count bins; normalized units, the volume's "
              "longest axis spans 2): where the views it was chosen on under-represent a bin, the promise can fail there. "
              "The speed-up over the RecNN alone is over the bin's timed views: where on the trajectory the trade pays.", "",
              md_table(["camera distance", "views", "mean gap (dB)", "largest gap (dB)", "IML/S C-share", "speed-up (timed views)"],
                       [[f"{fmt(b['lo'], 2)}–{fmt(b['hi'], 2)}", b["views"], fmt(b["gap_db"], 2), fmt(b["max_gap_db"], 2),
                         "–" if b.get("c_share") is None else f"{100 * float(b['c_share']):.1f}%", _bin_speedup(b)]
                        for b in bins], "lrrrrr"), ""]
    return L


def _bin_speedup(b: Mapping[str, Any]) -> str:
    """A distance bin's speed-up cell: ``2.31× (3 views)``; none of its views timed (or a bin from before the key): ``–``."""
    if b.get("speedup") is None:
        return "–"
    return f"{float(b['speedup']):.2f}× ({int(b.get('timed_views') or 0)} views)"


def _two_pass_lines(tp: dict[str, Any], views: str) -> list[str]:
    """The section ``Two-pass sampler's share``: its search, by band where it has bands, and its gap on the evaluated
    views by camera distance, judged as the ORP is (the strongest untrained rival gets the product's protocol)."""
    eps = float(tp["epsilon_db"])
    L = ["## The two-pass sampler's share (no IMS, searched like the ORP)", "",
         f"A blue-noise first pass of {100 * float(tp['base']):.0f}% of C, then the pixels it predicts worst. Its share was "
         f"searched on {tp['where']}: the smallest whose bound stays within ε = {fmt(eps, 2)} dB of the RecNN alone.", "",
         md_table(["share of C", "gap (dB)", "gap bound (dB)", "C-share kept"],
                  [[f"{100 * float(r['share']):.0f}%", fmt(r["gap_db"], 2), fmt(r["gap_bound_db"], 2),
                    f"{100 * float(r['c_share']):.1f}%"] for r in tp["rows"]], "rrrr"), ""]
    b = tp.get("by_distance")
    if b:
        L += ["Then each band of camera distance its own share, never above the one that held in every band, judged on "
              "its own search views and its part of the new views:", "",
              md_table(["band (search views' distance)", "up to", "views", "share of C", "C-share kept", "gap (dB)", "gap bound (dB)"],
                       [[f"{fmt(lo, 2)}-{fmt(hi, 2)}", fmt(e, 3) if e is not None else "–", n, f"{100 * float(x):.0f}%",
                         f"{100 * float(c):.1f}%", fmt(g, 2), fmt(bd, 2)]
                        for lo, hi, e, n, x, c, g, bd in zip(b["lo"], b["hi"], [*b["edges"], None], b["views"], b["shares"],
                                                              b["c_shares"], b["gaps_db"], b["bounds_db"])], "lrrrrrr"), ""]
    t = tp.get("test")
    if t:
        ok = "yes" if t["gap_db"] <= eps else "**no**"
        L += [f"On {views}, never tuned on: {fmt(t['psnr_recnn'], 2)} dB for the RecNN alone, {fmt(t['psnr_imls'], 2)} dB "
              f"for the two-pass sampler, a mean gap of {fmt(t['gap_db'], 2)} dB (std {fmt(t['gap_std_db'], 2)}, {t['views']} "
              f"views; within ε: {ok}).", ""]
    bins = tp.get("test_by_distance") or []
    if t and len(bins) > 1:
        L += [md_table(["camera distance", "views", "mean gap (dB)", "largest gap (dB)", "C-share", "speed-up (timed views)"],
                       [[f"{fmt(x['lo'], 2)}–{fmt(x['hi'], 2)}", x["views"], fmt(x["gap_db"], 2), fmt(x["max_gap_db"], 2),
                         "–" if x.get("c_share") is None else f"{100 * float(x['c_share']):.1f}%", _bin_speedup(x)]
                        for x in bins], "lrrrrr"), ""]
    return L


def _front_lines(ctx: ReportContext) -> list[str]:
    """The section ``Speed-quality front``: the table, where IML/S lies, the plot."""
    views = len(ctx.sweep_positions)
    imls_note = next((p["note"] for p in ctx.front if p["method"] == "imls" and "setting" not in p), None)
    L = ["## Speed-quality front", "",
         f"Every method as one or more points, from this run on the same {views} view(s) (positions "
         f"{_positions(ctx.sweep_positions)}): median latency (over the views, of the per-view medians of {ctx.repeats} runs) "
         "against mean PSNR and SSIM. IML/S + RecNN at its operating point and at fixed shares of C (each view's IMS "
         "mask brought to that share by bisection on u outside the timed stages; the IMS network runs inside them), "
         "blue noise + decoder at the same shares, IML + RecNN (the bound: it renders the whole pattern) at each "
         "mean value, LAS at each IPR, the RecNN alone on its pattern and on a sparser one (the same RecNN trained "
         "the same way on fewer pixels: what a user would do instead), the full ray cast. ◆ and bold: on the Pareto "
         "front (no other point is as fast and as good, and better in one). The per-view adaptive mean is reported by "
         "`python -m imls_lightning.adaptive`, not in this run.", "",
         front_markdown(ctx.front), "",
         "Where IML/S lies: " + front_verdict(ctx.front, ctx.scene, operating_note=imls_note), "",
         "![Speed-quality front](speed_quality_front.png)", ""]
    return L


def _positions(ps: Sequence[int], limit: int = 24) -> str:
    ps = [int(p) for p in ps]
    if len(ps) > 1 and ps == list(range(ps[0], ps[-1] + 1)):
        return f"{ps[0]}–{ps[-1]}"
    s = ", ".join(str(p) for p in ps[:limit])
    return s + (f", … ({len(ps)} in all)" if len(ps) > limit else "")
