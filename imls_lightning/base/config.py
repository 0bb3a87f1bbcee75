"""Config helpers: OmegaConf resolvers, settings hashes, and safe checkpoint loading."""
from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any, Mapping

import torch
from omegaconf import DictConfig, ListConfig, OmegaConf

from imls_lightning.base.errors import InputError

# Keys that never change a trained result (where things go, how many loader processes, ...):
# left out of run hashes so that e.g. more render workers still find the same run.
NON_RESULT_KEYS = frozenset({"cache_dir", "cache_path", "fsync", "workers", "loader_workers", "progress", "runs_dir", "shard"})

# Keys added after runs existed, left out of run hashes while they hold the value every earlier run had, so
# those runs are still found (a run's directory is the hash of its settings): data.train_pixels (all: whole frames),
# model.fill (c: the IML decoder's fill in the C-Image's layout; a foveal run filling at the FR positions is a new run),
# renderer.skip_empty (true: empty-space skipping; it never changes a pixel, but an estimate's times depend on it),
# renderer.interpolation (trilinear; imls_lightning.render.PIXEL_KEYS_NEUTRAL_AT, for cache keys).
KEYS_NEUTRAL_AT = {"train_pixels": "all", "fill": "c", "skip_empty": True, "interpolation": "trilinear",
                   # the IMS's decoder-only stage (model.train_generator=false) and its masks; off, runs keep their hashes
                   "decoder_sharpness": [1.0], "decoder_lift": False, "train_generator": True, "init_checkpoint": None}


def to_plain(obj: Any) -> Any:
    """DictConfig/ListConfig (resolved) -> plain dicts/lists; anything else unchanged."""
    if isinstance(obj, (DictConfig, ListConfig)):
        return OmegaConf.to_container(obj, resolve=True)
    return obj


def is_checkpoint_key(key: Any) -> bool:
    """Config keys that name an input checkpoint file (``checkpoint``, ``iml_checkpoint``, ...)."""
    return isinstance(key, str) and (key == "checkpoint" or key.endswith("_checkpoint"))


def _strip(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _checkpoint_id(v) if is_checkpoint_key(k) else _strip(v)
                for k, v in sorted(obj.items()) if k not in NON_RESULT_KEYS and KEYS_NEUTRAL_AT.get(k, object()) != v}
    if isinstance(obj, (list, tuple)):
        return [_strip(v) for v in obj]
    return obj


def _checkpoint_id(value: Any) -> Any:
    """An input checkpoint enters a hash by its content, not its path: a checkpoint replaced at the
    same path gives another hash, the same file moved elsewhere the same one. A path that is not a
    file (yet) stays as it is (its use fails later with a one-line error)."""
    if isinstance(value, str) and value.strip():
        p = Path(value).expanduser()
        if p.is_file():
            return {"sha256": file_hash(p)}
    return value


def settings_hash(*parts: Any, length: int = 8) -> str:
    """Stable short hash of config parts (order matters, non-result keys ignored, a later key at its
    neutral value ignored, input checkpoints by their content).

    Example:
        >>> settings_hash({"data": {"num_views": 4}}) == settings_hash({"data": {"num_views": 4, "train_pixels": "all"}})
        True
        >>> settings_hash({"data": {"num_views": 4}}) == settings_hash({"data": {"num_views": 4, "train_pixels": "pattern"}})
        False
    """
    plain = [_strip(to_plain(p)) for p in parts]
    blob = json.dumps(plain, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:length]


#: (resolved path, inode, size, mtime) -> SHA-256 hex of the file: config resolution asks again and again
_FILE_HASHES: dict[tuple, str] = {}


