"""``python -m imls_lightning.web`` checks before it says "serving": the checkpoints, the report and the port first; a
busy port, a missing checkpoint or report, or a report path that does not exist is one line, a non-zero exit and no
"serving" line. ``--help`` lists only what the viewer reads."""
from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli import run_in_process

ROOT = Path(__file__).resolve().parents[2]

pytest.importorskip("trame", reason="the web extra is not installed (pip install -e '.[web]')")


def _refused(args) -> str:
    r = run_in_process("imls_lightning.web", args)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "serving" not in r.stderr + r.stdout, (r.returncode, r.stderr)
    return lines[0]


def test_exception_a_busy_port_is_one_line_before_serving(tiny_checkpoints):
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        line = _refused([f"ims_checkpoint={tiny_checkpoints['ims_pim']}", f"port={port}", "host=127.0.0.1"])
    assert line == (f"error: port={port}: already in use on 127.0.0.1 (another server, or a viewer still running); "
                    "pass another port, or port=0 for a free one")


def test_exception_missing_or_damaged_checkpoints_are_one_line_before_serving(tiny_checkpoints, tmp_path):
    assert _refused([f"ims_checkpoint={tmp_path / 'no.ckpt'}"]) == f"error: ims_checkpoint={tmp_path / 'no.ckpt'}: file not found"
    text = tmp_path / "notes.ckpt"
    text.write_text("not a checkpoint\n")
    assert _refused([f"ims_checkpoint={text}"]).startswith(f"error: ims_checkpoint={text}: not a loadable checkpoint")
    ims = tiny_checkpoints["ims_pim"]
    assert _refused([f"ims_checkpoint={ims}", f"las_checkpoint={tmp_path / 'las.ckpt'}"]) == \
        f"error: las_checkpoint={tmp_path / 'las.ckpt'}: file not found"
    assert _refused([f"ims_checkpoint={ims}", f"adaptive_predictor={tmp_path / 'p.pt'}"]).startswith(
        f"error: adaptive_predictor={tmp_path / 'p.pt'}: file not found")
    assert _refused([f"ims_checkpoint={ims}", "port=70000"]) == "error: port=70000: expected an integer in [0, 65535]"


def test_exception_a_report_that_does_not_exist_is_one_line(tmp_path):
    """An evaluation folder's config.yaml beside a report.md that is not there: refused, not served."""
    folder = tmp_path / "eval"
    folder.mkdir()
    (folder / "config.yaml").write_text(f"checkpoints:\n  ims: {tmp_path / 'ims.ckpt'}\n")
    missing = folder / "no_such_report.md"
    assert _refused([f"from_report={missing}"]) == (f"error: from_report={missing}: no such file; expected an evaluation's "
                                                    "report.md (the demo prints its path last)")
    (folder / "report.md").write_text("# report\n")
    assert _refused([f"from_report={folder / 'report.md'}"]) == \
        f"error: from_report={folder / 'report.md'}: its checkpoints.ims ({tmp_path / 'ims.ckpt'}): file not found"


def test_help_lists_only_what_the_viewer_reads():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.web", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "Configuration groups" not in p.stdout and "scene:" not in p.stdout and "trainer:" not in p.stdout
    for key in ("ims_checkpoint:", "from_report:", "port:", "timeout:", "share:", "mean:", "options:"):
        assert key in p.stdout
