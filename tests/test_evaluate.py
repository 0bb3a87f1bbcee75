"""The evaluation CLI (``python -m imls_lightning.evaluate``) end to end on ``scene=tiny data=tiny``.

Real checkpoints (``tiny_checkpoints`` in conftest.py), the real numba renderer and the real cache;
the evaluation runs once per module through the CLI with few views (the stage-time medians keep the
minimum of 10 repeats) and the tests read what it wrote.
"""
from __future__ import annotations

import csv
import json
import dataclasses
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from imls_lightning.base.errors import InputError
from imls_lightning.inference.pipeline import STAGES
from imls_lightning.report import METHOD_ORDER as ALL_METHODS, summary

ROOT = Path(__file__).resolve().parents[1]
MEANS = [0.1, 0.3]
LAS_IPRS = [0.1]
LAS_SEARCH_IPRS = [0.05, 0.1, 0.25, 0.5]
FRONT_SHARES = [0.2, 1.0]
# the methods the module's evaluation measures: all but the ray caster twins with skipping on (its ray caster skips
# already; the twins march every sample: both_ray_casters) and imls_trained (only where the search kept the fill as
# decoder, orp_decoders)
METHOD_ORDER = tuple(m for m in ALL_METHODS if m not in ("recnn_skip", "imls_skip", "imls_trained"))
# the stages each method reports (pipeline.py's table); every other stage column stays empty
METHOD_STAGES = {
    "full": {"render"},
    "recnn": {"selective_render", "recnn"},
    "recnn_noskip": {"selective_render", "recnn"},
    "recnn_sparser": {"selective_render", "recnn"},
    "las": {"low_res_render", "importance", "selective_render", "recnn"},
    "las_searched": {"low_res_render", "importance", "selective_render", "recnn"},
    "las_equal": {"low_res_render", "importance", "selective_render", "recnn"},
    "iml": {"selective_render", "importance", "decoder", "recnn"},
    "imls": {"importance", "selective_render", "decoder", "recnn"},
    "imls_noskip": {"importance", "selective_render", "decoder", "recnn"},
    "imls_fill": {"importance", "selective_render", "decoder", "recnn"},
    "blue_noise": {"importance", "selective_render", "decoder", "recnn"},
    "two_pass": {"low_res_render", "importance", "selective_render", "decoder", "recnn"},
}
PLOTS = ("stage_breakdown.png", "psnr_per_view.png", "latency_vs_psnr.png", "image_grid.png", "speed_quality_front.png")


def _args(ck: dict, *extra: str) -> list[str]:
    return ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={ck['cache_dir']}",
            f"paths.runs_dir={ck['runs_dir']}", f"checkpoints.ims={ck['ims_pim']}", f"checkpoints.las={ck['las']}",
            f"checkpoints.blue_noise={ck['blue']}", f"checkpoints.recnn_sparser={ck['recnn_sparser']}", "orp_max_views=4",
            f"front_shares=[{','.join(map(str, FRONT_SHARES))}]",
            "progress=false", "max_views=2", "sweep_views=1", f"mean_values=[{','.join(map(str, MEANS))}]",
            f"las_iprs=[{','.join(map(str, LAS_IPRS))}]", f"las_search_iprs=[{','.join(map(str, LAS_SEARCH_IPRS))}]",
            "las_searched=true", "grid_views=2", "warmup=0", *extra]


def _cli(args: list[str], timeout: int = 300) -> subprocess.CompletedProcess:
    # one torch thread: on a shared 2-core machine two spinning OpenMP threads slow every conv down
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "imls_lightning.evaluate", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


def _rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as f:
        r = csv.DictReader(f)
        return list(r.fieldnames or []), list(r)


def _method_rows(run: dict, method: str) -> list[dict[str, str]]:
    """The rows of ``metrics.csv`` of an evaluation ``run`` that measured ``method``."""
    return [r for r in _rows(run["out"] / "metrics.csv")[1] if r["method"] == method]


@pytest.fixture(scope="module")
def run(tiny_checkpoints):
    t0 = time.perf_counter()
    p = _cli(_args(tiny_checkpoints))
    took = time.perf_counter() - t0
    assert p.returncode == 0, f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    report = Path(p.stdout.strip().splitlines()[-1])
    return {"proc": p, "report": report, "out": report.parent, "ck": tiny_checkpoints, "took": took}


# ---- the evaluation's files -------------------------------------------------------------------
def test_cli_prints_the_report_path_last(run):
    assert run["report"].name == "report.md" and run["report"].is_file()
    assert run["out"].parent == run["ck"]["runs_dir"] / "eval" and run["out"].name.startswith("tiny-enhancenet-")
    assert not list(run["out"].glob(".*.tmp")), "a temporary file was left behind"


def test_metrics_csv_has_every_method_and_stage(run):
    columns, rows = _rows(run["out"] / "metrics.csv")
    for col in [f"{s}_ms" for s in STAGES] + ["total_ms", "ipr", "psnr", "ssim", "view", "method"]:
        assert col in columns, col
    assert [r["method"] for r in rows[:len(METHOD_ORDER)]] == list(METHOD_ORDER)
    assert sorted((r["view"], r["method"]) for r in rows) == sorted((v, m) for v in {r["view"] for r in rows} for m in METHOD_ORDER)
    assert len({r["view"] for r in rows}) == 2
    for r in rows:
        stages = METHOD_STAGES[r["method"]]
        for s in STAGES:
            cell = r[f"{s}_ms"]
            if s in stages:
                assert float(cell) >= 0.0, (r["method"], s)
            else:
                assert cell == "", (r["method"], s, cell)
        assert float(r["total_ms"]) > 0.0
        assert 0.0 <= float(r["ipr"]) <= 1.0 and math.isfinite(float(r["psnr"])) and -1.0 <= float(r["ssim"]) <= 1.0
    full = [r for r in rows if r["method"] == "full"]
    assert all(float(r["psnr"]) == 100.0 and float(r["ipr"]) == 1.0 for r in full)  # the cache's own renderer
    recnn = [r for r in rows if r["method"] == "recnn"]
    assert all(float(r["ipr"]) == 0.25 for r in recnn)  # EnhanceNet's downsampling pattern: a quarter of the pixels
    sparser = [r for r in rows if r["method"] == "recnn_sparser"]
    assert all(float(r["ipr"]) == 1 / 16 and float(r["c_share"]) == 1.0 for r in sparser)  # 4x: a quarter of C
    s = summary(run["out"] / "metrics.csv")
    assert list(s) == list(METHOD_ORDER) and s["imls"]["views"] == 2


