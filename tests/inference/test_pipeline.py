"""Inference methods (imls_lightning.inference.pipeline): the IML/S renderer built from real checkpoints, the
baselines, selective rendering and stage timing.

The checkpoints are real (``tiny_checkpoints`` in conftest.py: RecNN -> IML -> IMS and LAS trained with
fast_dev_run on ``scene=tiny data=tiny``); the renderer is the real numba ray caster.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.inference.pipeline import (
    FullRayCast,
    IMLPlusRecNN,
    IMLSRenderer,
    LASMethod,
    NetOptions,
    RecNNAlone,
    RenderResult,
    las_mean_for_ipr,
    pick_device,
    to_uint8_image,
)
from imls_lightning.evaluation.timing import time_method, time_methods, timed
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.core.operating_point import OperatingPoint

ROOT = Path(__file__).resolve().parents[2]
CPU = NetOptions(device="cpu")
IMLS_STAGES = {"importance", "selective_render", "decoder", "recnn", "total"}


@pytest.fixture(scope="module")
def env(tiny_checkpoints):
    """Scene, numba renderer, the cache's test views and images, and the loaded tasks."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from data_gen.cache import ViewImageCache, ensure_cache
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_pipeline"):
        cfg = compose("evaluate", overrides=["scene=tiny", "data=tiny", "renderer=numba",
                                             f"data.cache_dir={tiny_checkpoints['cache_dir']}"])
    scene = build_scene(cfg.scene)
    cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=False))
    rows = cache.splits["test"][:3]
    return {
        "scene": scene,
        "renderer": make_renderer(scene, {"name": "numba"}),
        "views": [np.asarray(cache.views[r], np.float64) for r in rows],
        "truth": [np.asarray(cache.images[r]) for r in rows],
        "ims": load_task(tiny_checkpoints["ims"], expect="IMSTask"),
        "las": load_task(tiny_checkpoints["las"], expect="LASTask"),
        "ckpt": tiny_checkpoints,
    }


class RecordingRenderer:
    """The real renderer, recording which pixels each ``render_pixels`` call ray-casts."""

    def __init__(self, renderer):
        self.renderer = renderer
        self.calls: list[np.ndarray] = []

    def render(self, view, resolution):
        return self.renderer.render(view, resolution)

    def render_pixels(self, view, resolution, pixels):
        self.calls.append(np.array(pixels, copy=True))
        return self.renderer.render_pixels(view, resolution, pixels)


def _check_timings(timings: dict, stages: set[str]) -> None:
    assert set(timings) == stages
    assert all(math.isfinite(v) and v >= 0.0 for v in timings.values()), timings
    assert timings["total"] == pytest.approx(sum(v for k, v in timings.items() if k != "total"))


# ---- IML/S from checkpoints ------------------------------------------------------------------
def test_imls_renderer_round_trips_from_checkpoints(env):
    r = IMLSRenderer.from_checkpoints(str(env["ckpt"]["ims"]), scene=env["scene"], renderer_cfg={"name": "numba"}, opts=CPU)
    m = env["ims"].pattern.fr_size
    view = env["views"][0]
    image, timings = timed(r).render(view)
    assert image.shape == (m, m, 3) and image.dtype == np.uint8
    _check_timings(timings, IMLS_STAGES)
    assert np.array_equal(r.render(view), image)  # the renderer itself times nothing

    # the same image as the checkpoint's own modules give, step by step (nothing lost on the way)
    task = load_task(env["ckpt"]["ims"], expect="IMSTask")
    pattern, n = task.pattern, task.pattern.c_size
    with torch.inference_mode():
        im = task.predict_im(torch.tensor(view, dtype=torch.float32)[None])[0, 0]
        c_pos = np.flatnonzero(im.reshape(-1)[: pattern.count].numpy())
        flat = np.zeros((n * n, 3), np.float32)
        flat[c_pos] = env["renderer"].render_pixels(view, m, pattern.indices.numpy()[c_pos]) / 255.0
        pr_c = torch.from_numpy(flat).view(n, n, 3).permute(2, 0, 1)[None]
        direct = to_uint8_image(task.recnn(task.decoder(pr_c, im.float()[None, None])))
    np.testing.assert_array_equal(image, direct)

    # the stored RecNN is the frozen RecNN checkpoint the IML was trained with: passing it gives the same image
    again = IMLSRenderer.from_checkpoints(str(env["ckpt"]["ims"]), renderer=env["renderer"],
                                          recnn_checkpoint=str(env["ckpt"]["recnn"]), opts=CPU)
    np.testing.assert_array_equal(again.render(view), image)

    # the IMS checkpoint records its scene and renderer: the checkpoint alone is enough
    assert env["ims"].hparams["scene"]["name"] == "tiny" and env["ims"].hparams["renderer"]["name"] == "numba"
    alone = IMLSRenderer.from_checkpoints(str(env["ckpt"]["ims"]), opts=CPU)
    np.testing.assert_array_equal(alone.render(view), image)


