"""data_gen.contact_sheet: which views a contact sheet picks, and the sheet written from a real cache."""
from __future__ import annotations

from data_gen.cache import ViewImageCache, render_cache
from tests.data_gen.helpers import VTK
from tests.data_gen.helpers import cache_data as _data


def test_contact_sheet_sample_covers_splits(tmp_path, tiny_scene):
    from PIL import Image

    from data_gen.contact_sheet import pick_views, write_contact_sheet

    path = render_cache(tiny_scene, _data(tmp_path), VTK, progress=False).path
    c = ViewImageCache.open(path)
    picks = pick_views(c.splits, 8)
    assert len(picks) == 8 and {s for _, s in picks} == {"train", "val", "test"}
    assert all(i in c.splits[s] for i, s in picks)
    png = write_contact_sheet(c, tmp_path / "sheet.png", num=8, columns=4)
    assert Image.open(png).size == (4 * 96, 2 * (96 + 14))
