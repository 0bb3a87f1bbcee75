"""One-line errors: InputError, cli_errors, and the config-group choice check of the commands."""
from __future__ import annotations

from pathlib import Path

import pytest

from imls_lightning.base.errors import InputError, check_group_choices, config_keys, quote_non_ascii

CONF = Path(__file__).resolve().parents[2] / "conf"


def test_group_choices_listed_in_one_line():
    with pytest.raises(InputError, match=r"^scene=no_such_scene: no such scene; expected one of ct_head, .*, tiny$") as e:
        check_group_choices(CONF, ["data=tiny", "scene=no_such_scene"])
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match=r"^data=huge: no such data; expected one of bench, default, paper_cpu, small, tiny$"):
        check_group_choices(CONF, ["+data=huge"])
    with pytest.raises(InputError, match="scene=nope"):
        check_group_choices(CONF, ["-m", "scene=tiny,nope"])


def test_group_choices_leave_everything_else_to_hydra():
    check_group_choices(CONF, ["scene=tiny", "data=tiny", "experiment=null", "scene.name=anything", "seed=3",
                               "hydra/sweeper=orp", "--cfg", "job", "scene=choice(tiny,flame)", "paths.runs_dir=/x=y"])


def test_config_keys_names_the_users_key():
    with pytest.raises(InputError, match=r"^model.depth=0: expected"):
        with config_keys({"depth": "model.depth"}):
            raise InputError("depth=0: expected an integer >= 1")
    with pytest.raises(InputError, match=r"^c_size=3: expected"):  # not a key of the user's: as it was
        with config_keys({"depth": "model.depth"}):
            raise InputError("c_size=3: expected")


def test_non_ascii_values_are_quoted_for_hydra():
    """A volume path with non-ASCII characters ended in Hydra's lexer traceback (issue 17, 13)."""
    argv = ["scene=file", "scene.volume.path=/data/volumes_é/x y.raw", "--cfg", "job", 'a="already é"']
    assert quote_non_ascii(argv) == ["scene=file", "scene.volume.path='/data/volumes_é/x y.raw'", "--cfg", "job", 'a="already é"']
    with pytest.raises(InputError, match=r"quote each string that holds them") as e:
        quote_non_ascii(["x.paths=[/é/a,/é/b]"])
    assert "\n" not in str(e.value)