def test_imls_info_counts_the_pixels_of_its_mask(env):
    ims = env["ims"]
    r = IMLSRenderer(RecordingRenderer(env["renderer"]), ims.pattern, ims.mask_head, ims.decoder, ims.recnn, CPU)
    m = r.fr_size
    for view in env["views"]:
        res = r.run(view)
        assert isinstance(res, RenderResult) and np.isfinite(res.image.astype(float)).all()
        im = res.info["im"]
        assert im.shape == (r.pattern.c_size, r.pattern.c_size) and im.dtype == torch.bool
        count = int(im.sum())
        assert res.info["rendered_pixels"] == count == len(r.renderer.calls[-1])
        assert res.info["ipr"] == pytest.approx(count / m**2)


def test_selective_render_casts_only_the_masked_pixels(env):
    """A given IM (not the untrained IMS's): exactly its pixels are ray-cast, at their FR positions, and the
    decoder sees their colours and zeros elsewhere."""
    task = env["ims"]
    pattern, n, m = task.pattern, task.pattern.c_size, task.pattern.fr_size
    g = torch.Generator().manual_seed(0)
    mask = (torch.rand(1, 1, n, n, generator=g) < 0.3) & pattern.valid.view(1, 1, n, n)
    seen: list[torch.Tensor] = []

    class Decoder(torch.nn.Module):  # the real decoder, with its input kept for the check
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, x, im):
            seen.append(x.clone())
            return self.inner(x, im)

    rec = RecordingRenderer(env["renderer"])
    r = IMLSRenderer(rec, pattern, lambda v: mask, Decoder(task.decoder), task.recnn, CPU)
    view = env["views"][1]
    res = r.run(view)
    chosen = np.flatnonzero(mask.reshape(-1)[: pattern.count].numpy())
    assert len(rec.calls) == 1
    np.testing.assert_array_equal(rec.calls[0], pattern.indices.numpy()[chosen])
    assert res.info["rendered_pixels"] == int(mask.sum()) == len(chosen) > 0
    assert res.info["c_share"] == pytest.approx(len(chosen) / pattern.count)
    pr_c = seen[0][0].permute(1, 2, 0).reshape(-1, 3)
    full = env["renderer"].render(view, m).reshape(-1, 3)
    torch.testing.assert_close(pr_c[chosen], torch.from_numpy(full[pattern.indices.numpy()[chosen]]).float() / 255.0)
    off = np.setdiff1d(np.arange(n * n), chosen)
    assert float(pr_c[off].abs().max()) == 0.0


# ---- baselines -----------------------------------------------------------------------------------
def test_full_ray_cast_reproduces_the_cache(env):
    m = env["ims"].pattern.fr_size
    image, timings = timed(FullRayCast(env["renderer"], m, CPU)).render(env["views"][0])
    _check_timings(timings, {"render", "total"})
    np.testing.assert_array_equal(image, env["truth"][0])  # same renderer, deterministic: PSNR 100 in the report


