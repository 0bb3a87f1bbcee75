"""Memory of a paper-size volume: stream a procedural field of the Flame dataset's size
(1408 x 1080 x 1100 float32 = 6.7 GB) to a .raw file, open it the way training does
(``experiment=large_flame``: memory-mapped), render a few cache views with ``renderer=numba``, and
report the peak memory of each phase against the file size.

    python scripts/measure_large_volume.py                          # full size into cache/volumes/ (~7 GB)
    python scripts/measure_large_volume.py --dims 512 512 512 --out /tmp/vol --json mem.json

What is measured (Linux, ``/proc/self/status`` sampled every 10 ms by a thread, plus
``resource.getrusage`` and ``tracemalloc``):

* ``anon``: private memory (``RssAnon``: heap, numpy arrays). A second in-RAM copy of the volume
  would show here as the file size; streaming and memory-mapping keep it small.
* ``anon +``: its rise during the phase (what the phase itself allocated).
* ``mapped``: resident pages of the volume file's memory map (``/proc/self/smaps``; part of
  ``RssFile``, which also counts the shared libraries). Touching every
  voxel of the memory map (value-range scan, empty-space bricks, ray marching) makes them resident:
  shared page cache that the kernel evicts under pressure, not a copy owned by the process.
* ``ru_maxrss``: the kernel's lifetime peak of anon + file; ``tracemalloc``: peak of the
  allocations Python and numpy made in the phase.

Writes ``<out>/flame_XxYxZ_float32.raw`` (default ``cache/volumes/``, where ``experiment=large_flame``
looks for the full-size file; kept unless ``--remove``; an existing complete file is reused) and the
views' cache under ``--cache-dir``. The numbers go to stdout as a table and, with
``--json``, to a file.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import shutil
import sys
import threading
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.errors import InputError, cli_errors  # noqa: E402

FLAME_DIMS = (1408, 1080, 1100)  # the paper's Flame dataset (Table 1)


def _status_kb() -> dict[str, int]:
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "RssAnon", "RssFile", "RssShmem"):
                out[key] = int(rest.split()[0])
    return out


def _mapped_rss_kb(path: str) -> int:
    """Resident kB of this process's mappings of ``path`` (``/proc/self/smaps``)."""
    total, inside = 0, False
    with open("/proc/self/smaps") as f:
        for line in f:
            first = line.split(None, 1)[0]
            if "-" in first and not first.endswith(":"):  # a mapping's header line
                inside = line.rstrip().endswith(path)
            elif inside and first == "Rss:":
                total += int(line.split()[1])
    return total


class MemorySampler:
    """Peaks of ``RssAnon`` / ``RssFile`` / ``VmRSS`` per phase, sampled by a background thread
    (every ``interval`` s), and of the resident pages mapped from ``watch`` (every 20th sample:
    smaps is long)."""

    def __init__(self, interval: float = 0.01, watch: str | None = None):
        self.interval = interval
        self.watch = watch
        self._n = 0
        self.phases: list[dict] = []
        self._peak: dict[str, int] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self, smaps: bool = False) -> None:
        s = _status_kb()
        self._n += 1
        if self.watch and (smaps or self._n % 20 == 0):
            s["mapped"] = _mapped_rss_kb(self.watch)
        with self._lock:
            for k, v in s.items():
                self._peak[k] = max(self._peak.get(k, 0), v)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            time.sleep(self.interval)

    @contextlib.contextmanager
    def phase(self, name: str, **info):
        with self._lock:
            self._peak = {}
        self._sample(smaps=True)
        start = _status_kb()
        tracemalloc.start()
        t0 = time.perf_counter()
        try:
            yield info
        finally:
            seconds = time.perf_counter() - t0
            _, traced_peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            self._sample(smaps=True)
            with self._lock:
                peak = dict(self._peak)
            self.phases.append({
                "phase": name, "seconds": round(seconds, 2),
                "peak_anon_mb": round(peak.get("RssAnon", 0) / 1024, 1),
                "anon_increase_mb": round((peak.get("RssAnon", 0) - start.get("RssAnon", 0)) / 1024, 1),
                "peak_file_mb": round(peak.get("RssFile", 0) / 1024, 1),
                "peak_volume_mapped_mb": round(peak.get("mapped", 0) / 1024, 1),
                "peak_rss_mb": round(peak.get("VmRSS", 0) / 1024, 1),
                "tracemalloc_peak_mb": round(traced_peak / 2**20, 1),
                **info,
            })

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dims", type=int, nargs=3, default=list(FLAME_DIMS), metavar=("X", "Y", "Z"),
                   help="volume size (default: the Flame dataset's 1408 1080 1100)")
    p.add_argument("--out", default="cache/volumes", help="directory for the .raw file (default: cache/volumes/)")
    p.add_argument("--cache-dir", default="cache", help="data.cache_dir of the rendered views (default: cache/)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--chunk-z", type=int, default=4, help="z-slices per slab while writing (default 4: ~10 slab-sized temporaries of the generator)")
    p.add_argument("--views", type=int, default=4, help="cache views to render (default 4)")
    p.add_argument("--resolution", type=int, default=64, help="cache image side (default 64)")
    p.add_argument("--threads", type=int, default=0, help="numba render threads (0: all cores)")
    p.add_argument("--remove", action="store_true", help="delete the .raw file and the cache afterwards")
    p.add_argument("--json", default=None, help="also write the results to this JSON file")
    return p.parse_args(argv)


