"""The classical two-pass sampler (imls_lightning.inference.two_pass) on the real numba ray caster and the tiny
checkpoints' RecNN: what it ray-casts, that it is the estimate's two-pass mask, and its errors."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.evaluation.timing import timed_run
from imls_lightning.core.compaction import compact
from imls_lightning.core.unpredictability import base_unpredictability, two_pass_mask
from imls_lightning.inference.pipeline import NetOptions, RecNNAlone
from imls_lightning.inference.two_pass import TwoPassFill
from imls_lightning.core.pull_push import fill_c_image

from .test_pipeline import RecordingRenderer, env  # noqa: F401  (the module's fixture)

CPU = NetOptions(device="cpu")


def test_two_pass_casts_the_base_then_the_rest_of_its_mask(env):  # noqa: F811
    ims = env["ims"]
    pattern, idx = ims.pattern, ims.pattern.indices.numpy()
    rec = RecordingRenderer(env["renderer"])
    method = TwoPassFill(rec, pattern, ims.recnn, share=0.5, base=0.2, opts=CPU)
    res = timed_run(method, env["views"][0])
    first, second = rec.calls
    keep = res.info["im"]
    assert len(set(first) & set(second)) == 0                         # no ray is cast twice
    assert sorted(np.concatenate([first, second])) == sorted(idx[keep.flatten()[:pattern.count].numpy()])
    assert res.info["rendered_pixels"] == len(first) + len(second) and abs(res.info["c_share"] - 0.5) < 0.08
    assert set(res.timings) == {"low_res_render", "importance", "selective_render", "decoder", "recnn", "total"}
    assert all(math.isfinite(v) and v >= 0 for v in res.timings.values())


def test_two_pass_equals_the_cache_path_of_the_estimate(env):  # noqa: F811
    """The mask and image from the renderer equal the ones computed from the full render (the estimate's
    ``share_gaps(base=...)`` path): the first pass reads only its own pixels."""
    ims = env["ims"]
    pattern = ims.pattern
    method = TwoPassFill(env["renderer"], pattern, ims.recnn, share=0.6, base=0.25, opts=CPU)
    for view, truth in zip(env["views"], env["truth"]):
        res = method.run(view)
        fr = torch.from_numpy(np.asarray(truth, np.float32) / 255.0).permute(2, 0, 1)[None]
        c = compact(fr, pattern.indices, pattern.c_size)
        score, first = base_unpredictability(c, pattern, 0.25)
        keep = two_pass_mask(score, first, 0.6, pattern, 0.25)[0, 0]
        assert torch.equal(res.info["im"], keep)
        m = keep[None, None].float()
        with torch.inference_mode():
            out = ims.recnn(fill_c_image(c * m, m, pattern))
        expect = (out[0].clamp(0, 1).mul(255).round().to(torch.uint8).permute(1, 2, 0).numpy())
        assert np.abs(res.image.astype(int) - expect.astype(int)).max() <= 1


def test_two_pass_at_the_whole_pattern_is_the_recnn_alone(env):  # noqa: F811
    ims = env["ims"]
    alone = RecNNAlone(env["renderer"], ims.pattern, ims.recnn, CPU).run(env["views"][1]).image
    both = TwoPassFill(env["renderer"], ims.pattern, ims.recnn, share=1.0, base=0.3, opts=CPU).run(env["views"][1])
    assert both.info["c_share"] == 1.0 and np.array_equal(both.image, alone)


@pytest.mark.parametrize("share,base", [(0.5, 0.5), (0.5, 0.0), (1.2, 0.2), (0.3, 0.4)])
def test_exception_two_pass_shares(env, share, base):  # noqa: F811
    with pytest.raises(InputError, match="base=.*share=") as e:
        TwoPassFill(env["renderer"], env["ims"].pattern, env["ims"].recnn, share=share, base=base, opts=CPU)
    assert "\n" not in str(e.value)


def test_two_pass_by_distance_runs_each_view_at_its_bands_share(env):  # noqa: F811
    """``by_distance`` (the evaluation's per-band point): a view runs exactly as the fixed-share sampler at its band's
    share of C."""
    from imls_lightning.models.ims import DistanceMeans

    ims = env["ims"]
    views = env["views"]
    d = [float(np.linalg.norm(np.asarray(v, np.float64)[:3])) for v in views]
    near, far = int(np.argmin(d)), int(np.argmax(d))
    assert d[near] < d[far]
    sched = DistanceMeans([0.5 * (d[near] + d[far])], [0.4, 0.8])
    method = TwoPassFill(env["renderer"], ims.pattern, ims.recnn, share=0.8, base=0.2, opts=CPU, by_distance=sched)
    assert method.shares == [0.4, 0.8] and TwoPassFill(env["renderer"], ims.pattern, ims.recnn, share=0.6, opts=CPU).shares == [0.6]
    for i, share in ((near, 0.4), (far, 0.8)):
        assert method.share_for(views[i]) == pytest.approx(share)
        got = method.run(views[i])
        fixed = TwoPassFill(env["renderer"], ims.pattern, ims.recnn, share=share, base=0.2, opts=CPU).run(views[i])
        assert torch.equal(got.info["im"], fixed.info["im"]) and np.array_equal(got.image, fixed.image)
        assert abs(got.info["c_share"] - share) < 0.08


def test_exception_two_pass_band_shares_at_or_below_the_base(env):  # noqa: F811
    from imls_lightning.models.ims import DistanceMeans

    with pytest.raises(InputError, match=r"by_distance: shares \[0.2, 0.8\]: expected each in \(base=0.2, 1\]") as e:
        TwoPassFill(env["renderer"], env["ims"].pattern, env["ims"].recnn, share=0.8, base=0.2, opts=CPU,
                    by_distance=DistanceMeans([3.0], [0.2, 0.8]))
    assert "\n" not in str(e.value)


def test_every_fill_path_gives_the_recnn_the_layout_the_recnn_alone_gets(env):  # noqa: F811
    """The pull-push fill returns plain contiguous memory, on which the RecNN ran up to 1.7x slower than on the
    rendered C-Image's channels-last layout (rayleigh_taylor's row: 22.9 against 14.5 ms), slowing the two-pass
    sampler and IML/S's mask + fill; both now hand the RecNN the layout the RecNN alone gets."""
    from imls_lightning.inference.pipeline import IMLSRenderer
    from imls_lightning.models.iml import FillDecoder

    ims, view = env["ims"], env["views"][0]
    seen = []
    hook = ims.recnn.register_forward_pre_hook(
        lambda _m, args: seen.append(args[0].is_contiguous(memory_format=torch.channels_last) and not args[0].is_contiguous()))
    try:
        RecNNAlone(env["renderer"], ims.pattern, ims.recnn, CPU).run(view)
        TwoPassFill(env["renderer"], ims.pattern, ims.recnn, share=0.5, base=0.2, opts=CPU).run(view)
        IMLSRenderer(env["renderer"], ims.pattern, ims.mask_head, FillDecoder(ims.pattern), ims.recnn, CPU).run(view)
    finally:
        hook.remove()
    assert seen == [True, True, True]
