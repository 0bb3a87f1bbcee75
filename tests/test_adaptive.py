"""Adaptive mean value (``imls_lightning.adaptive``): labels, predictor, adaptive renderers, CLI.

Real components: the ``tiny_checkpoints`` fixture (conftest.py) gives a RecNN, an end-to-end IML and
an IMS (``target="im"``) on ``scene=tiny data=tiny``; the IMS checkpoint is copied once with
``target="pim"`` (same weights: the generator's output is then read as PIM'), which is what the
adaptive renderer needs. The bisection is checked against synthetic monotone gaps with a known answer.
"""
from __future__ import annotations

import copy
import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from data_gen.errors import InputError
from imls_lightning.adaptive import (
    AdaptiveIMLPlusRecNN,
    AdaptiveIMLSRenderer,
    ConstantMean,
    MeanLabels,
    MeanPredictor,
    bisect_mean,
    check_epsilon,
    compute_labels,
    im_at_means,
    iml_pim,
    mean_for_ipr,
    quality_at_means,
    scaled_pim_im,
    tradeoff,
    train_predictor,
    view_complexity,
)
from imls_lightning.pipeline import IMLPlusRecNN, IMLSRenderer, NetOptions
from imls_lightning.tasks.base import load_task

ROOT = Path(__file__).resolve().parents[1]
CPU = NetOptions(device="cpu")


# ---- fixtures ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pim_ckpt(tiny_checkpoints, tmp_path_factory) -> Path:
    """The tiny IMS checkpoint with ``target="pim"`` (in ``<run>/checkpoints/``, like a real run)."""
    ck = torch.load(tiny_checkpoints["ims"], map_location="cpu", weights_only=True)
    ck["hyper_parameters"]["target"] = "pim"
    out = tmp_path_factory.mktemp("adaptive_run") / "checkpoints" / "ims_pim.ckpt"
    out.parent.mkdir(parents=True)
    torch.save(ck, out)
    return out


