"""``make bench-paper`` (imls_lightning.bench_paper): the stage commands per pair, the CSV of issue 18,
the report, the BENCHMARKS.md section and the CLI's dry run."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.pipelines import bench_paper as bp

ROOT = Path(__file__).resolve().parents[1]


def _cfg(**over):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_bench_paper"):
        # never the repository's README: a test that wants the table names its own file
        return compose("bench_paper", overrides=[f"{k}={v}" for k, v in {"readme": "null", **over}.items()])


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
    assert list(enh.stages.recnn_sparser) == []  # the demo trains it as the recnn stage on a sparser pattern
    assert bp.pair_config(_cfg(**{"stages.recnn_sparser": "null"}), "ct_head", "enhancenet").stages.recnn_sparser is None
    fov = bp.pair_config(cfg, "mri_head", "fovolnet")
    assert fov.stages.las is None  # LAS does not do foveated rendering (the paper)
    assert not any(a.startswith("data.crop") for st in ("recnn", "iml") for a in fov.stages[st])
    # the paper-regime scenes by default (issue 31), the super-resolution rows first
    scenes = ["rayleigh_taylor", "flame_sheets", "seed_shell"]
    assert bp.pairs(cfg) == [(s, "enhancenet") for s in scenes] + [(s, "fovolnet") for s in scenes]
    assert bp.pairs(_cfg(scene="flame", recnns="[enhancenet]")) == [("flame", "enhancenet")]


def test_the_decoder_stage_trains_on_the_evaluations_mask_sharpness():
    """stages.ims_decoder: the IMS's decoder trained further on the masks the evaluation searches (its ims_sharpness);
    without an ims_sharpness the stage's own (or the default, 1); null skips the stage."""
    enh = bp.pair_config(_cfg(evaluate='["repeats=10","ims_sharpness=[2.0,3.0]"]'), "flame_whole", "enhancenet")
    assert "model.decoder_sharpness=[2.0,3.0]" in enh.stages.ims_decoder and "model.decoder_lift=true" in enh.stages.ims_decoder
    plain = bp.pair_config(_cfg(), "flame_whole", "enhancenet")
    assert plain.stages.ims_decoder is not None and not any("decoder_sharpness" in a for a in plain.stages.ims_decoder)
    assert bp.pair_config(_cfg(**{"stages.ims_decoder": "null"}), "flame_whole", "enhancenet").stages.ims_decoder is None


def test_skip_empty_false_reaches_every_stage_that_times_and_no_stage_that_renders_pixels():
    """skip_empty=false: the estimate, the evaluation and the adaptive mean time a ray caster without empty-space
    skipping; the cache and the training render as before (the same pixels, so the same caches and runs)."""
    plain, default = _cfg(skip_empty="false"), _cfg()
    enh = bp.pair_config(plain, "flame_whole", "enhancenet")
    assert "renderer.skip_empty=false" in enh.evaluate and "renderer.skip_empty=false" in enh.adaptive
    assert "renderer.skip_empty=false" in bp.estimate_args(plain, enh)
    assert enh.stages == bp.pair_config(default, "flame_whole", "enhancenet").stages
    assert not any("skip_empty" in a for a in [*bp.pair_config(default, "x", "enhancenet").evaluate,
                                               *bp.estimate_args(default, enh)])
    with pytest.raises(InputError, match="skip_empty='no': expected true or false"):
        bp.pair_config(_cfg(skip_empty="no"), "flame_whole", "enhancenet")


def test_renderer_overrides_reach_every_stage_and_a_malformed_one_is_refused_in_one_line():
    """``renderer_overrides`` follow ``renderer=<name>`` in the cache's, the training's, the evaluation's and the
    estimate's commands; none by default, so every existing command (and its hashes) stays as it was."""
    from imls_lightning.pipelines import stage_args

    cubic = bp.pair_config(_cfg(renderer_overrides='["renderer.interpolation=tricubic"]'), "flame_whole", "enhancenet")
    for args in (*stage_args(cubic), bp.estimate_args(_cfg(), cubic)):
        i = args.index("renderer=numba")
        assert args[i + 1] == "renderer.interpolation=tricubic"
    default = bp.pair_config(_cfg(), "flame_whole", "enhancenet")
    assert not any("interpolation" in a for a in [*stage_args(default)[1], *bp.estimate_args(_cfg(), default)])
    for bad in ('["interpolation=tricubic"]', '["renderer.interpolation"]', '"renderer.interpolation=tricubic"'):
        with pytest.raises(InputError, match="renderer_overrides"):
            bp.pair_config(_cfg(renderer_overrides=bad), "flame_whole", "enhancenet")


