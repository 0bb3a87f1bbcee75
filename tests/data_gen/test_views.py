"""Training views on a shell, the train/val split, and the exploratory test trajectory."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.render.camera import validate_view
from imls_lightning.base.errors import InputError
from data_gen.views import exploration_trajectory, load_views_file, sample_training_views, split_train_val

SHELL = (2.5, 4.0)


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


# ---- training views -------------------------------------------------------------------------
def test_smoke_training_views_on_shell_with_orthogonal_up():
    v = sample_training_views(500, SHELL, seed=3, lookat_jitter=0.2)
    assert v.shape == (500, 9) and v.dtype == np.float64
    r = np.linalg.norm(v[:, :3], axis=1)
    assert r.min() >= SHELL[0] and r.max() <= SHELL[1]
    # radius spread over the whole shell, directions over the whole sphere
    assert r.min() < SHELL[0] + 0.1 and r.max() > SHELL[1] - 0.1
    d = _unit(v[:, :3])
    assert np.abs(d.mean(axis=0)).max() < 0.15
    assert (d[:, 2] > 0.9).any() and (d[:, 2] < -0.9).any()
    assert np.linalg.norm(v[:, 3:6], axis=1).max() <= 0.2 + 1e-12
    up = v[:, 6:9]
    fwd = _unit(v[:, 3:6] - v[:, :3])
    np.testing.assert_allclose(np.linalg.norm(up, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(up * fwd, axis=1), 0.0, atol=1e-12)
    # up is random, not a fixed axis
    assert np.abs(up.mean(axis=0)).max() < 0.15
    for row in v:
        validate_view(row)


def test_training_views_deterministic_per_seed():
    a = sample_training_views(50, SHELL, seed=0)
    np.testing.assert_array_equal(a, sample_training_views(50, SHELL, seed=0))
    assert not np.allclose(a, sample_training_views(50, SHELL, seed=1))
    # zero jitter pins the look-at to the centre
    z = sample_training_views(20, SHELL, seed=0, lookat_jitter=0.0)
    assert np.all(z[:, 3:6] == 0)


def test_training_views_stratified_distance_one_per_slice():
    n = 6
    a = sample_training_views(n, SHELL, seed=4, stratify_distance=True)
    b = sample_training_views(n, SHELL, seed=4)
    r = np.linalg.norm(a[:, :3], axis=1)
    # one eye in each sixth of the shell's thickness, the directions and look-at points as without it
    slices = np.floor((r - SHELL[0]) / (SHELL[1] - SHELL[0]) * n).astype(int)
    assert sorted(slices.tolist()) == list(range(n))
    np.testing.assert_allclose(_unit(a[:, :3]), _unit(b[:, :3]), atol=1e-12)
    np.testing.assert_array_equal(a[:, 3:6], b[:, 3:6])
    for row in a:
        validate_view(row)
    # a degenerate shell (r_min = r_max) puts every eye on it
    c = sample_training_views(3, (3.0, 3.0), seed=0, stratify_distance=True)
    np.testing.assert_allclose(np.linalg.norm(c[:, :3], axis=1), 3.0)


@pytest.mark.parametrize("kw", [{"num_views": 0}, {"num_views": 2.5}, {"camera_distance": (0.0, 1.0)},
                                {"camera_distance": (4.0, 2.0)}, {"lookat_jitter": -1.0}])
def test_exception_training_views_bad_input(kw):
    args = {"num_views": 10, "camera_distance": SHELL}
    args.update({k: v for k, v in kw.items() if k in args})
    with pytest.raises(InputError):
        sample_training_views(args["num_views"], args["camera_distance"], seed=0,
                              lookat_jitter=kw.get("lookat_jitter", 0.1))


# ---- split ----------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 10, 37, 2000])
def test_split_nine_to_one_disjoint_covering(n):
    s = split_train_val(n, val_fraction=0.1, seed=5)
    tr, va = s["train"], s["val"]
    assert len(va) == max(1, round(n * 0.1))
    assert len(np.intersect1d(tr, va)) == 0
    np.testing.assert_array_equal(np.sort(np.concatenate([tr, va])), np.arange(n))
    assert np.all(np.diff(tr) > 0) and np.all(np.diff(va) > 0)
    s2 = split_train_val(n, val_fraction=0.1, seed=5)
    np.testing.assert_array_equal(s2["val"], va)


def test_split_edge_cases():
    assert len(split_train_val(1, seed=0)["val"]) == 0  # one view: it trains
    assert len(split_train_val(10, val_fraction=0.0, seed=0)["val"]) == 0
    assert not np.array_equal(split_train_val(100, seed=0)["val"], split_train_val(100, seed=1)["val"])
    with pytest.raises(InputError, match="val_fraction"):
        split_train_val(10, val_fraction=1.0)


# ---- test trajectory ------------------------------------------------------------------------
def test_smoke_trajectory_120_smooth_in_shell():
    p = exploration_trajectory(120, SHELL, seed=0, lookat_jitter=0.1)
    assert p.shape == (120, 9)
    r = np.linalg.norm(p[:, :3], axis=1)
    assert r.min() >= SHELL[0] and r.max() <= SHELL[1]
    # zooms in and out across most of the shell
    assert r.max() - r.min() > 0.8 * (SHELL[1] - SHELL[0])
    # orbits: the azimuth covers more than a full turn
    az = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    assert abs(az[-1] - az[0]) > 2 * np.pi
    # smooth: bounded steps in eye direction (< 6 degrees), radius, focus and up
    d = _unit(p[:, :3])
    ang = np.degrees(np.arccos(np.clip(np.sum(d[1:] * d[:-1], axis=1), -1, 1)))
    assert ang.max() < 6.0
    assert np.abs(np.diff(r)).max() < 0.1 * (SHELL[1] - SHELL[0]) + 1e-9
    assert np.linalg.norm(np.diff(p[:, 3:6], axis=0), axis=1).max() < 0.02
    up_ang = np.degrees(np.arccos(np.clip(np.sum(p[1:, 6:9] * p[:-1, 6:9], axis=1), -1, 1)))
    assert up_ang.max() < 8.0
    # changes of focus: the look-at point moves around inside its ball
    look = p[:, 3:6]
    assert np.linalg.norm(look, axis=1).max() <= 0.1 + 1e-9
    assert np.ptp(look, axis=0).min() > 0.05
    fwd = _unit(p[:, 3:6] - p[:, :3])
    np.testing.assert_allclose(np.sum(p[:, 6:9] * fwd, axis=1), 0.0, atol=1e-12)


def test_trajectory_deterministic_and_distinct_from_training():
    a = exploration_trajectory(120, SHELL, seed=0)
    np.testing.assert_array_equal(a, exploration_trajectory(120, SHELL, seed=0))
    assert not np.allclose(a, exploration_trajectory(120, SHELL, seed=1))
    train = sample_training_views(2000, SHELL, seed=0)
    dist = np.linalg.norm(a[:, None, :] - train[None, :, :], axis=2)
    assert dist.min() > 1e-3


# ---- user view files ------------------------------------------------------------------------
def test_load_views_file_text_and_npy(tmp_path):
    v = exploration_trajectory(5, SHELL, seed=0)
    np.savetxt(tmp_path / "v.txt", v)
    np.save(tmp_path / "v.npy", v)
    np.testing.assert_allclose(load_views_file(tmp_path / "v.txt"), v, rtol=1e-12)
    np.testing.assert_array_equal(load_views_file(tmp_path / "v.npy"), v)


def test_exception_views_file_degenerate_rows(tmp_path):
    good = [0, 0, 3, 0, 0, 0, 0, 1, 0]
    cases = {
        "eye == lookAt": [1, 1, 1, 1, 1, 1, 0, 1, 0],
        "parallel": [0, 0, 3, 0, 0, 0, 0, 0, 1],
        "non-finite": [0, 0, np.nan, 0, 0, 0, 0, 1, 0],
    }
    for what, bad in cases.items():
        f = tmp_path / "views.txt"
        np.savetxt(f, np.array([good, bad], float))
        with pytest.raises(InputError, match=r"view 1") as e:
            load_views_file(f)
        assert "\n" not in str(e.value), what
    np.savetxt(tmp_path / "short.txt", np.zeros((2, 8)))
    with pytest.raises(InputError, match="rows of 9"):
        load_views_file(tmp_path / "short.txt")
    with pytest.raises(InputError, match="not found"):
        load_views_file(tmp_path / "nope.txt")
