"""IML labels for training the IMS network: per cached view, the importance mask that a trained IML
encoder gives in inference mode and the continuous PIM' behind it.

Once the IML network is trained, the paper collects (view, IM) pairs to train the IMS network by
supervised learning. :func:`ensure_labels` runs the IML encoder over every row of a view/image
cache (train, val and the test trajectory) and stores, next to the cache::

    <cache>/labels/iml-<sha256 of the IML checkpoint file, 16 hex>/
        meta.json        checkpoint path + hash, mean u, alpha, c_size, fr_size, pattern (config and
                         fingerprint), rows, chunk size; when complete also per-split counts and
                         label IPR / C-share statistics. Written at initialisation (complete=false)
                         and rewritten, atomically, when the last chunk is done.
        im.npy           (N, n, ceil(n / 8)) uint8: the hard IM, one bit per pixel
                         (``np.packbits`` along the columns, big bit order); 0 on C-Image padding
        pim.npy          (N, n, n) float32: PIM', the normalized importance the IM was sampled from
                         (``IM = PIM' > P``, P the plastic rank pattern, and IM = 0 on padding)
        chunks/<a>-<b>.json   completion marker of rows a..b-1 (CRC-32 of their bytes)
        .lock            one writer at a time (fcntl)

Crash safety (like the cache). Rows are labelled in chunks; a chunk's marker is written atomically
(temporary file, fsync, rename) only after its rows were written to the memory-mapped arrays and
flushed to disk (``msync``). After a crash or ``kill -9`` at any moment every marked chunk has its
data; unmarked chunks are labelled again by the next run. When every chunk is marked the meta file
is rewritten with ``complete: true``: a complete set is returned at once (nothing is recomputed),
and :meth:`ImportanceLabels.open` refuses sets that are not complete.

Example:
    >>> path = ensure_labels(cache_dir, "runs/iml-.../checkpoints/epoch012.ckpt")  # doctest: +SKIP
    >>> lab = ImportanceLabels.open(path)                                         # doctest: +SKIP
    >>> lab.im(0).shape, lab.im(0).dtype, lab.pim(0).dtype                        # doctest: +SKIP
    ((64, 64), dtype('uint8'), dtype('float32'))
"""
from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import shutil
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch

from imls_lightning.base.atomic import atomic_json, fsync_dir
from imls_lightning.base.errors import InputError

from ..core.compaction import compact
from ..base.config import file_hash
from ..tasks.checkpoint_checks import check_resolution

__all__ = ["ensure_labels", "labels_path_for", "ImportanceLabels", "LABELS_FORMAT", "label_iml"]

LABELS_FORMAT = 1
META, IM, PIM, CHUNKS, LOCK = "meta.json", "im.npy", "pim.npy", "chunks", ".lock"


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    with open(path, "a+b") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)  # a second process (e.g. another DDP rank) waits here
        try:
            yield
        finally:
            fcntl.flock(f.fileno(), fcntl.LOCK_UN)


def _chunk_name(a: int, b: int) -> str:
    return f"{a:08d}-{b:08d}.json"


def _read_marker(path: Path) -> dict | None:
    try:
        m = json.loads(path.read_text())
    except (OSError, ValueError):
        return None  # a torn or foreign file is not a marker: that chunk is redone
    return m if isinstance(m, dict) and "rows" in m else None


def _crc(a: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(a).tobytes()) & 0xFFFFFFFF


# ---------------------------------------------------------------------------------------------
# labelling
# ---------------------------------------------------------------------------------------------
def labels_path_for(cache_path: str | Path, iml_checkpoint: str | Path) -> Path:
    """``<cache>/labels/iml-<sha256(checkpoint file)[:16]>`` (computes nothing else).

    Raises:
        InputError: the checkpoint file does not exist.
    """
    ck = Path(str(iml_checkpoint)).expanduser()
    if not ck.is_file():
        raise InputError(f"iml.checkpoint={iml_checkpoint}: file not found")
    return Path(str(cache_path)).expanduser() / "labels" / f"iml-{file_hash(ck, 16)}"


