"""imls_lightning.adaptive.settings: conf/adaptive.yaml validated (parse_settings)."""
from __future__ import annotations

from pathlib import Path

import pytest

from data_gen.errors import InputError

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("override, needle", [("epsilon_db=-1", "epsilon_db"), ("steps=0", "steps"),
                                              ("predictor.margin=0", "margin"), ("views=train", "views"),
                                              ("reference=full", "reference"), ("unreachable=all", "unreachable"),
                                              ("label_source=vtk", "label_source"), ("tradeoff_margins=[0]", "tradeoff_margins"),
                                              ("tradeoff_margins=[x]", "tradeoff_margins"), ("tradeoff_means=-1", "tradeoff_means")])
def test_exception_cli_bad_settings(tiny_checkpoints, pim_ckpt, override, needle):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.adaptive import parse_settings

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="adaptive_test"):
        cfg = compose("adaptive", overrides=["scene=tiny", "data=tiny", f"ims_checkpoint={pim_ckpt}", override])
    with pytest.raises(InputError, match=needle):
        parse_settings(cfg)
