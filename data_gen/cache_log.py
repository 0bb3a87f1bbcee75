"""The cache's completion log and pixel checksums: which views are done, and are their pixels intact.

A view is done when its line in ``done.log`` (or a shard's ``done-shard-I-of-N.log``) is intact:
``<index> <crc32 of its pixels> <render seconds> <crc32 of the line>``. The line is appended only
after :func:`write_view` has written (and flushed) the pixels, so every logged view has them; their
CRC-32 is checked against the log (:func:`bad_views`) whenever a cache is opened or rendered,
once per process while its files do not change (:func:`remember_checked`).

Example:
    >>> import tempfile
    >>> log_path = Path(tempfile.mkdtemp()) / "done.log"
    >>> log = CompletionLog(log_path, fsync=False)
    >>> log.append(1, 0xDEADBEEF, 0.5)
    >>> log.close()
    >>> done, crc, seconds = read_log(log_path, 3)
    >>> done.tolist(), hex(int(crc[1])), float(seconds[1])
    ([False, True, False], '0xdeadbeef', 0.5)
"""
from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np

from .cache_keys import IMAGES, LOG, SHARD_LOGS


def _log_line(index: int, crc: int, seconds: float) -> bytes:
    body = f"{int(index)} {int(crc) & 0xFFFFFFFF:08x} {float(seconds):.9f}"
    return f"{body} {zlib.crc32(body.encode()) & 0xFFFFFFFF:08x}\n".encode()


def read_log(path: Path, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parse the completion log: ``(done (n,) bool, crc (n,) uint32, seconds (n,) float32)``.

    Lines that are torn (a crash while appending), fail their checksum or name an index outside
    ``[0, n)`` are ignored; for repeated indices the last intact line wins.
    """
    done = np.zeros(n, bool)
    crc = np.zeros(n, np.uint32)
    sec = np.full(n, np.nan, np.float32)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return done, crc, sec
    for raw in data.split(b"\n"):
        parts = raw.split(b" ")
        if len(parts) != 4:
            continue
        body = b" ".join(parts[:3])
        try:
            if int(parts[3], 16) != zlib.crc32(body) & 0xFFFFFFFF:
                continue
            i, c, s = int(parts[0]), int(parts[1], 16), float(parts[2])
        except ValueError:
            continue
        if 0 <= i < n and np.isfinite(s):
            done[i], crc[i], sec[i] = True, c, s
    return done, crc, sec


def read_logs(cache_dir: Path, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`read_log` of ``done.log`` merged with every shard's ``done-shard-I-of-N.log``."""
    done, crc, sec = read_log(cache_dir / LOG, n)
    for p in sorted(cache_dir.glob(SHARD_LOGS)):
        d2, c2, s2 = read_log(p, n)
        done[d2], crc[d2], sec[d2] = True, c2[d2], s2[d2]
    return done, crc, sec


def bad_views(images: np.ndarray, rows, crc: np.ndarray) -> np.ndarray:
    """Rows of ``images`` (``(N, m, m, 3)``, e.g. memory-mapped) whose CRC-32 is not ``crc[row]``.

    One CRC-32 per view: about 0.4 ms for a 512x512 view in the page cache, over 1000x less than
    rendering it (0.45-0.55 s for the tiny scene on 2 CPU cores; ``scripts/measure_pixel_check.py``, removed after its
    result was committed: ``git show 97cc83f:scripts/measure_pixel_check.py``).
    """
    bad = [int(i) for i in np.asarray(rows, np.int64)
           if zlib.crc32(np.ascontiguousarray(images[i])) & 0xFFFFFFFF != int(crc[i])]
    return np.asarray(bad, np.int64)


#: caches whose every logged view was checked in this process: path -> file signature at that time
_CHECKED: dict[str, tuple] = {}


def _signature(path: Path) -> tuple | None:
    try:
        files = [path / IMAGES, path / LOG, *sorted(path.glob(SHARD_LOGS))]
        return tuple((f.name, st.st_ino, st.st_size, st.st_mtime_ns) for f in files if f.exists() for st in [f.stat()])
    except OSError:
        return None


def remember_checked(path: Path) -> None:
    """Note that every logged view of the cache at ``path`` was checked (or written) just now."""
    sig = _signature(path)
    if sig is not None:
        _CHECKED[str(path.absolute())] = sig


def checked_already(path: Path) -> bool:
    """Whether :func:`remember_checked` noted ``path`` and its files have not changed since."""
    sig = _CHECKED.get(str(path.absolute()))
    return sig is not None and sig == _signature(path)


def forget_checked() -> None:
    """Forget every :func:`remember_checked` (the next open checks the pixels again, as a new process would)."""
    _CHECKED.clear()


class CompletionLog:
    """Append-only completion log (parent process only): one checksummed line per finished view."""

    def __init__(self, path: Path, fsync: bool):
        self._f = open(path, "ab")
        self._fsync = fsync
        # a torn last line from a crash: start on a fresh line so the next record parses
        if self._f.tell() > 0:
            with open(path, "rb") as r:
                r.seek(-1, os.SEEK_END)
                if r.read(1) != b"\n":
                    self._f.write(b"\n")

    def append(self, index: int, crc: int, seconds: float) -> None:
        self._f.write(_log_line(index, crc, seconds))
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


def write_view(fd: int, img: np.ndarray, index: int, data_offset: int, fsync: bool) -> int:
    """Write one view's pixels in place into ``images.npy`` (open as ``fd``, data at ``data_offset``),
    flushed to disk when ``fsync``; returns their CRC-32 (what the completion log records)."""
    b = np.ascontiguousarray(img, dtype=np.uint8).tobytes()
    pos, view = data_offset + index * len(b), memoryview(b)
    while view:  # pwrite may write less than asked
        k = os.pwrite(fd, view, pos)
        view, pos = view[k:], pos + k
    if fsync:
        os.fdatasync(fd)
    return zlib.crc32(b) & 0xFFFFFFFF


__all__ = ["read_log", "read_logs", "bad_views", "remember_checked", "checked_already", "forget_checked",
           "CompletionLog", "write_view"]
