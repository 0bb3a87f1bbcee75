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