def test_recnn_alone_and_iml_plus_recnn_shapes(env):
    task = env["ims"]
    pattern, m = task.pattern, task.pattern.fr_size
    rec = RecordingRenderer(env["renderer"])
    res = timed(RecNNAlone(rec, pattern, task.recnn, CPU)).run(env["views"][0])
    assert res.image.shape == (m, m, 3) and res.image.dtype == np.uint8
    _check_timings(res.timings, {"selective_render", "recnn", "total"})
    assert res.info["rendered_pixels"] == pattern.count == len(rec.calls[-1])
    assert res.info["ipr"] == pytest.approx(pattern.count / m**2)

    iml = IMLPlusRecNN(env["renderer"], pattern, task.iml, task.recnn, CPU)
    res = timed(iml).run(env["views"][0])
    assert res.image.shape == (m, m, 3) and res.image.dtype == np.uint8
    _check_timings(res.timings, {"selective_render", "importance", "decoder", "recnn", "total"})
    assert res.info["rendered_pixels"] == pattern.count  # the IML needs the whole C-Image
    assert res.info["ipr"] == pytest.approx(int(res.info["im"].sum()) / m**2)

    # another inference mean works on a copy: the shared IML keeps its trained mean, the mask grows with u
    trained = float(task.iml.mean)
    low = IMLPlusRecNN(env["renderer"], pattern, task.iml, task.recnn, CPU, mean=0.05).run(env["views"][0])
    high = IMLPlusRecNN(env["renderer"], pattern, task.iml, task.recnn, CPU, mean=0.6).run(env["views"][0])
    assert float(task.iml.mean) == trained
    assert int(high.info["im"].sum()) > int(low.info["im"].sum())


def test_las_method_samples_its_ipr(env):
    las = env["las"]
    m = int(las.hparams["fr_size"])
    rec = RecordingRenderer(env["renderer"])
    method = LASMethod(rec, las.net, m, int(las.hparams["low_res"]), ipr=0.25, opts=CPU)
    image, timings = timed(method).render(env["views"][0])
    assert image.shape == (m, m, 3) and image.dtype == np.uint8
    _check_timings(timings, {"low_res_render", "importance", "selective_render", "recnn", "total"})
    res = method.run(env["views"][0])
    assert res.info["rendered_pixels"] == len(rec.calls[-1])
    assert abs(res.info["ipr"] - 0.25) < 0.05  # per-view bisection of u to the requested share
    # the trained mean when no IPR is given
    assert LASMethod(env["renderer"], las.net, m, int(las.hparams["low_res"]), opts=CPU).run(env["views"][0]).info["rendered_pixels"] > 0
    # the IPR is an argument of each call too; the method keeps its own
    other = method.run(env["views"][0], ipr=0.5)
    assert method.ipr == 0.25 and abs(other.info["ipr"] - 0.5) < 0.05
    fresh = LASMethod(env["renderer"], las.net, m, int(las.hparams["low_res"]), ipr=0.5, opts=CPU).run(env["views"][0])
    assert np.array_equal(other.image, fresh.image) and torch.equal(other.info["mask"], fresh.info["mask"])


def test_imls_run_renders_a_given_mask_and_still_times_the_ims(env):
    """run(view, im=...) renders another mask than the IMS's ("the IML's IM, selectively rendered"):
    the IMS still runs in the timed importance stage; the image is that of a renderer whose mask is
    that IM."""
    ims = env["ims"]
    rec = RecordingRenderer(env["renderer"])
    r = IMLSRenderer(rec, ims.pattern, ims.mask_head, ims.decoder, ims.recnn, CPU)
    with torch.inference_mode():
        other = ims.predict_im(torch.tensor(env["views"][1], dtype=torch.float32)[None])[0, 0]  # another view's IM
    image, med, info = time_method(r, env["views"][0], repeats=1, warmup=0, im=other)  # the argument reaches the run
    assert torch.equal(info["im"], other) and info["rendered_pixels"] == int(other.sum()) == len(rec.calls[-1])
    _check_timings(med, IMLS_STAGES)
    fixed = IMLSRenderer(env["renderer"], ims.pattern, lambda v: other.to(v.device)[None, None], ims.decoder, ims.recnn, CPU)
    assert np.array_equal(fixed.run(env["views"][0]).image, image)


