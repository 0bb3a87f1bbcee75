"""imls_lightning.report.machine: what a report records about its run."""
from __future__ import annotations

import os

from imls_lightning.report.machine import hydra_command, machine_info


def test_machine_info_names_the_cpu_cores_and_libraries():
    info = machine_info("cpu")
    assert info["cores"] == str(os.cpu_count()) and info["device"] == "cpu"
    assert info["cpu"] and info["torch"] and info["python"].count(".") == 2


def test_hydra_command_outside_hydra_is_the_fallback():
    assert hydra_command("imls_lightning.evaluate", "through the Python API") == "through the Python API"


def test_others_cores_against_a_direct_count():
    from imls_lightning.report.machine import others_cores

    # 4 s of the machine busy over 2 s of wall time, 3 of them ours: another job kept half a core busy
    assert others_cores(busy_s=4.0, own_s=3.0, wall_s=2.0, cores=2) == 0.5
    assert others_cores(busy_s=2.9, own_s=3.0, wall_s=2.0, cores=2) == 0.0  # tick granularity: clamped at 0
    assert others_cores(busy_s=9.0, own_s=0.0, wall_s=2.0, cores=2) == 2.0  # at most every core
    assert others_cores(busy_s=1.0, own_s=0.0, wall_s=0.0, cores=2) == 0.0


def test_other_load_sees_a_busy_child_and_not_its_own_threads():
    """A spinning child process counts as another job; the timed block's own work does not (busy_cores, read
    during a timing, would count it)."""
    import subprocess
    import sys
    import time

    import pytest

    from imls_lightning.report.machine import OtherLoad

    if not os.path.exists("/proc/stat"):
        pytest.skip("no /proc/stat here")
    child = subprocess.Popen([sys.executable, "-c", "import time\nt = time.time() + 30\nwhile time.time() < t: pass"])
    try:
        time.sleep(0.5)  # the interpreter's start-up
        with OtherLoad() as busy:
            time.sleep(1.5)
    finally:
        child.kill()
        child.wait()
    assert busy.cores is not None and busy.cores >= 0.5 and busy.seconds >= 1.5
    with OtherLoad() as own:
        t_end = time.perf_counter() + 1.5
        while time.perf_counter() < t_end:  # this process spins: its own time, not another job's
            pass
    # the spin is this process's own time (all its threads), which the other jobs' count leaves out; on 2 shared cores
    # (the suite's other worker, a training) it gets half a core or less, and without os.times it would read 0
    assert own.own_cores >= 0.2 and busy.own_cores < 0.3
