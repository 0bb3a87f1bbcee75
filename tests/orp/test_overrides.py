"""imls_lightning.orp.overrides: Hydra override lines (quoting, keys, the IMS job's overrides)."""
from __future__ import annotations

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from imls_lightning.orp.overrides import ims_overrides_for, override_key, quote_override_value


def test_values_are_quoted_by_the_one_quoting_function():
    """Tested against Hydra's parser in ``tests/base/test_overrides.py``."""
    from imls_lightning.base import overrides

    assert quote_override_value is overrides.quote_override_value
    flag = {"stage": "recnn", "path": "it's a\\", "views": [1, "a,b"], "device": None}
    line = f"++orp_job={quote_override_value(flag)}"
    assert OverridesParser.create().parse_overrides([line])[0].value() == flag


@pytest.mark.parametrize("line, key", [("model=ims", "model"), ("+model.x=1", "model.x"), ("~trainer.a", "trainer.a"),
                                       ("++orp_job={k:1}", "orp_job"), ("model@iml=iml", "model"),
                                       ("iml.checkpoint='a=b'", "iml.checkpoint")])
def test_override_key(line, key):
    assert override_key(line) == key


def test_ims_overrides_drop_the_imls_own_settings_and_keep_the_rest():
    job = ["model=iml", "model.mean=0.1", "+model.depth=2", "scene=tiny", "recnn.checkpoint=/r.ckpt",
           "iml.checkpoint=/old.ckpt", "++orp_job={k:1}", "trainer.max_epochs=2", "models=x"]
    assert ims_overrides_for(job, "/i.ckpt", extra=["model.layers=5"]) == [
        "scene=tiny", "recnn.checkpoint=/r.ckpt", "trainer.max_epochs=2", "models=x", "model=ims",
        "iml.checkpoint=/i.ckpt", "model.layers=5"]
    out = ims_overrides_for(job, "/i.ckpt", recnn_checkpoint="/s.ckpt")
    assert "recnn.checkpoint=/r.ckpt" not in out and out[-1] == "recnn.checkpoint=/s.ckpt"