def test_the_evaluations_sharpness_candidates_reach_the_estimate_and_the_row_reads_the_kept_ones_curve():
    """ims_sharpness in the evaluation's overrides: the estimate renders a curve per candidate (sharpness=...), and a
    row whose ORP kept gamma = 2 takes its estimated_speedup from that curve; the paper's masks alone add nothing."""
    from imls_lightning.estimate import RenderCurve

    evaluate = '["repeats=10","ims_sharpness=[1.0,1.5,2.0]"]'
    cfg = _cfg(evaluate=evaluate)
    enh = bp.pair_config(cfg, "flame_whole", "enhancenet")
    assert "sharpness=[1.0,1.5,2.0]" in bp.estimate_args(cfg, enh)
    assert not any(a.startswith("sharpness=") for a in bp.estimate_args(_cfg(), bp.pair_config(_cfg(), "flame_whole", "enhancenet")))
    assert bp.evaluated_sharpness(_cfg(evaluate='["ims_sharpness=[1.0]"]')) == []
    paper = RenderCurve((0.5, 1.0), (150.0, 240.0)).to_dict()
    sharp = RenderCurve((0.5, 1.0), (180.0, 240.0)).to_dict()
    est = {"c_render_ms": 240.0, "nets_ms": 30.0, "recnn_ms": 15.0, "background_density": 0.25, "bilinear_db": 33.0,
           "render_curve": paper, "by_sharpness": {"2": {"render_curve": sharp}}}
    summ = _summary("flame_whole")
    summ["methods"]["imls"]["c_share"] = 0.5
    kept = {**summ, "orp": {**summ["orp"], "sharpness": 2.0}}
    assert bp.csv_row(kept, est)["estimated_speedup"] == pytest.approx(255.0 / (30.0 + 180.0 + 15.0))
    assert bp.csv_row(summ, est)["estimated_speedup"] == pytest.approx(255.0 / (30.0 + 150.0 + 15.0))


def test_rows_timed_without_skipping_are_marked_in_both_tables():
    rows = [bp.csv_row(_summary("ct_head")), bp.csv_row({**_summary("flame_whole"), "skip_empty": False})]
    text = bp.section_text(rows, partial=False)
    assert "| flame_whole (no skipping) |" in text and "| ct_head |" in text and "*(no skipping)*" in text
    assert "no skipping" not in bp.section_text(rows[:1], partial=False)
    md = bp.report_markdown(rows, [], partial=False, stage_minutes={}, command="", machine={})
    assert "| flame_whole (no skipping) |" in md and "*(no skipping)*" in md
    # a pair's per-view row still follows its main row
    assert bp.rows_beside([["flame_whole (no skipping)", "enhancenet"]], {("flame_whole", "enhancenet"): ["x", "y"]}) == \
        [["flame_whole (no skipping)", "enhancenet"], ["x", "y"]]


def test_pairs_exception_unknown_recnn():
    with pytest.raises(InputError, match="recnns: 'srgan' is not a RecNN"):
        bp.pairs(_cfg(recnns="[srgan]"))


def test_csv_row_smoke_has_exactly_the_issue_columns():
    row = bp.csv_row(_summary())
    assert tuple(row) == bp.CSV_COLUMNS
    assert row["speedup"] == pytest.approx(500.0 / 200.0) and row["gap_db"] == pytest.approx(0.9)
    assert row["mean"] == 0.31 and row["las_ms"] == 350.0 and row["full_ms"] == 1500.0
    assert row["skip_empty"] is True and bp.csv_row({**_summary(), "skip_empty": False})["skip_empty"] is False