@pytest.fixture(scope="module")
def tiny_cache(tiny_checkpoints):
    from data_gen.cache import ViewImageCache

    for manifest in sorted(Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")):
        c = ViewImageCache.open(manifest.parent, require_complete=False)
        if c.resolution == 32 and c.complete:
            return c
    pytest.fail("no complete 32^2 tiny cache in the fixture's cache_dir")


@pytest.fixture(scope="module")
def pim_task(pim_ckpt):
    return load_task(pim_ckpt, expect="IMSTask")


@pytest.fixture(scope="module")
def renderer(pim_task):
    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene

    return make_renderer(build_scene(pim_task.hparams["scene"]), pim_task.hparams["renderer"])


def _c_fr(cache, rows, pattern):
    from imls_lightning.compaction import compact

    img = torch.from_numpy(np.array(cache.images[rows])).permute(0, 3, 1, 2).float() / 255
    return compact(img, pattern.indices, pattern.c_size), img


# ---- bisection ---------------------------------------------------------------------------------
def test_bisect_mean_finds_the_known_answer_of_a_monotone_gap():
    # gap(u) = 20 log10(t / u) for u < t (0 beyond): the smallest u with gap <= eps is t * 10^(-eps/20)
    t = torch.tensor([0.005, 0.05, 0.3, 0.99, 5.0], dtype=torch.float64)
    eps, steps = 1.0, 10
    res = bisect_mean(lambda u: (20 * torch.log10(t / u)).clamp(min=0), len(t), eps, steps)
    answer = t * 10 ** (-eps / 20)
    tol = math.log(100) / 2**steps + 1e-12
    assert res.met.tolist() == [True, True, True, True, False]
    assert res.u[0] == 0.01                      # passes at the lower end already
    assert res.u[4] == 1.0                       # nothing in [0.01, 1] meets epsilon
    for i in (1, 2, 3):
        assert answer[i] <= res.u[i] <= answer[i] * math.exp(tol)  # never below the answer, within one step
        assert res.gap[i] <= eps
    assert res.evaluations == steps + 2


def test_bisect_mean_treats_nan_as_failing_and_is_vectorized():
    calls = []

    def gap(u):
        calls.append(u.clone())
        return torch.where(u > 0.2, torch.zeros_like(u), torch.full_like(u, float("nan")))

    res = bisect_mean(gap, 4, 0.5, steps=6)
    assert len(calls) == 8 and all(c.shape == (4,) for c in calls)
    assert torch.all(res.u > 0.2) and torch.all(res.u < 0.2 * 100 ** (1 / 64) + 1e-9) and res.met.all()


def test_bisect_mean_unreachable_best_labels_within_epsilon_of_the_best_gap():
    # gap(u) = max(floor, 20 log10(t / u)): views with floor > eps never meet epsilon; "best" gives the
    # smallest u with gap <= floor + eps (= t * 10^(-(floor + eps)/20) where that is inside the bracket)
    t = torch.tensor([0.05, 0.5, 0.5, 0.5], dtype=torch.float64)
    floor = torch.tensor([0.0, 0.0, 3.0, 50.0], dtype=torch.float64)
    eps, steps = 1.0, 12

    def gap(u):
        return torch.maximum(floor, 20 * torch.log10(t / u))

    hi = bisect_mean(gap, 4, eps, steps, unreachable="hi")
    best = bisect_mean(gap, 4, eps, steps, unreachable="best")
    assert hi.met.tolist() == best.met.tolist() == [True, True, False, False]
    assert torch.equal(hi.u[:2], best.u[:2])                  # reachable views: the same labels
    assert hi.u[2] == hi.u[3] == 1.0
    tol = math.log(100) / 2**steps + 1e-12
    answer = 0.5 * 10 ** (-(3.0 + eps) / 20)
    assert answer <= best.u[2] <= answer * math.exp(tol) and best.gap[2] <= 3.0 + eps
    assert best.u[3] == 0.01                                   # flat at 50 dB: the bracket's bottom is as good
    with pytest.raises(InputError, match="unreachable"):
        bisect_mean(gap, 4, eps, unreachable="nope")


@pytest.mark.parametrize("eps", [-1.0, float("nan"), float("inf"), "x", True])
def test_exception_bad_epsilon(eps):
    with pytest.raises(InputError, match="epsilon_db"):
        check_epsilon(eps)
    with pytest.raises(InputError, match="epsilon_db"):
        bisect_mean(lambda u: u * 0, 2, eps)


def test_exception_bad_steps_and_bracket():
    with pytest.raises(InputError, match="steps"):
        bisect_mean(lambda u: u * 0, 2, 1.0, steps=0)
    with pytest.raises(InputError, match="bracket"):
        bisect_mean(lambda u: u * 0, 2, 1.0, bracket=(0.5, 0.1))


# ---- the IML path at per-view means --------------------------------------------------------------
def test_im_at_means_is_the_imls_own_path_at_each_mean(tiny_checkpoints, tiny_cache):
    iml = load_task(tiny_checkpoints["iml"], expect="IMLTask")
    c, _ = _c_fr(tiny_cache, tiny_cache.splits["train"][:3], iml.pattern)
    means = [0.01, 0.137, 1.0]
    with torch.inference_mode():
        got = im_at_means(iml.iml, iml_pim(iml.iml, c), means)
        for b, u in enumerate(means):
            net = copy.deepcopy(iml.iml)
            net.mean = u
            assert torch.equal(got[b:b + 1], net.importance(c[b:b + 1], hard=True)), u
    counts = got.flatten(1).sum(1)
    assert counts[0] <= counts[1] <= counts[2]


def test_labels_on_tiny_are_in_range_and_consistent(tiny_checkpoints, tiny_cache, pim_task, tmp_path):
    rows = tiny_cache.splits["train"][:6]
    lab = compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn,
                         epsilon_db=1.0, steps=4, batch_size=4, device="cpu", progress=False)
    assert len(lab) == 6 and lab.views.shape == (6, 9)
    assert np.all((lab.u >= 0.01) & (lab.u <= 1.0))
    assert np.all(lab.gap_db[lab.met] <= 1.0) and np.all(np.isfinite(lab.psnr_ref))
    assert np.all(lab.u[~lab.met] == 1.0)
    assert np.all((lab.complexity >= 0) & (lab.complexity <= 1))
    back = MeanLabels.load(lab.save(tmp_path / "l.npz"))
    assert np.array_equal(back.u, lab.u) and back.meta["steps"] == 4


def test_view_complexity_counts_non_background_pixels():
    img = np.zeros((2, 4, 4, 3), np.uint8)
    img[0, 0, :2] = 255
    img[1] = 255
    assert view_complexity(img).tolist() == [2 / 16, 1.0]
    assert view_complexity(img, background=(1.0, 1.0, 1.0)).tolist() == [14 / 16, 0.0]
    with pytest.raises(InputError, match="images"):
        view_complexity(np.zeros((4, 4, 3), np.uint8))


