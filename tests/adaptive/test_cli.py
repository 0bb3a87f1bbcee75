"""imls_lightning.adaptive.cli: ``python -m imls_lightning.adaptive`` end to end on tiny."""
from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


# ---- the CLI -------------------------------------------------------------------------------------
def _cli(ck: dict, ims: Path, *extra: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    args = ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={ck['cache_dir']}", f"paths.runs_dir={ck['runs_dir']}",
            f"ims_checkpoint={ims}", "progress=false", "steps=3", "predictor.epochs=40", "predictor.hidden=8",
            "repeats=2", "timing_views=2", *extra]
    return subprocess.run([sys.executable, "-m", "imls_lightning.adaptive", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)


def _direct_product_orp(pim_ckpt, cache) -> float:
    """The product path's ORP on the cache's validation views, by a direct call of the evaluation's search."""
    import torch
    from torch.utils.data import DataLoader

    from imls_lightning.core.importance import MEAN_RANGE
    from imls_lightning.data.datamodule import ViewImageDataset
    from imls_lightning.orp.product import product_orp
    from imls_lightning.inference.checkpoints import load_task

    ims = load_task(pim_ckpt, expect="IMSTask").eval()
    ds = ViewImageDataset(cache.path, cache.splits["val"], ims.pattern, fields=("view", "fr", "c"))
    with torch.inference_mode():
        res = product_orp(ims.mask_head, ims.decoder, ims.recnn.eval(), list(DataLoader(ds, batch_size=16)), 1.0)
    return float(res.mean) if res.found else MEAN_RANGE[1]


def test_cli_end_to_end_on_tiny(tiny_checkpoints, pim_ckpt, tiny_cache, tmp_path):
    p = _cli(tiny_checkpoints, pim_ckpt, f"output_dir={tmp_path / 'out'}")
    assert p.returncode == 0, f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-2000:]}\nSTDERR:\n{p.stderr[-4000:]}"
    report = Path(p.stdout.strip().splitlines()[-1])
    assert report == tmp_path / "out" / "adaptive.md" and report.is_file()
    text = report.read_text()
    for needle in ("## Summary", "IML/S, adaptive u", "IML/S, fixed u (IPR-matched)", "fixed u (ORP)", "views within epsilon",
                   "label_source=ims", "## Trade-off: adaptive vs the whole fixed-mean curve (IML/S + RecNN)", "adaptive x1.25"):
        assert needle in text
    with open(report.parent / "tradeoff.csv", newline="") as f:
        trade = list(csv.DictReader(f))
    assert len(trade) == 16 + 4 + 1  # the fixed means, the margins, the oracle
    assert all(0 <= float(r["ipr"]) <= 1 and math.isfinite(float(r["psnr"])) for r in trade)
    assert (report.parent / "tradeoff.png").stat().st_size > 1000
    with open(report.parent / "adaptive.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 12  # data=tiny: a 12-view trajectory
    for r in rows:
        assert 0.01 <= float(r["u_pred"]) <= 1.0 and 0.01 <= float(r["u_label"]) <= 1.0
        assert float(r["ipr_imls_adaptive"]) >= 0 and math.isfinite(float(r["psnr_imls_adaptive"]))
        assert r["u_fixed"] == rows[0]["u_fixed"]
    assert (report.parent / "adaptive.png").stat().st_size > 1000 and (report.parent / "mean_predictor.pt").is_file()
    # the fixed-mean ORP is the product path's (as the evaluation searches it), not the IML bound's u
    assert "RecNN alone on the product path (IML/S + RecNN: the evaluation's ORP)" in text
    assert json.loads((report.parent / "adaptive.json").read_text())["u_orp"] == _direct_product_orp(pim_ckpt, tiny_cache)
    labels = sorted((pim_ckpt.parent.parent / "adaptive" / "labels").glob("*.npz"))
    assert {x.name.split("-")[0] for x in labels} == {"train", "val", "test"}
    # a second run reuses the labels
    p2 = _cli(tiny_checkpoints, pim_ckpt, f"output_dir={tmp_path / 'out2'}")
    assert p2.returncode == 0 and p2.stderr.count("reusing") == 3, p2.stderr[-2000:]


# slow: the default suite took 18 min on an AVX2-only 2-core EPYC (issue 31's machine); make test-all runs it
@pytest.mark.slow
def test_cli_lifted_masks_and_reuse_of_a_finished_run(tiny_checkpoints, pim_ckpt, tmp_path):
    """ims_lift=true (as make bench-paper passes when the evaluation's ORP was lifted): its own labels, the
    report says so; reuse=true prints the finished run's report without running it again."""
    args = (f"output_dir={tmp_path / 'lifted'}", "ims_lift=true", "tradeoff_means=3", "options.half=true", "reuse=true")
    p = _cli(tiny_checkpoints, pim_ckpt, *args)
    assert p.returncode == 0, p.stderr[-4000:]
    report = Path(p.stdout.strip().splitlines()[-1])
    text = report.read_text()
    assert "lifted to u's share of C (ims_lift=true" in text and "autocast" in text
    data = json.loads((report.parent / "adaptive.json").read_text())
    u = data["u_adaptive"]
    assert 0.01 <= u["min"] <= u["median"] <= u["max"] <= 1.0
    p2 = _cli(tiny_checkpoints, pim_ckpt, *args)
    assert p2.returncode == 0 and "reusing the finished run" in p2.stderr, p2.stderr[-2000:]
    assert p2.stdout.strip().splitlines()[-1] == str(report)


def test_exception_cli_target_im_exits_2(tiny_checkpoints):
    p = _cli(tiny_checkpoints, tiny_checkpoints["ims"])
    assert p.returncode == 2 and "target=pim" in p.stderr and "Traceback" not in p.stderr
