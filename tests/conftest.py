"""Shared fixtures: tiny analytic volumes and scenes, and the real-volume folder (skipped if absent)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
VOLUMES_DIR = Path(os.environ.get("IMLS_VOLUMES_DIR", ROOT.parent / "shared" / "volumes"))


@pytest.fixture(scope="session")
def volumes_dir() -> Path:
    """``../shared/volumes`` (or ``$IMLS_VOLUMES_DIR``); skips the test cleanly when it is absent."""
    if not VOLUMES_DIR.is_dir():
        pytest.skip(f"real volumes not available: {VOLUMES_DIR} does not exist (set IMLS_VOLUMES_DIR)")
    return VOLUMES_DIR


@pytest.fixture(scope="session")
def blob_volume():
    """A small anisotropic analytic volume (no reader or generator involved)."""
    from data_gen.volume import Volume

    z, y, x = np.mgrid[-1:1:24j, -1:1:32j, -1:1:40j]
    d = np.exp(-3 * (x * x + y * y + z * z)) + 0.25 * np.sin(6 * x) * np.cos(5 * y)
    d = d.astype(np.float32)
    return Volume(d, (1.0, 1.0, 1.5), (float(d.min()), float(d.max())), "blob", "test:blob")


@pytest.fixture(scope="session")
def blob_scene(blob_volume):
    from data_gen.scene import Scene, TransferFunction

    tf = TransferFunction(
        [[0.0, 0.1, 0.2, 0.9], [0.5, 1.0, 0.6, 0.1], [1.0, 1.0, 1.0, 1.0]],
        [[0.0, 0.0], [0.55, 0.0], [0.7, 0.4], [1.0, 0.9]],
    )
    return Scene("blob", blob_volume, tf)
