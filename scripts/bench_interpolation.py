"""renderer.interpolation: cost per object and per background pixel (trilinear vs tricubic, skipping on, one
thread) and a contact sheet (trilinear | tricubic | difference x4) of the same views.

Run on one core: ``taskset -c 1 python scripts/bench_interpolation.py [--sheet docs/interpolation.png]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from data_gen.scenes import build_scene, preset_config
from imls_lightning.render.numba import NumbaRenderer

# far enough that the box leaves background around the object (the presets' camera_distance reaches 4.5)
VIEWS = {"marschner_lobb": [1.2, 1.9, 4.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
         "tiny": [1.6, 1.3, 4.3, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]}


def _median_ms(renderer, view, m, pixels, repeats):
    times = []
    for _ in range(repeats):
        renderer.render_pixels(view, m, pixels)
        times.append(renderer.last_render_seconds * 1e3)
    return float(np.median(times))


def measure(scene_name: str, m: int, repeats: int) -> None:
    scene = build_scene(preset_config(scene_name))
    view = VIEWS[scene_name]
    for interpolation in ("trilinear", "tricubic"):
        r = NumbaRenderer(scene, threads=1, skip_empty=True, interpolation=interpolation)
        r.render(view, m)
        samples = r.last_ray_samples.copy()
        obj = np.flatnonzero(samples > 1)  # rays that interpolated a sample
        bg = np.flatnonzero(samples <= 1)  # missed the box, or skipped all of it
        skipped = int(np.count_nonzero(samples == 1))
        full = _median_ms(r, view, m, np.arange(m * m), repeats)
        t_obj = _median_ms(r, view, m, obj, repeats)
        t_bg = _median_ms(r, view, m, bg, repeats)
        print(f"{scene_name:15s} {interpolation:9s} {m}^2 frame {full:7.2f} ms | object {obj.size:5d} px "
              f"{t_obj / obj.size * 1e3:6.2f} us/px ({samples[obj].mean() - 1:5.1f} samples) | background {bg.size:5d} px "
              f"{t_bg / max(bg.size, 1) * 1e3:5.3f} us/px ({skipped} of them skipped across the box)")


def sheet(path: str, m: int = 192) -> None:
    from PIL import Image, ImageDraw

    rows = []
    for name, view in VIEWS.items():
        scene = build_scene(preset_config(name))
        lin = NumbaRenderer(scene).render(view, m)
        cub = NumbaRenderer(scene, interpolation="tricubic").render(view, m)
        diff = np.clip(np.abs(lin.astype(int) - cub.astype(int)) * 4, 0, 255).astype(np.uint8)
        row = np.concatenate([lin, cub, diff], axis=1)
        img = Image.fromarray(row)
        draw = ImageDraw.Draw(img)
        for i, label in enumerate((f"{name}: trilinear", "tricubic (B-spline)", "|difference| x4")):
            draw.text((i * m + 6, 4), label, fill=(255, 255, 255))
        rows.append(np.asarray(img))
    # a 256-colour palette keeps the picture small in the repository
    Image.fromarray(np.concatenate(rows, axis=0)).quantize(256).save(path, optimize=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--sheet", default=None, help="write the contact sheet PNG here (skip the timing)")
    a = p.parse_args()
    if a.sheet:
        sheet(a.sheet)
        return
    for name in VIEWS:
        measure(name, a.resolution, a.repeats)


if __name__ == "__main__":
    main()