@torch.no_grad()
def label_iml(iml, pattern, images_uint8: np.ndarray, device: torch.device) -> tuple[np.ndarray, np.ndarray]:
    """IML labels of a batch of FR-Images.

    Args:
        iml: an :class:`~imls_lightning.models.iml.IMLNet` (eval mode, on ``device``).
        pattern: its :class:`~imls_lightning.core.patterns.SamplingPattern`.
        images_uint8: ``(B, m, m, 3)`` uint8 FR-Images.

    Returns:
        ``im`` ``(B, n, n)`` bool (hard rejection sampling, 0 on padding) and ``pim`` ``(B, n, n)``
        float32 PIM'.
    """
    x = torch.from_numpy(np.array(images_uint8, dtype=np.uint8)).to(device).permute(0, 3, 1, 2).float().div_(255.0)
    c = compact(x, pattern.indices.to(device), pattern.c_size)
    _, pim_norm = iml.encode(c)
    im = iml.sample(pim_norm, hard=True) > 0.5
    return im[:, 0].cpu().numpy(), pim_norm[:, 0].float().cpu().numpy()


def _resolve_device(device: str | torch.device) -> torch.device:
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        return torch.device(device)
    except (RuntimeError, TypeError):
        raise InputError(f"device={device!r}: expected 'auto', 'cpu', 'cuda' or 'cuda:N'") from None


def _stats(values: np.ndarray) -> dict[str, float]:
    if values.size == 0:
        return {"mean": None, "std": None, "min": None, "max": None}
    v = values.astype(np.float64)
    return {"mean": float(v.mean()), "std": float(v.std()), "min": float(v.min()), "max": float(v.max())}


def ensure_labels(
    cache_path: str | Path,
    iml_checkpoint: str | Path,
    batch_size: int = 16,
    device: str | torch.device = "auto",
    progress: bool = True,
    chunk_size: int = 128,
) -> Path:
    """Label every row of a view/image cache with a trained IML encoder (resumable); see the module doc.

    Args:
        cache_path: a complete cache directory (:func:`data_gen.cache.ensure_cache`).
        iml_checkpoint: an ``IMLTask`` checkpoint (standalone or end-to-end); its ``fr_size`` must be
            the cache's resolution.
        batch_size: views per encoder call.
        device: ``"auto"`` (CUDA when available), ``"cpu"``, ``"cuda"``, ...
        progress: show a tqdm bar.
        chunk_size: rows per completion marker (a killed run loses at most one chunk of work).

    Returns:
        the label directory ``<cache>/labels/iml-<hash16>`` (complete).

    Raises:
        InputError: missing/foreign checkpoint, incomplete cache, resolution mismatch, bad sizes.
    """
    from data_gen.cache import ViewImageCache

    from ..tasks.iml import IMLTask

    if not (isinstance(batch_size, int) and batch_size >= 1):
        raise InputError(f"labels batch_size={batch_size}: expected an integer >= 1")
    if not (isinstance(chunk_size, int) and chunk_size >= 1):
        raise InputError(f"labels chunk_size={chunk_size}: expected an integer >= 1")
    out = labels_path_for(cache_path, iml_checkpoint)
    if _is_complete(out):
        return out  # nothing to do: not even the checkpoint is loaded
    cache = ViewImageCache.open(cache_path)
    task = IMLTask.from_checkpoint(iml_checkpoint, what="iml.checkpoint")
    hp = task.hparams
    m = cache.resolution
    check_resolution(hp, m, key="iml.checkpoint", path=iml_checkpoint, network="IML", against=f"the cache {cache.path} holds",
                     hint=f"use data.resolution={hp['fr_size']}")
    pattern = task.pattern
    n, N = pattern.c_size, len(cache)
    packed_cols = (n + 7) // 8
    meta = {
        "format": LABELS_FORMAT,
        "checkpoint": str(Path(str(iml_checkpoint)).expanduser().resolve()),
        "checkpoint_sha256": out.name[len("iml-"):],
        "cache": str(Path(cache.path).resolve()),
        "rows": N,
        "fr_size": m,
        "c_size": n,
        "pattern": hp["pattern"],
        "pattern_fingerprint": pattern.fingerprint(),
        "pattern_count": pattern.count,
        "mean": float(hp["mean"]),
        "alpha": float(hp["alpha"]),
        "iml_mode": hp.get("mode"),
        "im_encoding": "np.packbits(axis=-1, bitorder=big)",
        "chunk_size": chunk_size,
        "complete": False,
    }
    out.mkdir(parents=True, exist_ok=True)
    with _locked(out / LOCK):
        if _is_complete(out):
            return out  # another process finished it while we waited for the lock
        _initialise(out, meta, N, n, packed_cols)
        meta = json.loads((out / META).read_text())  # the chunking of the run that started it
        chunk = int(meta["chunk_size"])
        chunks = [(a, min(a + chunk, N)) for a in range(0, N, chunk)]
        done = {c for c in chunks if _read_marker(out / CHUNKS / _chunk_name(*c)) is not None}
        todo = [c for c in chunks if c not in done]
        dev = _resolve_device(device)
        iml = task.iml.to(dev).eval()
        im_mm = np.load(out / IM, mmap_mode="r+")
        pim_mm = np.load(out / PIM, mmap_mode="r+")
        from tqdm.auto import tqdm

        bar = tqdm(total=N, initial=sum(b - a for a, b in done), desc=f"IML labels {out.name}", unit="view",
                   disable=not progress, leave=False)
        try:
            for a, b in todo:
                for s in range(a, b, batch_size):
                    e = min(s + batch_size, b)
                    im, pim = label_iml(iml, pattern, cache.images[s:e], dev)
                    im_mm[s:e] = np.packbits(im, axis=-1)
                    pim_mm[s:e] = pim
                    bar.update(e - s)
                # data first (msync), marker last: a marker always vouches for flushed rows
                im_mm.flush()
                pim_mm.flush()
                _write_marker(out, a, b, im_mm[a:b], pim_mm[a:b])
        finally:
            bar.close()
            del im_mm, pim_mm
        _complete(out, meta, cache, pattern)
    return out


