"""``make bench-paper`` (imls_lightning.bench_paper): the stage commands per pair, the CSV of issue 18,
the report, the BENCHMARKS.md section and the CLI's dry run."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from data_gen.errors import InputError
from imls_lightning import bench_paper as bp

ROOT = Path(__file__).resolve().parents[1]


def _cfg(**over):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_bench_paper"):
        return compose("bench_paper", overrides=[f"{k}={v}" for k, v in over.items()])


def _summary(scene="ct_head", recnn="enhancenet", imls_ms=200.0):
    lat = lambda **kw: {**kw, "total": sum(kw.values())}  # noqa: E731
    return {
        "scene": scene, "recnn": recnn, "fr_size": 512, "c_size": 256, "sample_distance_voxels": 0.5, "imls_mean": 0.3,
        "orp": {"found": True, "mean": 0.31, "c_share": 0.3, "ipr": 0.075, "gap_db": 0.9, "evaluations": 6},
        "views": 120, "timed_views": 12,
        "methods": {
            "full": {"latency_ms": lat(render=1500.0), "psnr": 100.0, "ipr": 1.0},
            "recnn": {"latency_ms": lat(selective_render=380.0, recnn=120.0), "psnr": 40.0, "ipr": 0.25},
            "las": {"latency_ms": lat(low_res_render=90.0, importance=40.0, selective_render=120.0, recnn=100.0), "psnr": 35.0, "ipr": 0.075},
            "iml": {"latency_ms": lat(selective_render=380.0, importance=30.0, decoder=30.0, recnn=120.0), "psnr": 39.5, "ipr": 0.075},
            "imls": {"latency_ms": lat(importance=10.0, selective_render=imls_ms - 160.0, decoder=30.0, recnn=120.0),
                     "psnr": 39.1, "ipr": 0.075, "c_share": 0.3},
        },
        "equal_share": [
            {"share": 0.1, "mask": m, "reconstruction": r, "psnr": p, "c_share": 0.1, "density_background": 0.02,
             "density_object": 0.2}
            for m, r, p in [("ims", "decoder", 33.0), ("ims", "fill", 31.0), ("blue_noise", "decoder", 30.0), ("blue_noise", "fill", 29.0)]
        ],
    }


def test_pair_config_smoke_crop_net_and_las_per_recnn():
    cfg = _cfg()
    enh = bp.pair_config(cfg, "ct_head", "enhancenet")
    assert enh.data == "paper_cpu" and enh.scene == "ct_head"
    for stage in ("recnn", "iml", "blue_noise"):
        assert "data.crop=128" in enh.stages[stage] and "recnn.net.channels=16" in enh.stages[stage]
    assert not any(a.startswith("data.crop") for a in enh.stages.ims)
    assert enh.stages.las is not None and any("timed_views" in a for a in enh.evaluate)
    fov = bp.pair_config(cfg, "mri_head", "fovolnet")
    assert fov.stages.las is None  # LAS does not do foveated rendering (the paper)
    assert not any(a.startswith("data.crop") for st in ("recnn", "iml") for a in fov.stages[st])
    assert bp.pairs(cfg) == [("ct_head", "enhancenet"), ("mri_head", "enhancenet"), ("ct_head", "fovolnet"), ("mri_head", "fovolnet")]
    assert bp.pairs(_cfg(scene="flame", recnns="[enhancenet]")) == [("flame", "enhancenet")]


def test_pairs_exception_unknown_recnn():
    with pytest.raises(InputError, match="recnns: 'srgan' is not a RecNN"):
        bp.pairs(_cfg(recnns="[srgan]"))


def test_csv_row_smoke_has_exactly_the_issue_columns():
    row = bp.csv_row(_summary())
    assert tuple(row) == bp.CSV_COLUMNS
    assert row["speedup"] == pytest.approx(500.0 / 200.0) and row["gap_db"] == pytest.approx(0.9)
    assert row["mean"] == 0.31 and row["las_ms"] == 350.0 and row["full_ms"] == 1500.0


def test_csv_roundtrip_and_merge_keeps_other_pairs(tmp_path):
    path = tmp_path / "paper_scale.csv"
    bp.write_csv([bp.csv_row(_summary("ct_head")), bp.csv_row(_summary("mri_head"))], path)
    old = bp.read_rows(path)
    assert [r["scene"] for r in old] == ["ct_head", "mri_head"] and float(old[0]["speedup"]) == pytest.approx(2.5)
    merged = bp.merge_rows(old, [bp.csv_row(_summary("mri_head", imls_ms=250.0)), bp.csv_row(_summary("flame"))])
    assert [r["scene"] for r in merged] == ["ct_head", "mri_head", "flame"]
    assert merged[1]["imls_ms"] == pytest.approx(250.0)


def test_read_rows_exception_foreign_table(tmp_path):
    path = tmp_path / "paper_scale.csv"
    path.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="paper_scale.csv: its columns"):
        bp.read_rows(path)


def test_update_section_appends_then_replaces_keeping_the_rest(tmp_path):
    md = tmp_path / "BENCHMARKS.md"
    md.write_text("# Benchmarks\n\nthe quick one\n")
    bp.update_section(md, "first")
    bp.update_section(md, "second")
    text = md.read_text()
    assert text.startswith("# Benchmarks\n\nthe quick one\n") and "second" in text and "first" not in text
    assert text.count(bp.SECTION_BEGIN) == 1 and text.count(bp.SECTION_END) == 1


def test_report_and_breakdown_plot(tmp_path):
    s = _summary()
    rows = [bp.csv_row(s)]
    text = bp.report_markdown(rows, [s], partial=True, stage_minutes={"ct_head, enhancenet": 61.0}, command="cmd",
                              machine={"cpu": "test"}, settings={"enhancenet": {"recnn": ["data.crop=128"], "las": None}})
    assert "| enhancenet | recnn | `data.crop=128` |" in text and "| enhancenet | las | skipped |" in text
    assert "partial" in text and "limit: the ORP's pixels alone" in text and "2.50×" in text
    assert "| 33.00 | 31.00 | 2.00 dB | 3.00 dB |" in text  # decoder − fill, mask − blue noise
    assert "Flame" in text  # the paper's figures beside ours
    lim = [r for r in bp.breakdown_rows(s) if r[0].startswith("limit")][0]
    assert "**40.00**" in lim and "12.50×" in lim
    png = bp.plot_breakdown([s, _summary("mri_head")], tmp_path / "b.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "speed-up" in bp.section_text(rows, partial=False) and "| 30.0% |" in bp.section_text(rows, partial=False)
    assert bp.orp_cell({"mean": "", "c_share": "0.2"}) == "none (ran at 20.0%)"


def test_cli_dry_run_prints_every_stage_command():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "dry_run=true", "scenes=[ct_head]", "recnns=[enhancenet]"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 7 and lines[0].startswith("python -m data_gen scene=ct_head data=paper_cpu")
    assert "data.crop=128" in lines[1] and "timed_views=6" in lines[-1]


def test_cli_gpu_schedule_train_only_prints_the_training_stages():
    """bench_paper_gpu.yaml: bench_paper.yaml with the longer schedules; train_only drops the evaluation."""
    p = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "--config-name", "bench_paper_gpu", "dry_run=true",
                        "train_only=true", "scenes=[ct_head]", "recnns=[enhancenet]"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 6 and not any("imls_lightning.evaluate" in ln for ln in lines)
    iml = next(ln for ln in lines if "model=iml" in ln and "importance=uniform" not in ln)
    assert "data.crop=128" in iml and "trainer.max_epochs=40" in iml and "test=false" in iml