def test_csv_roundtrip_and_merge_keeps_other_pairs(tmp_path):
    path = tmp_path / "paper_scale.csv"
    bp.write_csv([bp.csv_row(_summary("ct_head")), bp.csv_row(_summary("mri_head"))], path)
    old = bp.read_rows(path)
    assert [r["scene"] for r in old] == ["ct_head", "mri_head"] and float(old[0]["speedup"]) == pytest.approx(2.5)
    merged = bp.merge_rows(old, [bp.csv_row(_summary("mri_head", imls_ms=250.0)), bp.csv_row(_summary("flame"))])
    assert [r["scene"] for r in merged] == ["ct_head", "mri_head", "flame"]
    assert merged[1]["imls_ms"] == pytest.approx(250.0)


def test_the_object_floor_margin_column_and_tables_from_before_it(tmp_path):
    """A row whose evaluation chose an object floor carries its margin; none chosen, or no ORP, leaves it empty; a
    table written before the column is read with it empty, and written back with every column."""
    s = _summary()
    floored = {**s, "orp": {**s["orp"], "object_floor": {"chosen": {"margin": 0.12, "tau": 0.2}}}}
    assert bp.csv_row(floored)["object_floor_margin"] == 0.12
    assert bp.csv_row({**s, "orp": {**s["orp"], "object_floor": {"chosen": None}}})["object_floor_margin"] == ""
    assert bp.csv_row(s)["object_floor_margin"] == ""
    path = tmp_path / "paper_scale.csv"
    before = bp.LEGACY_COLUMNS + bp.ESTIMATE_COLUMNS + bp.RENDERER_COLUMNS
    bp.write_csv([{k: v for k, v in bp.csv_row(s).items() if k in before}], path, columns=before)
    old = bp.read_rows(path)
    assert old[0]["object_floor_margin"] == "" and old[0]["scene"] == s["scene"]
    bp.write_csv(bp.merge_rows(old, [bp.csv_row({**floored, "scene": "seed_whole"})]), path)
    again = bp.read_rows(path)
    assert [r["object_floor_margin"] for r in again] == ["", "0.12"]


