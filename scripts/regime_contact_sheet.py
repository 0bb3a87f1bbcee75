"""One picture of the paper-regime scenes: per scene, the first view of its before-training estimate's contact
sheet (the FR render | bilinear from the C-Image | the error x4), labelled, one row per scene.

The estimates are those of an estimates table (``python -m imls_lightning.estimate ... table=...``), so the picture
shows exactly the volumes, transfer functions and cameras the table measured.

    python scripts/regime_contact_sheet.py benchmarks/paper_regime_estimates.csv benchmarks/paper_regime_contact_sheet.png \\
        rayleigh_taylor flame_sheets seed_shell ct_head
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.atomic import atomic_write  # noqa: E402
from data_gen.errors import InputError, cli_errors  # noqa: E402


def scene_rows(table: Path, scenes: list[str], recnn: str = "enhancenet") -> list[tuple[str, np.ndarray]]:
    """``(label, first row of the scene's estimate contact sheet)`` per scene, in order (refused in one line when
    the table has no estimate of a scene, or its contact sheet is missing)."""
    from PIL import Image

    try:
        rows = {r["scene"]: r for r in csv.DictReader(table.open(encoding="utf-8")) if r.get("recnn") == recnn}
    except OSError as err:
        raise InputError(f"{table}: cannot read the estimates table ({err.strerror})") from None
    out = []
    for scene in scenes:
        if scene not in rows:
            raise InputError(f"{scene}: no {recnn} estimate in {table} (run python -m imls_lightning.estimate scene={scene} table={table})")
        est_path = Path(rows[scene]["path"])
        try:
            est = json.loads(est_path.read_text())
            sheet = np.asarray(Image.open(est["contact_sheet"]).convert("RGB"))
        except (OSError, ValueError, KeyError) as err:
            raise InputError(f"{est_path}: no readable estimate with a contact sheet ({err})") from None
        n_views = len(est.get("bilinear_db_per_view") or [1])
        label = f"{scene} ({est['volume_dims']}, bilinear {est['bilinear_db_per_view'][0]:.1f} dB)"
        out.append((label, sheet[: sheet.shape[0] // n_views]))
    return out


def draw(rows: list[tuple[str, np.ndarray]], path: Path) -> Path:
    """Stack the rows with a label on each and the column titles on the first."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(np.concatenate([r for _, r in rows], axis=0))
    pen = ImageDraw.Draw(img)
    tile = rows[0][1].shape[1] // 3
    y = 0
    for i, (label, row) in enumerate(rows):
        pen.text((6, y + 4), label, fill=(255, 255, 255))
        if i == 0:
            pen.text((tile + 6, y + 4), "bilinear from the C-Image", fill=(255, 255, 255))
            pen.text((2 * tile + 6, y + 4), "|error| x 4", fill=(255, 255, 255))
        y += row.shape[0]
    return atomic_write(path, lambda f: img.save(f, format="PNG"))


@cli_errors
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--recnn", default="enhancenet")
    a = ap.parse_args(argv)
    print(draw(scene_rows(a.table, a.scenes, a.recnn), a.out))


if __name__ == "__main__":
    main()