def _is_complete(out: Path) -> bool:
    try:
        meta = json.loads((out / META).read_text())
    except (OSError, ValueError):
        return False
    return bool(meta.get("complete")) and meta.get("format") == LABELS_FORMAT


def _initialise(out: Path, meta: dict, N: int, n: int, packed_cols: int) -> None:
    """Create the arrays and meta (meta last) unless a compatible unfinished set is there."""
    try:
        old = json.loads((out / META).read_text())
    except (OSError, ValueError):
        old = None
    keys = ("format", "rows", "c_size", "fr_size", "pattern_fingerprint", "checkpoint_sha256")
    if old is not None and all(old.get(k) == meta[k] for k in keys) and (out / IM).is_file() and (out / PIM).is_file():
        return  # resume
    # fresh start (or leftovers of an initialisation that was interrupted / of another format)
    for name in (META, IM, PIM):
        for p in (out / name, out / (name + ".tmp")):
            p.unlink(missing_ok=True)
    shutil.rmtree(out / CHUNKS, ignore_errors=True)
    (out / CHUNKS).mkdir()
    for name, dtype, shape in ((IM, np.uint8, (N, n, packed_cols)), (PIM, np.float32, (N, n, n))):
        tmp = out / (name + ".tmp")
        mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=shape)  # sparse file
        del mm
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, out / name)
    meta = dict(meta, created=_now())
    atomic_json(out / META, meta)


def _write_marker(out: Path, a: int, b: int, im_rows: np.ndarray, pim_rows: np.ndarray) -> None:
    atomic_json(out / CHUNKS / _chunk_name(a, b), {"rows": [a, b], "crc_im": _crc(im_rows), "crc_pim": _crc(pim_rows)})