def test_the_pipeline_module_names_no_training_task():
    """The product path is plain modules: inference/pipeline.py does not mention training tasks."""
    import imls_lightning.inference.pipeline as pipeline

    assert "task" not in Path(pipeline.__file__).read_text().lower()


# ---- timing ---------------------------------------------------------------------------------------
def test_time_method_on_a_real_method(env):
    m = env["ims"].pattern.fr_size
    image, med, info = time_method(FullRayCast(env["renderer"], m, CPU), env["views"][0], repeats=10, warmup=1)
    assert set(med) == {"render", "total"} and all(v > 0 for v in med.values())
    assert image.shape == (m, m, 3) and info["rendered_pixels"] == m * m


def test_time_methods_on_real_methods(env):
    """Two real methods in one interleaved schedule: each image is that method's own (the full ray cast is
    the renderer's image, whatever ran between its runs)."""
    m = env["ims"].pattern.fr_size
    full = FullRayCast(env["renderer"], m, CPU)
    alone = RecNNAlone(env["renderer"], env["ims"].pattern, env["ims"].recnn, CPU)
    out = time_methods({"full": full, "alone": alone}, env["views"][0], repeats=10, warmup=1)
    assert set(out) == {"full", "alone"}
    assert all(v > 0 for v in out["full"][1].values()) and out["alone"][1]["total"] > 0
    assert np.array_equal(out["full"][0], full.render(env["views"][0]))
    assert out["alone"][2]["c_share"] == 1.0


# ---- errors ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("view,needle", [
    ([0, 0, 3, 0, 0, 0, 0, 1], "9 floats"),
    ([0, 0, 3, 0, 0, 0, 0, 0, 1], "parallel"),
    ([0, 0, 0, 0, 0, 0, 0, 1, 0], "eye == lookAt"),
])
def test_exception_bad_view(env, view, needle):
    m = env["ims"].pattern.fr_size
    with pytest.raises(InputError, match=needle):
        FullRayCast(env["renderer"], m, CPU).render(view)
    with pytest.raises(InputError, match=needle):
        time_method(FullRayCast(env["renderer"], m, CPU), view)


@pytest.mark.parametrize("ipr", [0, 1.5, -0.1, "many"])
def test_exception_las_bad_ipr(env, ipr):
    las = env["las"]
    with pytest.raises(InputError, match="ipr"):
        LASMethod(env["renderer"], las.net, 32, int(las.hparams["low_res"]), ipr=ipr, opts=CPU)
    with pytest.raises(InputError, match="ipr"):
        las_mean_for_ipr(las.net, torch.zeros(1, 1, 32, 32), ipr)


def test_exception_from_checkpoints(env, tmp_path):
    ck = env["ckpt"]
    old = torch.load(ck["ims"], map_location="cpu", weights_only=False)
    old["hyper_parameters"]["scene"] = None  # a checkpoint from before scenes were recorded
    sceneless = tmp_path / "sceneless.ckpt"
    torch.save(old, sceneless)
    with pytest.raises(InputError, match="stores no scene .*pass scene= or renderer="):
        IMLSRenderer.from_checkpoints(str(sceneless), opts=CPU)
    with pytest.raises(InputError, match=r"ims_checkpoint=.*RecNNTask checkpoint, expected a IMSTask"):
        IMLSRenderer.from_checkpoints(str(ck["recnn"]), renderer=env["renderer"], opts=CPU)
    with pytest.raises(InputError, match="ims_checkpoint=/nonexistent/ims.ckpt: file not found"):
        IMLSRenderer.from_checkpoints("/nonexistent/ims.ckpt", renderer=env["renderer"], opts=CPU)
    with pytest.raises(InputError, match=r"recnn_checkpoint=.*expected a RecNNTask"):
        IMLSRenderer.from_checkpoints(str(ck["ims"]), renderer=env["renderer"], recnn_checkpoint=str(ck["iml"]), opts=CPU)
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a loadable checkpoint"):
        IMLSRenderer.from_checkpoints(str(junk), renderer=env["renderer"], opts=CPU)