# ---- the predictor -------------------------------------------------------------------------------
def _synthetic(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    eye = torch.randn(n, 3, generator=g)
    eye = eye / eye.norm(dim=1, keepdim=True) * (3 + 1.5 * torch.rand(n, 1, generator=g))
    views = torch.cat([eye, torch.zeros(n, 3), torch.tensor([[0.0, 1.0, 0.0]]).expand(n, 3)], 1)
    u = torch.exp(-1.0 - 2.0 * (eye[:, 0] / eye.norm(dim=1)).clamp(-1, 1))  # in [e^-3, e^1] -> clamp
    return views, u.clamp(0.01, 1.0)


def test_predictor_trains_is_deterministic_and_in_range():
    views, u = _synthetic(64)
    vv, vu = _synthetic(32, seed=1)
    p1, h1 = train_predictor(views, u, val=(vv, vu), epochs=300, hidden=16, seed=3)
    p2, h2 = train_predictor(views, u, val=(vv, vu), epochs=300, hidden=16, seed=3)
    with torch.no_grad():
        a, b = p1(vv), p2(vv)
    assert torch.equal(a, b) and h1["train_l1"] == h2["train_l1"]
    assert h1["train_l1"] < 0.5 * h1["constant_l1"] and h1["val_l1"] < h1["val_constant_l1"]
    assert a.shape == (32,) and bool(((a >= 0.01) & (a <= 1.0)).all())
    p1.margin = 2.0
    with torch.no_grad():
        assert torch.allclose(p1(vv), (2 * a).clamp(0.01, 1.0))


def test_predictor_keeps_the_epoch_with_the_lowest_validation_l1():
    views, u = _synthetic(24)
    vv, vu = _synthetic(16, seed=1)
    vu = vu.flip(0)  # unrelated validation labels: training longer makes the validation L1 worse
    p, h = train_predictor(views, u, val=(vv, vu), epochs=200, hidden=16, seed=0)
    assert 1 <= h["best_epoch"] < 200
    # the same seed trained for exactly best_epoch steps without validation is the kept model
    q, hq = train_predictor(views, u, epochs=h["best_epoch"], hidden=16, seed=0)
    assert hq["best_epoch"] == h["best_epoch"]
    with torch.no_grad():
        assert torch.allclose(p(vv), q(vv), atol=1e-6)
    for epochs in (h["best_epoch"] + 1, 200):
        r, _ = train_predictor(views, u, epochs=epochs, hidden=16, seed=0)
        with torch.no_grad():
            l1 = float((r.log_mean(vv) - vu.clamp(0.01, 1).log()).abs().mean())
        assert l1 >= h["val_l1"] - 1e-6


def test_predictor_gradients_are_finite_at_extreme_inputs():
    p = MeanPredictor(hidden=8, layers=2)
    p.fit_normalization(_synthetic(16)[0])
    views = torch.tensor([[1e6] * 9, [-1e6] * 9, [0.0] * 9, [1.0, 2, 3, 1, 2, 3, 0, 1, 0]], requires_grad=True)
    u = p(views)
    assert bool(((u >= 0.01) & (u <= 1.0)).all())
    p.log_mean(views).sum().backward()
    assert torch.isfinite(views.grad).all()
    assert all(torch.isfinite(q.grad).all() for q in p.parameters())


def test_predictor_save_load_roundtrip(tmp_path):
    p, _ = train_predictor(*_synthetic(16), epochs=5, hidden=8)
    q = MeanPredictor.load(p.save(tmp_path / "p.pt"), margin=1.5)
    v = _synthetic(4, 2)[0]
    with torch.no_grad():
        assert torch.allclose(q(v), (1.5 * torch.exp(p.log_mean(v))).clamp(0.01, 1))
    with pytest.raises(InputError, match="margin"):
        MeanPredictor(margin=0)
    with pytest.raises(InputError, match="predictor="):
        MeanPredictor.load(tmp_path / "missing.pt")


# ---- scaling the IMS's PIM' ------------------------------------------------------------------------
def test_scaled_pim_im_equals_output_to_im_at_the_trained_mean_and_grows_with_u(pim_task):
    n = pim_task.pattern.c_size
    g = torch.rand(3, 1, n, n, generator=torch.Generator().manual_seed(0)) * 2 - 1
    g[0, 0, 0, :4] = 1.0  # saturated pixels
    u0 = float(pim_task.iml.mean)
    assert torch.equal(scaled_pim_im(pim_task, g, torch.full((3,), u0)), pim_task.output_to_im(g))
    counts = [int(scaled_pim_im(pim_task, g, u).sum()) for u in (0.01, u0 / 2, u0, min(1.0, 3 * u0), 1.0)]
    assert counts == sorted(counts) and counts[0] < counts[2] < counts[-1]


def test_mean_for_ipr_matches_a_monotone_ipr():
    assert abs(mean_for_ipr(lambda u: u**2, 0.04) - 0.2) < 1e-6


# ---- adaptive renderers ------------------------------------------------------------------------------
def test_adaptive_renderer_with_the_trained_mean_is_imls_renderer(pim_task, renderer, tiny_cache):
    u0 = float(pim_task.iml.mean)
    base = IMLSRenderer.from_task(pim_task, renderer, opts=CPU)
    ada = AdaptiveIMLSRenderer(renderer, pim_task, ConstantMean(u0), opts=CPU)
    for r in tiny_cache.splits["test"][:3]:
        view = tiny_cache.views[int(r)]
        a, b = base.run(view), ada.run(view)
        assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], b.info["im"])
        assert b.info["rendered_pixels"] == a.info["rendered_pixels"] and b.info["mean"] == pytest.approx(u0)
        assert set(b.timings) == {"mean", "importance", "selective_render", "decoder", "recnn", "total"}
        assert b.timings["total"] == pytest.approx(sum(v for k, v in b.timings.items() if k != "total"))