def test_the_timing_busy_cores_column_and_tables_from_before_it(tmp_path):
    """rt_plumes's row was timed beside a niced test suite: its IML/S decoder read 193 ms, 50 ms with the cores free,
    and nothing in the table said so. The row now carries the most cores other jobs kept busy during its timing."""
    s = _summary()
    assert bp.csv_row({**s, "timing_load": {"views": 8, "mean": 0.4, "max": 1.1, "over": 3, "limit": 0.25}})["timing_busy_cores"] == 1.1
    assert bp.csv_row(s)["timing_busy_cores"] == ""  # an evaluation from before it: unknown, not 0
    path = tmp_path / "paper_scale.csv"
    before = bp.LEGACY_COLUMNS + bp.ESTIMATE_COLUMNS + bp.RENDERER_COLUMNS + bp.FLOOR_COLUMNS
    bp.write_csv([{k: v for k, v in bp.csv_row(s).items() if k in before}], path, columns=before)
    old = bp.read_rows(path)
    assert old[0]["timing_busy_cores"] == ""
    bp.write_csv(bp.merge_rows(old, [bp.csv_row({**s, "scene": "rt_plumes", "timing_load": {"max": 0.03}})]), path)
    assert [r["timing_busy_cores"] for r in bp.read_rows(path)] == ["", "0.03"]
    assert open(path).readline().strip().split(",") == list(bp.CSV_COLUMNS)


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
                              machine={"cpu": "test"}, settings={"ct_head, enhancenet": {"recnn": ["data.crop=128"], "las": None}},
                              commands={"ct_head, enhancenet": "python -m imls_lightning.bench_paper scenes=[ct_head]"})
    assert "| ct_head, enhancenet | recnn | `data.crop=128` |" in text and "| ct_head, enhancenet | las | skipped |" in text
    assert "| ct_head, enhancenet | 61.0 | `python -m imls_lightning.bench_paper scenes=[ct_head]` |" in text
    assert "partial" in text and "limit: the ORP's pixels alone" in text and "2.50×" in text
    assert "| 33.00 | 31.00 | 2.00 dB | 3.00 dB |" in text  # decoder − fill, mask − blue noise
    assert "Flame" in text  # the paper's figures beside ours
    lim = [r for r in bp.breakdown_rows(s) if r[0].startswith("limit")][0]
    assert "**40.00**" in lim and "12.50×" in lim
    png = bp.plot_breakdown([s, _summary("mri_head")], tmp_path / "b.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "speed-up" in bp.section_text(rows, partial=False) and "| 30.0% |" in bp.section_text(rows, partial=False)
    assert bp.orp_cell({"mean": "", "c_share": "0.2"}) == "none (ran at 20.0%)"
    # the evaluation's speed-quality front, per pair
    front = [{"method": "recnn", "label": "RecNN alone", "note": "its pattern", "latency_ms": 500.0, "psnr": 40.0, "ssim": 0.9,
              "views": 2, "on_front": True},
             {"method": "imls", "label": "IML/S + RecNN", "note": "ORP u=0.31", "latency_ms": 200.0, "psnr": 39.1, "ssim": 0.9,
              "views": 2, "on_front": True}]
    s2 = dict(s, front=front, front_views=[0, 119], orp=dict(s["orp"], gap_bound_db=0.95, test={"gap_db": 0.9, "views": 120}))
    text = bp.report_markdown([bp.csv_row(s2)], [s2], partial=False, stage_minutes={}, command="cmd", machine={})
    part = text.split("### Speed-quality front")[1]
    assert "Every method on the evaluation's 2 sweep view(s)" in part and "| **IML/S + RecNN** | ORP u=0.31 |" in part
    assert "Where IML/S lies: **ct_head, enhancenet**: 1 of the 1 IML/S + RecNN points lie on the Pareto front" in part
    assert "0.90 dB on the validation views (bound 0.95 dB), 0.90 dB on the 120 evaluated trajectory views" in part


def test_cli_dry_run_prints_every_stage_command():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "dry_run=true", "scenes=[ct_head]", "recnns=[enhancenet]"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 11 and lines[1].startswith("python -m data_gen scene=ct_head data=paper_cpu")
    assert lines[3] == lines[2] + " pattern.factor=4"  # the RecNN on a sparser pattern, trained the same way
    assert "checkpoints.recnn_sparser=" in lines[-2]
    # the IMS's decoder stage right after the IMS, from its checkpoint, and the evaluation runs its checkpoint
    ims, decoder = lines[5], lines[6]
    assert "model=ims" in ims and "init_checkpoint" not in ims and "model.decoder_every=4" in ims
    assert decoder.startswith(ims.split(" model.decoder_lr=")[0]) and "'model.init_checkpoint=<IMS>'" in decoder
    assert all(k in decoder for k in ("model.train_generator=false", "model.decoder_lift=true", "model.decoder_lr=3.0e-4",
                                      "'model.decoder_mean_range=[0.1,0.5]'", "model.monitor=val/decoder_fr_psnr"))
    assert "'checkpoints.ims=<IMS-decoder>'" in lines[-2]
    # the before-training estimate first, with the sizes the stages train
    assert lines[0].startswith("python -m imls_lightning.estimate scene=ct_head recnn=enhancenet renderer=numba")
    assert all(k in lines[0] for k in ("recnn.net.channels=16", "recnn.net.blocks=4", "iml.depth=4", "iml.base_channels=8",
                                       "ims.layers=7", "ims.base_channels=16", "ims.max_channels=256"))
    assert "data.crop=128" in lines[2] and "timed_views=6" in lines[-2] and "options.half=auto" in lines[-2]
    # the per-view adaptive mean last, on the evaluation's masks
    assert lines[-1].startswith("python -m imls_lightning.adaptive scene=ct_head") and "ims_lift=" in lines[-1]


def test_cli_dry_run_the_ims_finetune_stage_sits_between_the_ims_and_its_decoder():
    """stages.ims_finetune: a step decay of the IMS's learning rate as a stage of its own, from the IMS stage's best;
    the decoder stage then starts from the fine-tuned IMS (null, the default: no such stage)."""
    p = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "dry_run=true", "train_only=true", "scenes=[ct_head]",
                        "recnns=[enhancenet]", 'stages.ims_finetune=["model.lr=1.0e-4","trainer.max_epochs=3"]'],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    ims = next(i for i, ln in enumerate(lines) if "model=ims" in ln and "init_checkpoint" not in ln)
    finetune, decoder = lines[ims + 1], lines[ims + 2]
    assert "'model.init_checkpoint=<IMS>'" in finetune and "model.lr=1.0e-4" in finetune and "trainer.max_epochs=3" in finetune
    assert "train_generator" not in finetune and "model.decoder_every=4" in finetune
    assert "'model.init_checkpoint=<IMS-fine-tune>'" in decoder and "model.train_generator=false" in decoder