def test_exception_iml_mean_out_of_range(env):
    task = env["ims"]
    with pytest.raises(InputError, match="mean"):
        IMLPlusRecNN(env["renderer"], task.pattern, task.iml, task.recnn, CPU, mean=2.0)


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA present: the request is valid here")
def test_exception_cuda_without_cuda():
    with pytest.raises(InputError, match="CUDA is not available"):
        pick_device("cuda")
    assert pick_device("auto") == torch.device("cpu")


# ---- the invariant at the extreme: every pattern pixel rendered -> exactly the RecNN alone ----------
def test_full_mask_gives_the_recnn_alone_exactly(env):
    """C-share 100 %: IML/S + RecNN and IML + RecNN equal the RecNN alone (the refine decoder passes
    rendered pixels through), within 0.1 dB (here: bit for bit)."""
    from imls_lightning.evaluation import image_quality

    ims = env["ims"]
    valid = ims.pattern.valid.bool()[None, None]
    imls = IMLSRenderer(env["renderer"], ims.pattern, lambda v: valid.to(v.device), ims.decoder, ims.recnn, CPU)
    alone = RecNNAlone(env["renderer"], ims.pattern, ims.recnn, CPU)
    for view, truth in zip(env["views"], env["truth"]):
        a = alone.render(view)
        b = imls.render(view)
        assert np.array_equal(a, b)
        assert abs(image_quality(a, truth)[0] - image_quality(b, truth)[0]) < 0.1
    iml = ims.iml
    c = torch.rand(2, 3, ims.pattern.c_size, ims.pattern.c_size)
    full = ims.pattern.valid.float()[None, None].expand(2, 1, -1, -1)
    torch.testing.assert_close(ims.recnn(iml.decode(full * c, full)), ims.recnn(c * full), rtol=0, atol=0)


def test_imls_renderer_at_another_mean_needs_a_pim_target(env):
    ims = env["ims"]
    if ims.target == "pim":
        pytest.skip("the tiny IMS regresses PIM'")
    with pytest.raises(InputError, match="target=pim"):
        IMLSRenderer(env["renderer"], ims.pattern, ims.mask_head, ims.decoder, ims.recnn, CPU, point=OperatingPoint(share=0.3))


def test_a_point_with_the_fill_as_decoder_renders_the_imls_mask_and_fill_pixels(env):
    """OperatingPoint(decoder="fill"): the renderer rebuilds the C-Image with the pull-push fill of the same pixels, so
    it renders exactly what IML/S's mask + fill of the evaluation renders (the mask, then FillDecoder), and its IM is
    the trained decoder's point's; an unknown decoder is refused in one line."""
    from imls_lightning.models.iml import FillDecoder

    ims, view = env["ims"], env["views"][0]
    trained = IMLSRenderer(env["renderer"], ims.pattern, ims.mask_head, ims.decoder, ims.recnn, CPU)
    point = trained.point.replace(decoder="fill") if trained.point is not None else OperatingPoint(decoder="fill")
    filled = IMLSRenderer(env["renderer"], ims.pattern, ims.mask_head, ims.decoder, ims.recnn, CPU, point=point)
    by_hand = IMLSRenderer(env["renderer"], ims.pattern, trained.predict_im, FillDecoder(ims.pattern), ims.recnn, CPU)
    assert isinstance(filled.decoder, FillDecoder) and not isinstance(trained.decoder, FillDecoder)
    a, b, t = filled.run(view), by_hand.run(view), trained.run(view)
    assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], t.info["im"])
    with pytest.raises(InputError, match=re.escape("decoder='refine': expected 'trained' (the IMS's own decoder) or 'fill'")):
        OperatingPoint(share=0.3, decoder="refine")