def _compose_scene(raw: Path):
    """The ``experiment=large_flame`` scene node with the file's path (as the train CLI composes it)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from data_gen.scene import register_resolvers

    register_resolvers()
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("data_gen", overrides=["+experiment=large_flame", f"scene.volume.path={raw}"])
    return OmegaConf.to_container(cfg.scene, resolve=True)


@cli_errors
def main(argv=None) -> dict:
    import numpy as np

    from data_gen.cache import ViewImageCache, render_cache
    from data_gen.procedural import write_procedural_raw
    from data_gen.renderers import make_renderer
    from data_gen.scene import build_scene

    a = parse_args(argv)
    dims = tuple(int(d) for d in a.dims)
    if min(dims) < 2:
        raise InputError(f"--dims {dims}: expected three integers >= 2")
    if a.views < 1 or a.resolution < 8:
        raise InputError(f"--views {a.views} / --resolution {a.resolution}: expected >= 1 view and a side >= 8")
    out = Path(a.out).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    file_bytes = dims[0] * dims[1] * dims[2] * 4
    raw = out / f"flame_{dims[0]}x{dims[1]}x{dims[2]}_float32.raw"
    have = raw.is_file() and raw.stat().st_size == file_bytes
    free = shutil.disk_usage(out).free
    if not have and free < file_bytes + (1 << 30):
        raise InputError(f"--out {out}: {file_bytes / 1e9:.2f} GB needed for {raw.name} (+1 GB margin), only "
                         f"{free / 1e9:.2f} GB free; choose another --out or smaller --dims")
    print(f"volume {dims[0]} x {dims[1]} x {dims[2]} float32 = {file_bytes / 1e9:.2f} GB ({file_bytes / 2**30:.2f} GiB) -> {raw}",
          flush=True)

    mem = MemorySampler(watch=str(raw.resolve()))
    try:
        with mem.phase("write (stream slabs)", reused=have):
            t0 = time.perf_counter()
            write_procedural_raw("flame", dims, raw, seed=a.seed, chunk_z=a.chunk_z)
            if not have:
                print(f"  wrote in {time.perf_counter() - t0:.0f} s", flush=True)
        with mem.phase("open (memmap + value-range scan)"):
            scene = build_scene(_compose_scene(raw))
            data = scene.volume.data
            assert isinstance(data, np.memmap) and Path(data.filename).resolve() == raw.resolve(), "volume not memory-mapped"
        with mem.phase("renderer (numba: bricks, JIT)"):
            renderer = make_renderer(scene, {"name": "numba", "threads": a.threads})
            del renderer  # the cache makes its own; this phase isolates construction
        data_cfg = {"num_views": a.views, "test_views": 0, "val_fraction": 0.0, "resolution": a.resolution,
                    "workers": 0, "cache_dir": str(Path(a.cache_dir).expanduser()), "fsync": False}
        with mem.phase("cache (render views in-process)", views=a.views, resolution=a.resolution):
            report = render_cache(scene, data_cfg, {"name": "numba", "threads": a.threads}, progress=False)
        cache = ViewImageCache.open(report.path)
        lit = [float((np.asarray(cache.images[i]).max(axis=2) > 10).mean()) for i in range(len(cache))]
    finally:
        mem.close()

    usage = resource.getrusage(resource.RUSAGE_SELF)
    result = {
        "dims_xyz": list(dims), "file": str(raw), "file_mb": round(file_bytes / 2**20, 1),
        "ru_maxrss_mb": round(usage.ru_maxrss / 1024, 1),
        "peak_anon_mb": max(p["peak_anon_mb"] for p in mem.phases),
        "max_anon_increase_mb": max(p["anon_increase_mb"] for p in mem.phases),
        "phases": mem.phases,
        "render_seconds_per_view": round(float(np.nanmean(cache.render_seconds)), 3),
        "lit_pixel_share_per_view": [round(x, 3) for x in lit],
        "cache": str(report.path),
    }
    print(f"\n{'phase (peaks, MiB)':34s} {'s':>7s} {'anon':>8s} {'anon +':>8s} {'mapped':>8s} {'RssFile':>8s} {'VmRSS':>8s} {'tracemalloc':>12s}")
    for p in mem.phases:
        print(f"{p['phase']:34s} {p['seconds']:7.1f} {p['peak_anon_mb']:8.1f} {p['anon_increase_mb']:8.1f} "
              f"{p['peak_volume_mapped_mb']:8.1f} {p['peak_file_mb']:8.1f} {p['peak_rss_mb']:8.1f} {p['tracemalloc_peak_mb']:12.1f}")
    print(f"\nfile {result['file_mb']:.0f} MiB; peak private (anon) memory {result['peak_anon_mb']:.0f} MiB "
          f"({100 * result['peak_anon_mb'] / result['file_mb']:.1f}% of the file), of which at most "
          f"{result['max_anon_increase_mb']:.0f} MiB allocated by one phase; ru_maxrss {result['ru_maxrss_mb']:.0f} MiB "
          f"(includes the resident file-backed pages of the memory map)")
    print(f"render call per view at {a.resolution}^2: {result['render_seconds_per_view']} s; lit pixels per view: "
          f"{result['lit_pixel_share_per_view']}")
    if a.json:
        Path(a.json).write_text(json.dumps(result, indent=1) + "\n")
    if a.remove:
        raw.unlink(missing_ok=True)
        shutil.rmtree(report.path, ignore_errors=True)
    return result


if __name__ == "__main__":
    main()
