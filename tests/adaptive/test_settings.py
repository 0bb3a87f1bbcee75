"""imls_lightning.adaptive.settings: conf/adaptive.yaml validated (parse_settings)."""
from __future__ import annotations

from pathlib import Path

import pytest

from imls_lightning.base.errors import InputError

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("override, needle", [("epsilon_db=-1", "epsilon_db"), ("steps=0", "steps"),
                                              ("predictor.margin=0", "margin"), ("views=train", "views"),
                                              ("reference=full", "reference"), ("unreachable=all", "unreachable"),
                                              ("label_source=vtk", "label_source"), ("tradeoff_margins=[0]", "tradeoff_margins"),
                                              ("tradeoff_margins=[x]", "tradeoff_margins"), ("tradeoff_means=-1", "tradeoff_means"),
                                              ("ims_lift=maybe", "ims_lift=maybe: expected true"),
                                              ("options.half=2", r"options\.half=2: expected true or false"),
                                              ("+options.fast=true", r"options\.fast: unknown option")])
def test_exception_cli_bad_settings(tiny_checkpoints, pim_ckpt, override, needle):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.adaptive import parse_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="adaptive_test"):
        cfg = compose("adaptive", overrides=["scene=tiny", "data=tiny", f"ims_checkpoint={pim_ckpt}", override])
    with pytest.raises(InputError, match=needle):
        parse_settings(cfg)


def _settings(pim_ckpt, *overrides):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.adaptive import parse_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="adaptive_test"):
        return parse_settings(compose("adaptive", overrides=["scene=tiny", "data=tiny", f"ims_checkpoint={pim_ckpt}", *overrides]))


def test_settings_lift_and_options_enter_the_keys_only_when_set(tiny_checkpoints, pim_ckpt):
    plain = _settings(pim_ckpt)
    assert not plain.ims_lift and not plain.options.half and not plain.reuse
    assert "ims_lift" not in plain.label_key() and "options" not in plain.hashed()  # earlier runs keep their names
    lifted = _settings(pim_ckpt, "ims_lift=true", "options.half=true", "device=cpu", "reuse=true")
    assert lifted.label_key()["ims_lift"] is True and lifted.hashed()["options"]["half"] is True
    assert lifted.options.device == "cpu" and lifted.reuse and "reuse" not in lifted.hashed()


def test_settings_orp_path_follows_the_labels(tiny_checkpoints, pim_ckpt):
    """The fixed-mean ORP is searched where the labels bisect: the product path against the RecNN alone
    (the evaluation's ORP) by default; the IML + RecNN path otherwise. The run's folder says which."""
    assert _settings(pim_ckpt).orp_path == "product"
    assert _settings(pim_ckpt, "label_source=iml").orp_path == "iml"
    assert _settings(pim_ckpt, "reference=iml").orp_path == "iml"
    assert _settings(pim_ckpt).hashed()["orp_path"] == "product"
