"""The views an evaluation may read, and when: settings are chosen on views no network trained on, and the test
trajectory is read once, at the end.

Two rules, each a one-line refusal where it is broken (:func:`check_view_seeds`):

* **Validation views nobody trained on.** The object floor's margin (and the ORP with ``orp_views=val``) is chosen on
  the cache's validation split. Its views are drawn from ``data.seed``'s training stream
  (:func:`data_gen.views.sample_training_views`); an IMS trained on a larger cache of the same seed (1,500 views)
  has trained on their eye directions: a cache's first draws are the same whatever its size. So the IMS's training
  views must come from another seed (the row protocol: ``data.seed=100``).
* **A fresh test trajectory.** ``trajectory_seed=N`` draws the test trajectory anew: the same path model and the same
  shell of camera distances (:func:`data_gen.views.exploration_trajectory`), phases of seed ``N``, rendered into a
  cache of its own. ``N`` must be none of the seeds whose views chose something: ``data.seed`` (the training views
  and the trajectory every earlier design decision read), the ORP's search paths and the IMS's training seed.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from imls_lightning.base.atomic import atomic_npy
from imls_lightning.base.errors import InputError


def training_data_seed(checkpoint: str | os.PathLike) -> int | None:
    """``data.seed`` of the views ``checkpoint`` trained on: recorded in the checkpoint
    (:class:`~imls_lightning.training.callbacks.TrainingViews`), else in its run's ``result.json`` (the folder of
    ``checkpoints/``); None where neither says (then nothing can be checked)."""
    from ..base.config import load_checkpoint
    from ..training.callbacks import TRAINING_VIEWS_KEY

    seed = (load_checkpoint(checkpoint, what="checkpoints.ims").get(TRAINING_VIEWS_KEY) or {}).get("seed")
    if seed is not None:
        return int(seed)
    p = Path(str(checkpoint)).expanduser().resolve()
    for folder in (p.parent, p.parent.parent):
        rec = folder / "result.json"
        if rec.is_file():
            try:
                seed = ((json.loads(rec.read_text()).get("config") or {}).get("data") or {}).get("seed")
            except (OSError, ValueError, AttributeError):
                return None
            return None if seed is None else int(seed)
    return None


def search_path_seeds(s, cfg) -> range:
    """The seeds of the ORP's search paths (``orp_views=path``) or held-out views; empty for ``orp_views=val``."""
    if s.orp_views == "val":
        return range(0)
    first = int(cfg.data.seed) + 1 if s.orp_views_seed is None else int(s.orp_views_seed)
    return range(first, first + (s.orp_paths if s.orp_views == "path" else 1))


def reads_validation_views(s) -> bool:
    """Whether this evaluation chooses a setting on the cache's validation split: the ORP with ``orp_views=val``, or
    the object floor's margin (the two-pass sampler and LAS are searched on the ORP's own search views)."""
    return bool(s.orp and (s.orp_views == "val" or s.orp_object_floor))


def check_view_seeds(s, cfg, ims_seed: int | None) -> None:
    """Refuse, in one line, validation views whose eye directions the IMS trained on, and a trajectory seed that some
    choice already read (module docstring). ``ims_seed``: the IMS's training ``data.seed`` (None: unknown, not
    checked)."""
    data_seed = int(cfg.data.seed)
    if ims_seed is not None and ims_seed == data_seed and reads_validation_views(s) and not s.orp_from:
        raise InputError(f"checkpoints.ims: trained on views of data.seed={ims_seed}, the seed of the validation views this "
                         "evaluation chooses settings on (their eye directions overlap); train the IMS on views of another "
                         "seed (data.seed=100, as the row protocol does)")
    t = s.trajectory_seed
    if t is None:
        return
    taken = {data_seed: "data.seed (the training views and the trajectory earlier decisions read)"}
    taken.update({k: "a seed of the ORP's search views" for k in search_path_seeds(s, cfg)})
    if ims_seed is not None:
        taken[ims_seed] = "the IMS's training data.seed"
    if t in taken:
        raise InputError(f"trajectory_seed={t}: equals {taken[t]}; pick a seed no choice has read")


def fresh_trajectory_data(s, cfg, scene):
    """The ``data`` node of the fresh test trajectory's own cache (``trajectory_seed``): one training view (a cache
    needs one) and the trajectory, written as a content-named views file under ``data.cache_dir/trajectories``."""
    from data_gen.views import exploration_trajectory

    n = int(cfg.data.test_views)
    if n < 1:
        raise InputError(f"trajectory_seed={s.trajectory_seed}: data.test_views={n}, expected at least 1 view")
    views = exploration_trajectory(n, scene.camera_distance, seed=int(s.trajectory_seed),
                                   lookat_jitter=float(cfg.data.lookat_jitter))
    path = write_views_file(views, Path(str(cfg.data.cache_dir)) / "trajectories")
    return OmegaConf.merge(cfg.data, {"num_views": 1, "val_fraction": 0.0, "test_views": n, "test_trajectory": str(path),
                                      "cache_path": None, "shard": None})


def write_views_file(views: np.ndarray, folder: Path) -> Path:
    """``views`` ``(N, 9)`` saved as ``folder/<sha256[:16]>.npy`` (content-named, written atomically; an existing file
    of that name holds the same views)."""
    views = np.ascontiguousarray(views, dtype=np.float64)
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{hashlib.sha256(views.tobytes()).hexdigest()[:16]}.npy"
    if not out.is_file():
        atomic_npy(out, views, unique=True)  # several sittings may write the same views at once
    return out


def trajectory_note(s, cache) -> dict[str, Any] | None:
    """``summary.json``'s ``trajectory``: the fresh trajectory's seed and cache (None: the cache's own trajectory)."""
    if s.trajectory_seed is None:
        return None
    return {"seed": int(s.trajectory_seed), "cache": str(cache.path)}