class _IndexColours:
    """A ray caster whose colours are a fixed function of the FR raster index: the product's image then depends on the
    networks and the operating point only (no volume needed)."""

    def render_pixels(self, view, m, idx):
        idx = np.asarray(idx, np.int64)
        return np.stack([(idx * 37) % 251, (idx * 101 + 7) % 241, (idx // 512 * 3 + idx % 512) % 239], 1).astype(np.uint8)


#: the product's IM and image on three views, made with the code of commit 579d537 (before the operating point became
#: one frozen OperatingPoint and timing moved out of the renderer): seed_whole's committed networks at its recorded
#: point (by camera distance, sharpness 3, lifted, the object floor per band), then the plain head at u = 0.3
SEED_WHOLE_PRODUCT = {
    0: ("7c9ed69d9d92a8a3", "c1b3f03d4ebad060", 28304, 0.4217),
    1: ("20746c2516466567", "523621b7c5a16cab", 23932, 0.36518),
    2: ("b6dad232ea54c05f", "a776388ac31dbb2b", 15501, 0.23714),
    "plain": ("5422a48901abdd60", None, 18835, 0.3),
}


def test_the_product_of_committed_networks_at_their_point_is_bit_identical_to_before():
    """Behaviour unchanged: seed_whole's committed IMS (its decoder and RecNN) at its recorded operating point renders
    the same IM and the same image, bit for bit, as the code before the refactor (SEED_WHOLE_PRODUCT)."""
    import hashlib

    from imls_lightning.core.operating_point import Bands
    from imls_lightning.inference.checkpoints import load_ims_nets

    nets = load_ims_nets(ROOT / "benchmarks" / "rows" / "seed_whole" / "ims.ckpt")
    bands = Bands([3.808149662596027, 4.2323177988619545, 4.791850412524883], [0.4217, 0.36518, 0.28387, 0.23714],
                  [0.14, 0.02, None, None])
    at_point = OperatingPoint(share=0.4217, lift=True, bands=bands, sharpness=3.0, object_floor=(0.14, 0.2))
    point = IMLSRenderer(_IndexColours(), nets.pattern, nets.head, nets.decoder, nets.recnn, CPU, point=at_point)
    plain = IMLSRenderer(_IndexColours(), nets.pattern, nets.head, nets.decoder, nets.recnn, CPU, point=OperatingPoint(share=0.3))
    views = [[0, 0, 3.7, 0, 0, 0, 0, 1, 0], [2.9, 0.4, 3.0, 0, 0, 0, 0, 1, 0], [0, 4.9, 0.3, 0, 0, 0, 1, 0, 0]]
    digest = lambda a: hashlib.sha256(a.tobytes()).hexdigest()[:16]  # noqa: E731
    # one thread, as the digests were made: a convolution's float sums are bit-reproducible only for the same thread
    # count (two threads on a 2-core machine moved one uint8 pixel of view 0)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        _check_product_digests(point, plain, views, digest)
    finally:
        torch.set_num_threads(threads)


def _check_product_digests(point, plain, views, digest) -> None:
    with torch.inference_mode():
        for key, (image, im, count, u) in SEED_WHOLE_PRODUCT.items():
            r = plain if key == "plain" else point
            res = r.run(np.asarray(views[0 if key == "plain" else key], np.float64))
            assert digest(res.image) == image and res.info["rendered_pixels"] == count
            assert im is None or digest(res.info["im"].numpy()) == im
            assert key == "plain" or res.info["mean"] == pytest.approx(u, abs=1e-6)


def test_iml_plus_recnn_at_another_mean_passes_it_per_call_and_changes_no_shared_iml(env):
    """IML + RecNN at a mean value u normalizes each run at u (an argument, no private copy of the IML): the same IM and
    image as an IML whose own mean is u, and the IML it shares with other methods keeps its trained mean."""
    import copy

    task, view = env["ims"], env["views"][0]
    trained = float(task.iml.mean)
    u = 0.3 if abs(trained - 0.3) > 1e-6 else 0.5
    per_call = IMLPlusRecNN(env["renderer"], task.pattern, task.iml, task.recnn, CPU, mean=u)
    own = copy.deepcopy(task.iml)
    own.mean = u
    a, b = per_call.run(view), IMLPlusRecNN(env["renderer"], task.pattern, own, task.recnn, CPU).run(view)
    assert np.array_equal(a.image, b.image) and torch.equal(a.info["im"], b.info["im"])
    assert per_call.mean == u and float(task.iml.mean) == trained
