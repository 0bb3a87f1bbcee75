"""One home for atomic file writes.

Every file the tools write that another run may read later (cache arrays and manifests, label
markers, training results, reports, images) goes through :func:`atomic_write`: the bytes go to a
temporary sibling, are flushed and fsynced, and the sibling is renamed over the target; the folder is
fsynced too. A crash leaves the old file or the new one, never a mix; a failed write removes its
temporary file.

Temporary names: ``<name>.tmp`` by default (the cache and the label sets know that suffix and clean
it up); ``unique=True`` adds the process id (``.<name>.<pid>.tmp``) where several processes may write
the same file at once (reports).

Example:
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> atomic_json(d / "a.json", {"b": 1}).read_text()
    '{\\n "b": 1\\n}\\n'
    >>> sorted(p.name for p in d.iterdir())
    ['a.json']
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, BinaryIO, Callable

__all__ = ["fsync_dir", "atomic_write", "atomic_write_text", "atomic_json", "atomic_npy"]


def fsync_dir(path: str | Path) -> None:
    """fsync a folder, so a rename inside it reaches the disk (best effort: some filesystems refuse)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path: str | Path, write: Callable[[BinaryIO], Any], unique: bool = False) -> Path:
    """Write ``path`` through ``write(binary file)`` on a temporary sibling, fsync, rename; returns ``path``.

    ``unique``: the temporary name holds this process's id, so that several writers never share one; those a
    killed writer left (its process gone) are removed first.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if unique:
        from .orphans import remove_stale_temporaries

        remove_stale_temporaries(p)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp" if unique else p.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)  # only left when the write or the rename failed
    fsync_dir(p.parent)
    return p


def atomic_write_text(path: str | Path, text: str, unique: bool = False) -> Path:
    """:func:`atomic_write` of UTF-8 text (newlines kept as given)."""
    return atomic_write(path, lambda f: f.write(text.encode("utf-8")), unique=unique)


def atomic_json(path: str | Path, obj: Any, default: Callable[[Any], Any] | None = str, indent: int = 1,
                sort_keys: bool = True) -> Path:
    """:func:`atomic_write` of ``obj`` as JSON (one trailing newline)."""
    return atomic_write_text(path, json.dumps(obj, indent=indent, sort_keys=sort_keys, default=default) + "\n")


def atomic_npy(path: str | Path, arr: Any, unique: bool = False) -> Path:
    """:func:`atomic_write` of a NumPy array in ``.npy`` format (no pickles)."""
    import numpy as np

    return atomic_write(path, lambda f: np.save(f, arr, allow_pickle=False), unique=unique)
