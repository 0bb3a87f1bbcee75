"""Settings shared by the cache's test modules (one home: cache, reader, workers, contact sheet)."""
from __future__ import annotations

from pathlib import Path

# VTK's fixed-point mapper: deterministic, and fast enough for 24^2 test caches
VTK = {"name": "vtk", "mapper": "fixed_point"}


def cache_data(tmp_path, **kw) -> dict:
    """A small ``data`` config node (10 views + 6 test views at 24^2) caching under ``tmp_path/cache``;
    ``kw`` overrides or adds keys."""
    d = {"num_views": 10, "test_views": 6, "resolution": 24, "workers": 0, "seed": 0,
         "cache_dir": str(tmp_path / "cache")}
    d.update(kw)
    return d


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie or a dead process does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")
