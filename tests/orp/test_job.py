"""imls_lightning.orp.job: one sweep job (a failing stage fails the job, recorded in its job file)."""
from __future__ import annotations

import json

import pytest

from imls_lightning import orp


def test_exception_bad_stage_fails_the_job_not_the_sweep(tmp_path):
    from omegaconf import OmegaConf

    cfg = OmegaConf.create({"orp_job": {"stage": "las"}, "paths": {"runs_dir": str(tmp_path)}})
    with pytest.raises(orp.ORPJobError, match="orp_job.stage='las'"):
        orp.orp_main(cfg)
    assert json.loads((tmp_path / "orp_job" / orp.JOB_FILE).read_text())["status"] == "failed"
