"""``python -m imls_lightning.cost_mask``: a committed row's masks measured by the share of the render cost they keep
(the tiny row of conftest.py plays a committed one)."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.base.config import file_hash
from imls_lightning.evaluation.protocol import training_data_seed
from imls_lightning.pipelines.cost_mask import cost_masks

ROOT = Path(__file__).resolve().parents[1]


def _cfg(spec, tmp_path, **over):
    base = {"row": spec, "views": 1, "seed": 2026, "iml_means": [0.3], "epsilon_db": 1.0, "times": "row",
            "options": {"half": False, "channels_last": False, "compile": False},
            "output_dir": str(tmp_path / "out"), "runs_dir": str(tmp_path / "runs")}
    return OmegaConf.create({**base, **over})


@pytest.fixture(scope="module")
def spec_with_iml(row, tmp_path_factory):
    """The tiny row with its IML committed too (the IML's masks are one of the kinds measured)."""
    folder = tmp_path_factory.mktemp("row_iml")
    for f in ("ims.ckpt", "las.ckpt"):
        shutil.copyfile(row["folder"] / f, folder / f)
    shutil.copytree(row["folder"] / "point", folder / "point")
    shutil.copyfile(row["ck"]["iml"], folder / "iml.ckpt")
    spec = json.loads(json.dumps(row["spec"]))
    spec["dir"] = str(folder)
    spec["networks"]["iml"] = {"file": "iml.ckpt", "sha256": file_hash(folder / "iml.ckpt", length=64)}
    return spec


def test_cost_masks_report_every_mask_kind(spec_with_iml, tmp_path):
    path = cost_masks(_cfg(spec_with_iml, tmp_path))
    r = json.loads(path.read_text())
    assert path.name == "cost_mask.json" and r["row"] == "tiny_row" and r["views"] == 1
    assert set(r["masks"]) == {"product", "iml", "oracle_alpha0", "oracle_alpha0.5", "oracle_alpha1", "oracle_alpha2"}
    assert 0.0 <= r["object_cost"] <= 1.0 and r["alone_ms"] > 0 and set(r["needed_for"]) == {"1x", "1.5x"}
    # the ceilings take the row's own evaluation's stage times; this run's are reported beside them
    point = json.loads((Path(spec_with_iml["dir"]) / "point" / "summary.json").read_text())
    assert r["pattern_ms"] == pytest.approx(point["methods"]["recnn"]["latency_ms"]["selective_render"])
    assert r["times"].startswith("the row's evaluation") and r["measured_here"]["pattern_ms"] > 0
    for f in ("cost_mask.md", "cost_mask.png"):
        assert (path.parent / f).stat().st_size > 0
    md = (path.parent / "cost_mask.md").read_text()
    assert "IML/S (the product" in md and "importance / (1 + cost)^1" in md


def test_exception_a_seed_a_network_trained_on_writes_nothing(row, tmp_path):
    seed = training_data_seed(row["folder"] / "ims.ckpt")
    assert seed is not None
    with pytest.raises(InputError, match=f"seed={seed}: the ims network trained on views of that seed"):
        cost_masks(_cfg(row["spec"], tmp_path, seed=seed))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("over,needle", [({"views": 0}, "views"), ({"iml_means": [2.0]}, "iml_means")])
def test_exception_bad_settings_write_nothing(row, tmp_path, over, needle):
    with pytest.raises(InputError, match=needle):
        cost_masks(_cfg(row["spec"], tmp_path, **over))
    assert not (tmp_path / "out").exists()


def test_cli_unknown_row_is_one_line_with_status_2():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.cost_mask", "row=no_such_row"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "no_such_row" in p.stderr, p.stderr
