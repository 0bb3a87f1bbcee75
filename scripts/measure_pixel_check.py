"""Cost of the cache's per-view pixel check (CRC-32, done each time a cache is opened or rendered)
against the cost of rendering one view, measured on a real cache.

    python scripts/measure_pixel_check.py --scene tiny --resolution 512 --views 8 --renderer numba

Renders a small cache into a temporary directory (or ``--cache-dir``), then times
``data_gen.cache.bad_views`` over all its views (the code ``ViewImageCache.open`` runs; the images
are in the page cache, as right after rendering) and prints one line: the median render-call time
per view (recorded in the cache), the check's time per view and their ratio.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="tiny")
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--renderer", default="numba", choices=["numba", "vtk"])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--cache-dir", default=None)
    a = ap.parse_args(argv)
    from data_gen.cache import ViewImageCache, bad_views, render_cache
    from data_gen.scene import build_scene, preset_config

    scene = build_scene(preset_config(a.scene))
    with tempfile.TemporaryDirectory() as tmp:
        d = {"num_views": a.views, "test_views": 0, "resolution": a.resolution, "workers": 0,
             "cache_dir": a.cache_dir or tmp}
        path = render_cache(scene, d, {"name": a.renderer}, progress=False).path
        c = ViewImageCache.open(path)
        rows = np.arange(len(c))
        t0 = time.perf_counter()
        for _ in range(a.repeats):
            assert len(bad_views(c.images, rows, c.crc)) == 0
        check = (time.perf_counter() - t0) / (a.repeats * len(rows))
        render = float(np.median(c.render_seconds))
    out = {"resolution": a.resolution, "renderer": a.renderer, "render_ms": 1e3 * render, "check_ms": 1e3 * check,
           "ratio": render / check}
    print(f"{a.scene} {a.resolution}x{a.resolution} {a.renderer}: render {out['render_ms']:.2f} ms/view (median render call), "
          f"pixel check {out['check_ms']:.3f} ms/view: {out['ratio']:.0f}x cheaper", flush=True)
    return out


if __name__ == "__main__":
    main()