def test_adaptive_renderer_renders_more_pixels_at_a_larger_mean(pim_task, renderer, tiny_cache):
    u0 = float(pim_task.iml.mean)
    view = tiny_cache.views[int(tiny_cache.splits["test"][0])]
    counts = [AdaptiveIMLSRenderer(renderer, pim_task, ConstantMean(u), opts=CPU).run(view).info["rendered_pixels"]
              for u in (0.01, u0, 1.0)]
    assert counts[0] < counts[1] < counts[2]


def test_adaptive_iml_plus_recnn_with_a_constant_mean_is_iml_plus_recnn(tiny_checkpoints, pim_task, renderer, tiny_cache):
    view = tiny_cache.views[int(tiny_cache.splits["test"][1])]
    for u in (0.05, 0.3):
        a = IMLPlusRecNN(renderer, pim_task.pattern, pim_task.iml, pim_task.recnn, CPU, mean=u).run(view)
        b = AdaptiveIMLPlusRecNN(renderer, pim_task.pattern, pim_task.iml, pim_task.recnn, ConstantMean(u), CPU).run(view)
        assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], b.info["im"]) and "mean" in b.timings


def test_exception_target_im_is_refused(tiny_checkpoints, renderer):
    task = load_task(tiny_checkpoints["ims"], expect="IMSTask")
    assert task.target == "im"
    with pytest.raises(InputError, match="target=pim"):
        AdaptiveIMLSRenderer(renderer, task, ConstantMean(0.1), opts=CPU)
    with pytest.raises(InputError, match="target=pim"):
        scaled_pim_im(task, torch.zeros(1, 1, task.pattern.c_size, task.pattern.c_size), 0.1)


# ---- the CLI -------------------------------------------------------------------------------------
def _cli(ck: dict, ims: Path, *extra: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    args = ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={ck['cache_dir']}", f"paths.runs_dir={ck['runs_dir']}",
            f"ims_checkpoint={ims}", "progress=false", "steps=3", "predictor.epochs=40", "predictor.hidden=8",
            "repeats=2", "timing_views=2", *extra]
    return subprocess.run([sys.executable, "-m", "imls_lightning.adaptive", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def test_cli_end_to_end_on_tiny(tiny_checkpoints, pim_ckpt, tmp_path):
    p = _cli(tiny_checkpoints, pim_ckpt, f"output_dir={tmp_path / 'out'}")
    assert p.returncode == 0, f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-2000:]}\nSTDERR:\n{p.stderr[-4000:]}"
    report = Path(p.stdout.strip().splitlines()[-1])
    assert report == tmp_path / "out" / "adaptive.md" and report.is_file()
    text = report.read_text()
    for needle in ("## Summary", "IML/S, adaptive u", "IML/S, fixed u (IPR-matched)", "fixed u (ORP)", "views within epsilon",
                   "label_source=ims", "## Trade-off: adaptive vs the whole fixed-mean curve (IML/S + RecNN)", "adaptive x1.25"):
        assert needle in text
    with open(report.parent / "tradeoff.csv", newline="") as f:
        trade = list(csv.DictReader(f))
    assert len(trade) == 16 + 4 + 1  # the fixed means, the margins, the oracle
    assert all(0 <= float(r["ipr"]) <= 1 and math.isfinite(float(r["psnr"])) for r in trade)
    assert (report.parent / "tradeoff.png").stat().st_size > 1000
    with open(report.parent / "adaptive.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 12  # data=tiny: a 12-view trajectory
    for r in rows:
        assert 0.01 <= float(r["u_pred"]) <= 1.0 and 0.01 <= float(r["u_label"]) <= 1.0
        assert float(r["ipr_imls_adaptive"]) >= 0 and math.isfinite(float(r["psnr_imls_adaptive"]))
        assert r["u_fixed"] == rows[0]["u_fixed"]
    assert (report.parent / "adaptive.png").stat().st_size > 1000 and (report.parent / "mean_predictor.pt").is_file()
    labels = sorted((pim_ckpt.parent.parent / "adaptive" / "labels").glob("*.npz"))
    assert {x.name.split("-")[0] for x in labels} == {"train", "val", "test"}
    # a second run reuses the labels
    p2 = _cli(tiny_checkpoints, pim_ckpt, f"output_dir={tmp_path / 'out2'}")
    assert p2.returncode == 0 and p2.stderr.count("reusing") == 3, p2.stderr[-2000:]


@pytest.mark.parametrize("override, needle", [("epsilon_db=-1", "epsilon_db"), ("steps=0", "steps"),
                                              ("predictor.margin=0", "margin"), ("views=train", "views"),
                                              ("reference=full", "reference"), ("unreachable=all", "unreachable"),
                                              ("label_source=vtk", "label_source"), ("tradeoff_margins=[0]", "tradeoff_margins"),
                                              ("tradeoff_margins=[x]", "tradeoff_margins"), ("tradeoff_means=-1", "tradeoff_means")])
def test_exception_cli_bad_settings(tiny_checkpoints, pim_ckpt, override, needle):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.adaptive import parse_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="adaptive_test"):
        cfg = compose("adaptive", overrides=["scene=tiny", "data=tiny", f"ims_checkpoint={pim_ckpt}", override])
    with pytest.raises(InputError, match=needle):
        parse_settings(cfg)


