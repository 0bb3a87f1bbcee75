"""IMLTask: the decoder and importance options, the random mean per batch, what validation logs,
backward compatibility of checkpoints written before the refine decoder, and the errors."""
from __future__ import annotations

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.models.iml import PlainDecoder, RefineDecoder
from imls_lightning.tasks.iml import IMLTask, background_mask, iml_net_from_hparams

PATTERN = {"kind": "downsample", "factor": 2}
FR = 32


def _task(**kw) -> IMLTask:
    torch.manual_seed(0)
    args = dict(pattern=PATTERN, fr_size=FR, depth=2, base_channels=4, mean=0.2, decoder="refine")
    args.update(kw)
    return IMLTask(**args)


def _batch(b: int = 2):
    n = FR // 2
    c = torch.zeros(b, 3, n, n)
    c[:, :, 4:12, 4:12] = torch.rand(b, 3, 8, 8) * 0.8 + 0.2  # an object on black background
    return {"c": c, "fr": torch.nn.functional.interpolate(c, scale_factor=2), "view": torch.zeros(b, 9)}


class _Logs:
    def __init__(self, task):
        self.values = {}
        task.log = lambda name, value, *a, **k: self.values.__setitem__(name, float(value))


def test_smoke_validation_logs_psnr_fill_and_importance_stats():
    task = _task().eval()
    logs = _Logs(task)
    with torch.no_grad():
        task._step(_batch(), "val")
    for key in ("val/loss", "val/c_psnr", "val/fill_c_psnr", "val/pim_contrast", "val/density_background",
                "val/density_object", "val/ipr", "val/c_share"):
        assert key in logs.values and torch.isfinite(torch.tensor(logs.values[key])), key
    # a fresh refine decoder is the pull-push fill: the two PSNRs agree
    assert logs.values["val/c_psnr"] == pytest.approx(logs.values["val/fill_c_psnr"], abs=1e-4)


def test_mean_range_draws_a_mean_per_training_batch_and_leaves_the_trained_one():
    """A training step with mean_range normalizes at a drawn mean value passed to that call; the IML's own mean is never
    changed (validation and every other caller see the trained one)."""
    task = _task(mean_range=[0.05, 0.5]).train()
    seen = []
    orig = task.iml.normalization.forward

    def spy(pim, valid=None, mean=None):
        assert task.iml.mean == 0.2  # nothing swapped in for the step
        seen.append(task.iml.mean if mean is None else mean)
        return orig(pim, valid, mean=mean)

    task.iml.normalization.forward = spy
    _Logs(task)
    for _ in range(4):
        task._step(_batch(), "train")
    assert len(set(seen)) == 4 and all(0.05 <= u <= 0.5 for u in seen)
    assert task.iml.mean == 0.2
    task.eval()
    seen.clear()
    with torch.no_grad():
        task._step(_batch(), "val")
    assert seen == [0.2]  # validation at the trained mean


def test_background_mask_against_a_direct_threshold():
    c = torch.tensor([[[[0.0, 1.0 / 255]], [[0.0, 0.0]], [[0.5, 0.0]]]])
    assert background_mask(c).tolist() == [[[[False, True]]]]


def test_checkpoints_without_a_decoder_key_build_the_plain_decoder():
    from imls_lightning.core.patterns import build_pattern

    p = build_pattern(PATTERN, FR)
    old = iml_net_from_hparams({"depth": 2, "base_channels": 4}, p)  # hyperparameters of an old checkpoint
    assert isinstance(old.decoder, PlainDecoder) and old.encoder is not None
    new = iml_net_from_hparams(dict(_task().hparams), p)
    assert isinstance(new.decoder, RefineDecoder)
    # the state dict of the paper's decoder as written before (a bare U-Net) loads unchanged
    from imls_lightning.models.unet import UNet

    unet = UNet(3, 3, depth=2, base_channels=4)
    old.decoder.load_state_dict(unet.state_dict())
    c, m = torch.rand(1, 3, 16, 16), (torch.rand(1, 1, 16, 16) > 0.5).float()
    torch.testing.assert_close(old.decoder(c, m), unet(m * c))


def test_the_decoder_fills_where_model_fill_says_and_older_checkpoints_in_the_c_layout():
    from imls_lightning.core.patterns import foveal_pattern

    p = foveal_pattern(48, 16, None)
    hp = {"depth": 2, "base_channels": 4, "decoder": "refine"}
    assert iml_net_from_hparams({**hp, "fill": "fr"}, p).decoder.fill_pattern is p
    assert iml_net_from_hparams({**hp, "fill": "c"}, p).decoder.fill_pattern is None
    assert iml_net_from_hparams(hp, p).decoder.fill_pattern is None  # written before model.fill existed
    assert _task().hparams["fill"] == "c"


@pytest.mark.parametrize("kw,needle", [
    ({"mean_range": [0.5, 0.1]}, "model.mean_range"),
    ({"mean_range": [0.0, 0.5]}, "model.mean_range"),
    ({"mean_range": "wide"}, "model.mean_range"),
    ({"decoder": "unet"}, "decoder"),
    ({"importance": "random"}, "importance"),
    ({"fill": "fovea"}, "model.fill='fovea'"),
])
def test_exception_bad_options(kw, needle):
    with pytest.raises(InputError, match=needle):
        _task(**kw)


def test_exception_iml_errors_name_the_users_keys():
    """Errors named internal keys (depth=, alpha=) instead of the key the user typed (issue 17, minor)."""
    from imls_lightning.base.errors import InputError
    from imls_lightning.tasks.iml import IMLTask

    for kw, key in (({"depth": 0}, "model.depth=0"), ({"alpha": -1.0}, "model.alpha=-1"), ({"mean": 2.0}, "model.mean=2")):
        with pytest.raises(InputError, match=f"^{key}"):
            IMLTask({"kind": "downsample", "factor": 2}, 32, **kw)
