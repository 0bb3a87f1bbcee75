"""``python -m imls_lightning.size_search``: the candidates' stage overrides, the Pareto front, the
chosen ``<scene>_fast`` experiment, the documented errors, and a real tiny sweep through Hydra."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.pipelines import size_search as ss
from imls_lightning.pipelines import stage_overrides

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
SIZES = {"recnn_channels": 16, "recnn_blocks": 2, "decoder_depth": 3, "decoder_width": 4, "ims_layers": 4, "ims_width": 8}


def _cfg(*overrides: str, name: str = "size_search"):
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_size_search"):
        return compose(name, overrides=list(overrides))


def _record(imls_ms: float, psnr: float, feasible: bool = True, **sizes) -> dict:
    return {**SIZES, **sizes, "recnn_test_psnr_db": 40.0, "reference_test_psnr_db": 40.2, "recnn_ok": feasible,
            "orp_found": feasible, "mean": 0.4 if feasible else None, "c_share": 0.4, "psnr_recnn_db": 39.0,
            "psnr_imls_db": psnr, "gap_db": 39.0 - psnr, "recnn_ms": 100.0, "imls_ms": imls_ms,
            "speedup": 100.0 / imls_ms, "feasible": feasible, "report": "r/report.md"}


# ---- config and candidates ---------------------------------------------------------------------------
def test_config_smoke_is_a_multirun_over_sizes_with_the_front_callback():
    cfg = _cfg()
    assert ss.check_sizes(OmegaConf.to_container(cfg.size)) == {
        "recnn_channels": 16, "recnn_blocks": 4, "decoder_depth": 4, "decoder_width": 8, "ims_layers": 5, "ims_width": 16}
    assert list(cfg.search_skips) == ["blue_noise", "las", "recnn_sparser"]  # the search needs the product path only
    assert dict(cfg.reference) == {"channels": 64, "blocks": 10}


def test_candidate_config_puts_each_size_into_its_stages_and_wins_over_the_scene_entries():
    cfg = _cfg("scene=ct_head")
    job = ss.candidate_config(cfg, SIZES)
    assert "recnn.net.channels=16" in stage_overrides(job, "recnn") and "recnn.net.blocks=2" in stage_overrides(job, "recnn")
    iml = stage_overrides(job, "iml")
    assert "model.base_channels=4" in iml and "model.depth=3" in iml
    assert "model.base_channels=16" not in iml  # ct_head's scene entry (width 16) is replaced by the candidate's
    ims = stage_overrides(job, "ims")
    assert "model.layers=4" in ims and "model.base_channels=8" in ims and "model.layers=5" not in ims
    assert job.stages.las is None and job.stages.blue_noise is None
    with pytest.raises(InputError, match="search_skips: unknown stage 'lass'"):
        ss.candidate_config(_cfg("search_skips=[lass]"), SIZES)


def test_candidate_with_the_demo_sizes_has_the_demo_stage_overrides():
    # so its runs are the demo's own (reused, not trained again)
    demo, cfg = _cfg(name="demo"), _cfg()
    job = ss.candidate_config(cfg, ss.check_sizes(OmegaConf.to_container(cfg.size)))
    for stage in ("recnn", "iml", "ims"):
        assert sorted(stage_overrides(job, stage)) == sorted(stage_overrides(demo, stage)), stage


def test_candidate_name_smoke():
    assert ss.candidate_name(SIZES) == "r16x2-d3w4-s4w8"


@pytest.mark.parametrize("bad, match", [({"recnn_channels": 0}, "size.recnn_channels=0"),
                                        ({"ims_width": 2.5}, "size.ims_width=2.5"),
                                        ({"decoder_depth": True}, "size.decoder_depth=True"),
                                        ({"recnn_width": 8}, "size.recnn_width: unknown size")])
def test_exception_bad_size_is_one_line(bad, match):
    with pytest.raises(InputError, match=match):
        ss.check_sizes({**SIZES, **bad})


def test_exception_recnn_result_without_a_test_pass(tmp_path):
    ck = tmp_path / "run" / "checkpoints" / "epoch000.ckpt"
    ck.parent.mkdir(parents=True)
    (tmp_path / "run" / "result.json").write_text(json.dumps({"best_checkpoint": str(ck)}))
    with pytest.raises(InputError, match="no test PSNR of the RecNN"):
        ss.recnn_test_psnr(ck)
    (tmp_path / "run" / "result.json").write_text(json.dumps({"test": {"test/fr_psnr": 31.5}}))
    assert ss.recnn_test_psnr(ck) == 31.5


# ---- the front ------------------------------------------------------------------------------------
def _dominated_direct(points, i):
    t, q = points[i]
    return any(t2 <= t and q2 >= q and (t2, q2) != (t, q) for j, (t2, q2) in enumerate(points) if j != i)


def test_pareto_flags_against_direct_definition():
    import random

    rnd = random.Random(0)
    for _ in range(50):
        pts = [(rnd.choice([10.0, 20.0, 30.0, 40.0]), rnd.choice([28.0, 30.0, 32.0])) for _ in range(6)]
        assert ss.pareto_flags(pts) == [not _dominated_direct(pts, i) for i in range(len(pts))]
    assert ss.pareto_flags([(10.0, math.nan)]) == [False]


def test_choose_takes_the_fastest_feasible_candidate():
    recs = [_record(50.0, 30.0, feasible=False), _record(70.0, 31.0), _record(60.0, 30.5, decoder_width=8)]
    assert ss.choose(recs)["imls_ms"] == 60.0
    assert ss.choose([_record(50.0, 30.0, feasible=False)]) is None


def test_write_front_and_experiment_compose_with_the_demo(tmp_path):
    recs = [_record(50.0, 30.0, feasible=False), _record(70.0, 31.0, decoder_width=8), _record(60.0, 30.5)]
    paths = ss.write_front(recs, tmp_path, "flame")
    rows = list(__import__("csv").DictReader(paths["csv"].open()))
    assert [r["imls_ms"] for r in rows] == ["50", "60", "70"] and list(rows[0]) == list(ss.FRONT_COLUMNS)
    assert [r["pareto"] for r in rows] == ["True", "True", "True"]
    md = paths["md"].read_text()
    assert "Chosen: **r16x2-d3w4-s4w8**" in md and paths["png"].stat().st_size > 0
    cfg = _cfg("scene=ct_head")
    exp = ss.write_experiment(tmp_path, cfg, ss.choose(recs))
    assert exp.name == "ct_head_fast.yaml" and ss.written_by_search(exp.read_text())
    (tmp_path / "experiment").mkdir()
    exp.rename(tmp_path / "experiment" / exp.name)
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_size_search"):
        merged = compose("demo", overrides=[f"hydra.searchpath=[file://{tmp_path}]", "+experiment=ct_head_fast"])
    iml = stage_overrides(merged, "iml")
    assert "model.base_channels=4" in iml and "model.base_channels=16" not in iml  # ct_head's width 16 is gone
    assert "recnn.net.blocks=2" in stage_overrides(merged, "recnn") and "trainer.max_epochs=10" in stage_overrides(merged, "recnn")
    assert "model.base_channels=4" in stage_overrides(merged, "blue_noise")  # the baseline's decoder the same size
    assert stage_overrides(merged, "las") == stage_overrides(_cfg(name="demo"), "las")  # the search skipped it; the experiment keeps it


def test_exception_experiment_never_overwrites_a_file_it_did_not_write(tmp_path):
    (tmp_path / "flame_fast.yaml").write_text("# my own config\nscene: flame\n")
    with pytest.raises(InputError, match="was not written by the size search"):
        ss.write_experiment(tmp_path, _cfg(), _record(60.0, 30.5))
    assert (tmp_path / "flame_fast.yaml").read_text().startswith("# my own")


def test_read_records_skips_a_damaged_record_with_a_warning(tmp_path, capsys):
    (tmp_path / "a.json").write_text(json.dumps(_record(60.0, 30.5)))
    (tmp_path / "b.json").write_text("{not json")
    (tmp_path / "c.json").write_text(json.dumps({**_record(60.0, 30.5), "recnn_blocks": -1}))
    assert len(ss.read_records(tmp_path)) == 1
    err = capsys.readouterr().err
    assert "b.json is not a job record" in err and "c.json is not a job record" in err


def test_shipped_experiments_compose_with_the_demo():
    for path in sorted((ROOT / "conf" / "pipelines" / "experiment").glob("*_fast.yaml")):
        assert ss.written_by_search(path.read_text()), path
        cfg = _cfg(f"+experiment={path.stem}", name="demo")
        assert cfg.scene == path.stem[: -len("_fast")] and cfg.scene_stages is None
        assert any(o.startswith("recnn.net.channels=") for o in stage_overrides(cfg, "recnn")), path
        assert any(o.startswith("model.base_channels=") for o in stage_overrides(cfg, "iml")), path


# ---- through Hydra ---------------------------------------------------------------------------------
def test_cli_dry_run_sweeps_the_grid(tmp_path):
    p = subprocess.run([PY, "-m", "imls_lightning.size_search", "dry_run=true", f"output_dir={tmp_path}/out",
                        f"runs_dir={tmp_path}/runs", "size.decoder_width=4,8", "size.recnn_channels=16"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    iml_cmds = [c for c in p.stdout.splitlines() if "model=iml" in c]
    assert len(iml_cmds) == 2 and "model.base_channels=4" in iml_cmds[0] and "model.base_channels=8" in iml_cmds[1]
    refs = [c for c in p.stdout.splitlines() if "recnn.net.channels=64" in c and "recnn.net.blocks=10" in c]
    assert len(refs) == 2  # the reference RecNN per job (trained once, then reused)
    assert "no job records" in p.stderr
    assert not (tmp_path / "out" / "flame" / "jobs").exists()  # a dry run records nothing


# slow: the default suite took 18 min on an AVX2-only 2-core EPYC (issue 31's machine); make test-all runs it
@pytest.mark.slow
def test_smoke_size_search_on_tiny_writes_the_front_and_the_experiment(tmp_path):
    def ov(key, *items):
        return f"{key}=[" + ",".join(f"'{i}'" for i in items) + "]"

    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    exp_dir = tmp_path / "experiments"
    exp_dir.mkdir()
    cmd = [PY, "-m", "imls_lightning.size_search", "scene=tiny", "data=tiny", "progress=false",
           f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache", f"output_dir={tmp_path}/out",
           f"experiment_dir={exp_dir}", "reference.channels=8", "reference.blocks=1", "recnn_bound_db=100",
           "size.recnn_channels=4", "size.recnn_blocks=1", "size.decoder_depth=2", "size.decoder_width=2,4",
           "size.ims_layers=3", "size.ims_width=8",
           ov("stages.recnn", "trainer.max_epochs=1"),
           ov("stages.iml", "model.mode=end_to_end", "trainer.max_epochs=1"),
           ov("stages.ims", "model.target=pim", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0",
              "model.loss.adversarial=0.0", "trainer.max_epochs=1"),
           ov("evaluate", "max_views=2", "repeats=10", "warmup=0", "sweep_views=1", "grid_views=0", "shares=[]",
              "las_iprs=[]", "mean_values=[0.2]", "epsilon_db=100")]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1200)
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    folder = tmp_path / "out" / "tiny"
    assert sorted(x.name for x in (folder / "jobs").glob("*.json")) == ["r4x1-d2w2-s3w8.json", "r4x1-d2w4-s3w8.json"]
    rows = list(__import__("csv").DictReader((folder / "pareto.csv").open()))
    assert len(rows) == 2 and all(float(r["imls_ms"]) > 0 and math.isfinite(float(r["psnr_imls_db"])) for r in rows)
    assert (folder / "pareto.png").is_file() and "Chosen:" in (folder / "pareto.md").read_text()
    assert ss.written_by_search((exp_dir / "tiny_fast.yaml").read_text())