def _training_cache(ck: dict):
    """The tiny training cache (data.seed 0; the held-out one is seed 1) the module's checkpoints were trained on."""
    from data_gen.cache import ViewImageCache

    return next(c for c in (ViewImageCache.open(p) for p in sorted(ck["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)


def _compose(*overrides: str):
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_evaluate"):
        return compose("evaluate", overrides=list(overrides))


def test_stage_times_are_medians_of_at_least_ten_runs(run):
    from imls_lightning.evaluation import evaluate

    settings = yaml.safe_load((run["out"] / "config.yaml").read_text())["settings"]
    assert settings["repeats"] == 10
    assert "median of 10 runs" in run["report"].read_text()
    for bad in ("repeats=9", "repeats=0", "repeats=true"):
        with pytest.raises(InputError, match=r"repeats=.*expected an integer >= 10"):
            evaluate(_compose(*_args(run["ck"], bad)))


def test_timed_views_interleave_the_methods_by_default(run):
    """timing=interleaved (the default): each timed view's methods run in rounds, so a load that comes and goes
    slows them alike; the report and summary.json say so, and blocked (the order before the key) keeps the
    directories of the evaluations made before it."""
    from imls_lightning.evaluation import evaluate, parse_settings

    assert "the methods interleaved run by run" in run["report"].read_text()
    summ = json.loads((run["out"] / "summary.json").read_text())
    assert summ["timing"] == "interleaved" and summ["repeats"] == 10
    s = parse_settings(_compose(*_args(run["ck"])))
    assert s.timing == "interleaved" and s.hashed()["timing"] == "interleaved"
    blocked = parse_settings(_compose(*_args(run["ck"], "timing=blocked")))
    assert blocked.timing == "blocked" and "timing" not in blocked.hashed()
    with pytest.raises(InputError, match=re.escape("timing=shuffled: expected one of ['interleaved', 'blocked']")):
        evaluate(_compose(*_args(run["ck"], "timing=shuffled")))


def test_sweep_csv_means_and_las_iprs(run):
    _, rows = _rows(run["out"] / "sweep.csv")
    got = {(r["method"], float(r["value"])) for r in rows}
    assert got == ({(m, u) for m in ("iml", "iml_selective") for u in MEANS} | {("las", p) for p in LAS_IPRS}
                   | {("imls", s) for s in FRONT_SHARES} | {("blue_noise", s) for s in FRONT_SHARES if s < 1})
    by = {(r["method"], float(r["value"]), r["view"]): r for r in rows}
    for u in MEANS:
        for (m, v, view), r in by.items():
            if m == "iml" and v == u:
                sel = by[("iml_selective", u, view)]
                # the IML's mask, selectively rendered: the same pixels and (exact selective render) the same image
                assert sel["ipr"] == r["ipr"] and float(sel["psnr"]) == pytest.approx(float(r["psnr"]), abs=1e-6)
                assert int(float(sel["rendered_pixels"])) < int(float(r["rendered_pixels"])) or float(r["ipr"]) == 0.25
    view = rows[0]["view"]
    assert float(by[("iml", MEANS[1], view)]["ipr"]) > float(by[("iml", MEANS[0], view)]["ipr"])  # higher u, more pixels
    las = [r for r in rows if r["method"] == "las"]
    assert all(abs(float(r["ipr"]) - LAS_IPRS[0]) < 0.03 for r in las)


def test_report_has_the_paper_tables(run):
    text = run["report"].read_text()
    for needle in ("# IML/S evaluation: tiny, enhancenet", "| scene | tiny |", "| RecNN | enhancenet |",
                   "32×32", "C-Image size | 16×16", "| renderer | numba |", "python -m imls_lightning.evaluate",
                   "## Average latency per method and stage (ms)", "## Speed-up of IML/S + RecNN", "over RecNN alone",
                   "over LAS", "over LAS at the promise", "over Full ray cast", "## Average image quality", "## Latency / PSNR sweep",
                   "IML IM, selectively rendered", "IPR=0.1", "u=0.3"):
        assert needle in text, needle
    table = text.split("## Average latency per method and stage (ms)")[1].split("\n\n")[1]
    lines = table.splitlines()
    assert lines[0].startswith("| Method | IPR |") and "RecNN (ms)" in lines[0] and "decoder (ms)" in lines[0]
    assert [ln.split("|")[1].strip() for ln in lines[2:]] == ["Full ray cast", "RecNN alone", "RecNN alone, sparser pattern", "LAS",
                                                              "LAS at the promise (its IPR searched)",
                                                              "LAS at equal quality (within 0.1 dB of IML/S)", "IML + RecNN",
                                                              "IML/S + RecNN", "IML/S mask + fill + RecNN",
                                                              "blue noise + decoder + RecNN", "two passes + fill + RecNN (no IMS)",
                                                              "RecNN alone, every sample marched",
                                                              "IML/S + RecNN, every sample marched"]
    # the speed-up over the RecNN alone is its total over IML/S's total
    s = summary(run["out"] / "metrics.csv")
    ratio = s["recnn"]["latency_ms"]["total"] / s["imls"]["latency_ms"]["total"]
    assert f"**{ratio:.2f}×**" in text.split("## Speed-up of IML/S + RecNN")[1].split("##")[0]
    for name in PLOTS:
        assert f"]({name})" in text, name


def test_the_speedup_comes_with_its_interval_over_the_timed_views(run):
    """summary.json's ``speedup_interval``: every timed method over the RecNN alone, from the per-view totals of
    metrics.csv; the report's speed-up table shows IML/S's, with the number of views it resampled."""
    from imls_lightning.report.speedup import speedup_intervals

    summ = json.loads((run["out"] / "summary.json").read_text())
    with open(run["out"] / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    again = speedup_intervals(rows)
    assert list(summ["speedup_interval"]) == list(again)
    for method, iv in again.items():
        # metrics.csv keeps 6 significant digits: a bootstrap quantile on them moves by a few parts in a million
        assert summ["speedup_interval"][method] == pytest.approx(iv, rel=1e-4), method
    imls = summ["speedup_interval"]["imls"]
    s = summary(run["out"] / "metrics.csv")
    assert imls["speedup"] == pytest.approx(s["recnn"]["latency_ms"]["total"] / s["imls"]["latency_ms"]["total"])
    assert imls["low"] <= imls["speedup"] <= imls["high"] and imls["views"] == summ["timed_views"]
    assert "recnn" not in summ["speedup_interval"] and "full" in summ["speedup_interval"]
    table = run["report"].read_text().split("## Speed-up of IML/S + RecNN")[1].split("##")[0]
    assert "95% interval (timed views resampled)" in table
    line = next(ln for ln in table.splitlines() if ln.startswith("| over RecNN alone"))
    assert f"({imls['views']} views)" in line


def test_plots_and_image_grid_are_pngs(run):
    from matplotlib.image import imread

    for name in PLOTS:
        path = run["out"] / name
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        h, w = imread(path).shape[:2]
        assert h > 100 and w > 100, (name, h, w)
    h, w = imread(run["out"] / "image_grid.png").shape[:2]
    assert w > 3 * h  # 2 view rows x (truth + 7 methods + 7 error maps + IM) columns


def test_orp_on_the_product_path_and_the_untrained_baselines(run):
    text = run["report"].read_text()
    orp = text.split("## ORP on the product path")[1].split("\n## ")[0]
    assert "IMS mask from the view" in orp or "No mean value" in orp
    settings = yaml.safe_load((run["out"] / "config.yaml").read_text())["settings"]
    assert settings["orp"] is True and settings["epsilon_db"] == 1.0
    table = text.split("## Learned parts against untrained baselines, at equal share")[1].split("\n## ")[0]
    for needle in ("decoder − fill", "mask − blue noise", "IMS (from the view)", "IML (from the C-Image)",
                   "blue noise (untrained)", "| 10 % |", "| 20 % |", "| 40 % |", "density: background"):
        assert needle in table, needle
    _, rows = _rows(run["out"] / "metrics.csv")
    # the fill baseline renders exactly the product's pixels
    by = {(r["view"], r["method"]): r for r in rows}
    for v in {r["view"] for r in rows}:
        assert by[(v, "imls_fill")]["rendered_pixels"] == by[(v, "imls")]["rendered_pixels"]


def test_the_speed_quality_front_puts_every_method_on_the_same_views(run):
    import json

    text = run["report"].read_text()
    front = text.split("## Speed-quality front")[1].split("\n## ")[0]
    for needle in ("RecNN alone, sparser pattern", "| IML/S + RecNN | 20% of C |", "100% of C", "ORP u=", "IPR=0.1",
                   "u=0.3", "blue noise + decoder + RecNN", "Full ray cast", "◆", "Where IML/S lies: **tiny**",
                   "](speed_quality_front.png)"):
        assert needle in front, needle
    assert "IML IM, selectively rendered" not in front  # no method a user can run
    summ = json.loads((run["out"] / "summary.json").read_text())
    pts, views = summ["front"], summ["front_views"]
    assert len(views) == 1 and all(p["views"] == 1 for p in pts)  # sweep_views=1: every point on that view
    assert {p["method"] for p in pts} >= {"full", "recnn", "recnn_sparser", "las", "iml", "imls", "imls_fill", "blue_noise"}
    assert sum(p["method"] == "imls" for p in pts) == 1 + len(FRONT_SHARES)
    # the marks are the Pareto front of the points (report.front.pareto_front, tested against its definition)
    from imls_lightning.report import pareto_front

    assert [p["on_front"] for p in pts] == pareto_front([p["latency_ms"] for p in pts], [p["psnr"] for p in pts])
    # IML/S at 100% of C renders the whole pattern: the RecNN alone's image (the decoder keeps every given pixel)
    full_c = next(p for p in pts if p["method"] == "imls" and p.get("value") == 1.0)
    assert full_c["c_share"] == 1.0
    _, rows = _rows(run["out"] / "metrics.csv")
    recnn = next(r for r in rows if r["method"] == "recnn" and int(r["view"]) == views[0])
    assert full_c["psnr"] == pytest.approx(float(recnn["psnr"]), abs=1e-6)


def test_orp_gap_on_validation_and_test_views_side_by_side(run):
    import json

    orp = json.loads((run["out"] / "summary.json").read_text())["orp"]
    assert orp["confidence"] == 0.95 and orp["test"]["views"] == 2 and orp["future_views"] == 2
    # searched on held-out views: 4 (orp_max_views) of their own, drawn with data.seed + 1
    assert orp["where"] == "4 held-out views (seed 1: no network trained on them)" and orp["views"] == 4
    if orp["found"]:
        assert orp["gap_db"] <= orp["gap_bound_db"] <= orp["epsilon_db"]
    s = summary(run["out"] / "metrics.csv")
    assert orp["test"]["gap_db"] == pytest.approx(s["recnn"]["psnr"] - s["imls"]["psnr"], abs=1e-6)
    section = run["report"].read_text().split("## ORP on the product path")[1].split("\n## ")[0]
    if orp["found"]:
        assert "| 4 held-out views (seed 1: no network trained on them) (the ORP is chosen here) | 4 |" in section
        assert "the test trajectory, evaluated (never tuned on)" in section
        assert "Its gap on the evaluated views by camera distance" in section
    assert "gap bound (dB)" in section
    # where on the test views the gap is lost: by camera distance, in equal-count bins of the evaluated views
    bins = orp["test_by_distance"]
    assert sum(b["views"] for b in bins) == 2 and len(bins) == 2 and bins[0]["hi"] <= bins[1]["lo"]
    assert np.mean([b["gap_db"] for b in bins]) == pytest.approx(orp["test"]["gap_db"], abs=1e-6)
    # and where the trade pays: each bin's speed-up over its timed views, from metrics.csv's totals
    summ = json.loads((run["out"] / "summary.json").read_text())
    assert sum(b["timed_views"] for b in bins) == summ["timed_views"]
    totals = {(r["method"], int(r["view"])): float(r["total_ms"]) for r in csv.DictReader(open(run["out"] / "metrics.csv")) if r["total_ms"]}
    for b in bins:
        assert (b["speedup"] is None) == (b["timed_views"] == 0)
    if [b["timed_views"] for b in bins] == [1, 1]:  # one view a bin: each bin's speed-up is its view's
        ratios = [totals[("recnn", v)] / totals[("imls", v)] for (m, v) in totals if m == "imls"]
        assert sorted(ratios) == pytest.approx(sorted(b["speedup"] for b in bins), rel=1e-6)
    if orp["found"]:
        assert "speed-up (timed views)" in section


def test_orp_search_views_path_are_exploratory_paths_of_their_own_seeds(run):
    """orp_views=path: the views of orp_paths exploratory paths drawn like the test trajectory, from seeds 1, 2, ...,
    never the evaluated cache's test trajectory (seed 0); each row's path label says which."""
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from data_gen.views import exploration_trajectory
    from imls_lightning.evaluation import orp_search_views, parse_settings

    cfg = _compose(*_args(run["ck"], "orp_views=path", "orp_paths=2"))
    caches = [ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*"))]
    main = next(c for c in caches if c.manifest["data"]["seed"] == 0)
    scene = build_scene(cfg.scene)
    held, rows, where, paths = orp_search_views(parse_settings(cfg), cfg, main, scene)
    assert held.path != main.path and len(rows) == 4 and list(rows) == list(held.splits["test"]) and paths == [0, 0, 1, 1]
    assert where == "4 views on 2 exploratory paths of their own (seeds 1-2: no network trained on them)"
    jitter = float(cfg.data.lookat_jitter)
    want = np.concatenate([exploration_trajectory(2, scene.camera_distance, seed=k, lookat_jitter=jitter) for k in (1, 2)])
    np.testing.assert_allclose(np.asarray(held.views[rows]), want, atol=1e-6)
    assert not np.allclose(np.asarray(held.views[rows]), np.asarray(main.views[main.splits["test"]])[:4], atol=1e-3)
    # the same settings find the same cache and views file again
    again = orp_search_views(parse_settings(cfg), cfg, main, scene)
    assert again[0].path == held.path and list(again[1]) == list(rows)


@pytest.mark.parametrize("args, message", [
    (["orp_paths=1"], "orp_paths=1: expected an integer >= 2"),
    (["orp_views=path", "orp_paths=3"], "orp_max_views=4: orp_views=path needs at least 2 views per path (orp_paths=3)"),
])
def test_exception_orp_paths(run, args, message):
    from imls_lightning.evaluation import parse_settings

    with pytest.raises(InputError, match=re.escape(message)):
        parse_settings(_compose(*_args(run["ck"], *args)))


def test_exception_orp_paths_seeds_must_not_include_the_test_trajectorys(run):
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import orp_search_views, parse_settings

    cfg = _compose(*_args(run["ck"], "orp_views=path", "orp_paths=2", "orp_views_seed=0"))
    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    with pytest.raises(InputError, match=re.escape("orp_views_seed=0: the search paths' seeds 0-1 include data.seed=0")):
        orp_search_views(parse_settings(cfg), cfg, main, build_scene(cfg.scene))


@pytest.mark.slow  # two ORP searches on real networks; the banded bound itself: tests/orp/test_search.py
def test_orp_strata_judges_the_bound_in_each_band_of_camera_distance(run):
    """orp_strata=2: the ORP's bound must hold in both distance bands of the search views, so it is never a lower
    mean value than the bound over all of them; the record keeps each band's mean gap."""
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import product_path_orp

    caches = [ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*"))]
    main = next(c for c in caches if c.manifest["data"]["seed"] == 0)
    results = {}
    for k in (1, 2):
        cfg = _compose(*_args(run["ck"], f"orp_strata={k}"))
        s = parse_settings(cfg)
        assert s.orp_strata == k and ("orp_strata" in s.hashed()) == (k != 1)  # earlier evaluations keep their folders
        nets = load_networks(s, int(cfg.data.resolution))
        results[k] = product_path_orp(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    one, two = results[1], results[2]
    assert "in each of 2 equal-count bands of camera distance" in two.where and "bands" not in one.where
    rec = two.evaluations[0].record
    assert len(rec["strata_gap_db"]) == 2 and rec["gap_bound_db"] >= max(rec["strata_gap_db"]) - 1e-9
    assert "strata_gap_db" not in one.evaluations[0].record
    if two.found:
        assert one.found and two.mean >= one.mean - 0.05  # the search's tolerance
    with pytest.raises(InputError, match=re.escape("orp_strata=0: expected an integer >= 1")):
        parse_settings(_compose(*_args(run["ck"], "orp_strata=0")))


@pytest.mark.slow  # an ORP search on real networks; the pass bound itself: tests/orp, tests/inference/test_baselines.py
def test_orp_on_path_views_counts_passes_and_the_report_says_so(run):
    """orp_views=path: the search's bound counts passes (here each of the 2 paths is one pass), the summary records
    how many, and the report's rule names them instead of the per-view bound."""
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import orp_summary, product_path_orp
    from imls_lightning.report.document import _orp_lines

    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    cfg = _compose(*_args(run["ck"], "orp_views=path", "orp_paths=2"))
    s = parse_settings(cfg)
    assert s.hashed()["orp_paths"] == 2 and "orp_paths" not in parse_settings(_compose(*_args(run["ck"]))).hashed()
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    assert "(2 passes: the bound counts passes)" in res.where
    assert all(e.record.get("passes") == 2 for e in res.evaluations if e.status == "ok")
    orp = orp_summary(res, s, lifted=res.lifted)
    assert orp["passes"] == (2 if res.found else None)
    if res.found:
        assert "over the 2 search passes' mean gaps" in "\n".join(_orp_lines(orp, "test"))


def test_orp_by_distance_gives_each_band_its_own_mean_value(run):
    """orp_by_distance=true: after the banded search each band of camera distance searches its own mean value on its
    own search views (never above the value that held in every band); IML/S then runs each view at its band's, the
    summary and the record carry the bands. It needs orp_strata >= 2 (a one-line error)."""
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import distance_means, orp_summary, product_path_orp

    caches = [ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*"))]
    main = next(c for c in caches if c.manifest["data"]["seed"] == 0)
    cfg = _compose(*_args(run["ck"], "orp_strata=2", "orp_by_distance=true", "orp_confidence=0.5"))
    s = parse_settings(cfg)
    assert s.orp_by_distance and s.hashed()["orp_by_distance"] is True
    assert "orp_by_distance" not in parse_settings(_compose(*_args(run["ck"], "orp_strata=2"))).hashed()  # earlier folders kept
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    assert res.found and "then each band's own mean value" in res.where
    b = res.by_distance
    assert len(b["means"]) == 2 and all(u <= res.mean + 1e-12 for u in b["means"]) and b["views"] == [2, 2]
    assert b["hi"][0] < b["edges"][0] < b["lo"][1] and all(g <= 1.0 + 1e-9 for g in b["gaps_db"])  # confidence 0.5: the mean
    sched = distance_means(res)
    assert sched.means.tolist() == pytest.approx(b["means"]) and distance_means(None) is None
    orp = orp_summary(res, s, lifted=res.lifted)
    assert orp["by_distance"] is b
    from imls_lightning.report.document import _orp_lines

    section = "\n".join(_orp_lines(orp, "test"))
    assert "**By camera distance** (`orp_by_distance`): each of the 2 bands" in section
    assert f"| {b['lo'][0]:.2f}-{b['hi'][0]:.2f} | {b['edges'][0]:.3f} | 2 | {b['means'][0]:.4f} |" in section
    # IML/S runs each search view at its band's mean value
    from imls_lightning.render.camera import view_tensor

    near, _ = _band_ends(b)
    assert float(sched(view_tensor(near, "cpu"))[0]) == pytest.approx(b["means"][0])
    with pytest.raises(InputError, match=re.escape("orp_by_distance=true: needs orp_strata >= 2 (got 1)")):
        parse_settings(_compose(*_args(run["ck"], "orp_by_distance=true")))
    with pytest.raises(InputError, match=re.escape("orp_by_distance=maybe: expected true or false")):
        parse_settings(_compose(*_args(run["ck"], "orp_strata=2", "orp_by_distance=maybe")))


def test_orp_searched_at_each_mask_sharpness_keeps_the_smallest_share(run, tmp_path):
    """ims_sharpness=[1, 3]: the ORP is searched at each sharpness, the point that ray-casts the smallest share of C
    is kept, the task's masks stay at it, and the summary and the record beside the checkpoint carry it (a renderer
    built from the checkpoint alone then makes the same masks). Bad values are one-line errors."""
    import shutil

    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import operating_share, orp_summary, point_of, product_path_orp, record_operating_point
    from imls_lightning.inference.checkpoints import load_product

    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    cfg = _compose(*_args(run["ck"], "ims_sharpness=[3,1]", "orp_confidence=0.5"))
    s = parse_settings(cfg)
    assert s.ims_sharpness == [1.0, 3.0] and s.hashed()["ims_sharpness"] == [1.0, 3.0]
    assert "ims_sharpness" not in parse_settings(_compose(*_args(run["ck"]))).hashed()  # earlier folders kept
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    cands = res.sharpness_candidates
    assert [c["sharpness"] for c in cands] == [1.0, 3.0]
    found = [c for c in cands if c["found"]]
    assert found and res.sharpness == min(found, key=lambda c: (c["c_share"], c["sharpness"]))["sharpness"]
    assert operating_share(res) == pytest.approx(min(c["c_share"] for c in found))
    assert nets.ims_task.mask_head.sharpness == 1.0  # the search leaves the IMS task as it is
    orp = orp_summary(res, s, lifted=res.lifted)
    assert point_of(orp, res.mean, res.lifted).sharpness == res.sharpness  # the point carries the sharpness kept
    assert orp["sharpness"] == res.sharpness and orp["sharpness_candidates"] is cands
    from imls_lightning.report.document import _orp_lines

    section = "\n".join(_orp_lines(orp, "test"))
    assert f"the point that ray-casts the smallest share of C on the search views was kept: **γ = {res.sharpness:.2f}**" in section
    assert "| γ | decoder | ORP found | u | C-share (search views) | lifted | product (ms, search views) |" in section
    # the record travels with a copy of the checkpoint: its renderers sharpen their masks the same way
    ck = tmp_path / "ims.ckpt"
    shutil.copy(s.ims, ck)
    record_operating_point(dataclasses.replace(s, ims=str(ck)), {**orp, "sharpness": 3.0}, "tiny", tmp_path / "report.md", 2)
    product = load_product(ck)
    assert product.record.sharpness == 3.0 and product.point.sharpness == 3.0
    assert "sharpness 3" in product.record.describe()
    for bad, msg in (("ims_sharpness=0.5", "ims_sharpness=0.5: expected a number in [1, 8]"),
                     ("ims_sharpness=[]", "ims_sharpness=[]: expected a number or a list"),
                     ("ims_sharpness=[1,nan]", "ims_sharpness=nan")):
        with pytest.raises(InputError, match=re.escape(msg)):
            parse_settings(_compose(*_args(run["ck"], bad)))


def test_mask_sharpness_candidates_timed_on_the_search_views_the_fastest_kept(run):
    """With the evaluation's renderer, the found candidates' products (mask at each point, its pixels ray-cast,
    decoder, RecNN) are timed interleaved on ims_sharpness_views search views and the fastest is kept; the report
    says so. ims_sharpness_views=0 keeps the smallest share (the rule without a renderer)."""
    from data_gen.cache import ViewImageCache
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import orp_summary, product_path_orp
    from imls_lightning.report.document import _orp_lines

    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    # a loose bound: both sharpnesses find a point, so there is a choice to time
    cfg = _compose(*_args(run["ck"], "ims_sharpness=[1,3]", "orp_confidence=0.5", "epsilon_db=30", "ims_sharpness_views=2"))
    s = parse_settings(cfg)
    assert s.ims_sharpness_views == 2 and s.hashed()["ims_sharpness_views"] == 2
    scene = build_scene(cfg.scene)
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, scene, nets, nets.ims_task.pattern, "cpu", future_views=2,
                           renderer=make_renderer(scene, {"name": "numba"}))
    cands = res.sharpness_candidates
    assert all(c["found"] for c in cands) and all(c["ms"] > 0 for c in cands)
    assert res.sharpness == min(cands, key=lambda c: (c["ms"], c["sharpness"]))["sharpness"]
    section = "\n".join(_orp_lines(orp_summary(res, s, lifted=res.lifted), "test"))
    assert "whose product ran fastest on the search views" in section and f"**γ = {res.sharpness:.2f}**" in section
    by_share = parse_settings(_compose(*_args(run["ck"], "ims_sharpness=[1,3]", "orp_confidence=0.5", "epsilon_db=30",
                                              "ims_sharpness_views=0")))
    res0 = product_path_orp(by_share, cfg, main, scene, nets, nets.ims_task.pattern, "cpu", future_views=2,
                            renderer=make_renderer(scene, {"name": "numba"}))
    assert all(c["ms"] is None for c in res0.sharpness_candidates)
    assert res0.sharpness == min(res0.sharpness_candidates, key=lambda c: (c["c_share"], c["sharpness"]))["sharpness"]
    assert "ims_sharpness_views" not in parse_settings(_compose(*_args(run["ck"]))).hashed()
    with pytest.raises(InputError, match="ims_sharpness_views"):
        parse_settings(_compose(*_args(run["ck"], "ims_sharpness_views=-1")))


def test_orp_decoders_searched_as_candidates_the_fastest_kept_and_carried_by_the_point(run, tmp_path):
    """orp_decoders=[trained, fill]: the ORP is searched with the IMS's own decoder and with the pull-push fill of the
    same pixels, each found point's product timed on the search views and the fastest kept; the summary, the point,
    the record beside the checkpoint and a renderer built from it all carry the decoder kept, and where it is the fill
    the evaluation also runs the trained decoder at its own point (imls_trained). Bad values are one-line errors."""
    import shutil

    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import (candidate_key, orp_summary, point_of, product_path_orp,
                                                           record_operating_point, trained_decoder_point)
    from imls_lightning.inference.pipeline import IMLSRenderer
    from imls_lightning.models.iml import FillDecoder
    from imls_lightning.render import make_renderer
    from imls_lightning.report.document import _orp_lines

    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    cfg = _compose(*_args(run["ck"], "orp_decoders=[trained,fill]", "orp_confidence=0.5", "epsilon_db=30",
                          "ims_sharpness_views=2"))
    s = parse_settings(cfg)
    assert s.orp_decoders == ["trained", "fill"] and s.hashed()["orp_decoders"] == ["trained", "fill"]
    assert s.hashed()["ims_sharpness_views"] == 2  # two candidates: how they are timed is part of the result
    assert "orp_decoders" not in parse_settings(_compose(*_args(run["ck"]))).hashed()  # earlier folders kept
    scene = build_scene(cfg.scene)
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, scene, nets, nets.ims_task.pattern, "cpu", future_views=2,
                           renderer=make_renderer(scene, {"name": "numba"}))
    cands = res.sharpness_candidates
    assert [c["decoder"] for c in cands] == ["trained", "fill"] and all(c["found"] and c["ms"] > 0 for c in cands)
    fastest = min(cands, key=lambda c: (c["ms"], c["decoder"] != "trained"))
    assert res.decoder == fastest["decoder"] and candidate_key(res) == (1.0, res.decoder)
    orp = orp_summary(res, s, lifted=res.lifted)
    assert orp.get("decoder", "trained") == res.decoder
    section = "\n".join(_orp_lines(orp, "test"))
    assert f"**decoder {res.decoder}**" in section and "`orp_decoders`" in section

    # the fill kept (whatever the timing said above): the point, its record and a renderer from the checkpoint carry it
    fill = {**orp, "decoder": "fill", "sharpness_candidates": cands}
    point = point_of(fill, res.mean, res.lifted)
    assert point.decoder == "fill" and point_of({**orp, "decoder": None}, res.mean, res.lifted).decoder == "trained"
    own = trained_decoder_point(fill)
    assert own is not None and own.decoder == "trained" and own.share == pytest.approx(cands[0]["mean"])
    assert trained_decoder_point({**fill, "decoder": "trained"}) is None
    ims = nets.ims_task
    r = IMLSRenderer(make_renderer(scene, {"name": "numba"}), ims.pattern, ims.mask_head, ims.decoder, nets.recnn, point=point)
    assert isinstance(r.decoder, FillDecoder)
    ck = tmp_path / "ims.ckpt"
    shutil.copy(s.ims, ck)
    record_operating_point(dataclasses.replace(s, ims=str(ck)), fill, "tiny", tmp_path / "report.md", 2)
    from imls_lightning.inference.checkpoints import load_product

    product = load_product(ck)
    assert product.record.decoder == "fill" and product.point.decoder == "fill"
    assert "the pull-push fill as decoder" in product.record.describe()
    # the evaluation's methods: IML/S rebuilds with the fill, and the trained decoder runs beside it at its own point
    from imls_lightning.evaluation.run import build_methods

    rows_all = main.splits["val"]
    notes: list[str] = []
    methods, _ = build_methods(s, nets, make_renderer(scene, {"name": "numba"}), main, rows_all, [0], "cpu",
                               int(cfg.data.resolution), point, notes, orp=fill)
    assert isinstance(methods["imls"].decoder, FillDecoder) and methods["imls"].point.decoder == "fill"
    assert not isinstance(methods["imls_trained"].decoder, FillDecoder) and methods["imls_trained"].point == own
    assert any("imls_trained is the IMS's own decoder" in n for n in notes)
    methods, _ = build_methods(s, nets, make_renderer(scene, {"name": "numba"}), main, rows_all, [0], "cpu",
                               int(cfg.data.resolution), point.replace(decoder="trained"), [], orp={**fill, "decoder": "trained"})
    assert "imls_trained" not in methods and not isinstance(methods["imls"].decoder, FillDecoder)
    for bad in ("orp_decoders=[]", "orp_decoders=[refine]", "orp_decoders=[fill,fill]"):
        with pytest.raises(InputError, match=re.escape(f"{bad}: expected a non-empty list of distinct names")):
            parse_settings(_compose(*_args(run["ck"], bad)))


def test_object_floor_chosen_on_the_validation_views_travels_with_the_point(run, tmp_path):
    """orp_object_floor=[...]: after the search each candidate margin (no floor first) is judged on the cache's
    validation views at the found point; the cheapest whose bound holds is kept (a direct re-check of the rule), the
    task's masks carry it, and the summary, the report and the record beside the checkpoint say so (a renderer built
    from the checkpoint alone floors its masks the same way). Bad values are one-line errors."""
    import shutil

    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.operating_point import orp_summary, point_of, product_path_orp, record_operating_point
    from imls_lightning.inference.checkpoints import load_product
    from imls_lightning.report.document import _orp_lines

    main = next(c for c in (ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*")))
                if c.manifest["data"]["seed"] == 0)
    assert len(main.splits["val"]) == 2
    # a loose bound: a point is found, and more than one candidate holds, so the cheapest is a choice
    cfg = _compose(*_args(run["ck"], "orp_object_floor=[0.5,0.0]", "orp_confidence=0.5", "epsilon_db=30", "ims_lift=true"))
    s = parse_settings(cfg)
    assert s.orp_object_floor == [0.0, 0.5] and s.hashed()["orp_object_floor"] == {"margins": [0.0, 0.5], "tau": 0.2}
    assert "orp_object_floor" not in parse_settings(_compose(*_args(run["ck"]))).hashed()  # earlier folders kept
    nets = load_networks(s, int(cfg.data.resolution))
    res = product_path_orp(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    assert res.found
    f = res.object_floor
    assert [c["margin"] for c in f["candidates"]] == [None, 0.0, 0.5] and f["views"] == 2 and f["tau"] == 0.2
    shares = [c["c_share"] for c in f["candidates"]]
    assert shares[0] <= shares[1] + 1e-9 <= shares[2] + 2e-9  # a floor only adds pixels
    held = [c for c in f["candidates"] if c["gap_bound_db"] <= 30]
    best = min(held, key=lambda c: c["c_share"])
    assert (f["chosen"] is None) == (best["margin"] is None)
    orp = orp_summary(res, s, lifted=res.lifted)
    assert nets.ims_task.mask_head.object_floor is None  # the search leaves the IMS task as it is; the point carries the floor
    if f["chosen"] is not None:
        assert f["chosen"]["margin"] == best["margin"] and point_of(orp, res.mean, res.lifted).object_floor == (best["margin"], 0.2)
    else:
        assert point_of(orp, res.mean, res.lifted).object_floor is None
    assert orp["object_floor"] is f
    section = "\n".join(_orp_lines(orp, "test"))
    assert "**Object floor** (`orp_object_floor`)" in section and "| no floor |" in section
    # the record travels with a copy of the checkpoint: a floor chosen there floors its renderers' masks
    ck = tmp_path / "ims.ckpt"
    shutil.copy(s.ims, ck)
    chosen = {"margin": 0.5, "tau": 0.2, "c_share": shares[2], "gap_db": 0.1, "gap_bound_db": 0.2, "views": 2}
    record_operating_point(dataclasses.replace(s, ims=str(ck)), {**orp, "object_floor": {**f, "chosen": chosen}}, "tiny",
                           tmp_path / "report.md", 2)
    product = load_product(ck)
    assert product.record.object_floor == chosen and product.point.object_floor == (0.5, 0.2)
    for bad, msg in (("orp_object_floor=1.5", "orp_object_floor=1.5: expected a margin or a list of margins in [0, 1]"),
                     ("orp_object_floor=[0.1,nan]", "orp_object_floor=nan"),
                     ("orp_object_floor_tau=1", "orp_object_floor_tau=1: expected an importance in (0, 1)")):
        with pytest.raises(InputError, match=re.escape(msg)):
            parse_settings(_compose(*_args(run["ck"], bad)))


def test_object_floor_by_band_keeps_each_bands_cheapest_margin_that_holds_there():
    """orp_object_floor_by_band: from the candidates' per-view gaps and shares on the validation views, each band of
    camera distance keeps the cheapest margin whose bound on its own views (the stratified bound, a band per stratum)
    holds and that leaves at most tail of them over epsilon (a direct re-check); the chosen record's views are each at
    its band's margin; a band with no validation view takes the largest margin; without bands it is a one-line
    error."""
    from types import SimpleNamespace

    from imls_lightning.evaluation.operating_point import _object_floor_by_band
    from imls_lightning.models.ims import DistanceMeans
    from imls_lightning.orp import stratified_gap_bound

    rng = np.random.default_rng(3)
    d = np.array([2.0, 2.1, 2.2, 2.3, 3.1, 3.2, 3.3, 3.4, 3.5, 3.6])
    views = np.zeros((10, 9), np.float32)
    views[:, 2] = d
    cache = SimpleNamespace(views=views)
    near = d < 3.0
    # no floor: near views 1.5-2 dB off, far ones 0.2-1.4 (one over); margins close the gap, near ones need 0.2
    base = np.where(near, 1.5 + 0.5 * rng.random(10), 0.2 + 0.2 * rng.random(10))
    base[-1] = 1.4
    cands = []
    for margin, fix_near, fix_far in ((None, 1.0, 1.0), (0.0, 1.0, 0.4), (0.1, 0.6, 0.2), (0.2, 0.2, 0.1)):
        gaps = base * np.where(near, fix_near, fix_far)
        shares = np.where(near, 0.4, 0.2) + (0.0 if margin is None else margin)
        cands.append({"margin": margin, "gaps_db": gaps.tolist(), "c_shares": shares.tolist(), "gap_db": float(gaps.mean()),
                      "gap_bound_db": float(gaps.max()), "c_share": float(shares.mean()),
                      "views_over_epsilon": int((gaps > 1.0).sum())})
    bands = DistanceMeans([3.0], [0.4, 0.2])
    s = SimpleNamespace(orp_confidence=0.95, epsilon_db=1.0, orp_object_floor_tail=0.0)
    f = _object_floor_by_band(s, cache, list(range(10)), bands, [dict(c) for c in cands], 0.2, 20)

    def held(k, c):
        idx = (d >= 3.0) == bool(k)
        _, each = stratified_gap_bound(c["gaps_db"], (d >= 3.0).astype(int), 0.95, 20)
        return each[k].bound <= 1.0 and int((np.asarray(c["gaps_db"])[idx] > 1.0).sum()) == 0

    want = [min((c for c in cands if held(k, c)), key=lambda c: np.mean(np.asarray(c["c_shares"])[(d >= 3.0) == bool(k)]))["margin"]
            for k in (0, 1)]
    assert want == [0.2, 0.0]  # the near band needs the largest margin, the far one the object alone
    c = f["chosen"]
    assert f["by_band"] and c["band_margins"] == want and c["margin"] == 0.2
    pick = {0.2: 3, 0.0: 1}
    gaps = [cands[pick[want[int(x >= 3.0)]]]["gaps_db"][j] for j, x in enumerate(d)]
    assert c["gap_db"] == pytest.approx(np.mean(gaps)) and c["views_over_epsilon"] == 0
    assert all("gaps_db" not in x for x in f["candidates"]) and len(f["candidates"][0]["band_bounds_db"]) == 2
    from imls_lightning.report.document import _object_floor_lines

    section = "\n".join(_object_floor_lines(f, 1.0))
    assert "its band's margin (below)" in section and "near to far 0.20 / 0.00." in section
    assert "| C-share by band |" in section and section.count("\n| ") >= 2 + len(cands)
    # a tail of 1: the bound alone; the far band then needs no floor (its bound holds with one view over)
    loose = _object_floor_by_band(SimpleNamespace(orp_confidence=0.95, epsilon_db=1.0, orp_object_floor_tail=1.0), cache,
                                  list(range(10)), bands, [dict(c) for c in cands], 0.2, 20)
    assert loose["chosen"]["band_margins"][1] is None
    # a band no validation view falls in: the largest margin
    three = DistanceMeans([3.0, 9.0], [0.4, 0.2, 0.1])
    g3 = _object_floor_by_band(s, cache, list(range(10)), three, [dict(c) for c in cands], 0.2, 20)
    assert g3["chosen"]["band_margins"] == [0.2, 0.0, 0.2]
    with pytest.raises(InputError, match=re.escape("orp_object_floor_by_band=true: the operating point has no bands")):
        _object_floor_by_band(s, cache, list(range(10)), None, cands, 0.2, 20)


def test_object_floor_by_band_settings_and_their_errors():
    from imls_lightning.evaluation import parse_settings

    base = ["checkpoints.ims=ims.ckpt", "orp_object_floor=[0.0,0.1]"]
    s = parse_settings(_compose(*base, "orp_by_distance=true", "orp_strata=4", "orp_object_floor_by_band=true",
                                "orp_object_floor_tail=0.1"))
    assert s.orp_object_floor_by_band and s.orp_object_floor_tail == 0.1
    assert s.hashed()["orp_object_floor"] == {"margins": [0.0, 0.1], "tau": 0.2, "by_band": True, "tail": 0.1}
    assert parse_settings(_compose(*base)).hashed()["orp_object_floor"] == {"margins": [0.0, 0.1], "tau": 0.2}
    for bad, msg in ((["orp_object_floor_by_band=true"], "orp_object_floor_by_band=true: a margin per band of camera "
                      "distance needs the bands (orp_by_distance=true)"),
                     (["orp_object_floor_by_band=maybe"], "orp_object_floor_by_band='maybe': expected true or false"),
                     (["orp_object_floor_tail=1.5"], "orp_object_floor_tail=1.5: expected the share in [0, 1]")):
        with pytest.raises(InputError, match=re.escape(msg)):
            parse_settings(_compose(*base, *bad))


def test_object_floor_without_validation_views_is_a_one_line_error():
    from types import SimpleNamespace

    from imls_lightning.evaluation.operating_point import object_floor_point

    cache = SimpleNamespace(splits={"val": np.array([], dtype=np.int64)}, path="cache/x")
    with pytest.raises(InputError, match=re.escape("orp_object_floor: the cache cache/x has no validation views")):
        object_floor_point(SimpleNamespace(orp_object_floor=[0.1]), cache, None, None, "cpu", None, 2)


def test_orp_search_views_heldout_are_none_of_the_caches_views(run):
    from data_gen.cache import ViewImageCache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import orp_search_views, parse_settings

    cfg = _compose(*_args(run["ck"]))
    s = parse_settings(cfg)
    caches = [ViewImageCache.open(p) for p in sorted(run["ck"]["cache_dir"].glob("tiny-*"))]
    main = next(c for c in caches if c.manifest["data"]["seed"] == 0)  # the training cache (the held-out one is seed 1)
    held, rows, where, paths = orp_search_views(s, cfg, main, build_scene(cfg.scene))
    assert held.path != main.path and len(rows) == 4 and held.manifest["data"]["seed"] == 1 and paths is None
    # no held-out eye direction is one of the evaluated cache's (the IMS's cache shares those of the same seed)
    d = lambda v: v[:, :3] / np.linalg.norm(v[:, :3], axis=1, keepdims=True)  # noqa: E731
    cos = d(np.asarray(held.views[rows])) @ d(np.asarray(main.views)).T
    assert cos.max() < 0.9999
    val_cache, val_rows, val_where, _ = orp_search_views(parse_settings(_compose(*_args(run["ck"], "orp_views=val"))), cfg, main, None)
    assert val_cache is main and list(val_rows) == list(main.splits["val"]) and val_where.endswith("validation views")
    with pytest.raises(InputError, match=re.escape("orp_views=test: expected one of ['heldout', 'path', 'val']")):
        parse_settings(_compose(*_args(run["ck"], "orp_views=test")))


def test_exception_sparser_recnn_must_be_sparser_and_of_the_same_kind(run):
    from imls_lightning.evaluation import evaluate

    with pytest.raises(InputError, match=r"checkpoints.recnn_sparser=.*its pattern has 256 pixels, not at most half of the evaluation's 256"):
        evaluate(_compose(*_args(run["ck"], f"checkpoints.recnn_sparser={run['ck']['recnn']}", "output_dir=" + str(run["out"] / "x"))))
    for bad, needle in (("orp_confidence=1.0", "orp_confidence=1.0: expected a confidence in [0.5, 1)"),
                        ("front_shares=[0,0.5]", "front_shares=[0, 0.5]: expected numbers in (0.0, 1.0]")):
        with pytest.raises(InputError, match=re.escape(needle)):
            evaluate(_compose(*_args(run["ck"], bad)))


# ---- reuse and errors -------------------------------------------------------------------------------
def test_second_run_with_reuse_returns_the_report_at_once(run):
    before = {p.name: p.stat().st_mtime_ns for p in run["out"].iterdir()}
    t0 = time.perf_counter()
    p = _cli(_args(run["ck"], "reuse=true"))
    took = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr[-3000:]
    assert Path(p.stdout.strip().splitlines()[-1]) == run["report"] and "reusing it" in p.stderr
    assert {q.name: q.stat().st_mtime_ns for q in run["out"].iterdir()} == before  # nothing re-measured
    assert took < run["took"]  # no network built, nothing rendered (the first run measured 150 renders)


def test_an_interrupted_evaluation_resumes_at_the_view_it_was_measuring(run, tmp_path, monkeypatch, capsys):
    """A killed evaluation (a session's end) keeps its searched point and its measured views in partial/; the same
    command then measures only the rest, and writes what an uninterrupted run writes."""
    from imls_lightning.evaluation import evaluate
    from imls_lightning.evaluation import run as run_mod

    import shutil

    ims = tmp_path / "ims.ckpt"  # its own copy: these runs record their points beside it, not beside the module's
    shutil.copyfile(run["ck"]["ims_pim"], ims)
    args = [a for a in _args(run["ck"], "max_views=3", "shares=null", "mean_values=[0.1]", "grid_views=2")
            if not a.startswith("checkpoints.ims=")] + [f"checkpoints.ims={ims}"]
    measure, calls = run_mod.measure_methods, []

    def killed_at_the_second_view(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return measure(*a, **kw)

    out = tmp_path / "eval"
    monkeypatch.setattr(run_mod, "measure_methods", killed_at_the_second_view)
    with pytest.raises(KeyboardInterrupt):
        evaluate(_compose(*args, f"output_dir={out}"))
    assert not (out / "report.md").exists() and (out / "partial" / "point.json").is_file()
    assert len((out / "partial" / "views.jsonl").read_text().splitlines()) == 1
    shutil.copytree(out / "partial", tmp_path / "kept")  # for resume=false below

    def searched_again(*a, **kw):
        raise AssertionError("the operating point was searched again")

    calls.clear()
    monkeypatch.setattr(run_mod, "measure_methods", lambda *a, **kw: (calls.append(1), measure(*a, **kw))[1])
    monkeypatch.setattr(run_mod, "operating_point", searched_again)
    monkeypatch.setattr(run_mod, "two_pass_point", searched_again)
    capsys.readouterr()
    report = evaluate(_compose(*args, f"output_dir={out}"))
    assert len(calls) == 2 and "resuming: 1 of the 3 views already measured" in capsys.readouterr().err
    assert not (out / "partial").exists()  # a finished evaluation keeps no partial results
    assert "Resumed evaluation (sitting 2): 1 of the 3 views were measured in an earlier sitting" in report.read_text()

    monkeypatch.undo()  # the same settings uninterrupted: the same point and the same images
    whole = evaluate(_compose(*args, f"output_dir={tmp_path / 'whole'}"))
    a, b = (json.loads((r.parent / "summary.json").read_text()) for r in (report, whole))
    assert a["orp"]["mean"] == b["orp"]["mean"] and a["orp"]["points"] == b["orp"]["points"]
    assert a["two_pass"]["share"] == b["two_pass"]["share"] and a["las_ipr"] == pytest.approx(b["las_ipr"])
    psnr = lambda r: {(x["view"], x["method"]): float(x["psnr"]) for x in _rows(r.parent / "metrics.csv")[1]}  # noqa: E731
    assert psnr(report) == pytest.approx(psnr(whole), abs=1e-6) and len(psnr(report)) == 3 * len(a["methods"])
    assert (report.parent / "image_grid.png").is_file()
    assert "Resumed evaluation" not in whole.read_text()
    # resume=false starts over: the point is searched again
    (out / "report.md").unlink()
    shutil.copytree(tmp_path / "kept", out / "partial")
    monkeypatch.setattr(run_mod, "operating_point", searched_again)
    with pytest.raises(AssertionError, match="searched again"):
        evaluate(_compose(*args, f"output_dir={out}", "resume=false"))


def test_an_evaluation_uses_a_finished_ones_operating_point_with_orp_from(run, tmp_path, monkeypatch, capsys):
    """orp_from: the point another evaluation of the same IMS and RecNN searched, used unsearched on other views (the
    sparser-pattern baseline added beside a row, a new trajectory); its gaps measured afresh; other networks refused."""
    import shutil

    from imls_lightning.evaluation import evaluate
    from imls_lightning.evaluation import run as run_mod

    def searched_again(*a, **kw):
        raise AssertionError("the operating point was searched again")

    source = json.loads((run["out"] / "summary.json").read_text())
    assert set(source["checkpoints_sha256"]) >= {"ims", "las", "blue_noise", "recnn_sparser"}
    args = [*_args(run["ck"], "max_views=3", "shares=null", "mean_values=[0.1]", "grid_views=0"), f"orp_from={run['out']}"]
    monkeypatch.setattr(run_mod, "operating_point", searched_again)
    monkeypatch.setattr(run_mod, "two_pass_point", searched_again)
    record = Path(str(run["ck"]["ims_pim"]) + ".orp.json")
    recorded = record.read_bytes() if record.is_file() else None
    report = evaluate(_compose(*args, f"output_dir={tmp_path / 'borrowed'}"))
    got = json.loads((report.parent / "summary.json").read_text())
    assert got["imls_mean"] == source["imls_mean"] and got["orp"]["points"] == source["orp"]["points"]
    assert got["views"] == 3 and got["orp"]["test"]["views"] == 3  # its gap on these views, not the source's
    assert f"the evaluation in {run['out']} searched" in report.read_text()
    assert (record.read_bytes() if record.is_file() else None) == recorded  # the source's record stands
    # an evaluation from before the hashes were recorded: checked against the files its config.yaml names
    old = tmp_path / "old"
    shutil.copytree(run["out"], old)
    (old / "summary.json").write_text(json.dumps({k: v for k, v in source.items() if k != "checkpoints_sha256"}))
    again = evaluate(_compose(*[a for a in args if not a.startswith("orp_from=")], f"orp_from={old}",
                              f"output_dir={tmp_path / 'from_old'}"))
    assert json.loads((again.parent / "summary.json").read_text())["imls_mean"] == source["imls_mean"]
    # refused in one line: other networks, no point found, not an evaluation's folder
    other = tmp_path / "other"
    shutil.copytree(run["out"], other)
    (other / "summary.json").write_text(json.dumps({**source, "checkpoints_sha256": {**source["checkpoints_sha256"], "ims": "0" * 16}}))
    base = [a for a in args if not a.startswith("orp_from=")]
    with pytest.raises(InputError, match=r"orp_from=.*other: its checkpoints.ims is not this run's checkpoints.ims"):
        evaluate(_compose(*base, f"orp_from={other}", f"output_dir={tmp_path / 'x'}"))
    (other / "summary.json").write_text(json.dumps({**source, "orp": None}))
    with pytest.raises(InputError, match=r"orp_from=.*other: that evaluation found no operating point"):
        evaluate(_compose(*base, f"orp_from={other}", f"output_dir={tmp_path / 'x'}"))
    with pytest.raises(InputError, match=r"orp_from=.*: expected a finished evaluation's folder \(it has no summary.json\)"):
        evaluate(_compose(*base, f"orp_from={tmp_path}", f"output_dir={tmp_path / 'x'}"))


def test_python_api_reuses_the_same_directory(run):
    from imls_lightning.evaluation import evaluate

    assert evaluate(_compose(*_args(run["ck"], "reuse=true"))) == run["report"]
    with pytest.raises(InputError, match=r"checkpoints.ims=.*RecNNTask checkpoint, expected a IMSTask"):
        evaluate(_compose(*_args(run["ck"], f"checkpoints.ims={run['ck']['recnn']}")))
    with pytest.raises(InputError, match=r"checkpoints.las=/nonexistent/las.ckpt: file not found"):
        evaluate(_compose(*_args(run["ck"], "checkpoints.las=/nonexistent/las.ckpt")))


@pytest.mark.parametrize("override,needle", [
    ("scene=marschner_lobb", r"checkpoints.ims=.*: trained on scene=tiny, this evaluation uses scene=marschner_lobb .*allow_mismatch=true"),
    ("scene.transfer_function.colormap=viridis", r"trained on scene=tiny, this evaluation uses scene=tiny \(scene differs in transfer_function.colormap\)"),
    ("renderer=vtk", r"checkpoints.ims=.*: trained with renderer=numba, this evaluation uses renderer=vtk"),
])
def test_exception_scene_or_renderer_other_than_trained(tiny_checkpoints, tmp_path, override, needle):
    """Evaluating an IMS on another scene wrote a plausible but wrong report (issue 17, 5)."""
    from imls_lightning.evaluation import check_trained_on, evaluate, parse_settings

    args = [*_args(tiny_checkpoints), f"output_dir={tmp_path / 'out'}", override]
    with pytest.raises(InputError, match=needle) as e:
        evaluate(_compose(*args))
    assert "\n" not in str(e.value) and not (tmp_path / "out").exists()
    cfg = _compose(*args, "allow_mismatch=true")
    check_trained_on(cfg, parse_settings(cfg))  # the explicit override lets it through


@pytest.mark.parametrize("override,needle", [
    (None, "error: checkpoints.ims: required"),
    ("checkpoints.ims=/nonexistent/ims.ckpt", "error: checkpoints.ims=/nonexistent/ims.ckpt: file not found"),
])
def test_exception_missing_or_nonexistent_checkpoint(run, override, needle):
    args = [a for a in _args(run["ck"]) if not a.startswith("checkpoints.ims=")]
    p = _cli(args + ([override] if override else []))
    assert p.returncode == 2, (p.returncode, p.stderr[-2000:])
    assert "Traceback" not in p.stderr
    errors = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(needle), p.stderr[-2000:]
    assert p.stdout.strip() == ""


def test_write_report_with_options_and_without_sweeps(run, tmp_path):
    """The options table and plot (a failed option is reported, not plotted); no sweep rows: no sweep table."""
    from imls_lightning.report import OPTION_COLUMNS, ReportContext, read_csv, write_metrics_csv, write_report

    rows = read_csv(run["out"] / "metrics.csv")
    options = [
        {"option": "baseline", "first_call_s": 0.02, "importance_ms": 1.0, "decoder_ms": 2.0, "recnn_ms": 3.0,
         "networks_ms": 6.0, "total_ms": 9.0, "psnr": 20.0},
        {"option": "half", "first_call_s": 0.5, "importance_ms": 0.5, "decoder_ms": 1.0, "recnn_ms": 1.5,
         "networks_ms": 3.0, "total_ms": 6.0, "psnr": 19.9},
        {"option": "compile", "error": "RuntimeError: no C++ compiler"},
    ]
    write_metrics_csv(options, tmp_path / "options.csv", OPTION_COLUMNS)
    ctx = ReportContext(out=tmp_path, scene="tiny", recnn_name="enhancenet", resolution=32, c_size=16, pattern="p",
                        renderer="numba", views="test", positions=[0, 11], trajectory_len=12, repeats=10, warmup=0,
                        options={"device": "cpu"}, device="cpu", checkpoints={"IMS": "x.ckpt"}, iml_mean=0.1,
                        rows=rows, option_rows=options, order=list(METHOD_ORDER))
    report = write_report(ctx)
    text = report.read_text()
    assert report == tmp_path / "report.md"
    assert "## Inference options (IML/S network stages)" in text and "| half | 0.50 | 1.00 | 1.50 | **3.00** |" in text
    assert "failed: RuntimeError: no C++ compiler" in text
    assert "## Latency / PSNR sweep" not in text and "image_grid.png" not in text
    assert (tmp_path / "options.png").is_file() and (tmp_path / "latency_vs_psnr.png").is_file()
    _, back = _rows(tmp_path / "options.csv")
    assert [r["option"] for r in back] == ["baseline", "half", "compile"] and back[2]["error"].startswith("RuntimeError")


def test_summary_json_has_what_the_benchmarks_collect(run):
    import json

    s = json.loads((run["out"] / "summary.json").read_text())
    assert (s["scene"], s["recnn"], s["fr_size"], s["c_size"]) == ("tiny", "enhancenet", 32, 16)
    assert s["views"] == s["timed_views"] == 2 and s["sample_distance_voxels"] > 0
    assert s["skip_empty"] is True  # the renderer's default: bench_paper's skip_empty column
    assert set(METHOD_ORDER) <= set(s["methods"]) and s["orp"] is not None and s["equal_share"]
    # the same numbers as the report's metrics.csv
    assert s["methods"]["imls"]["psnr"] == pytest.approx(summary(run["out"] / "metrics.csv")["imls"]["psnr"])
    # and make bench-paper's CSV row from it (imls_lightning.bench_paper)
    from imls_lightning.pipelines.bench_paper import CSV_COLUMNS, csv_row, read_summary

    row = csv_row(read_summary(run["report"]))
    assert tuple(row) == CSV_COLUMNS and all(math.isfinite(float(row[k])) for k in ("psnr_imls_db", "imls_ms", "speedup", "las_ms",
                                                                               "las_searched_ipr", "las_searched_ms", "las_searched_psnr_db"))
    # the other jobs while its views were timed: the row's timing_busy_cores, a line in the report
    load = s["timing_load"]
    assert load is None or (load["views"] == 2 and 0.0 <= load["mean"] <= load["max"] <= os.cpu_count())
    if load is not None:
        assert row["timing_busy_cores"] == load["max"]
        assert f"while the {load['views']} timed views ran" in run["report"].read_text()


def test_timed_views_smoke_times_a_subset_and_scores_every_view(run, tmp_path):
    from imls_lightning.evaluation import evaluate

    # the cheapest evaluation that still has an untimed view: no ORP, no equal-share table, one sweep point, no grid
    report = evaluate(_compose(*_args(run["ck"], "max_views=2", "timed_views=1", "orp=false", "shares=null", "mean_values=[0.1]",
                                      "grid_views=0", f"output_dir={tmp_path / 'eval'}")))
    _, rows = _rows(report.parent / "metrics.csv")
    assert len({r["view"] for r in rows}) == 2 and all(math.isfinite(float(r["psnr"])) for r in rows)
    timed = {r["view"] for r in rows if r["total_ms"] != ""}
    assert len(timed) == 1, timed
    assert all(r[f"{s}_ms"] == "" for r in rows if r["view"] not in timed for s in STAGES)
    assert "Latency: stage times on 1 of the 2 evaluated views" in report.read_text()
    with pytest.raises(InputError, match="timed_views=0"):
        evaluate(_compose(*_args(run["ck"], "timed_views=0")))


# ---- the operating point travels with the IMS checkpoint -------------------------------------------
def _band_ends(b: dict) -> tuple[list[float], list[float]]:
    """Two views on the z axis looking at the origin: at the near end of a point's first band of camera distance and
    at the far end of its last (``b``: its ``by_distance``)."""
    return [0.0, 0.0, b["lo"][0], 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, b["hi"][-1], 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]


def _orp_views(ck: dict) -> list:
    """The views the evaluation searched the ORP on (orp_max_views=4 held-out views: evaluate.orp_search_views)."""
    import numpy as np

    from data_gen.cache import ViewImageCache, ensure_cache
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import orp_search_views, parse_settings

    cfg = _compose(*_args(ck))
    scene = build_scene(cfg.scene)
    cache = ViewImageCache.open(ensure_cache(scene, cfg.data, cfg.renderer, progress=False))
    held, rows, _, _ = orp_search_views(parse_settings(cfg), cfg, cache, scene)
    return [np.asarray(held.views[r], np.float64) for r in rows]


def _trained_mean(ckpt) -> float:
    from imls_lightning.inference.checkpoints import load_task

    return float(load_task(str(ckpt), expect="IMSTask").iml.mean)


def _orp_lines(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]


def test_the_evaluation_records_its_orp_beside_the_ims_checkpoint(run):
    import json

    from imls_lightning.base.config import file_hash
    from imls_lightning.inference.operating_point import read_operating_point, sidecar_path

    ims = run["ck"]["ims_pim"]
    side = sidecar_path(ims)
    assert side == Path(str(ims) + ".orp.json") and f"recorded for the IMS checkpoint: {side}" in run["proc"].stderr
    rec = json.loads(side.read_text())
    orp = json.loads((run["out"] / "summary.json").read_text())["orp"]
    assert orp["found"]  # ims_lift=auto: lifted, u = 1 renders the whole pattern, so an ORP exists
    assert rec["ims_checkpoint_sha256"] == file_hash(ims, length=64)
    assert (rec["mean"], rec["lift"], rec["c_share"], rec["ipr"], rec["gap_db"]) == (
        orp["mean"], orp["lift"], orp["c_share"], orp["ipr"], orp["gap_db"])
    assert (rec["epsilon_db"], rec["views"], rec["scene"], rec["report"]) == (1.0, len(_orp_views(run["ck"])), "tiny",
                                                                              str(run["report"].resolve()))
    point = read_operating_point(ims, log=None)
    assert point.mean == orp["mean"] and point.lift == orp["lift"] and point.c_share == orp["c_share"]


def test_a_renderer_from_the_ims_checkpoint_alone_runs_at_the_reports_orp(run, capsys):
    """The report's operating point, within 5 points of its share of C on the views it was chosen on;
    an explicit mean value overrides it, without reading the record."""
    import json

    import numpy as np

    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ims, cpu = str(run["ck"]["ims_pim"]), NetOptions(device="cpu")
    orp = json.loads((run["out"] / "summary.json").read_text())["orp"]
    capsys.readouterr()
    r = IMLSRenderer.from_checkpoints(ims, opts=cpu)
    lines = _orp_lines(capsys)
    assert len(lines) == 1 and "running at the evaluation's operating point" in lines[0] and f"u = {orp['mean']:.3f}" in lines[0]
    assert r.mean == orp["mean"] and r.record.lift == orp["lift"] and r.record.c_share == orp["c_share"]
    views = _orp_views(run["ck"])
    share = float(np.mean([r.run(v).info["c_share"] for v in views]))
    assert abs(share - orp["c_share"]) <= 0.05, (share, orp["c_share"])
    # an explicit mean value (or the trained one) overrides the record, which is then not read
    trained = IMLSRenderer.from_checkpoints(ims, opts=cpu, mean="trained")
    assert trained.mean == pytest.approx(_trained_mean(ims)) and trained.record is None
    at = IMLSRenderer.from_checkpoints(ims, opts=cpu, mean=0.05)
    assert at.mean == 0.05 and at.record is None and _orp_lines(capsys) == []
    assert float(np.mean([at.run(v).info["c_share"] for v in views])) < share
    with pytest.raises(InputError, match=r"^mean=1.5: expected a number in \[0.01, 1\]"):
        IMLSRenderer.from_checkpoints(ims, opts=cpu, mean=1.5)


def test_the_record_is_checked_by_the_checkpoints_bytes(run, tmp_path, capsys):
    """The sidecar travels with a copy of the checkpoint; without one, or with another checkpoint's or
    an unreadable one, the renderer runs at the trained mean and says so in one line."""
    import json
    import shutil

    from imls_lightning.base.config import file_hash
    from imls_lightning.inference.operating_point import sidecar_path
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    src, copy, cpu = run["ck"]["ims_pim"], tmp_path / "copy.ckpt", NetOptions(device="cpu")
    shutil.copy(src, copy)
    u0 = _trained_mean(src)
    capsys.readouterr()
    r = IMLSRenderer.from_checkpoints(str(copy), opts=cpu)
    lines = _orp_lines(capsys)
    assert r.mean == pytest.approx(u0) and r.record is None
    assert len(lines) == 1 and "no recorded operating point" in lines[0] and f"running at the trained mean u = {u0:.3f}" in lines[0]
    shutil.copy(sidecar_path(src), sidecar_path(copy))
    mean = json.loads(sidecar_path(src).read_text())["mean"]
    assert IMLSRenderer.from_checkpoints(str(copy), opts=cpu).mean == mean
    capsys.readouterr()
    rec = json.loads(sidecar_path(copy).read_text())
    sidecar_path(copy).write_text(json.dumps({**rec, "ims_checkpoint_sha256": file_hash(run["ck"]["ims"], length=64)}))
    for broken, why in ((None, "it belongs to another checkpoint"), ("{not json", "unreadable")):
        if broken is not None:
            sidecar_path(copy).write_text(broken)
        r = IMLSRenderer.from_checkpoints(str(copy), opts=cpu)
        lines = _orp_lines(capsys)
        assert r.mean == pytest.approx(u0) and r.record is None
        assert len(lines) == 1 and lines[0].startswith(f"[orp] warning: {sidecar_path(copy)} ignored: {why}"), lines
        assert lines[0].endswith(f"running at the trained mean u = {u0:.3f}")


# ---- the IMS's masks lifted to their mean value (ims_lift) ---------------------------------------
@pytest.mark.parametrize("value,expected", [(None, "auto"), ("true", True), ("false", False), ("auto", "auto")])
def test_ims_lift_setting(tiny_checkpoints, value, expected):
    from imls_lightning.evaluation import parse_settings

    extra = [f"ims_lift={value}"] if value is not None else []
    assert parse_settings(_compose(*_args(tiny_checkpoints), *extra)).ims_lift == expected


def test_exception_ims_lift_is_one_line(tiny_checkpoints):
    from imls_lightning.evaluation import parse_settings

    with pytest.raises(InputError, match=r"^ims_lift=maybe: expected auto, true or false$"):
        parse_settings(_compose(*_args(tiny_checkpoints), "ims_lift=maybe"))


def test_orp_with_lift_auto_searches_again_lifted_only_when_the_rescale_finds_none(capsys):
    """The control flow of ims_lift=auto with the real ORP search (the gap is a function of the
    lifted state; the lift itself is tested on a real IMS in tests/adaptive/test_renderer.py)."""
    from imls_lightning.evaluation import orp_with_lift
    from imls_lightning.orp import ORPSearch, batched

    def search(lift: bool):  # the lift is the search's argument, not state
        # the rescale's gap never drops below 2 dB; lifted, every u >= 0.5 is within 1 dB
        gap = lambda u: (0.0 if u >= 0.5 else 3.0) if lift else 2.0  # noqa: E731
        return ORPSearch(epsilon_db=1.0).run(batched(lambda u: {"gap_db": gap(u), "c_share": min(u, 0.6)}))

    res = orp_with_lift(search, "auto")
    assert res.found and 0.5 <= res.mean <= 0.56 and res.lifted is True
    assert res.rescale_points and all(p[1] == 2.0 for p in res.rescale_points)
    assert "ORP: none with the paper's rescale (largest share 60.0% of C)" in capsys.readouterr().err
    for lift in (False, True):
        res = orp_with_lift(search, lift)
        assert res.lifted is lift and res.found is lift and getattr(res, "rescale_points", None) is None


# ---- the two-pass sampler (the classical alternative: no IMS, no decoder) --------------------------------
def test_two_pass_sampler_runs_at_a_share_searched_on_the_orps_views_and_reports_its_test_gap(run):
    """On by default (two_pass.base=0.2): its share is the smallest searched share above the first pass whose bound
    holds on the ORP's search views; the summary keeps every searched share and its gap on the evaluated views, and
    its rows render exactly that share's pixels (the base's blue noise, then its most unpredictable neighbours)."""
    import json

    s = json.loads((run["out"] / "summary.json").read_text())
    tp = s["two_pass"]
    assert (tp["base"], tp["floor"], tp["epsilon_db"]) == (0.2, 0.25, 1.0)
    shares = [r["share"] for r in tp["rows"]]
    assert shares == sorted(shares) and shares[0] == 0.25 and shares[-1] == 1.0
    if tp["found"]:
        chosen = next(r for r in tp["rows"] if r["share"] == tp["share"])
        assert chosen["gap_bound_db"] <= 1.0 < min([r["gap_bound_db"] for r in tp["rows"] if r["share"] < tp["share"]] or [2.0])
        assert tp["record"]["gap_bound_db"] == chosen["gap_bound_db"]
    else:
        assert tp["share"] == 1.0 and tp["record"] is None
    assert "held-out views" in tp["where"] and tp["test"]["views"] == 2 and math.isfinite(tp["test"]["gap_db"])
    two = _method_rows(run, "two_pass")
    assert len(two) == 2 and all(abs(float(r["c_share"]) - tp["share"]) <= 0.05 for r in two)
    text = run["report"].read_text()
    assert "two passes + fill + RecNN (no IMS)" in text and "Two passes + fill + RecNN (no IMS, no decoder" in text
    assert "## The two-pass sampler's share (no IMS, searched like the ORP)" in text and tp["by_distance"] is None
    assert sum(b["views"] for b in tp["test_by_distance"]) == 2
    settings = yaml.safe_load((run["out"] / "config.yaml").read_text())["settings"]
    assert settings["two_pass"] == {"base": 0.2, "floor": 0.25}


def test_two_pass_sampler_by_distance_gives_each_band_its_own_share(run):
    """orp_by_distance=true: the two-pass sampler's share is searched per band of camera distance as the ORP's mean
    value is (never above the share that held in every band), from the gaps its search measured; its method runs each
    view at its band's share, and the settings hash changes with it (its results do)."""
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.two_pass import two_pass_method, two_pass_point

    main = _training_cache(run["ck"])
    cfg = _compose(*_args(run["ck"], "orp_strata=2", "orp_by_distance=true", "orp_confidence=0.5", "epsilon_db=3.0"))
    s = parse_settings(cfg)
    assert s.hashed()["two_pass"] == {"base": 0.2, "floor": 0.25, "by_distance": True}
    nets = load_networks(s, int(cfg.data.resolution))
    point = two_pass_point(s, cfg, main, build_scene(cfg.scene), nets, nets.ims_task.pattern, "cpu", future_views=2)
    assert point.found
    b = point.by_distance
    assert len(b["shares"]) == 2 and all(0.2 < x <= point.value for x in b["shares"]) and b["views"] == [2, 2]
    assert b["hi"][0] < b["edges"][0] < b["lo"][1] and all(g <= 3.0 for g in b["bounds_db"])
    method = two_pass_method(point, object(), nets.ims_task.pattern, nets.recnn, None)
    assert method.shares == pytest.approx(b["shares"])
    assert tuple(map(method.share_for, _band_ends(b))) == pytest.approx(tuple(b["shares"]))


# ---- LAS at the product's promise (its IPR searched as the ORP is) ---------------------------------------------
def test_las_at_the_promise_runs_at_an_ipr_searched_on_the_orps_views_and_reports_its_test_gap(run):
    """las_searched=true: LAS's IPR is the smallest of las_search_iprs whose bound holds on the ORP's search views
    (the largest where none does); the summary keeps every IPR searched and its gap on the evaluated views, its rows
    sample that IPR of the FR pixels, and the report names it beside LAS at IML/S's IPR."""
    s = json.loads((run["out"] / "summary.json").read_text())
    ls = s["las_searched"]
    assert [r["ipr"] for r in ls["rows"]] == LAS_SEARCH_IPRS and ls["epsilon_db"] == 1.0
    if ls["found"]:
        chosen = next(r for r in ls["rows"] if r["ipr"] == ls["ipr"])
        assert chosen["gap_bound_db"] <= 1.0 < min([r["gap_bound_db"] for r in ls["rows"] if r["ipr"] < ls["ipr"]] or [2.0])
    else:
        assert ls["ipr"] == LAS_SEARCH_IPRS[-1] and ls["record"] is None
    assert all(0.0 < r["kept"] <= 1.0 for r in ls["rows"])
    assert "held-out views" in ls["where"] and ls["test"]["views"] == 2 and math.isfinite(ls["test"]["gap_db"])
    las = _method_rows(run, "las_searched")
    assert len(las) == 2 and all(abs(float(r["ipr"]) - ls["ipr"]) <= 0.02 for r in las)
    text = run["report"].read_text()
    assert "LAS at the promise (its IPR searched)" in text and "LAS at the product's promise (what a user who chose LAS" in text
    settings = yaml.safe_load((run["out"] / "config.yaml").read_text())["settings"]
    assert settings["las_searched"] is True and settings["las_search_iprs"] == LAS_SEARCH_IPRS


def test_las_search_gap_is_the_gap_the_method_measures_on_the_same_view(run):
    """las_gaps (the search) and LASMethod (the measured method) agree on a view: the same low-res render, the same
    bisected mask, the cached FR pixels the ray caster returns; so the gap searched is the gap LAS runs at."""
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene
    from imls_lightning.core.metrics import psnr_per_image
    from imls_lightning.estimate.measure import frame_tensor
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.las_point import las_gaps
    from imls_lightning.inference.pipeline import LASMethod, RecNNAlone

    cfg = _compose(*_args(run["ck"]))
    s = parse_settings(cfg)
    nets = load_networks(s, int(cfg.data.resolution))
    main = _training_cache(run["ck"])
    renderer = make_renderer(build_scene(cfg.scene), dict(cfg.renderer))
    view, truth = np.asarray(main.views[0], np.float64), np.asarray(main.images[0])
    kept, gaps = las_gaps(nets.las_task.net.eval(), nets.recnn.eval(), nets.ims_task.pattern, renderer, [view], [truth],
                          [0.1, 0.5])
    m = int(cfg.data.resolution)
    target = frame_tensor(truth)

    def db(method, **kw):
        return float(psnr_per_image(frame_tensor(method.run(view, **kw).image), target)[0])

    ref = db(RecNNAlone(renderer, nets.ims_task.pattern, nets.recnn))
    las = LASMethod(renderer, nets.las_task.net, m, int(nets.las_task.hparams["low_res"]))
    for j, ipr in enumerate([0.1, 0.5]):
        assert gaps[0, j] == pytest.approx(ref - db(las, ipr=ipr), abs=0.1)
        assert kept[0, j] == pytest.approx(las.run(view, ipr=ipr).info["ipr"], abs=1e-6)


def test_las_at_the_promise_by_distance_gives_each_band_its_own_ipr(run):
    """orp_by_distance=true: LAS's IPR is searched per band of camera distance (never above the IPR that held in
    every band); its method runs each view at its band's IPR."""
    from imls_lightning.render import make_renderer
    from data_gen.scenes import build_scene
    from imls_lightning.evaluation import load_networks, parse_settings
    from imls_lightning.evaluation.baseline_point import SearchedPoint
    from imls_lightning.evaluation.las_point import las_point, las_searched_method

    main = _training_cache(run["ck"])
    cfg = _compose(*_args(run["ck"], "orp_strata=2", "orp_by_distance=true", "orp_confidence=0.5", "epsilon_db=60.0"))
    s = parse_settings(cfg)
    nets = load_networks(s, int(cfg.data.resolution))
    scene = build_scene(cfg.scene)
    point = las_point(s, cfg, main, scene, nets, make_renderer(scene, dict(cfg.renderer)), "cpu", future_views=2)
    assert point.found
    b = point.by_distance
    assert len(b["values"]) == 2 and all(x <= point.value for x in b["values"]) and b["views"] == [2, 2]
    assert b["hi"][0] < b["edges"][0] < b["lo"][1] and all(g <= 60.0 for g in b["bounds_db"])
    again = SearchedPoint.from_dict(json.loads(json.dumps(point.to_dict())))  # as an interrupted run restores it
    method = las_searched_method(again, object(), nets.las_task, int(cfg.data.resolution), None)
    assert method.name == "las_searched" and method.iprs == pytest.approx(b["values"])
    assert tuple(map(method.ipr_for, _band_ends(b))) == pytest.approx(tuple(b["values"]))


@pytest.mark.parametrize("override, attr, off_value, key", [
    ("two_pass.base=null", "two_pass_base", None, "two_pass"),
    ("las_searched=false", "las_searched", False, "las_searched"),
])
def test_a_baseline_off_keeps_the_settings_hash_of_evaluations_without_it(run, override, attr, off_value, key):
    """The two-pass sampler and LAS at the promise, each turned off: its key leaves the settings hash."""
    from imls_lightning.evaluation import parse_settings

    off = parse_settings(_compose(*_args(run["ck"], override)))
    assert getattr(off, attr) is off_value and key not in off.hashed()


def test_las_search_iprs_are_hashed(run):
    from imls_lightning.evaluation import parse_settings

    assert parse_settings(_compose(*_args(run["ck"]))).hashed()["las_search_iprs"] == LAS_SEARCH_IPRS


@pytest.mark.parametrize("override, message", [
    ("two_pass.base=1.0", "two_pass.base=1.0: expected the first pass's share of C in (0, 1), or null (no two-pass sampler)"),
    ("two_pass.base=0", "two_pass.base=0: expected the first pass's share of C in (0, 1)"),
    ("two_pass.floor=-1", "two_pass.floor=-1: expected a number >= 0"),
    ("las_searched=yes", "las_searched='yes': expected true or false"),
    ("las_search_iprs=[]", "las_search_iprs=[]: expected at least one IPR in [0.01, 1] to search LAS's among"),
    ("las_search_iprs=[0.001]", "las_search_iprs=[0.001]: expected numbers in [0.01, 1.0]"),
    ("checkpoints.las=null", "las_searched=true: needs checkpoints.las (the LAS checkpoint whose IPR is searched)"),
])
def test_exception_baseline_settings_are_one_line(run, override, message):
    """The two-pass sampler's and LAS at the promise's settings: each wrong one is one line naming it."""
    from imls_lightning.evaluation import parse_settings

    with pytest.raises(InputError, match=re.escape(message)):
        parse_settings(_compose(*_args(run["ck"], override)))


@pytest.mark.slow  # torch.compile compiles every method's networks (about a minute on 2 cores), beside an eager run
def test_every_method_runs_compiled_and_scores_as_eager(tiny_checkpoints, tmp_path):
    """``options.compile=true``: every method's networks compiled, the same methods and views scored, each within
    0.1 dB of the same evaluation run eagerly (issue 19's bound for an inference option), and no network falling back
    to eager after too many recompilations."""
    db = {}
    for compiled in (False, True):
        p = _cli(_args(tiny_checkpoints, f"options.compile={str(compiled).lower()}", "orp=false", "shares=null",
                       f"output_dir={tmp_path / str(compiled)}"), timeout=900)
        assert p.returncode == 0, f"exit {p.returncode}\nSTDERR:\n{p.stderr[-5000:]}"
        assert "recompile_limit" not in p.stderr and "cache_size_limit" not in p.stderr, p.stderr[-3000:]
        _, rows = _rows(Path(p.stdout.strip().splitlines()[-1]).parent / "metrics.csv")
        db[compiled] = {(r["method"], r["view"]): float(r["psnr"]) for r in rows}
    assert db[True].keys() == db[False].keys() and {m for m, _ in db[True]} >= {"recnn", "imls", "blue_noise", "las"}
    far = {k: (db[True][k], db[False][k]) for k in db[True] if not abs(db[True][k] - db[False][k]) < 0.1}
    assert not far, far


# ---- the fastest baseline and the protocol's views ---------------------------------------------------------------
def test_both_ray_casters_are_timed_in_one_run_and_the_speedup_counts_against_the_faster(run):
    """both_ray_casters (default): the RecNN alone and IML/S are timed with skipping off too, on every timed view, with
    the very same images; summary.json's ray_casters and the CSV row give both and speedup_vs_fastest."""
    from imls_lightning.pipelines.bench_paper import csv_row, read_summary

    _, rows = _rows(run["out"] / "metrics.csv")
    by = {(r["view"], r["method"]): r for r in rows}
    timed = {r["view"] for r in rows if r["method"] == "recnn" and r["total_ms"] != ""}
    assert timed
    for v in timed:
        for name in ("recnn", "imls"):
            twin = by[(v, f"{name}_noskip")]
            assert float(twin["psnr"]) == float(by[(v, name)]["psnr"])  # the same pixels on either ray caster
            assert float(twin["total_ms"]) > 0
    s = json.loads((run["out"] / "summary.json").read_text())
    rc = s["ray_casters"]
    fast_recnn = min(rc["recnn_skip_ms"], rc["recnn_noskip_ms"])
    fast_imls = min(rc["imls_skip_ms"], rc["imls_noskip_ms"])
    assert rc["speedup_vs_fastest"] == pytest.approx(fast_recnn / fast_imls)
    assert rc["speedup_vs_fastest_low"] <= rc["speedup_vs_fastest"] <= rc["speedup_vs_fastest_high"]
    row = csv_row(read_summary(run["report"]))
    assert row["speedup_vs_fastest"] == rc["speedup_vs_fastest"] and row["recnn_noskip_ms"] == rc["recnn_noskip_ms"]
    assert "**The fastest baseline**" in run["report"].read_text()
    # the report's last line: whether it pays against the fastest, and where it does (make reproduce)
    last = run["report"].read_text().rstrip().splitlines()[-1]
    assert last.startswith("**Verdict: IML/S ") and f"{rc['speedup_vs_fastest']:.2f}x the fastest RecNN alone" in last
    assert "make reproduce ROW=seed_whole" in last


def test_a_fresh_trajectory_of_its_own_seed_is_what_the_evaluation_measures(run, tmp_path):
    """trajectory_seed=N: the test views are the path model's views of seed N, rendered into a cache of their own;
    the settings' validation views stay the training cache's."""
    from data_gen.scenes import build_scene
    from data_gen.views import exploration_trajectory
    from imls_lightning.evaluation import evaluate

    cfg = _compose(*_args(run["ck"], "trajectory_seed=7", "orp=false", "shares=null", "mean_values=[0.1]", "grid_views=0",
                          "las_searched=false", "both_ray_casters=false", "timed_views=1", f"output_dir={tmp_path / 'eval'}"))
    report = evaluate(cfg)
    s = json.loads((report.parent / "summary.json").read_text())
    assert s["trajectory"]["seed"] == 7 and s["ray_casters"] is None
    from data_gen.cache import ViewImageCache

    cache = ViewImageCache.open(s["trajectory"]["cache"])
    scene = build_scene(cfg.scene)
    want = exploration_trajectory(int(cfg.data.test_views), scene.camera_distance, seed=7, lookat_jitter=float(cfg.data.lookat_jitter))
    np.testing.assert_allclose(np.asarray(cache.views[cache.splits["test"]]), want.astype(np.float32))
    assert "a fresh trajectory of seed 7" in report.read_text()


@pytest.mark.parametrize("seed, needle", [
    (0, "trajectory_seed=0: equals data.seed"),
    (1, "trajectory_seed=1: equals a seed of the ORP's search views"),
    (100, "trajectory_seed=100: equals the IMS's training data.seed"),
])
def test_exception_a_trajectory_seed_some_choice_read_is_one_line(run, seed, needle):
    from imls_lightning.evaluation import evaluate

    with pytest.raises(InputError, match=re.escape(needle)):
        evaluate(_compose(*_args(run["ck"], f"trajectory_seed={seed}")))


def test_exception_validation_views_whose_directions_the_ims_trained_on_are_refused(run):
    """An IMS trained on views of the cache's own seed has seen the validation views' eye directions: choosing the
    object floor on them is refused in one line (the module's IMS trained on seed 100: its run record says so)."""
    from imls_lightning.evaluation.protocol import check_view_seeds, training_data_seed
    from imls_lightning.evaluation.settings import parse_settings

    assert training_data_seed(run["ck"]["ims_pim"]) == 100 and training_data_seed(run["ck"]["iml"]) == 0
    s = parse_settings(_compose(*_args(run["ck"], "orp_object_floor=[0.0,0.1]")))
    cfg = _compose(*_args(run["ck"]))
    check_view_seeds(s, cfg, 100)  # passes
    with pytest.raises(InputError, match=re.escape("checkpoints.ims: trained on views of data.seed=0, the seed of the validation views")):
        check_view_seeds(s, cfg, 0)
    check_view_seeds(parse_settings(_compose(*_args(run["ck"], "orp_object_floor=[]"))), cfg, 0)  # no floor: nothing read


def test_summary_says_where_the_mask_put_its_pixels_on_object_and_background(run):
    """summary.json's mask_density: the share of the C-Image's object and background pixels IML/S's mask kept, over the
    evaluated views, and the object's share of the C-Image."""
    s = json.loads((run["out"] / "summary.json").read_text())
    d = s["mask_density"]
    assert 0.0 <= d["object_fraction"] <= 1.0
    for k in ("object_density", "background_density"):
        assert d[k] is None or math.isnan(d[k]) or 0.0 <= d[k] <= 1.0
    # the kept share of C is the two densities weighed by the object's share (per view; here on average, to rounding)
    if all(math.isfinite(d[k]) for k in d):
        share = d["object_fraction"] * d["object_density"] + (1 - d["object_fraction"]) * d["background_density"]
        assert share == pytest.approx(s["methods"]["imls"]["c_share"], abs=0.1)


def test_las_at_equal_quality_runs_at_the_smallest_searched_ipr_within_0_1_db_of_imls(run):
    """las_equal: of the IPRs LAS's promise search scored, the smallest whose mean gap on the search views is within
    0.1 dB of IML/S's validation gap; its CSV cells beside LAS at the promise."""
    from imls_lightning.evaluation.las_point import imls_validation_gap
    from imls_lightning.pipelines.bench_paper import csv_row, read_summary

    s = json.loads((run["out"] / "summary.json").read_text())
    rows = sorted(s["las_searched"]["rows"], key=lambda r: r["ipr"])
    target = imls_validation_gap(s["orp"]) + 0.1
    ok = [r["ipr"] for r in rows if r["gap_db"] <= target]
    want = ok[0] if ok else min(rows, key=lambda r: abs(r["gap_db"] - target))["ipr"]
    _, metrics = _rows(run["out"] / "metrics.csv")
    got = {round(float(r["ipr"]), 6) for r in metrics if r["method"] == "las_equal"}
    las = [r for r in metrics if r["method"] == "las_equal"]
    assert las and all(abs(float(r["ipr"]) - want) < 0.02 for r in las), (got, want)
    row = csv_row(read_summary(run["report"]))
    assert row["las_equal_psnr_db"] == pytest.approx(s["methods"]["las_equal"]["psnr"])
    assert "LAS at equal quality: IPR" in run["report"].read_text()
