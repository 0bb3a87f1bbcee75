"""View sets: random training views on a spherical shell and the 120-view test trajectory.

Every view is 9 floats ``(eye_xyz, lookAt_xyz, up_xyz)`` in the normalized space (the volume is
centred at the origin, longest axis spanning [-1, 1]); see :mod:`imls_lightning.render.camera`.

* Training views (paper: 2000 per volume, split 9:1 into train/val): eyes uniformly distributed
  over directions, radius uniform in ``camera_distance = (r_min, r_max)``; the look-at point is
  jittered inside a small ball around the centre; the up vector is random and made orthogonal to
  the view direction.
* Test trajectory (paper: 120 views "forming an exploratory trajectory to simulate real user
  exploration"): a smooth orbit around the volume whose radius zooms in and out inside the same
  shell, whose elevation swings up and down, whose focus wanders smoothly inside the same look-at
  ball, with a gentle camera roll. Consecutive views differ by a bounded step.

Everything is deterministic from a seed (``numpy.random.SeedSequence`` streams, so the training
views, the split and the trajectory do not share random numbers).
"""
from __future__ import annotations

import numpy as np

from imls_lightning.render.camera import validate_view
from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_integer, check_number, check_numbers, expected

# Independent random streams derived from the one user seed.
_STREAM_TRAIN, _STREAM_SPLIT, _STREAM_TEST = 0, 1, 2


def _rng(seed: int, stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), stream]))


def _check_distance(camera_distance) -> tuple[float, float]:
    what = "[min, max] with 0 < min <= max"
    lo, hi = check_numbers(camera_distance, "scene.camera_distance", 2, lo=0, lo_open=True, what=what)
    if lo > hi:
        raise expected("scene.camera_distance", camera_distance, what)
    return lo, hi


