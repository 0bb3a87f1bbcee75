"""The one quoting function for Hydra overrides (:mod:`imls_lightning.base.overrides`), checked against Hydra's
own override parser: every value reads back unchanged."""
from __future__ import annotations

import doctest

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from imls_lightning.base import overrides
from imls_lightning.base.errors import quote_non_ascii
from imls_lightning.base.overrides import quote_override_value

STRINGS = [
    "plain", "/runs/a-1/checkpoints/last.ckpt", "cache_dir", "a.b.c", "-a", "+a", "..", "",
    "back\\slash", "C:\\runs\\a.ckpt", "end\\", "two\\\\", "\\\\server\\share", "it's", "it\\'s", "two\\\\'q",
    "'quoted'", '"double"', "mixed 'single' \"double\"", "/a b/c.ckpt", " lead and trail ", "tab\tx",
    "x=y", "a,b", "[1,2]", "{k:v}", "(x)", "key=[a,'b']", "$HOME/x",
    "volumes_é/x y.raw", "名前", "emoji 🙂", "ß\\'",
    "123", "-4", "1_000", "1.5", ".5", "5.", "1e5", "1E-3", "inf", "-inf", "NaN", "true", "False", "null", "NULL",
]


def parsed(line: str):
    return OverridesParser.create().parse_overrides([line])[0].value()


@pytest.mark.parametrize("value", STRINGS)
def test_strings_read_back_unchanged_by_hydra(value):
    assert parsed(f"key={quote_override_value(value)}") == value


@pytest.mark.parametrize("value", [None, True, False, 3, -0.25, 1e-5, ["a b", "it's", None, 2], {"a": [1, "x=y"], "b": {"c": False}},
                                   {"path": "C:\\it's\\", "name": "é"}])
def test_other_values_read_back_unchanged_by_hydra(value):
    assert parsed(f"key={quote_override_value(value)}") == value


def test_plain_strings_stay_bare_and_look_alikes_of_other_types_are_quoted():
    """Bare where Hydra reads the word as the same string (readable commands, the same text as before
    for bench's sweep-directory hash); quoted where it would read a number, a boolean or null."""
    assert quote_override_value("/runs/a-1/last.ckpt") == "/runs/a-1/last.ckpt"
    assert [quote_override_value(s) for s in ("1e5", "true", "null", "", "a b")] == ["'1e5'", "'true'", "'null'", "''", "'a b'"]
    # only backslashes before a quote or the end are doubled: Hydra reads the others literally
    assert quote_override_value("C:\\a\\") == "'C:\\a\\\\'" and quote_override_value("a\\'") == "'a\\\\\\''"


def test_non_ascii_command_line_values_read_back_unchanged():
    argv = ["scene.volume.path=/data/volumes_é/x y.raw", "name=名前", "plain=/x"]
    assert [parsed(a) for a in quote_non_ascii(argv)] == ["/data/volumes_é/x y.raw", "名前", "/x"]


def test_every_caller_uses_it():
    from imls_lightning.pipelines import bench
    from imls_lightning.orp import overrides as orp_overrides

    assert bench.quote_override_value is orp_overrides.quote_override_value is quote_override_value
    assert not hasattr(bench, "quote")


def test_doctests():
    result = doctest.testmod(overrides)
    assert result.attempted > 0 and result.failed == 0, result