def test_cli_gpu_schedule_train_only_prints_the_training_stages():
    """bench_paper_gpu.yaml: bench_paper.yaml with the longer schedules; train_only drops the evaluation."""
    p = subprocess.run([sys.executable, "-m", "imls_lightning.bench_paper", "--config-name", "bench_paper_gpu", "dry_run=true",
                        "train_only=true", "scenes=[ct_head]", "recnns=[enhancenet]"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.strip().splitlines()
    assert len(lines) == 8 and not any("imls_lightning.evaluate" in ln for ln in lines)  # the IMS decoder stage included
    iml = next(ln for ln in lines if "model=iml" in ln and "importance=uniform" not in ln)
    assert "data.crop=128" in iml and "trainer.max_epochs=40" in iml and "test=false" in iml


def _adaptive(psnr=39.6, ipr=0.06, ms=150.0):
    lat = lambda **kw: {**kw, "total": sum(kw.values())}  # noqa: E731
    return {"report": "runs/x/adaptive.md", "u_median": 0.25, "summary": {
        "recnn": {"psnr": 40.0, "ipr": 0.25, "gap": 0.0, "within": 1.0, "latency_ms": lat(selective_render=390.0, recnn=110.0)},
        "imls_adaptive": {"psnr": psnr, "ipr": ipr, "gap": 40.0 - psnr, "within": 0.8,
                          "latency_ms": lat(importance=10.0, selective_render=ms - 130.0, decoder=30.0, recnn=90.0)},
        "imls_matched": {"psnr": 39.2, "ipr": ipr}}}


def test_adaptive_row_smoke_its_own_run_and_the_share_of_c():
    s = _summary()
    assert bp.adaptive_row(s) is None
    s["adaptive"] = _adaptive()
    a = bp.adaptive_row(s)
    assert tuple(a) == bp.ADAPTIVE_COLUMNS
    assert a["speedup"] == pytest.approx(500.0 / 150.0)  # against the RecNN alone timed in the adaptive run
    assert a["c_share"] == pytest.approx(0.06 * 0.3 / 0.075) and a["gap_db"] == pytest.approx(0.4)
    assert a["psnr_fixed_same_ipr_db"] == 39.2 and a["u_median"] == 0.25
    text = bp.report_markdown([bp.csv_row(s)], [s], partial=False, stage_minutes={}, command="cmd", machine={})
    assert "| ct_head | enhancenet, per-view u |" in text and "per view (median 0.250)" in text and "3.33×" in text
    assert "the fixed mean of the same IPR scores 39.20 dB" in text
    sec = bp.section_text([bp.csv_row(s)], False, [a])
    assert "| ct_head | enhancenet, per-view u | per view: 24.0% | 39.60 (0.40 dB) | 500.0 | 150.0 | 3.33× |" in sec


def test_exception_read_adaptive_and_read_pairs_refuse_foreign_files(tmp_path):
    (tmp_path / "adaptive.md").write_text("x")
    with pytest.raises(InputError, match="adaptive.json: cannot read the adaptive run's results"):
        bp.read_adaptive(tmp_path / "adaptive.md")
    (tmp_path / "adaptive.json").write_text('{"summary": {"recnn": {}}}')
    with pytest.raises(InputError, match="not an adaptive run's results"):
        bp.read_adaptive(tmp_path / "adaptive.md")
    pairs_json = tmp_path / "paper_scale_pairs.json"
    assert bp.read_pairs(pairs_json) == {}
    pairs_json.write_text('{"ct_head, enhancenet": {"summary": {}}}')
    with pytest.raises(InputError, match="not the benchmark's pair records"):
        bp.read_pairs(pairs_json)
    pairs_json.write_text("[1,")
    with pytest.raises(InputError, match="paper_scale_pairs.json: cannot read it"):
        bp.read_pairs(pairs_json)


def test_bench_paper_keeps_the_pairs_run_before(tmp_path, monkeypatch):
    """A run of one pair rewrites every table with the pairs of earlier runs (their breakdowns, times and
    commands), and the adaptive row of a pair that has one. The pipeline itself (demo) is exercised by
    tests/test_demo.py; here it is replaced by the evaluation and adaptive files it leaves."""
    def fake_demo(stages, scene_overrides, results):
        d = tmp_path / "runs" / stages.scene
        d.mkdir(parents=True)
        import json

        (d / "summary.json").write_text(json.dumps(_summary(stages.scene)))
        results["adaptive"] = None
        if stages.adaptive is not None:
            (d / "adaptive.json").write_text(json.dumps({"summary": _adaptive()["summary"], "u_adaptive": {"median": 0.3}}))
            results["adaptive"] = str(d / "adaptive.md")
        return d / "report.md"

    monkeypatch.setattr(bp, "demo", fake_demo)
    monkeypatch.setattr(bp, "pair_estimate", lambda cfg, stages, ov: _estimate(stages.scene))
    out = tmp_path / "bench"
    md = tmp_path / "BENCHMARKS.md"
    bp.bench_paper(_cfg(scenes="[ct_head]", recnns="[enhancenet]", output_dir=str(out), benchmarks_md=str(md), adaptive="null"),
                   command="first")
    bp.bench_paper(_cfg(scenes="[mri_head]", recnns="[enhancenet]", output_dir=str(out), benchmarks_md=str(md)), command="second")
    text = (out / "paper_scale.md").read_text()
    assert "## ct_head, enhancenet" in text and "## mri_head, enhancenet" in text
    assert "| ct_head, enhancenet |" in text and "`first`" in text and "`second`" in text
    rows = bp.read_rows(out / "paper_scale.csv")
    assert [r["scene"] for r in rows] == ["ct_head", "mri_head"]
    # the estimate's columns, the bound at the row's measured share (30% of C)
    assert rows[1]["volume_dims"] == "128x128x84" and float(rows[1]["c_render_ms"]) == 300.0
    expected = bp.speedup_from_estimate(_estimate("mri_head"), 0.3)
    assert float(rows[1]["estimated_speedup"]) == pytest.approx(expected, rel=1e-6) and expected > 1
    ad = (out / "paper_scale_adaptive.csv").read_text().splitlines()
    assert ad[0] == ",".join(bp.ADAPTIVE_COLUMNS) and len(ad) == 2 and ad[1].startswith("mri_head,enhancenet,0.3,")
    assert "mri_head | enhancenet, per-view u" in md.read_text()


def test_rows_beside_puts_each_pairs_extra_row_after_it():
    main = [["ct_head", "enhancenet", "1"], ["mri_head", "enhancenet", "2"]]
    extra = {("mri_head", "enhancenet"): ["mri_head", "enhancenet, per-view u", "3"], ("flame", "fovolnet"): ["flame", "x", "4"]}
    assert [r[2] for r in bp.rows_beside(main, extra)] == ["1", "2", "3", "4"]
    assert bp.rows_beside(main, {}) == main


def _estimate(scene: str) -> dict:
    from imls_lightning.estimate import RenderCost

    return {"volume_dims": "128x128x84" if scene == "mri_head" else "256x256x108", "c_render_ms": 300.0, "nets_ms": 30.0,
            "recnn_ms": 20.0, "bilinear_db": 33.0, "background_density": 0.25,
            "render_cost": RenderCost(1.0, 0.008, 0.001, 30000, 35536).to_dict()}


def test_legacy_table_reads_with_empty_estimate_columns(tmp_path):
    path = tmp_path / "paper_scale.csv"
    path.write_text(",".join(bp.LEGACY_COLUMNS) + "\n" + ",".join(["ct_head", "enhancenet"] + ["1"] * 15) + "\n")
    row = bp.read_rows(path)[0]
    assert row["scene"] == "ct_head" and all(row[k] == "" for k in bp.ESTIMATE_COLUMNS)
    assert row["skip_empty"] is True  # timed before the knob existed: with skipping
    # a table with the estimate's columns and without skip_empty reads too, and is written with it
    path.write_text(",".join(bp.LEGACY_COLUMNS + bp.ESTIMATE_COLUMNS) + "\n" + ",".join(["ct_head", "enhancenet"] + ["1"] * 20) + "\n")
    bp.write_csv([*bp.read_rows(path), {**bp.csv_row({**_summary("flame_whole"), "skip_empty": False})}], path)
    assert [r["skip_empty"] for r in bp.read_rows(path)] == ["true", "false"]
    assert bp.estimate_cells(None, 0.3) == {k: "" for k in bp.ESTIMATE_COLUMNS + bp.ESTIMATE_INTERVAL_COLUMNS}


def test_summarize_only_rewrites_the_tables_from_the_records(tmp_path, monkeypatch):
    out = tmp_path / "bench"
    with pytest.raises(InputError, match="summarize_only=true: .*paper_scale_pairs.json holds no pairs yet"):
        bp.bench_paper(_cfg(output_dir=str(out), benchmarks_md="null", summarize_only="true"))
    out.mkdir()
    s = _summary("mri_head")
    s["adaptive"] = _adaptive()
    import json

    (out / "paper_scale_pairs.json").write_text(json.dumps({"mri_head, enhancenet": {
        "summary": s, "minutes": 61.0, "command": "python -m imls_lightning.bench_paper scenes=[mri_head]", "settings": {"ims": ["a=1"]},
        "machine": {"cpu": "The CPU it was measured on"}}}))
    monkeypatch.setattr(bp, "demo", lambda *a, **k: pytest.fail("summarize_only must not run a stage"))
    # a pair recorded before the estimate existed gets one (and only that)
    monkeypatch.setattr(bp, "pair_estimate", lambda cfg, stages, ov: _estimate(stages.scene))
    md = bp.bench_paper(_cfg(output_dir=str(out), benchmarks_md="null", summarize_only="true"), command="summarize")
    assert json.loads((out / "paper_scale_pairs.json").read_text())["mri_head, enhancenet"]["estimate"]["volume_dims"] == "128x128x84"
    text = md.read_text()
    assert "| mri_head, enhancenet | 61.0 |" in text and "enhancenet, per-view u" in text
    assert "| cpu | The CPU it was measured on |" in text  # not relabelled with the machine that summarizes
    assert bp.read_rows(out / "paper_scale.csv")[0]["scene"] == "mri_head" and (out / "paper_scale_breakdown.png").is_file()


def test_the_speedup_interval_columns_and_tables_from_before_them(tmp_path):
    """A narrow pass (seed_whole: 2.02x against a 2x goal) needs its spread beside it: the row carries IML/S's 95%
    interval over its timed views, both tables show it, and a table written before the columns reads them empty."""
    s = {**_summary(), "speedup_interval": {"imls": {"speedup": 2.5, "low": 2.31, "high": 2.7, "views": 12, "confidence": 0.95},
                                            "las": {"speedup": 1.4, "low": 1.3, "high": 1.5, "views": 12, "confidence": 0.95}}}
    row = bp.csv_row(s)
    assert (row["speedup_low"], row["speedup_high"]) == (2.31, 2.7)
    assert (bp.csv_row(_summary())["speedup_low"], bp.csv_row(_summary())["speedup_high"]) == ("", "")
    path = tmp_path / "paper_scale.csv"
    before = bp.LEGACY_COLUMNS + bp.ESTIMATE_COLUMNS + bp.RENDERER_COLUMNS + bp.FLOOR_COLUMNS + bp.LOAD_COLUMNS
    bp.write_csv([{k: v for k, v in bp.csv_row(_summary("mri_head")).items() if k in before}], path, columns=before)
    old = bp.read_rows(path)
    assert old[0]["speedup_low"] == "" and old[0]["speedup_high"] == ""
    rows = bp.merge_rows(old, [row])
    bp.write_csv(rows, path)
    again = bp.read_rows(path)
    assert [r["speedup_low"] for r in again] == ["", "2.31"]
    assert [bp.speedup_cell(r) for r in again] == ["2.50×", "2.50× (2.31–2.70)"]
    section = bp.section_text(again, partial=False)
    assert "| speed-up (95% interval) |" in section and "2.50× (2.31–2.70)" in section


def test_module_doctests():
    """The examples in bench_paper's docstrings (speedup_cell, las_cell, estimate_args, ...) hold."""
    import doctest

    result = doctest.testmod(bp)
    assert result.attempted >= 5 and result.failed == 0, result
