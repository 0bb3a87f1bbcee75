"""Config helpers: OmegaConf resolvers, settings hashes, and safe checkpoint loading."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping

import torch
from omegaconf import DictConfig, ListConfig, OmegaConf

from data_gen.errors import InputError

# Keys that never change a trained result (where things go, how many loader processes, ...):
# left out of run hashes so that e.g. more render workers still find the same run.
NON_RESULT_KEYS = frozenset({"cache_dir", "cache_path", "fsync", "workers", "loader_workers", "progress", "runs_dir", "shard"})


def to_plain(obj: Any) -> Any:
    """DictConfig/ListConfig (resolved) -> plain dicts/lists; anything else unchanged."""
    if isinstance(obj, (DictConfig, ListConfig)):
        return OmegaConf.to_container(obj, resolve=True)
    return obj


def _strip(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _strip(v) for k, v in sorted(obj.items()) if k not in NON_RESULT_KEYS}
    if isinstance(obj, (list, tuple)):
        return [_strip(v) for v in obj]
    return obj


def settings_hash(*parts: Any, length: int = 8) -> str:
    """Stable short hash of config parts (order matters, non-result keys ignored)."""
    plain = [_strip(to_plain(p)) for p in parts]
    blob = json.dumps(plain, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:length]


def file_hash(path: str | Path, length: int = 16) -> str:
    """SHA-256 of a file's bytes (checkpoints are small enough to read whole)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:length]


def register_resolvers() -> None:
    """Register the project's resolvers once (``${imls_hash:...}``)."""
    if not OmegaConf.has_resolver("imls_hash"):
        OmegaConf.register_new_resolver("imls_hash", lambda *parts: settings_hash(*parts))


def load_checkpoint(path: str | Path, *, what: str = "checkpoint") -> dict:
    """Load a Lightning checkpoint safely (``weights_only=True``) on the CPU.

    Raises:
        InputError: the file is missing or is not a checkpoint of this project.
    """
    p = Path(str(path)).expanduser()
    if not p.is_file():
        raise InputError(f"{what}={path}: file not found")
    try:
        ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # unpickling errors of all kinds
        raise InputError(f"{what}={path}: not a loadable checkpoint ({type(err).__name__}: {str(err).splitlines()[0][:120]})") from None
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt or "hyper_parameters" not in ckpt:
        raise InputError(f"{what}={path}: not a Lightning checkpoint of this project (no state_dict/hyper_parameters)")
    return ckpt
