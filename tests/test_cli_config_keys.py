"""Every command meets the README's one-line rule for config mistakes (:func:`imls_lightning.base.errors.check_config_keys`, run by
:func:`imls_lightning.base.errors.checked_command_line` before Hydra composes anything): a typo'd key, an unknown key, or a ``+key``
that no config or schema reads is one line naming the key and the closest valid one, exit status 2; a ``+key`` that a
config reads still works (``--cfg job`` prints the composed config without running the command)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from imls_lightning.base.errors import InputError, check_config_keys
from tests.cli import run_in_process

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"

# (module, arguments every run needs, a typo'd key and the key the message must suggest, an unread +key, its suggestion)
COMMANDS = [
    ("imls_lightning.train", [], "data.resolutoin=32", "data.resolution", "+data.resolutoin=32", "data.resolution"),
    ("imls_lightning.evaluate", [], "max_veiws=3", "max_views", "+orp_max_veiws=3", "orp_max_views"),
    ("imls_lightning.estimate", [], "resolutoin=7", "resolution", "+frame_veiws=2", "frame_views"),
    ("imls_lightning.demo", [], "stags.recnn=[]", "stages.recnn", "+dry_runn=true", "dry_run"),
    ("imls_lightning.bench_paper", [], "recnns_=[fovolnet]", "recnns", "+scenes_=[flame]", "scenes"),
    ("imls_lightning.web", [], "prot=8081", "port", "+opne_browser=true", "open_browser"),
    ("imls_lightning.viewer", ["ims_checkpoint=x.ckpt"], "mas=false", "mask", "+screenshoot=a.png", "screenshot"),
    ("data_gen", [], "data.num_veiws=4", "data.num_views", "+contact_sheets=true", "contact_sheet"),
    ("imls_lightning.adaptive", [], "predictor.margn=1", "predictor.margin", "+tradeoff_mean=2", "tradeoff_means"),
]


def _one_line(r) -> str:
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, (r.returncode, r.stderr)
    return lines[0]


@pytest.mark.parametrize("module, base, typo, near, plus, plus_near", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_exception_a_typo_and_an_unread_plus_key_are_one_line(module, base, typo, near, plus, plus_near):
    line = _one_line(run_in_process(module, [*base, typo]))
    assert line == f"error: {typo}: no such setting; did you mean {near}?"
    line = _one_line(run_in_process(module, [*base, plus]))
    key = plus[1:].split("=", 1)[0]
    assert line == f"error: {plus}: no config or schema reads {key}; did you mean {plus_near}?"


def test_exception_the_issues_cases_on_train():
    """``+modle.x=1`` (a typo of a group), ``+model.x=1`` (a key the task's ``**_`` swallows: nothing reads it), a delete of
    a key that is not there, a key Hydra cannot parse."""
    assert _one_line(run_in_process("imls_lightning.train", ["+modle.x=1"])) == \
        "error: +modle.x=1: no config or schema reads modle.x; did you mean model?"
    assert "error: +model.x=1: no config or schema reads model.x" in _one_line(run_in_process("imls_lightning.train", ["+model.x=1"]))
    assert _one_line(run_in_process("imls_lightning.train", ["~data.resolutoin"])) == \
        "error: ~data.resolutoin: no such setting to delete; did you mean ~data.resolution?"
    assert _one_line(run_in_process("imls_lightning.train", ["data.resolution=[1,"])).startswith(
        "error: data.resolution=[1,: not an override Hydra can read")


def test_a_plus_key_a_config_or_schema_reads_still_works():
    """``+key`` on a key the config has is set (Hydra alone would refuse to append it); ``++recnn.net.features`` is
    FoVolNet's argument (its config node builds it with ``_target_``); ``+group=`` where the defaults have the slot."""
    r = run_in_process("imls_lightning.train", ["+data.resolution=48", "recnn=fovolnet", "++recnn.net.features=8",
                                                "+experiment=paper_enhancenet", "--cfg", "job"])
    assert r.returncode == 0, r.stderr
    assert "resolution: 48" in r.stdout and "features: 8" in r.stdout
    r = run_in_process("imls_lightning.web", ["+mean=0.4", "--cfg", "job"])
    assert r.returncode == 0 and "mean: 0.4" in r.stdout, r.stderr
    # recnn.net.features without +: not in the config, so Hydra needs it appended; the line says how
    assert _one_line(run_in_process("imls_lightning.train", ["recnn=fovolnet", "recnn.net.features=8"])) == \
        "error: recnn.net.features=8: recnn.net.features is not in the config, but recnn.net._target_ takes it: " \
        "add it with +recnn.net.features=8"


def test_exception_reproduce_checks_its_keys_too(tmp_path):
    """``reproduce`` composes ``row`` from ``conf/row/`` (none is committed here): the check runs on its config with a
    row of the test's own; without a row the command says so in one line."""
    conf = tmp_path / "conf"
    (conf / "row").mkdir(parents=True)
    (conf / "reproduce.yaml").write_text((CONF / "reproduce.yaml").read_text())
    (conf / "row" / "tiny_row.yaml").write_text("name: tiny_row\nscene: tiny\n")
    assert check_config_keys(conf, "reproduce", ["row=tiny_row", "views=4"]) == ["row=tiny_row", "views=4"]
    with pytest.raises(InputError, match=r"^trajectory_sed=3: no such setting; did you mean trajectory_seed\?$"):
        check_config_keys(conf, "reproduce", ["row=tiny_row", "trajectory_sed=3"])
    with pytest.raises(InputError, match=r"^\+timed_veiws=2: no config or schema reads timed_veiws; did you mean timed_views\?$"):
        check_config_keys(conf, "reproduce", ["row=tiny_row", "+timed_veiws=2"])
    line = _one_line(run_in_process("imls_lightning.reproduce", ["trajectory_sed=3"]))
    assert line.startswith("error: ") and "row" in line


def test_exception_cost_mask_checks_its_keys_too():
    """``cost_mask`` composes a committed row (conf/row/seed_whole.yaml): a typo in its own keys is one line, before
    any network loads."""
    assert _one_line(run_in_process("imls_lightning.cost_mask", ["row=seed_whole", "view=3"])) == \
        "error: view=3: no such setting; did you mean views?"


def test_exception_a_typo_is_one_line_in_a_real_subprocess():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.train", "data.resolutoin=32"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and p.stderr == "error: data.resolutoin=32: no such setting; did you mean data.resolution?\n"