def test_exception_cli_target_im_exits_2(tiny_checkpoints):
    p = _cli(tiny_checkpoints, tiny_checkpoints["ims"])
    assert p.returncode == 2 and "target=pim" in p.stderr and "Traceback" not in p.stderr


def test_labels_with_the_iml_reference_stay_below_the_trained_mean(tiny_cache, pim_task):
    u0 = float(pim_task.iml.mean)
    rows = tiny_cache.splits["train"][:4]
    lab = compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn, epsilon_db=0.5,
                         steps=4, batch_size=4, device="cpu", progress=False, reference="iml", bracket=(0.01, u0))
    # the trained mean is the reference itself: every view meets epsilon at or below it
    assert lab.met.all() and np.all((lab.u >= 0.01) & (lab.u <= u0 + 1e-12)) and np.all(lab.gap_db <= 0.5)
    with pytest.raises(InputError, match="reference"):
        compute_labels(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn, reference="x")


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


def test_labels_on_the_imls_path_meet_epsilon_there(tiny_cache, pim_task):
    rows = tiny_cache.splits["train"][:6]
    args = (tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, pim_task.recnn)
    lab = compute_labels(*args, epsilon_db=1.0, steps=5, batch_size=4, progress=False, source="ims", ims=pim_task,
                         unreachable="best")
    assert lab.meta["source"] == "ims" and np.all((lab.u >= 0.01) & (lab.u <= 1.0))
    # re-measure each view at its own label with the independent quality_at_means: the gap is the one bisected
    q = quality_at_means(tiny_cache, rows, pim_task.pattern, pim_task.iml, pim_task.recnn, {"label": lab.u, "top": 1.0},
                         source="ims", ims=pim_task)
    gap = q["recnn"]["psnr"] - q["label"]["psnr"]
    np.testing.assert_allclose(gap, lab.gap_db, atol=1e-4)
    thr = np.where(lab.met, 1.0, (q["recnn"]["psnr"] - q["top"]["psnr"]) + 1.0)
    assert np.all(gap <= thr + 1e-4)
    # the trained mean as the reference: every view meets epsilon at or below it
    u0 = float(pim_task.iml.mean)
    lab2 = compute_labels(*args, epsilon_db=0.5, steps=4, progress=False, source="ims", ims=pim_task, reference="iml",
                          bracket=(0.01, u0))
    assert lab2.met.all() and np.all(lab2.u <= u0 + 1e-12)
    with pytest.raises(InputError, match="label_source"):
        compute_labels(*args, source="ims", ims=None)


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


@pytest.mark.parametrize("module", ["", ".checks", ".labels", ".predictor", ".renderer", ".tradeoff", ".settings",
                                    ".report", ".cli"])
def test_module_doctests(module):
    import doctest
    import importlib

    mod = importlib.import_module(f"imls_lightning.adaptive{module}")
    assert doctest.testmod(mod).failed == 0
