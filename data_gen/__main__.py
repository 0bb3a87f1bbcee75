"""``python -m data_gen scene=NAME data.num_views=N data.resolution=M data.cache_dir=DIR``

Renders (or completes) the (view, image) cache of a scene with a progress bar on stderr, prints a
summary, optionally writes a contact sheet (``contact_sheet=true`` or ``contact_sheet=PATH``), and
prints the cache directory as the last line of stdout. Bad input: one line ``error: ...`` on
stderr, exit status 2.

Examples::

    python -m data_gen scene=tiny data=tiny                      # CI scale, a second
    python -m data_gen scene=ct_head data=small contact_sheet=true
    python -m data_gen scene=file scene.volume.path=/data/engine_256x256x128_uint8.raw
    python -m data_gen scene=ct_head renderer.mapper=gpu          # paper scale on a GPU machine
"""
from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import cli_errors, checked_command_line

CONF_DIR = str(Path(__file__).resolve().parents[1] / "conf")


@checked_command_line(CONF_DIR, "data_gen")
@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="data_gen")
@cli_errors
def main(cfg: DictConfig) -> None:
    from data_gen.cache import ViewImageCache, render_cache
    from data_gen.scenes import build_scene

    scene = build_scene(cfg.scene)
    report = render_cache(scene, cfg.data, cfg.renderer, progress=bool(cfg.get("progress", True)))
    print(report.summary(), file=sys.stderr, flush=True)
    sheet = cfg.get("contact_sheet", False)
    if sheet not in (None, False, "false", "False", ""):
        from data_gen.contact_sheet import write_contact_sheet

        out = None if sheet in (True, "true", "True") else str(sheet)
        png = write_contact_sheet(ViewImageCache.open(report.path), out, num=int(cfg.get("contact_sheet_views", 24)))
        print(f"contact sheet: {png}", flush=True)
    print(report.path, flush=True)


if __name__ == "__main__":
    main()
