"""Sampling patterns (downsample, foveal, full), the config builder and helpers.

The rank patterns (blue noise, the plastic P) are tested in ``tests/core/test_rank_patterns.py``."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.core import patterns as pat
from imls_lightning.core.compaction import compact, decompact
from imls_lightning.core.patterns import (
    SamplingPattern,
    build_pattern,
    c_pixels_to_fr,
    downsample_pattern,
    foveal_pattern,
    foveal_surface,
    full_pattern,
)
from imls_lightning.core.rank_patterns import blue_noise_ranks

CONF = Path(__file__).resolve().parents[2] / "conf" / "pattern"


# --- downsample / full ---------------------------------------------------------------------------


@pytest.mark.parametrize("m, f", [(12, 1), (12, 2), (12, 3), (12, 4), (15, 5), (8, 8)])
def test_downsample_compaction_equals_strided_slicing(m, f):
    p = downsample_pattern(m, f)
    o = (f - 1) // 2
    x = torch.rand(2, 3, m, m)
    assert p.c_size == m // f and p.count == (m // f) ** 2 and p.fill_ratio == 1.0
    assert torch.equal(compact(x, p.indices, p.c_size), x[..., o::f, o::f])


def test_downsample_picks_block_centre_for_odd_and_factor2_is_plain_stride():
    assert downsample_pattern(9, 3).indices.tolist()[:3] == [1 * 9 + 1, 1 * 9 + 4, 1 * 9 + 7]
    assert downsample_pattern(4, 2).indices.tolist() == [0, 2, 8, 10]


def test_paper_4x_super_resolution_is_factor_2():
    p = downsample_pattern(512, 2)
    assert (p.c_size, p.count, p.sampling_ratio) == (256, 256 * 256, 0.25)


@pytest.mark.parametrize("m, f, match", [(10, 3, "not divisible"), (8, 0, "pattern.factor"), (8, 2.0, "pattern.factor")])
def test_downsample_rejects_bad_factors(m, f, match):
    with pytest.raises(InputError, match=match):
        downsample_pattern(m, f)


def test_full_pattern_compaction_is_identity():
    p = full_pattern(6)
    x = torch.rand(1, 3, 6, 6)
    assert p.c_size == 6 and torch.equal(compact(x, p.indices, 6), x)


# --- foveal ----------------------------------------------------------------------------------------


def _ring_density(mask: torch.Tensor, edges) -> list[float]:
    m = mask.shape[0]
    c = (torch.arange(m, dtype=torch.float64) + 0.5) / m - 0.5
    r = torch.sqrt(c[None, :] ** 2 + c[:, None] ** 2)
    return [float(mask[(r >= a) & (r < b)].double().mean()) for a, b in zip(edges[:-1], edges[1:])]


@pytest.mark.parametrize("formulation, sigma", [("fovolnet", 0.12), ("paper", 60.0)])
def test_foveal_density_falls_with_distance_and_follows_the_surface(formulation, sigma):
    p = foveal_pattern(128, 64, sigma, formulation=formulation)
    edges = [0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.72]
    dens = _ring_density(p.mask, edges)
    assert all(a > b for a, b in zip(dens, dens[1:])), dens
    assert dens[0] > 0.9  # dense fovea: the paper's printed "P > E" would make this ~0
    expected = _ring_density(foveal_surface(128, sigma, formulation=formulation), edges)
    assert np.allclose(dens, expected, atol=0.03), (dens, expected)  # blue noise is uniform


def test_foveal_count_is_reported_and_matches_the_mask():
    p = foveal_pattern(64, 32, 0.1)
    assert p.count == int(p.mask.sum()) == int(p.valid.sum())
    assert p.fill_ratio == p.count / 32**2 and p.count < 32**2  # zero padded C-Image
    assert f"K={p.count}" in p.summary()


@pytest.mark.parametrize("formulation, denser", [("fovolnet", 1.01), ("paper", 0.99)])
def test_foveal_solved_sigma_is_the_densest_that_fits(formulation, denser):
    p = foveal_pattern(64, 32, formulation=formulation)
    sigma = p.param_dict["sigma"]
    assert p.count <= 32 * 32 and p.fill_ratio > 0.99
    again = foveal_pattern(64, 32, sigma, formulation=formulation)  # the printed sigma reproduces it
    assert torch.equal(again.indices, p.indices) and again.fingerprint() == p.fingerprint()
    with pytest.raises(InputError, match="pattern.sigma="):
        foveal_pattern(64, 32, sigma * denser, formulation=formulation)


def test_foveal_too_large_sigma_or_base_are_refused_with_the_fitting_value():
    with pytest.raises(InputError, match=r"more than the C-Image holds \(24x24=576\); use sigma <= 0\.\d+"):
        foveal_pattern(64, 24, 0.5)
    with pytest.raises(InputError, match="pattern.base=0.3: the base level alone"):
        foveal_pattern(64, 16, base=0.3)


def test_foveal_large_c_image_takes_every_pixel():
    p = foveal_pattern(16, 16)
    assert p.count == 256 and torch.equal(p.indices, torch.arange(256))


def test_foveal_base_defaults_per_formulation_and_centre_moves_the_fovea():
    assert foveal_pattern(32, 16).param_dict["base"] == pat.FOVOLNET_DEFAULT_BASE
    assert foveal_pattern(32, 16, formulation="paper").param_dict["base"] == 0.0
    p = foveal_pattern(96, 32, 0.05, base=0.0, center=(0.25, 0.75))
    rows, cols = np.nonzero(p.mask.numpy())
    assert abs((cols.mean() + 0.5) / 96 - 0.25) < 0.02 and abs((rows.mean() + 0.5) / 96 - 0.75) < 0.02


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(formulation="gauss"), "pattern.formulation"),
        (dict(base=1.5), "pattern.base"),
        (dict(center=(0.5,)), "pattern.center"),
        (dict(center=(0.5, float("nan"))), r"pattern.center\[1\]"),
        (dict(sigma=-1.0), "pattern.sigma"),
        (dict(seed=-2), "pattern.seed"),
    ],
)
def test_foveal_bad_parameters_raise_one_line_input_errors(kwargs, match):
    with pytest.raises(InputError, match=match) as err:
        foveal_pattern(32, 16, **kwargs)
    assert "\n" not in str(err.value)


# --- config and helpers ------------------------------------------------------------------------------


def test_build_pattern_from_the_hydra_group_files():
    down = build_pattern(OmegaConf.load(CONF / "downsample.yaml"), 32)
    assert (down.kind, down.c_size, down.count) == ("downsample", 16, 256)
    fov_cfg = OmegaConf.load(CONF / "foveal.yaml")
    OmegaConf.set_struct(fov_cfg, True)
    fov = build_pattern(fov_cfg, 32)
    assert (fov.kind, fov.c_size) == ("foveal", 16) and fov.count <= 256 and fov.fill_ratio > 0.99
    assert fov.param_dict["formulation"] == "fovolnet"
    fov_cfg.c_size = 12
    fov_cfg.sigma = 0.08
    fixed = build_pattern(fov_cfg, 32)
    assert fixed.c_size == 12 and fixed.param_dict["sigma"] == 0.08
    assert build_pattern({"kind": "full"}, 8).count == 64


def test_build_pattern_rejects_an_unknown_kind():
    with pytest.raises(InputError, match="pattern.kind='stripes': expected one of downsample, foveal, full"):
        build_pattern({"kind": "stripes"}, 16)


def test_c_pixels_to_fr_maps_mask_pixels_and_ignores_padding():
    p = foveal_pattern(16, 8, 0.1)  # padded: K < 64
    assert p.count < 64
    g = torch.Generator().manual_seed(0)
    im = torch.rand(8, 8, generator=g) < 0.5
    got = c_pixels_to_fr(p, im)
    want = torch.nonzero(decompact(im[None, None].float(), p.indices, 16)[0, 0].flatten()).flatten()
    assert torch.equal(got, want)
    assert torch.equal(c_pixels_to_fr(p, torch.ones(8, 8, dtype=torch.bool)), p.indices)
    assert torch.equal(c_pixels_to_fr(p, im.to(torch.uint8)), got)  # 0/1 numbers work too
    with pytest.raises(ValueError, match=r"expected a tensor of shape \(8, 8\)"):
        c_pixels_to_fr(p, torch.ones(16, 16, dtype=torch.bool))


def test_fingerprints_are_stable_and_distinguish_patterns():
    # pinned: a change here invalidates manifests and checkpoints that record the pattern
    assert downsample_pattern(16, 2).fingerprint() == downsample_pattern(16, 2).fingerprint()
    assert full_pattern(8).fingerprint() == full_pattern(8).fingerprint()
    assert downsample_pattern(16, 2).fingerprint() == PINNED["downsample16x2"]
    assert full_pattern(8).fingerprint() == PINNED["full8"]
    a = foveal_pattern(32, 16)
    blue_noise_ranks.cache_clear()
    assert foveal_pattern(32, 16).fingerprint() == a.fingerprint()
    prints = {a.fingerprint(), foveal_pattern(32, 16, seed=1).fingerprint(), foveal_pattern(32, 16, 0.1).fingerprint()}
    assert len(prints) == 3


PINNED = {"downsample16x2": "9976aa49fe1ec37a", "full8": "19ecad6366186e4c"}


def test_sampling_pattern_contract_checks():
    with pytest.raises(ValueError, match="ascending"):
        SamplingPattern("x", 4, 2, torch.tensor([3, 1]))
    with pytest.raises(ValueError, match="out of range"):
        SamplingPattern("x", 4, 2, torch.tensor([0, 16]))


# --- crop_pattern: the pattern of a training crop (data.crop) -----------------------------------
@pytest.mark.parametrize("factor", [2, 3])
def test_crop_pattern_smoke_is_the_window_of_the_full_pattern_at_grid_offsets(factor):
    m, c = 12 * factor, 4 * factor
    full = downsample_pattern(m, factor)
    crop = pat.crop_pattern(full, c)
    assert (crop.kind, crop.fr_size, crop.c_size) == ("downsample", c, c // factor)
    for y, x in [(0, 0), (factor, 2 * factor), (m - c, m - c)]:
        assert torch.equal(full.mask[y:y + c, x:x + c], crop.mask), (y, x)
    assert pat.crop_pattern(full_pattern(8), 4).count == 16


@pytest.mark.parametrize("crop, needle", [(7, "not a multiple of the downsampling factor 2"), (40, "larger than the FR-Image"),
                                          (0, "data.crop")])
def test_crop_pattern_exception_bad_size(crop, needle):
    with pytest.raises(InputError, match=needle):
        pat.crop_pattern(downsample_pattern(32, 2), crop)


def test_crop_pattern_exception_foveal_refused():
    with pytest.raises(InputError, match="foveal pattern changes with the position"):
        pat.crop_pattern(foveal_pattern(32, 16), 16)
