"""The sweeps of an evaluation: the latency / PSNR plot and the speed-quality front (:class:`Sweeps`,
view by view), how each method's main operating point shows on the front (:func:`front_notes`), and
the inference options one at a time (:func:`options_sweep`)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from imls_lightning.base.errors import InputError

from ..inference.pipeline import IMLPlusRecNN, IMLSRenderer, LASMethod, Method, NetOptions
from .baselines import blue_noise_method, ims_mask_at_share
from .measurement import measure
from .networks import Networks
from .settings import Settings


class Sweeps:
    """The sweeps of the latency / PSNR plot and the speed-quality front, run view by view.

    IML + RecNN and "IML IM, selectively rendered" at each mean; LAS at each IPR; for the front, IML/S
    + RecNN at each share of ``front_shares`` (the IMS mask of each view brought to that share of C by
    :func:`ims_mask_at_share`, outside the timed stages; the IMS network itself runs in the timed
    importance stage) and blue noise + decoder at each share below 1. :meth:`run_view` measures every
    job on one view; the evaluation calls it right after that view's methods, so every point of the
    front on a view is timed within the same seconds (a load that changes during the run moves them
    together, not apart).
    """

    def __init__(self, s: Settings, methods, nets: Networks, renderer, opts, m: int):
        self.s, self.nets = s, nets
        imls: IMLSRenderer = methods["imls"]  # type: ignore[assignment]
        self.lift = imls.lift
        self.head = nets.ims_task.mask_head.for_point(imls.point)  # the IMS's masks at IML/S's point (sharpness, floor)
        # the IML/S pipeline rendering another mask than the IMS's (run's im): the IMS still runs, timed
        self.selective = IMLSRenderer(renderer, imls.pattern, imls.mask, nets.ims_task.decoder, nets.recnn, opts)
        jobs: list[tuple[str, str, float, Method | None]] = []
        for u in s.mean_values:
            jobs.append(("iml", "mean", u, IMLPlusRecNN(renderer, imls.pattern, nets.iml, nets.recnn, opts, mean=u)))
            jobs.append(("iml_selective", "mean", u, None))  # runs right after iml, with its mask
        if nets.las_task is not None:
            for ipr in s.las_iprs:
                jobs.append(("las", "ipr", ipr, LASMethod(renderer, nets.las_task.net, m, int(nets.las_task.hparams["low_res"]),
                                                          ipr=ipr, opts=opts)))
        for share in s.front_shares:
            jobs.append(("imls", "share", share, None))  # the selective pipeline, with the IMS mask at this share
            if nets.blue is not None and share < 1.0:
                jobs.append(("blue_noise", "share", share, blue_noise_method(renderer, imls.pattern, nets.blue, nets.recnn, share, opts)))
        self.jobs = jobs

    def run_view(self, p: int, r: int, view: np.ndarray, truth: np.ndarray) -> list[dict[str, Any]]:
        """Every job on the view at trajectory position ``p`` (cache row ``r``): its sweep.csv rows."""
        s, out, iml_im = self.s, [], None
        for name, setting, value, method in self.jobs:
            if name == "iml_selective":
                fields, _, _ = measure(self.selective, view, truth, s.repeats, s.warmup, im=iml_im)
            elif name == "imls" and setting == "share":
                im = ims_mask_at_share(self.head, view, value, lift=self.lift)
                fields, _, _ = measure(self.selective, view, truth, s.repeats, s.warmup, im=im)
            else:
                fields, _, info = measure(method, view, truth, s.repeats, s.warmup)
                if name == "iml":
                    iml_im = info["im"]
            out.append({"view": p, "row": r, "method": name, "setting": setting, "value": value, **fields})
        return out


def front_notes(methods: dict[str, Method], imls_mean: float | None, orp_found: bool, las_ipr: float | None) -> dict[str, str]:
    """How each method's operating point in the main rows is shown on the speed-quality front (``orp_found``: IML/S runs
    at the searched ORP)."""
    at = f"ORP u={imls_mean:.3g}" if imls_mean is not None and orp_found else "trained u"
    notes = {"full": "every pixel", "recnn": "its pattern", "imls": at, "iml": f"{at} (bound)", "imls_fill": f"IML/S's pixels, {at}",
             "blue_noise": "IML/S's share"}
    if "two_pass" in methods:
        shares = methods["two_pass"].shares
        per_band = "s per band of camera distance (near to far)" if len(shares) > 1 else ""
        notes["two_pass"] = f"its own searched share{per_band}, {' / '.join(f'{x:.0%}' for x in shares)} of C"
    if "recnn_sparser" in methods:
        pat = methods["recnn_sparser"].pattern
        notes["recnn_sparser"] = f"{pat.count} pixels ({pat.count / methods['recnn'].pattern.count:.0%} of C)"
    if las_ipr is not None:
        notes["las"] = f"IPR={las_ipr:.3g} (IML/S's)"
    if "las_searched" in methods:
        iprs = methods["las_searched"].iprs
        per_band = "s per band of camera distance (near to far)" if len(iprs) > 1 else ""
        notes["las_searched"] = f"its own searched IPR{per_band}, {' / '.join(f'{x:.1%}' for x in iprs)}"
    return notes


def options_sweep(s: Settings, renderer, cache, rows_all, positions) -> list[dict[str, Any]]:
    """IML/S with each inference option alone (fresh networks per option); failures are reported."""
    import time

    out = []
    configs = [("baseline", {})] + [(o, {o: True}) for o in s.options_sweep_options]
    for name, kw in configs:
        opts = NetOptions(device=s.options.device, **kw)
        row: dict[str, Any] = {"option": name}
        try:
            method = IMLSRenderer.from_checkpoints(s.ims, renderer=renderer, recnn_checkpoint=s.recnn, opts=opts, mean="trained")
            first = int(rows_all[positions[0]])
            t0 = time.perf_counter()
            method.render(cache.views[first])  # first call: pays torch.compile's compilation
            row["first_call_s"] = time.perf_counter() - t0
            fields = []
            for p in positions:
                r = int(rows_all[p])
                f, _, _ = measure(method, np.asarray(cache.views[r], np.float64), np.asarray(cache.images[r]), s.repeats, max(s.warmup, 1))
                fields.append(f)
            for k in ("importance_ms", "selective_render_ms", "decoder_ms", "recnn_ms", "total_ms", "psnr"):
                row[k] = float(np.mean([f.get(k, math.nan) for f in fields]))
            row["networks_ms"] = row["importance_ms"] + row["decoder_ms"] + row["recnn_ms"]
        except InputError:
            raise
        except Exception as err:  # e.g. torch.compile without a working C++ toolchain: report it
            row["error"] = f"{type(err).__name__}: {str(err).splitlines()[0][:160] if str(err) else ''}"
        out.append(row)
    return out
