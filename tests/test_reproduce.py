"""``python -m imls_lightning.reproduce``: a committed row re-measured on a fresh trajectory, choosing nothing again.

The tiny checkpoints (conftest.py) play a committed row: copied into a row folder with their SHA-256, beside the
operating point a finished evaluation chose (its summary.json and config.yaml)."""
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
from imls_lightning.pipelines.reproduce import RESULT_KEYS, reproduce
from tests.conftest import ROW_SETTINGS as SETTINGS

ROOT = Path(__file__).resolve().parents[1]
def _cfg(row, tmp_path, **over):
    base = {"row": row["spec"], "trajectory_seed": None, "views": None, "timed_views": None, "output_dir": str(tmp_path / "out"),
            "runs_dir": str(tmp_path / "runs"), "cache_dir": str(row["ck"]["cache_dir"])}
    return OmegaConf.create({**base, **over})


def test_reproduce_measures_the_committed_point_on_a_fresh_trajectory(row, tmp_path):
    path = reproduce(_cfg(row, tmp_path))
    res = json.loads(path.read_text())
    assert tuple(res) == RESULT_KEYS
    assert res["row"] == "tiny_row" and res["trajectory_seed"] == 7 and res["views"] == 2 and res["timed_views"] == 1
    chosen = json.loads((row["chosen"] / "summary.json").read_text())
    summary = json.loads((path.parent / "summary.json").read_text())
    assert summary["orp"]["mean"] == chosen["orp"]["mean"]  # the committed point, not searched again
    assert summary["trajectory"]["seed"] == 7
    # both ray casters in one run; the speed-up that counts is against the faster RecNN alone
    assert res["speedup_vs_fastest"] == pytest.approx(min(res["recnn_skip_ms"], res["recnn_noskip_ms"])
                                                      / min(res["imls_skip_ms"], res["imls_noskip_ms"]))
    assert res["gap_db"] == pytest.approx(res["psnr_recnn_db"] - res["psnr_imls_db"])


def test_exception_an_altered_or_missing_network_writes_nothing(row, tmp_path):
    spec = json.loads(json.dumps(row["spec"]))
    spec["networks"]["las"]["sha256"] = "0" * 64
    with pytest.raises(InputError, match=r"row=tiny_row: .*las.ckpt has SHA-256 .* the file was altered"):
        reproduce(_cfg({**row, "spec": spec}, tmp_path))
    spec["networks"]["las"]["file"] = "gone.ckpt"
    with pytest.raises(InputError, match=r"row=tiny_row: its network las \(.*gone.ckpt\) is missing"):
        reproduce(_cfg({**row, "spec": spec}, tmp_path))
    assert not (tmp_path / "out").exists()


def test_exception_an_edited_point_writes_nothing(row, tmp_path):
    spec = {**row["spec"], "point_sha256": "0" * 64}
    with pytest.raises(InputError, match=r"row=tiny_row: .*summary.json is not the record the row committed"):
        reproduce(_cfg({**row, "spec": spec}, tmp_path))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("seed, needle", [(0, "equals data.seed"), (100, "equals the IMS's training data.seed"),
                                          (1, "equals a seed of the ORP's search views")])
def test_exception_a_trajectory_seed_a_choice_read_writes_nothing(row, tmp_path, seed, needle):
    with pytest.raises(InputError, match=f"trajectory_seed={seed}: {needle}"):
        reproduce(_cfg(row, tmp_path, trajectory_seed=seed))
    assert not (tmp_path / "out").exists()


def test_cli_unknown_row_is_one_line_with_status_2():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.reproduce", "row=no_such_row"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "no_such_row" in p.stderr, p.stderr


def test_pack_row_commits_the_evaluated_weights_and_reproduce_reads_the_row(row, tmp_path):
    """pack_row: the networks without their training-only state (the same weights), the point naming the packed
    files, conf/row/<name>.yaml with their SHA-256; reproduce then takes that row as it is."""
    import torch
    import yaml

    from imls_lightning.pipelines.pack_row import pack_row

    dest = tmp_path / "rows" / "packed"
    path = pack_row(row["chosen"], "packed", dest, data="tiny", trajectory_seed=7, settings=SETTINGS, views=2, timed_views=1,
                    row_dir=tmp_path / "conf")
    spec = yaml.safe_load(path.read_text())
    assert set(spec["networks"]) == {"ims", "las"} and spec["trajectory_seed"] == 7
    for key, net in spec["networks"].items():
        packed = torch.load(dest / net["file"], weights_only=True)
        original = torch.load(row["folder"] / f"{key}.ckpt", weights_only=True)
        assert "optimizer_states" not in packed and packed["hyper_parameters"] == original["hyper_parameters"]
        assert all(torch.equal(packed["state_dict"][k], v) for k, v in original["state_dict"].items())
        assert net["sha256"] == file_hash(dest / net["file"], length=64) and len(net["sha256"]) == 64
    point = json.loads((dest / "point" / "summary.json").read_text())
    assert point["checkpoints_sha256"] == {k: v["sha256"][:16] for k, v in spec["networks"].items()}
    assert point["packed_from"]["ims"] == file_hash(row["folder"] / "ims.ckpt")
    assert spec["point_sha256"] == file_hash(dest / "point" / "summary.json", length=64)
    out = reproduce(OmegaConf.create({"row": spec, "trajectory_seed": 9, "views": None, "timed_views": None,
                                      "output_dir": str(tmp_path / "out"), "runs_dir": str(tmp_path), "cache_dir": str(row["ck"]["cache_dir"])}))
    assert json.loads(out.read_text())["trajectory_seed"] == 9


def test_pack_trained_commits_networks_not_yet_evaluated(row, tmp_path):
    """A row whose session ended before its evaluation: its networks packed as pack_row packs them (the same weights,
    training-only state dropped), trained.yaml naming them by SHA-256; a missing checkpoint is refused in one line."""
    import torch
    import yaml

    from imls_lightning.pipelines.pack_row import pack_trained

    dest = tmp_path / "rows" / "trained"
    sources = {"ims": row["folder"] / "ims.ckpt", "las": row["folder"] / "las.ckpt"}
    record = yaml.safe_load(pack_trained(sources, "trained", dest, experiment="tiny_row").read_text())
    assert record["evaluated"] is False and record["experiment"] == "tiny_row" and set(record["networks"]) == {"ims", "las"}
    for key, net in record["networks"].items():
        packed = torch.load(dest / net["file"], weights_only=True)
        assert "optimizer_states" not in packed and net["sha256"] == file_hash(dest / net["file"], length=64)
        original = torch.load(sources[key], weights_only=True)
        assert all(torch.equal(packed["state_dict"][k], v) for k, v in original["state_dict"].items())
    with pytest.raises(InputError, match=r"checkpoints.recnn=.*gone.ckpt: no such checkpoint file"):
        pack_trained({"recnn": tmp_path / "gone.ckpt"}, "trained", tmp_path / "other")


def test_cli_pack_row_without_evaluation_or_checkpoints_is_one_line_with_status_2(tmp_path):
    p = subprocess.run([sys.executable, "-m", "imls_lightning.pack_row", "name=nothing", f"dest={tmp_path / 'd'}"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1 and "evaluation=" in p.stderr, p.stderr
    assert not (tmp_path / "d").exists()