def unit_vectors(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to length 1 along its last axis."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def camera_distance(view) -> float:
    """A view's camera distance from the volume's centre: the norm of its eye (the first 3 of its 9 floats).

    Example:
        >>> camera_distance([3.0, 4.0, 0.0, 0, 0, 0, 0, 0, 1])
        5.0
    """
    return float(np.linalg.norm(np.asarray(view, float).reshape(-1)[:3]))


def orthogonal_up(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Gram-Schmidt: remove from ``up`` its component along ``direction`` (both ``(N, 3)``)."""
    d = unit_vectors(direction)
    u = up - np.sum(up * d, axis=-1, keepdims=True) * d
    return unit_vectors(u)


def sample_training_views(
    num_views: int, camera_distance, *, seed: int = 0, lookat_jitter: float = 0.1, stratify_distance: bool = False
) -> np.ndarray:
    """Random views around the volume.

    Args:
        num_views: number of views ``N`` (>= 1).
        camera_distance: ``(r_min, r_max)``: eyes lie on the shell ``r_min <= |eye| <= r_max``.
        seed: random seed.
        lookat_jitter: radius of the ball around the origin the look-at point is drawn from
            (uniformly, normalized units).
        stratify_distance: draw the eyes' distances stratified (one in each of ``N`` equal slices of
            ``[r_min, r_max]``, the slice given by the draw's rank) instead of independently: a few views then cover the
            range of distances, which a view's cost and object size follow (the before-training estimate's
            few views). The directions and look-at points are drawn as without it.

    Returns:
        ``(N, 9)`` float64 views; each passes :func:`imls_lightning.render.camera.validate_view`, and the up
        vector is a unit vector orthogonal to ``lookAt - eye``.

    Example:
        >>> v = sample_training_views(4, (2.5, 4.0), seed=0)
        >>> v.shape, bool(np.all((np.linalg.norm(v[:, :3], axis=1) >= 2.5)))
        ((4, 9), True)
    """
    n = check_integer(num_views, "data.num_views", 1)
    lo, hi = _check_distance(camera_distance)
    jitter = check_lookat_jitter(lookat_jitter)
    rng = _rng(seed, _STREAM_TRAIN)
    direction = unit_vectors(rng.normal(size=(n, 3)))
    radius = rng.uniform(lo, hi, size=(n, 1))
    if stratify_distance and hi > lo:  # the same draws, each moved into its own slice of the range
        frac = (radius[:, 0] - lo) / (hi - lo)
        radius = lo + (hi - lo) * (np.argsort(np.argsort(frac)) + frac)[:, None] / n  # slice = the draw's rank
    eye = direction * radius
    # uniform in the ball: direction uniform, radius ~ r^(1/3)
    look = unit_vectors(rng.normal(size=(n, 3))) * (jitter * rng.uniform(0, 1, size=(n, 1)) ** (1 / 3))
    up = rng.normal(size=(n, 3))
    fwd = look - eye
    # a random up almost parallel to the view direction is redrawn (probability ~1e-6 per view)
    bad = np.linalg.norm(np.cross(unit_vectors(fwd), unit_vectors(up)), axis=1) < 1e-3
    while np.any(bad):
        up[bad] = rng.normal(size=(int(bad.sum()), 3))
        bad = np.linalg.norm(np.cross(unit_vectors(fwd), unit_vectors(up)), axis=1) < 1e-3
    up = orthogonal_up(fwd, up)
    views = np.concatenate([eye, look, up], axis=1)
    return validate_views(views, name="training view")


def split_train_val(num_views: int, *, val_fraction: float = 0.1, seed: int = 0) -> dict[str, np.ndarray]:
    """Seeded random split of ``range(num_views)`` into disjoint, covering train/val index sets.

    ``round(N * val_fraction)`` views go to validation (at least one when ``N >= 2`` and the
    fraction is positive; the paper's ratio is 9:1). Both arrays are sorted ascending, int64.

    Example:
        >>> s = split_train_val(20, seed=0)
        >>> len(s["train"]), len(s["val"])
        (18, 2)
    """
    n = check_integer(num_views, "data.num_views", 1)
    f = check_val_fraction(val_fraction)
    n_val = int(round(n * f))
    if f > 0 and n >= 2:
        n_val = max(n_val, 1)
    n_val = min(n_val, n - 1)
    perm = _rng(seed, _STREAM_SPLIT).permutation(n)
    return {"train": np.sort(perm[n_val:]).astype(np.int64), "val": np.sort(perm[:n_val]).astype(np.int64)}


def exploration_trajectory(
    num_views: int = 120, camera_distance=(2.5, 4.0), *, seed: int = 0, lookat_jitter: float = 0.1
) -> np.ndarray:
    """A smooth exploratory camera path (the paper's 120-view test set).

    The camera orbits once and a quarter around the polar (z) axis; its elevation swings between
    about -45 and +45 degrees; its distance zooms in and out across ``camera_distance`` one and a
    half times; its focus drifts smoothly inside the look-at ball (radius ``lookat_jitter``); the up
    vector follows +z with a gentle roll of up to 20 degrees. Phases come from ``seed``.

    Args:
        num_views: number of views ``T`` (the paper uses 120).
        camera_distance: ``(r_min, r_max)``; every eye lies in this shell.
        seed: random seed for the phases.
        lookat_jitter: radius of the ball the focus moves in.

    Returns:
        ``(T, 9)`` float64 views in path order.

    Example:
        >>> p = exploration_trajectory(120, (2.5, 4.0), seed=0)
        >>> p.shape, float(np.abs(np.diff(p[:, :3], axis=0)).max()) < 0.3
        ((120, 9), True)
    """
    t_n = check_integer(num_views, "data.test_views", 1)
    lo, hi = _check_distance(camera_distance)
    jitter = check_lookat_jitter(lookat_jitter)
    rng = _rng(seed, _STREAM_TEST)
    ph = rng.uniform(0, 2 * np.pi, size=8)
    s = np.linspace(0.0, 1.0, t_n)  # path parameter
    azimuth = ph[0] + 2.5 * np.pi * s  # 1.25 turns
    elevation = np.deg2rad(45.0) * np.sin(2 * np.pi * 1.0 * s + ph[1])
    # zoom in/out inside the shell, kept a little off its limits
    mid, amp = (lo + hi) / 2, (hi - lo) / 2 * 0.95
    radius = mid + amp * np.sin(2 * np.pi * 1.5 * s + ph[2])
    ce = np.cos(elevation)
    eye = radius[:, None] * np.stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)], axis=1)
    # changes of focus: a smooth Lissajous-like drift of the look-at point inside the jitter ball
    look = np.stack(
        [np.sin(2 * np.pi * 1.0 * s + ph[3]), np.sin(2 * np.pi * 1.5 * s + ph[4]), np.sin(2 * np.pi * 0.75 * s + ph[5])],
        axis=1,
    ) * (jitter / np.sqrt(3.0))
    fwd = unit_vectors(look - eye)
    up0 = orthogonal_up(fwd, np.broadcast_to(np.array([0.0, 0.0, 1.0]), fwd.shape))
    right = np.cross(fwd, up0)
    roll = np.deg2rad(20.0) * np.sin(2 * np.pi * 0.5 * s + ph[6])
    up = np.cos(roll)[:, None] * up0 + np.sin(roll)[:, None] * right
    views = np.concatenate([eye, look, up], axis=1)
    return validate_views(views, name="test trajectory view")


def load_views_file(path) -> np.ndarray:
    """Read a user's own view list: ``.npy`` array ``(T, 9)`` or a text file with 9 numbers per
    line (whitespace or comma separated, ``#`` comments). Every view is validated."""
    from pathlib import Path

    p = Path(str(path)).expanduser()
    if not p.is_file():
        raise InputError(f"data.test_trajectory={path}: file not found")
    try:
        if p.suffix == ".npy":
            a = np.load(p, allow_pickle=False)
        else:
            a = np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, ndmin=2, comments="#")
    except Exception as err:  # unreadable content: name the file, keep it to one line
        raise InputError(f"data.test_trajectory={path}: cannot read views ({type(err).__name__}: {err})") from None
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 9 or len(a) == 0:
        raise InputError(f"data.test_trajectory={path}: expected rows of 9 numbers (eye, lookAt, up), got shape {a.shape}")
    return validate_views(a, name=f"data.test_trajectory={path}: view")


def validate_views(views: np.ndarray, *, name: str = "view") -> np.ndarray:
    """Validate every row of ``(N, 9)`` views; the error names the first bad row."""
    v = np.asarray(views, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 9:
        raise InputError(f"{name}s: expected an (N, 9) array, got shape {v.shape}")
    for i in range(len(v)):
        validate_view(v[i], name=f"{name} {i}")
    return v


def check_val_fraction(value) -> float:
    """``data.val_fraction``: the share of the views held out for validation, a number in ``[0, 1)``.

    Example:
        >>> check_val_fraction(0.1)
        0.1
    """
    return check_number(value, "data.val_fraction", 0, 1, hi_open=True)


def check_lookat_jitter(value) -> float:
    """``data.lookat_jitter``: the radius of the look-at ball, a finite number >= 0 (normalized units).

    Example:
        >>> check_lookat_jitter(0.1)
        0.1
    """
    return check_number(value, "data.lookat_jitter", 0, what="a number >= 0 (normalized units)")


__all__ = ["sample_training_views", "split_train_val", "exploration_trajectory", "load_views_file", "validate_views",
           "unit_vectors", "orthogonal_up", "check_lookat_jitter", "check_val_fraction"]
