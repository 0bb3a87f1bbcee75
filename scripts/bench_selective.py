"""Benchmark selective rendering: VTK (opaque points) vs numba (own caster), side by side.

For each resolution and view it times, interleaved in one run (median of ``--repeats``):

* the full frame with VTK (renderer of record) and with numba, and their agreement;
* ``render_pixels`` through both routes for fractions of the pixels, drawn either uniformly at
  random or "IM-like" (clustered on image detail: the top of a blurred gradient-magnitude map of the
  frame, modulated by smooth noise, as an importance mask concentrates on structure);
* an empty pixel set.

Every selective result is checked against its renderer's full frame (max / mean absolute error and
PSNR over the rendered pixels). The table is printed and written as markdown.

Usage:
    .venv/bin/python scripts/bench_selective.py                       # ct_head, 256^2 and 512^2
    .venv/bin/python scripts/bench_selective.py --scene tiny --resolutions 128 --views 2 --repeats 3
"""
from __future__ import annotations

import argparse
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.errors import InputError, cli_errors  # noqa: E402

FRACTIONS = (1, 5, 10, 20, 50, 100)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two uint8 images (or pixel lists) of any shape: the one formula, ``core.metrics.psnr_from_mse``."""
    import torch

    from imls_lightning.core.metrics import psnr_from_mse

    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float(psnr_from_mse(torch.tensor(mse, dtype=torch.float64), data_range=255.0))


def load_scene(name: str):
    """The ``conf/scene/<name>.yaml`` preset, built as the data generator builds it."""
    from data_gen.scene import build_scene, preset_config

    path = ROOT / "conf" / "scene" / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (ROOT / "conf" / "scene").glob("*.yaml"))
        raise InputError(f"--scene {name}: no {path.relative_to(ROOT)} (known: {', '.join(known) or 'none'})")
    return build_scene(preset_config(name))


def bench_views(scene, count: int) -> np.ndarray:
    """``count`` views spread along the 120-view test trajectory of the scene."""
    from data_gen.views import exploration_trajectory

    traj = exploration_trajectory(120, scene.camera_distance, seed=0)
    return traj[np.linspace(0, len(traj) - 1, count + 1).astype(int)[:-1]]


def _blur(img: np.ndarray, r: int) -> np.ndarray:
    """Box blur of radius ``r`` (twice: roughly Gaussian), edges clamped."""
    out = img.astype(np.float64)
    for _ in range(2):
        for ax in (0, 1):
            p = np.pad(out, [(r + 1, r) if a == ax else (0, 0) for a in (0, 1)], mode="edge")
            c = np.cumsum(p, axis=ax)
            hi = [slice(None)] * 2
            lo = [slice(None)] * 2
            hi[ax] = slice(2 * r + 1, None)
            lo[ax] = slice(None, -2 * r - 1)
            out = (c[tuple(hi)] - c[tuple(lo)]) / (2 * r + 1)
    return out


def pixel_set(kind: str, frac: float, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    m = frame.shape[0]
    k = int(round(frac * m * m))
    if k >= m * m:
        return np.arange(m * m, dtype=np.int64)
    if kind == "random":
        return np.sort(rng.choice(m * m, k, replace=False)).astype(np.int64)
    lum = frame.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    gy, gx = np.gradient(lum)
    detail = _blur(np.hypot(gx, gy), max(1, m // 128))
    g = max(2, m // 32)  # smooth noise: bilinear upsampling of a coarse random grid
    coarse = rng.random((g + 1, g + 1))
    t = np.linspace(0, g, m)
    i0 = np.minimum(t.astype(int), g - 1)
    f = t - i0
    rows = coarse[i0] * (1 - f)[:, None] + coarse[i0 + 1] * f[:, None]
    noise = rows[:, i0] * (1 - f)[None, :] + rows[:, i0 + 1] * f[None, :]
    score = (detail / (detail.max() + 1e-12) + 0.05) * (0.25 + noise) + 1e-9 * rng.random((m, m))
    return np.sort(np.argsort(score.reshape(-1))[-k:]).astype(np.int64)


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


@cli_errors
def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="ct_head", help="a conf/scene preset (default: ct_head)")
    ap.add_argument("--resolutions", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--views", type=int, default=3, help="views along the test trajectory")
    ap.add_argument("--fractions", type=float, nargs="+", default=list(FRACTIONS), help="percent of pixels")
    ap.add_argument("--patterns", nargs="+", default=["random", "clustered"], choices=["random", "clustered"])
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats per measurement (median)")
    ap.add_argument("--threads", type=int, default=0, help="threads of both renderers (0 = all cores)")
    ap.add_argument("--out", default=str(ROOT / "bench_out" / "selective_{scene}.md"))
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.views < 1 or any(r <= 0 for r in args.resolutions):
        raise InputError("--repeats, --views and --resolutions must be positive")
    if any(not (0 < f <= 100) for f in args.fractions):
        raise InputError(f"--fractions {args.fractions}: expected percentages in (0, 100]")

    from data_gen.render_numba import NumbaRenderer
    from data_gen.render_vtk import VTKRenderer

    scene = load_scene(args.scene)
    t0 = time.perf_counter()
    vtk_r = VTKRenderer(scene, threads=args.threads)
    t_vtk_init = time.perf_counter() - t0
    t0 = time.perf_counter()
    nb_r = NumbaRenderer(scene, threads=args.threads)
    t_nb_init = time.perf_counter() - t0
    views = bench_views(scene, args.views)
    rng = np.random.default_rng(0)
    med = lambda xs: float(np.median(xs))  # noqa: E731

    rows, agree, empty = [], [], []
    for m in args.resolutions:
        for vi, view in enumerate(views):
            vtk_r.render(view, m)  # warm both (window size, texture, caches)
            nb_r.render(view, m)
            tv, tn = [], []
            for _ in range(args.repeats):
                full_v, t = timed(vtk_r.render, view, m)
                tv.append(t)
                full_n, t = timed(nb_r.render, view, m)
                tn.append(t)
            d = np.abs(full_v.astype(int) - full_n)
            agree.append(dict(m=m, view=vi, vtk=med(tv), numba=med(tn), psnr=psnr(full_v, full_n),
                              mean=float(d.mean()), max=int(d.max()), marched=nb_r.last_rays_marched))
            ev, en = [], []
            for _ in range(args.repeats):
                ev.append(timed(vtk_r.render_pixels, view, m, np.zeros(0, np.int64))[1])
                en.append(timed(nb_r.render_pixels, view, m, np.zeros(0, np.int64))[1])
            empty.append(dict(m=m, vtk=med(ev), numba=med(en)))
            for kind in args.patterns:
                for pct in args.fractions:
                    pix = pixel_set(kind, pct / 100.0, full_v, rng)
                    # each repeat times both full frames next to both routes, so that the ratios
                    # compare measurements taken under the same machine load
                    fv, fn, sv, sn = [], [], [], []
                    for _ in range(args.repeats):
                        fv.append(timed(vtk_r.render, view, m)[1])
                        cv, t = timed(vtk_r.render_pixels, view, m, pix)
                        sv.append(t)
                        fn.append(timed(nb_r.render, view, m)[1])
                        cn, t = timed(nb_r.render_pixels, view, m, pix)
                        sn.append(t)
                    ev_ = np.abs(cv.astype(int) - full_v.reshape(-1, 3)[pix])
                    en_ = np.abs(cn.astype(int) - full_n.reshape(-1, 3)[pix])
                    sv, sn, fv, fn = map(np.asarray, (sv, sn, fv, fn))
                    rows.append(dict(m=m, view=vi, kind=kind, pct=pct, k=len(pix), vtk=med(sv), numba=med(sn),
                                     r_vtk=med(sv / fv), r_nb=med(sn / fn), r_nb_vtk=med(sn / fv),
                                     vtk_max=int(ev_.max()), vtk_mean=float(ev_.mean()),
                                     vtk_psnr=psnr(cv, full_v.reshape(-1, 3)[pix]), nb_max=int(en_.max())))
            print(f"  {m}^2 view {vi}: full VTK {med(tv):.3f}s numba {med(tn):.3f}s, "
                  f"PSNR {agree[-1]['psnr']:.1f} dB", flush=True)

    # ---- tables ------------------------------------------------------------------------------
    lines = []
    cmd = "python " + " ".join(shlex.quote(a) for a in [str(Path(sys.argv[0]))] + list(argv or sys.argv[1:]))
    lines += [f"# Selective rendering benchmark: `{args.scene}`", "",
              f"Command: `{cmd}`  ", f"Machine: {platform.machine()}, {__import__('os').cpu_count()} CPU cores, "
              f"threads={args.threads or 'all'}; repeats={args.repeats} (medians), {args.views} views of the "
              f"test trajectory; renderer set-up: VTK {t_vtk_init:.2f}s, numba {t_nb_init:.2f}s "
              f"(compile/cache load {nb_r.warmup_seconds:.2f}s); transparent 8^3 bricks: "
              f"{100 * nb_r.transparent_brick_fraction:.0f}%.", ""]
    lines += ["## Full frames and agreement (numba vs VTK)", "",
              "| res | view | VTK full (s) | numba full (s) | numba/VTK | PSNR (dB) | mean abs err | max abs err |",
              "|---|---|---|---|---|---|---|---|"]
    for a in agree:
        lines.append(f"| {a['m']} | {a['view']} | {a['vtk']:.3f} | {a['numba']:.3f} | {a['numba'] / a['vtk']:.2f} | "
                     f"{a['psnr']:.1f} | {a['mean']:.3f} | {a['max']} |")
    lines += ["", "## Selective rendering (mean over views of per-view medians)", "",
              "Ratios: route time / the same renderer's full-frame time (`own`), and / VTK's full frame, "
              "each the median over repeats of the ratio of timings taken next to each other. Times are "
              "wall time of `render_pixels` (pixel validation, hit test and blocking geometry of the VTK "
              "route included).", "",
              "| res | pixels | % | VTK route (s) | VTK route / own | numba route (s) | numba / own | numba / VTK full | "
              "VTK route err max / mean / PSNR | numba err max |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    summary = {}
    for m in args.resolutions:
        for kind in args.patterns:
            for pct in args.fractions:
                sel = [r for r in rows if r["m"] == m and r["kind"] == kind and r["pct"] == pct]
                tv = np.mean([r["vtk"] for r in sel])
                tn = np.mean([r["numba"] for r in sel])
                rv = np.mean([r["r_vtk"] for r in sel])
                rn = np.mean([r["r_nb"] for r in sel])
                rnv = np.mean([r["r_nb_vtk"] for r in sel])
                ps = min(r["vtk_psnr"] for r in sel)
                summary[(m, kind, pct)] = (rv, rn, rnv)
                lines.append(f"| {m} | {kind} | {pct:g} | {tv:.4f} | {rv:.2f} | {tn:.4f} | {rn:.2f} | {rnv:.2f} | "
                             f"{max(r['vtk_max'] for r in sel)} / {np.mean([r['vtk_mean'] for r in sel]):.3f} / "
                             f"{'inf' if ps > 150 else f'{ps:.1f}'} | {max(r['nb_max'] for r in sel)} |")
    lines += ["", "Empty pixel set: " + "; ".join(
        f"{m}^2 VTK {1e6 * np.median([e['vtk'] for e in empty if e['m'] == m]):.0f} us, numba "
        f"{1e6 * np.median([e['numba'] for e in empty if e['m'] == m]):.0f} us" for m in args.resolutions) + "."]
    lines += ["", "## Requirements (issue 6: 10% of the pixels <= 25% of the full frame, 50% <= 60%)", ""]
    for m in args.resolutions:
        for kind in args.patterns:
            for pct, limit in ((10, 0.25), (50, 0.60)):
                if (m, kind, pct) not in summary:
                    continue
                rv, rn, rnv = summary[(m, kind, pct)]
                verdict = lambda x: "pass" if x <= limit else "FAIL"  # noqa: E731
                lines.append(f"- {m}^2 {kind} {pct}%: VTK route {rv:.2f} of its full frame ({verdict(rv)}); "
                             f"numba {rn:.2f} of its full frame ({verdict(rn)}), {rnv:.2f} of VTK's ({verdict(rnv)})")
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(args.out.format(scene=args.scene))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"written: {out}")


if __name__ == "__main__":
    main()