def _complete(out: Path, meta: dict, cache, pattern) -> None:
    """Per-split statistics of the labels, then meta.json with ``complete: true``."""
    lab = ImportanceLabels(out, meta, np.load(out / IM, mmap_mode="r"), np.load(out / PIM, mmap_mode="r"))
    bits = lab.bits_per_row()
    m2 = float(pattern.fr_size) ** 2
    stats, counts = {}, {}
    for split, rows in cache.splits.items():
        rows = np.asarray(rows, np.int64)
        counts[split] = int(len(rows))
        stats[split] = {"ipr": _stats(bits[rows] / m2), "c_share": _stats(bits[rows] / float(pattern.count))}
    stats["all"] = {"ipr": _stats(bits / m2), "c_share": _stats(bits / float(pattern.count))}
    meta = dict(meta, complete=True, finished=_now(), counts=counts, stats=stats)
    atomic_json(out / META, meta)


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
@dataclass
class ImportanceLabels:
    """A complete label set opened read-only (memory-mapped).

    Attributes:
        path: the label directory.
        meta: its ``meta.json``.
        packed_im: ``(N, n, ceil(n / 8))`` uint8, the bit-packed IMs.
        pim_all: ``(N, n, n)`` float32 PIM'.

    Example:
        >>> lab = ImportanceLabels.open(path)    # doctest: +SKIP
        >>> lab.im(3).sum() / lab.fr_size**2     # the IPR of row 3   # doctest: +SKIP
    """

    path: Path
    meta: dict[str, Any]
    packed_im: np.ndarray = field(repr=False)
    pim_all: np.ndarray = field(repr=False)

    @classmethod
    def open(cls, path: str | Path) -> "ImportanceLabels":
        """Open a label directory made by :func:`ensure_labels`.

        Raises:
            InputError: not a label directory, or not complete (a run was interrupted).
        """
        p = Path(str(path)).expanduser()
        try:
            meta = json.loads((p / META).read_text())
        except (OSError, ValueError):
            raise InputError(f"labels {p}: not an IML label directory (no readable {META}); make it with imls_lightning.data.labels.ensure_labels") from None
        if meta.get("format") != LABELS_FORMAT:
            raise InputError(f"labels {p}: format {meta.get('format')} is not {LABELS_FORMAT}; delete the directory to relabel")
        if not meta.get("complete"):
            k = sum(1 for q in (p / CHUNKS).glob("*.json") if _read_marker(q) is not None) if (p / CHUNKS).is_dir() else 0
            raise InputError(f"labels {p}: incomplete ({k} chunks labelled, interrupted run); run the same training command (or ensure_labels) again to finish them")
        try:
            im = np.load(p / IM, mmap_mode="r", allow_pickle=False)
            pim = np.load(p / PIM, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError) as err:
            raise InputError(f"labels {p}: unreadable ({type(err).__name__}: {err})") from None
        n, N = int(meta["c_size"]), int(meta["rows"])
        if im.shape != (N, n, (n + 7) // 8) or pim.shape != (N, n, n):
            raise InputError(f"labels {p}: arrays have shapes {im.shape}, {pim.shape}, expected ({N}, {n}, {(n + 7) // 8}), ({N}, {n}, {n})")
        return cls(p, meta, im, pim)

    def __len__(self) -> int:
        return int(self.packed_im.shape[0])

    @property
    def c_size(self) -> int:
        return int(self.meta["c_size"])

    @property
    def fr_size(self) -> int:
        return int(self.meta["fr_size"])

    def im(self, row: int) -> np.ndarray:
        """``(n, n)`` uint8 in {0, 1}: the IM of cache row ``row``."""
        return np.unpackbits(self.packed_im[int(row)], axis=-1, count=self.c_size)

    def pim(self, row: int) -> np.ndarray:
        """``(n, n)`` float32: PIM' of cache row ``row`` (a copy)."""
        return np.array(self.pim_all[int(row)], dtype=np.float32)

    def bits_per_row(self) -> np.ndarray:
        """``(N,)`` int64 number of important pixels per row."""
        # padding bits past column n are always 0 (packbits pads with zeros)
        table = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(1)
        return table[np.asarray(self.packed_im)].reshape(len(self), -1).sum(1).astype(np.int64)

    def ipr(self) -> np.ndarray:
        """``(N,)`` float64 label IPR (important pixels / FR pixels)."""
        return self.bits_per_row() / float(self.fr_size) ** 2

    def verify(self) -> list[tuple[int, int]]:
        """Chunks whose bytes no longer match their marker's CRC-32 (empty when all is well)."""
        bad = []
        for q in sorted((self.path / CHUNKS).glob("*.json")):
            mk = _read_marker(q)
            if mk is None:
                continue
            a, b = mk["rows"]
            if _crc(self.packed_im[a:b]) != mk["crc_im"] or _crc(self.pim_all[a:b]) != mk["crc_pim"]:
                bad.append((a, b))
        return bad
