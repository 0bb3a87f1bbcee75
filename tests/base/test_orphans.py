"""imls_lightning.base.orphans: workers that never outlive their parent, and what a killed writer leaves behind."""
from __future__ import annotations

import doctest
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from imls_lightning.base import orphans
from imls_lightning.base.atomic import atomic_write_text
from imls_lightning.base.orphans import pid_alive, remove_stale_temporaries

ROOT = Path(__file__).resolve().parents[2]


def test_module_doctests():
    result = doctest.testmod(orphans)
    assert result.attempted > 0 and result.failed == 0, result


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temporaries_of_dead_writers_are_removed_and_live_ones_kept(tmp_path):
    target = tmp_path / "vol_8x8x8_float32.raw"
    dead, live = tmp_path / f".{target.name}.{_dead_pid()}.tmp", tmp_path / f".{target.name}.{os.getppid()}.tmp"
    other = tmp_path / f".other.raw.{_dead_pid()}.tmp"
    for f in (dead, live, other):
        f.write_bytes(b"half")
    assert remove_stale_temporaries(target) == [dead]
    assert not dead.exists() and live.exists() and other.exists()
    dead.write_bytes(b"half")
    atomic_write_text(target, "whole", unique=True)  # a unique write sweeps first
    assert target.read_text() == "whole" and not dead.exists() and live.exists()
    assert not pid_alive(_dead_pid()) and pid_alive(os.getpid())


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:
        return []


def _running(pid: int) -> bool:
    stat = Path(f"/proc/{pid}/stat")
    try:
        return stat.read_text().split()[2] != "Z"
    except (FileNotFoundError, IndexError):
        return False


def test_volume_workers_exit_when_the_parent_is_terminated(tmp_path):
    """write_procedural_raw's process pool: the parent terminated mid-volume (SIGTERM, as ``kill`` or a session's
    end sends it) leaves no worker behind. Without the orphan watch they idled on their pipes for ever."""
    code = ("from data_gen.procedural import write_procedural_raw\n"
            "if __name__ == '__main__':\n"
            f"    write_procedural_raw('mixing_layer', 256, {str(tmp_path)!r}, workers=2, chunk_z=1)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(_children(parent.pid)) < 2 and parent.poll() is None:
            time.sleep(0.05)
        time.sleep(1.0)  # the workers are evaluating slabs
        workers = _children(parent.pid)
        assert len(workers) >= 2, "the pool never started"
    finally:
        os.kill(parent.pid, signal.SIGTERM)
        parent.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(_running(w) for w in workers):
        time.sleep(0.1)
    alive = [w for w in workers if _running(w)]
    for w in alive:
        os.kill(w, signal.SIGKILL)
    assert not alive, "orphaned volume workers still running"
