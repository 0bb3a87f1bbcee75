"""imls_lightning.adaptive.tradeoff: quality at per-view means and the fixed-mean curve comparison."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.adaptive import mean_for_ipr, quality_at_means, tradeoff


def _c_fr(cache, rows, pattern):
    from imls_lightning.core.compaction import compact

    img = torch.from_numpy(np.array(cache.images[rows])).permute(0, 3, 1, 2).float() / 255
    return compact(img, pattern.indices, pattern.c_size), img


def test_mean_for_ipr_matches_a_monotone_ipr():
    assert abs(mean_for_ipr(lambda u: u**2, 0.04) - 0.2) < 1e-6


# ---- labels and quality on the IML/S path; the trade-off curve ------------------------------------
def test_quality_at_means_is_the_imls_path_at_each_mean(tiny_cache, pim_task):
    from imls_lightning.tasks.base import psnr_per_image

    rows = tiny_cache.splits["test"][:5]
    u0 = float(pim_task.iml.mean)
    per_view = np.array([0.05, 0.2, u0, 0.7, 1.0])
    q = quality_at_means(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn,
                         {"trained": u0, "per_view": per_view, "small": 0.05}, source="ims", ims=pim_task, batch_size=2)
    c, fr = _c_fr(tiny_cache, rows, pim_task.pattern)
    views = torch.as_tensor(np.asarray(tiny_cache.views[rows], np.float32))
    with torch.inference_mode():
        im = pim_task.predict_im(views).float()  # the IMSTask's own inference mask at the trained mean
        direct = psnr_per_image(pim_task.recnn(pim_task.decoder(im * c, im)), fr).double().numpy()
        alone = psnr_per_image(pim_task.recnn(c), fr).double().numpy()
    n = pim_task.pattern.fr_size ** 2
    np.testing.assert_allclose(q["trained"]["ipr"], im.flatten(1).sum(1).numpy() / n)
    np.testing.assert_allclose(q["trained"]["psnr"], direct, rtol=1e-5)
    np.testing.assert_allclose(q["recnn"]["psnr"], alone, rtol=1e-5)
    np.testing.assert_allclose(q["per_view"]["psnr"][2], q["trained"]["psnr"][2], rtol=1e-6)
    assert np.all(q["small"]["ipr"] <= q["trained"]["ipr"]) and np.all(q["small"]["ipr"][:1] == q["per_view"]["ipr"][:1])
    # the IML source gives the IML's own masks
    qi = quality_at_means(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, {"t": u0}, source="iml")
    with torch.inference_mode():
        im_iml = pim_task.iml.importance(c, hard=True).float()
    np.testing.assert_allclose(qi["t"]["ipr"], im_iml.flatten(1).sum(1).numpy() / n)


def test_exception_quality_at_means_bad_input(tiny_cache, pim_task):
    rows = tiny_cache.splits["test"][:3]
    args = (tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn)
    with pytest.raises(InputError, match=r"means\['a'\]"):
        quality_at_means(*args, {"a": np.ones(2)}, ims=pim_task)
    with pytest.raises(InputError, match=r"means\['a'\]"):
        quality_at_means(*args, {"a": -0.1}, ims=pim_task)
    with pytest.raises(InputError, match="label_source"):
        quality_at_means(*args, {"a": 0.1}, source="ims", ims=None)
    with pytest.raises(InputError, match="label_source"):
        quality_at_means(*args, {"a": 0.1}, source="both", ims=pim_task)


def _direct_tradeoff(ref, fixed, point, eps):
    """Plain loops: the fixed curve's PSNR at the point's IPR (linear) and the fewest IPR reaching its PSNR."""
    curve = sorted((np.mean(d["ipr"]), np.mean(d["psnr"]), np.mean(ref - d["psnr"] <= eps + 1e-9)) for d in fixed.values())
    ip, ps = np.mean(point["ipr"]), np.mean(point["psnr"])
    at = None
    for (i0, p0, _), (i1, p1, _) in zip(curve, curve[1:]):
        if i0 <= ip <= i1:
            at = p0 + (p1 - p0) * (ip - i0) / (i1 - i0)
            break
    need, env = None, []  # the envelope: best average PSNR with at most this IPR, linear between the points
    for k, (i, p, _) in enumerate(curve):
        env.append(max(p, env[-1]) if env else p)
        if env[k] >= ps:
            need = i if k == 0 else curve[k - 1][0] + (i - curve[k - 1][0]) * (ps - env[k - 1]) / (env[k] - env[k - 1])
            break
    return at, need


def test_tradeoff_matches_a_direct_computation():
    rng = np.random.default_rng(0)
    n = 40
    ref = rng.uniform(25, 30, n)
    fixed = {}
    for u in (0.05, 0.1, 0.2, 0.4, 0.7, 1.0):  # a concave, saturating curve with per-view noise
        fixed[u] = {"ipr": u * 0.2 + rng.uniform(0, 0.01, n), "psnr": ref - 8 * np.exp(-4 * u) + rng.normal(0, 0.3, n)}
    points = {f"p{k}": {"ipr": rng.uniform(0.01, 0.2, n), "psnr": ref - rng.uniform(0, 8, n)} for k in range(12)}
    curve, got = tradeoff(ref, fixed, points, 1.0)
    assert [r["ipr"] for r in curve] == sorted(r["ipr"] for r in curve) and len(curve) == 6
    for p in got:
        at, need = _direct_tradeoff(ref, fixed, points[p.name], 1.0)
        assert (p.fixed_psnr is None) == (at is None) and (p.fixed_ipr is None) == (need is None), p
        if at is not None:
            assert p.fixed_psnr == pytest.approx(at) and p.d_psnr == pytest.approx(p.psnr - at)
        if need is not None:
            assert p.fixed_ipr == pytest.approx(need) and p.d_ipr == pytest.approx(p.ipr / need - 1)
        assert p.within == pytest.approx(np.mean(ref - points[p.name]["psnr"] <= 1.0 + 1e-9))
    # a point beyond the curve on both axes: nothing to compare with
    _, (far,) = tradeoff(ref, fixed, {"far": {"ipr": np.full(n, 0.9), "psnr": ref + 5}}, 1.0)
    assert far.fixed_psnr is None and far.fixed_ipr is None and far.d_psnr is None and far.d_ipr is None


def test_exception_tradeoff_bad_input():
    ref = np.zeros(3)
    with pytest.raises(InputError, match="at least one fixed mean"):
        tradeoff(ref, {}, {})
    with pytest.raises(InputError, match="3 per-view PSNRs"):
        tradeoff(ref, {0.1: {"ipr": np.zeros(2), "psnr": np.zeros(2)}}, {})
    with pytest.raises(InputError, match="epsilon"):
        tradeoff(ref, {0.1: {"ipr": np.zeros(3), "psnr": np.zeros(3)}}, {}, epsilon_db=-1)


def test_the_evaluations_bands_by_camera_distance_join_the_tradeoff(tiny_cache, pim_task, pim_ckpt, tmp_path):
    """The per-view predictor's untrained alternative: the evaluation's by-distance operating point (recorded beside the
    IMS checkpoint) is one more setting of the trade-off, at each view's band's mean value; a record of other masks
    (lift) or without bands adds nothing."""
    import shutil
    from types import SimpleNamespace

    from imls_lightning.adaptive.cli import BANDS_SETTING, recorded_bands, tradeoff_curve
    from imls_lightning.adaptive.labels import MeanLabels
    from imls_lightning.adaptive.report import tradeoff_markdown
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ck = tmp_path / "ims.ckpt"
    shutil.copy(pim_ckpt, ck)
    assert recorded_bands(str(ck), False) is None  # no record
    write_operating_point(ck, ORPRecord(mean=0.6, lift=False, c_share=0.5, ipr=0.1, epsilon_db=1.0))
    assert recorded_bands(str(ck), False) is None  # one mean value for every view
    bands = {"edges": [3.75], "means": [0.6, 0.15], "c_shares": [0.5, 0.1], "gaps_db": [0.5, 0.3], "views": [2, 2]}
    write_operating_point(ck, ORPRecord(mean=0.6, lift=False, c_share=0.5, ipr=0.1, epsilon_db=1.0, by_distance=bands))
    assert recorded_bands(str(ck), True) is None  # searched on other masks
    write_operating_point(ck, ORPRecord(mean=0.6, lift=False, c_share=0.5, ipr=0.1, epsilon_db=1.0, by_distance=bands,
                                             sharpness=2.0))
    assert recorded_bands(str(ck), False) is None  # sharpened masks: not this module's
    write_operating_point(ck, ORPRecord(mean=0.6, lift=False, c_share=0.5, ipr=0.1, epsilon_db=1.0, by_distance=bands))
    sched, record = recorded_bands(str(ck), False)
    assert record == bands
    rows = np.asarray(tiny_cache.splits["test"][:6])
    views_t = torch.as_tensor(np.asarray(tiny_cache.views[rows], np.float32))
    s = SimpleNamespace(tradeoff_means=3, tradeoff_margins=[1.0], label_source="ims", reference="recnn", epsilon_db=1.0,
                        batch_size=4, progress=False, views="test")
    nets = SimpleNamespace(pattern=pim_task.pattern, iml=pim_task.iml, recnn=pim_task.recnn, ims=pim_task, lift=False,
                           device="cpu", u_train=float(pim_task.iml.mean))
    n = len(rows)
    ev = MeanLabels(rows=rows, views=views_t.numpy(), u=np.full(n, 0.3), met=np.ones(n, bool), gap_db=np.zeros(n),
                    psnr_ref=np.zeros(n), complexity=np.zeros(n))
    predictor = SimpleNamespace(log_mean=lambda v: torch.full((v.shape[0],), math.log(0.3)))
    trade = tradeoff_curve(s, tiny_cache, ev, nets, predictor, views_t, tmp_path, sched)
    point = next(p for p in trade["points"] if p.name == BANDS_SETTING)
    u = sched(views_t).double().numpy()
    q = quality_at_means(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, {"bands": u}, source="ims",
                         ims=pim_task, batch_size=4)
    assert point.ipr == pytest.approx(float(q["bands"]["ipr"].mean())) and point.psnr == pytest.approx(float(q["bands"]["psnr"].mean()))
    assert len(set(np.round(u, 4))) == 2  # the trajectory crosses the split: both bands are used
    text = "\n".join(tradeoff_markdown(trade, SimpleNamespace(epsilon_db=1.0, reference="recnn", tradeoff_margins=[1.0],
                                                             views="test"), "IML/S + RecNN", len(rows)))
    assert f"| {BANDS_SETTING} |" in text and "Against the evaluation's bands by camera distance" in text