def file_hash(path: str | Path, length: int = 16) -> str:
    """SHA-256 of a file's bytes (checkpoints are small enough to read whole); remembered in this
    process while the file's inode, size and modification time stay the same."""
    p = Path(path)
    st = p.stat()
    key = (str(p.resolve()), st.st_ino, st.st_size, st.st_mtime_ns)
    if key not in _FILE_HASHES:
        h = hashlib.sha256()
        with open(p, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        _FILE_HASHES[key] = h.hexdigest()
    return _FILE_HASHES[key][:length]


#: logged metrics where higher is better (every other monitor is a loss or an error: lower is better)
HIGHER_IS_BETTER = ("psnr", "ssim", "iou", "accuracy")


def monitor_mode(metric: str) -> str:
    """``"max"`` for a metric where higher is better (PSNR, SSIM, IoU, accuracy), else ``"min"``: the
    mode of the best checkpoint and of early stopping on ``model.monitor`` (``${imls_monitor_mode:...}``).

    Example:
        >>> monitor_mode("val/fr_psnr"), monitor_mode("val/im_error"), monitor_mode("val/loss")
        ('max', 'min', 'min')
    """
    name = str(metric).rsplit("/", 1)[-1].lower()
    return "max" if any(name.endswith(k) or f"{k}_" in name for k in HIGHER_IS_BETTER) else "min"


def decoder_fill_for(pattern_kind: str) -> str:
    """``model.fill``'s default (``${imls_decoder_fill:${pattern.kind}}``, ``imls_lightning.tasks.iml.FILLS``): ``fr``,
    the IML decoder's fill at a foveal C-Image's FR positions; ``c`` on a grid pattern, where both fill alike and
    ``c`` (:data:`KEYS_NEUTRAL_AT`) leaves every grid-pattern run's settings hash as it was.

    Example:
        >>> decoder_fill_for("foveal"), decoder_fill_for("downsample")
        ('fr', 'c')
    """
    return "fr" if str(pattern_kind) == "foveal" else "c"


def register_resolvers() -> None:
    """Register the project's resolvers once (``${imls_hash:...}``, ``${imls_monitor_mode:...}``, ``${imls_decoder_fill:...}``)."""
    if not OmegaConf.has_resolver("imls_hash"):
        OmegaConf.register_new_resolver("imls_hash", lambda *parts: settings_hash(*parts))
    if not OmegaConf.has_resolver("imls_monitor_mode"):
        OmegaConf.register_new_resolver("imls_monitor_mode", monitor_mode)
    if not OmegaConf.has_resolver("imls_decoder_fill"):
        OmegaConf.register_new_resolver("imls_decoder_fill", decoder_fill_for)


def checkpoint_problem(path: str | Path) -> str | None:
    """Why ``path`` is not an intact checkpoint file (short phrase), or None when it is one.

    ``torch.save`` writes a zip archive whose members carry CRC-32s: a truncated file has no
    central directory, a changed byte fails its member's CRC (which ``torch.load`` does not check).
    Costs one read of the file.
    """
    p = Path(str(path)).expanduser()
    if not p.is_file():
        return "file not found"
    try:
        with zipfile.ZipFile(p) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError) as err:
        return f"not a loadable checkpoint (truncated, damaged or another kind of file: {type(err).__name__})"
    if bad is not None:
        return f"not a loadable checkpoint (damaged: its member {bad} fails its CRC-32)"
    return None


def load_checkpoint(path: str | Path, *, what: str = "checkpoint") -> dict:
    """Load a Lightning checkpoint safely (``weights_only=True``) on the CPU, after checking that
    the file is intact (:func:`checkpoint_problem`).

    Raises:
        InputError: the file is missing, damaged or is not a checkpoint of this project.
    """
    p = Path(str(path)).expanduser()
    problem = checkpoint_problem(p)
    if problem is not None:
        raise InputError(f"{what}={path}: {problem}")
    try:
        ckpt = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as err:  # unpickling errors of all kinds
        raise InputError(f"{what}={path}: not a loadable checkpoint ({type(err).__name__}: {str(err).splitlines()[0][:120]})") from None
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt or "hyper_parameters" not in ckpt:
        raise InputError(f"{what}={path}: not a Lightning checkpoint of this project (no state_dict/hyper_parameters)")
    return ckpt
