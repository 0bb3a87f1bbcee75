"""The public API of the package itself: ``from imls_lightning import IMLSRenderer, IMLNet, ...``.

Each name lives in one home module (``imls_lightning.HOMES``) and is imported lazily (PEP 562), so
``import imls_lightning`` loads no torch; the README's example runs on real (tiny) checkpoints.
"""
from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imls_lightning

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", imls_lightning.__all__)
def test_every_public_name_is_its_home_modules_object(name):
    home = imls_lightning.HOMES[name]
    obj = getattr(imls_lightning, name)
    assert obj is getattr(importlib.import_module(home), name)
    assert getattr(obj, "__module__", home) == home, f"{name} is defined in {obj.__module__}, not in its home {home}"
    ns: dict = {}
    exec(f"from imls_lightning import {name}", ns)
    assert ns[name] is obj


def test_all_lists_exactly_the_homes():
    assert sorted(imls_lightning.__all__) == sorted(imls_lightning.HOMES)
    assert {"IMLSRenderer", "IMLNet", "IMSGenerator", "EnhanceNet", "FoVolNet", "IMLTask", "IMSTask", "RecNNTask",
            "compact", "normalize_importance"} <= set(imls_lightning.__all__)
    assert set(imls_lightning.__all__) <= set(dir(imls_lightning))


def test_unknown_names_and_submodules():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        imls_lightning.nope  # noqa: B018
    from imls_lightning.core import patterns  # a submodule is still imported as such

    assert patterns.__name__ == "imls_lightning.core.patterns"


@pytest.mark.parametrize("code", ["import imls_lightning", "from imls_lightning import ORPSearch"])
def test_import_is_cheap(code):
    """Importing the package (or a torch-free name from it) loads no torch."""
    p = subprocess.run([sys.executable, "-c", f"import sys; {code}; assert 'torch' not in sys.modules"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]


def test_readme_example(tiny_checkpoints):
    """README's "Python API" example: an IMLSRenderer from an IMS checkpoint renders a view."""
    from imls_lightning import IMLSRenderer, NetOptions, timed

    r = IMLSRenderer.from_checkpoints(str(tiny_checkpoints["ims"]), opts=NetOptions(device="cpu"))
    view = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]  # eye, lookAt, up
    image, timings = timed(r).render(view)
    m = r.fr_size
    assert image.shape == (m, m, 3) and image.dtype == np.uint8
    assert {"importance", "selective_render", "decoder", "recnn", "total"} <= set(timings)
