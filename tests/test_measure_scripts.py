"""The measurement scripts (scripts/measure_recnn.py, scripts/measure_iml.py) end to end on the tiny scene.

Real trainings through the CLI (1 epoch, tiny networks), real evaluation on the tiny test
trajectory; checks the printed/written tables and the numbers behind them. The two training tests
take ~65 s together on 2 busy cores (3 training subprocesses), so they are marked slow.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from data_gen.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
TINY = ["--scene", "tiny", "--data", "tiny", "--enhancenet-epochs", "1", "--enhancenet-channels", "4",
        "--enhancenet-blocks", "1"]


def _run(script: str, args: list[str], tmp: Path, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, str(ROOT / "scripts" / script), *args, "--runs-dir", str(tmp / "runs"), "--cache-dir", str(tmp / "cache")]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    if check and p.returncode != 0:
        raise AssertionError(f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-3000:]}")
    return p


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("measure")


@pytest.fixture(scope="module")
def recnn_run(work):
    out = work / "recnn.md"
    p = _run("measure_recnn.py", [*TINY, "--fovolnet-epochs", "1", "--fovolnet-features", "4", "--fovolnet-base-channels", "4",
                                  "--fovolnet-depth", "2", "--out", str(out)], work)
    return p, out


@pytest.mark.slow
def test_smoke_measure_recnn_table_and_numbers(recnn_run):
    p, out = recnn_run
    rec = json.loads(out.with_suffix(".json").read_text())
    assert out.read_text() in p.stdout + "\n" or out.read_text().strip() in p.stdout  # same table on stdout and in the file
    for name in ("enhancenet", "bicubic_interpolate", "bicubic_aligned"):
        assert np.isfinite(rec["enhancenet"]["metrics"][name]["psnr"]) and 0 < rec["enhancenet"]["metrics"][name]["ssim"] <= 1
    for name in ("fovolnet", "nearest_fill"):
        assert np.isfinite(rec["fovolnet"]["metrics"][name]["psnr"])
    assert rec["enhancenet"]["metrics"]["_views"] == 12  # data=tiny: the 12-view test trajectory
    # our evaluation of the best checkpoint = the training's own test pass (same views, same PSNR)
    assert rec["enhancenet"]["metrics"]["enhancenet"]["psnr"] == pytest.approx(rec["enhancenet"]["result_test"]["test/fr_psnr"], abs=0.02)
    assert rec["enhancenet"]["train_minutes"] > 0 and rec["enhancenet"]["epochs"] >= 0
    assert "| EnhanceNet (downsample 2x) |" in out.read_text() and "nearest pattern pixel" in out.read_text()
    assert "(1/4) train EnhanceNet" in p.stderr and "elapsed" in p.stderr
    assert not list(out.parent.glob(".*.tmp"))  # atomic writes leave nothing behind


@pytest.mark.slow
def test_smoke_measure_iml_end_to_end_row(work, recnn_run):
    _, recnn_out = recnn_run
    ckpt = json.loads(recnn_out.with_suffix(".json").read_text())["enhancenet"]["checkpoint"]
    out = work / "iml.md"
    p = _run("measure_iml.py", [*TINY, "--iml-epochs", "1", "--iml-depth", "2", "--iml-base-channels", "4", "--means", "0.2",
                                "--modes", "end_to_end", "--recnn-checkpoint", ckpt, "--out", str(out)], work)
    rec = json.loads(out.with_suffix(".json").read_text())
    (row,) = rec["runs"]
    e = row["metrics"]
    assert row["mode"] == "end_to_end" and row["mean"] == 0.2 and e["views"] == 12
    # data=tiny 32^2 FR, 16^2 C-Image: IPR = C-share / 4 exactly for the 2x downsampling pattern
    assert e["ipr"] == pytest.approx(e["c_share"] / 4, rel=1e-6)
    assert 0 <= e["c_share"] <= 1 and e["pim_norm_mean"] == pytest.approx(0.2, rel=1e-3)
    # the hard-mask numbers agree with the run's own test pass
    t = row["result_test"]
    assert e["ipr"] == pytest.approx(t["test/ipr"], abs=1e-4) and e["psnr"] == pytest.approx(t["test/fr_psnr"], abs=0.02)
    assert rec["checks"] == []
    assert "| end_to_end | 0.2 |" in p.stdout and out.read_text().strip() in p.stdout


def test_exception_measure_iml_bad_means(tmp_path):
    p = _run("measure_iml.py", ["--means", "0.001,0.1"], tmp_path, check=False)
    assert p.returncode == 2 and "Traceback" not in p.stderr
    err = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")]
    assert len(err) == 1 and err[0].startswith("error: --means=0.001: expected a number in [0.01, 1"), p.stderr[-2000:]


def test_measure_pixel_check_script(tmp_path):
    """scripts/measure_pixel_check.py: the cache's per-view CRC-32 check vs one render (issue 17, 2)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("measure_pixel_check", ROOT / "scripts" / "measure_pixel_check.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.main(["--resolution", "64", "--views", "3", "--repeats", "5", "--cache-dir", str(tmp_path)])
    # timings are measured, not asserted (it read 16x, under the threshold of 20 it asserted, on a loaded CI run): check what they report
    assert out["render_ms"] > 0 and out["check_ms"] > 0 and math.isfinite(out["ratio"]), out
    assert out["ratio"] == pytest.approx(out["render_ms"] / out["check_ms"]) and out["resolution"] == 64


def _script_module(name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_ims_gap_object_oracle_against_a_direct_loop():
    torch = pytest.importorskip("torch")
    mod = _script_module("ims_gap")
    g = torch.Generator().manual_seed(0)
    valid = torch.ones(6, 6, dtype=torch.bool)
    obj = torch.rand(2, 1, 6, 6, generator=g) > 0.7
    bg = ~obj
    P = torch.rand(1, 1, 6, 6, generator=g)
    got = mod.object_oracle(obj, bg, P, valid, 0.5)
    for i in range(2):
        frac = max(0.5 * 36 - int(obj[i].sum()), 0) / max(int(bg[i].sum()), 1)
        want = obj[i] | (bg[i] & (P[0] < frac))
        assert torch.equal(got[i].bool(), want)
    assert got.dtype == torch.float32


def test_ims_gap_block_correlation_against_a_direct_loop():
    torch = pytest.importorskip("torch")
    mod = _script_module("ims_gap")
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(3, 1, 8, 8, generator=g, dtype=torch.float64), torch.rand(3, 1, 8, 8, generator=g, dtype=torch.float64)
    valid = torch.ones(8, 8, dtype=torch.bool)
    valid[:4, :4] = False  # a block of 4 with no pattern pixel is left out; partial blocks average their own pixels
    valid[6, 6] = False
    want = []
    for i in range(3):
        xs, ys = [], []
        for by in range(0, 8, 4):
            for bx in range(0, 8, 4):
                cells = [(y, x) for y in range(by, by + 4) for x in range(bx, bx + 4) if valid[y, x]]
                if cells:
                    xs.append(np.mean([float(a[i, 0, y, x]) for y, x in cells]))
                    ys.append(np.mean([float(b[i, 0, y, x]) for y, x in cells]))
        want.append(np.corrcoef(xs, ys)[0, 1])
    assert mod.block_correlation(a, b, valid, 4) == pytest.approx(float(np.mean(want)), abs=1e-9)
    assert mod.block_correlation(a, 3 * a - 1, valid, 1) == pytest.approx(1.0, abs=1e-9)
    assert np.isfinite(mod.block_correlation(torch.zeros(1, 1, 8, 8), b[:1].float(), valid, 4))  # a flat map: 0, not NaN


def test_ims_gap_script_on_real_checkpoints(tiny_checkpoints, tmp_path, capsys):
    """The script's IML rows equal the evaluation's equal-share rows on the same views (one formula),
    and it prints the agreement and the gap tables."""
    torch = pytest.importorskip("torch")
    from data_gen.cache import ViewImageCache
    from imls_lightning.inference.baselines import equal_share_rows
    from imls_lightning.inference.checkpoints import load_task

    mod = _script_module("ims_gap")
    fr_size = int(load_task(str(tiny_checkpoints["ims_pim"]), expect="IMSTask", what="ims").hparams["fr_size"])
    cache_dir = next(p.parent for p in Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")
                     if ViewImageCache.open(p.parent).images.shape[1] == fr_size)
    out = tmp_path / "gap.json"
    assert mod.main([str(tiny_checkpoints["ims_pim"]), str(cache_dir), "--views", "4", "--shares", "0.2", "1.0",
                     "--json", str(out)]) == 0
    assert torch.is_grad_enabled()  # the script leaves the process's autograd state as it found it
    text = capsys.readouterr().out
    assert "PIM' correlation" in text and "32 x 32 blocks" in text and "| 0.20 | ims |" in text and "| 1.00 | oracle |" in text
    data = json.loads(out.read_text())
    n = 16  # the tiny scene's C-Image: 32 x 32 blocks do not fit twice
    for split, r in data["agreement"].items():
        assert all(-1 <= r[f"corr_{k}"] <= 1 for k in mod.BLOCKS if 2 * k <= n) and r["corr_32"] is None, (split, r)
    assert len(data["rows"]) == 6 and all(np.isfinite(r["fr_psnr"]) for r in data["rows"])
    with torch.no_grad():
        ims = load_task(str(tiny_checkpoints["ims_pim"]), expect="IMSTask", what="ims").eval()
        batch = mod.load_views(ViewImageCache.open(cache_dir), ims.pattern, "test", 4)
        rows = equal_share_rows(batch["c"], batch["fr"], batch["view"], ims.recnn, iml=ims.iml, ims_task=ims, shares=[0.2])
    want = next(r for r in rows if r["mask"] == "iml" and r["reconstruction"] == "decoder")
    got = next(r for r in data["rows"] if r["mask"] == "iml" and r["share"] == 0.2)
    assert got["fr_psnr"] == pytest.approx(float(np.mean(want["psnr"])), abs=1e-4)
    assert got["density_object"] == pytest.approx(want["density_object"], abs=1e-6)


def test_ims_gap_picks_views_and_the_products_masks(tiny_checkpoints, tmp_path, capsys, monkeypatch):
    """``--views-at`` scores exactly those positions of the split; ``--sharpness`` and ``--lift`` reach the IMS's
    masks only (the IML's and the oracle's rows stay); a position outside the split or a sharpness outside [1, 8] is
    a one-line error."""
    import torch

    from data_gen.cache import ViewImageCache
    from imls_lightning.inference.checkpoints import load_task

    mod = _script_module("ims_gap")
    fr_size = int(load_task(str(tiny_checkpoints["ims_pim"]), expect="IMSTask", what="ims").hparams["fr_size"])
    cache_dir = next(p.parent for p in Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")
                     if ViewImageCache.open(p.parent).images.shape[1] == fr_size)
    ckpt = str(tiny_checkpoints["ims_pim"])
    runs, seen = {}, []
    real_rows = mod.gap_rows

    def spy(ims, batch, shares, lift=False):
        seen.append((ims.mask_sharpness, lift, batch["view"].shape[0]))
        return real_rows(ims, batch, shares, lift)

    monkeypatch.setattr(mod, "gap_rows", spy)
    for tag, extra in {"plain": [], "sharp": ["--sharpness", "3", "--lift"]}.items():
        out = tmp_path / f"{tag}.json"
        assert mod.main([ckpt, str(cache_dir), "--views-at", "2", "0", "--shares", "0.3", "--json", str(out), *extra]) == 0
        runs[tag] = {r["mask"]: r for r in json.loads(out.read_text())["rows"]}
    assert seen == [(1.0, False, 2), (3.0, True, 2)]
    assert runs["plain"]["iml"] == runs["sharp"]["iml"] and runs["plain"]["oracle"] == runs["sharp"]["oracle"]
    cache = ViewImageCache.open(cache_dir)
    ims = load_task(ckpt, expect="IMSTask", what="ims")
    picked = mod.load_views(cache, ims.pattern, "test", 99, [2, 0])
    test_rows = np.asarray(cache.splits["test"])
    assert picked["view"].shape[0] == 2
    assert torch.equal(picked["view"][0], torch.as_tensor(np.asarray(cache.views[test_rows[2]]), dtype=torch.float32))
    with pytest.raises(SystemExit, match=r"--views-at 999: the test split has views 0-"):
        mod.main([ckpt, str(cache_dir), "--views-at", "999"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        mod.main([ckpt, str(cache_dir), "--sharpness", "9"])
    assert "--sharpness 9.0: expected a mask sharpness in [1, 8]" in capsys.readouterr().err


def test_smoke_measure_backends_on_real_checkpoints(tiny_checkpoints, tmp_path, capsys):
    """Every backend runs the same IMS, views and mask: float32 PyTorch and its TorchScript / ONNX
    exports give the same image (PSNR within 0.01 dB), bfloat16 close to it; a missing ONNX Runtime is a row
    that says so, not an error."""
    from data_gen.cache import ViewImageCache
    from imls_lightning.inference.export import onnx_available
    from imls_lightning.inference.checkpoints import load_task

    mod = _script_module("measure_backends")
    fr_size = int(load_task(str(tiny_checkpoints["ims"]), expect="IMSTask", what="ims").hparams["fr_size"])
    cache_dir = next(p.parent for p in Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")
                     if ViewImageCache.open(p.parent).images.shape[1] == fr_size)
    out = tmp_path / "backends.md"
    assert mod.main([str(tiny_checkpoints["ims"]), "--cache", str(cache_dir), "--views", "2", "--repeats", "1", "--out", str(out)]) == 0
    text = out.read_text()
    assert text == capsys.readouterr().out.rstrip("\n") + "\n"
    rows = {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines() if line.startswith("| ") and "---" not in line}
    for name in ("PyTorch float32", "PyTorch bfloat16", "PyTorch bfloat16 + channels_last", "TorchScript float32 (export)",
                 "ONNX Runtime float32 (export)"):
        assert name in rows, text

    def delta(name: str) -> float:
        return float(rows[name].rstrip(" |").split(" | ")[-1])

    assert abs(delta("TorchScript float32 (export)")) < 0.01 and abs(delta("PyTorch bfloat16")) < 1.0
    if onnx_available():
        assert abs(delta("ONNX Runtime float32 (export)")) < 0.01
    else:
        assert "skipped: onnx / onnxruntime not installed" in rows["ONNX Runtime float32 (export)"]


def test_exception_measure_backends_bad_cache(tiny_checkpoints, tmp_path):
    mod = _script_module("measure_backends")
    with pytest.raises(SystemExit, match=f"--cache {tmp_path}: .*no manifest.json"):
        mod.main([str(tiny_checkpoints["ims"]), "--cache", str(tmp_path)])


def test_regime_evidence_bilinear_against_a_direct_loop_and_a_recnn_row(tiny_checkpoints, tmp_path, capsys):
    """scripts/regime_evidence.py on the tiny cache: the upsampling's PSNR equals a direct bilinear loop, and a
    RecNN run's row reads its test PSNR; a folder without result.json is refused in one line."""
    from data_gen.cache_reader import ViewImageCache
    from imls_lightning.core.metrics import psnr_from_mse
    from tests.estimate.test_measure import direct_bilinear

    mod = _script_module("regime_evidence")
    cache_dir = next(p for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if (p / "manifest.json").is_file())
    cache = ViewImageCache.open(cache_dir)
    got, name = mod.upsampling_psnr(cache, max_views=2)
    assert name == "bilinear"
    _, images = cache.split("test")
    picks = np.linspace(0, len(images) - 1, 2).round().astype(int)
    for value, img in zip(got, images[picks]):
        fr = np.asarray(img, np.float64).transpose(2, 0, 1) / 255.0
        up = direct_bilinear(fr[:, ::2, ::2], fr.shape[-1], 2)
        assert value == pytest.approx(float(psnr_from_mse(float(np.mean((up - fr) ** 2)))), abs=1e-3)
    run = tmp_path / "recnn-run"
    run.mkdir()
    (run / "result.json").write_text(json.dumps({"test": {"test/fr_psnr": 33.5}, "epochs": 20, "train_minutes": 9.5,
                                                  "config": {"recnn": {"net": {"_target_": "x", "channels": 16, "blocks": 4}}}}))
    row = mod.recnn_row(run)
    assert row["psnr_db"] == 33.5 and row["net"] == {"channels": 16, "blocks": 4}
    # a run is read only against the cache it was trained and tested on (recorded by the train CLI)
    result = json.loads((run / "result.json").read_text())
    (run / "result.json").write_text(json.dumps({**result, "caches": ["aaaaaaaaaaaa"]}))
    assert mod.recnn_row(run, "aaaaaaaaaaaa")["psnr_db"] == 33.5
    with pytest.raises(InputError, match="trained and tested on cache aaaaaaaaaaaa, not bbbbbbbbbbbb"):
        mod.recnn_row(run, "bbbbbbbbbbbb")
    # a run from before the record: its key is computed from the settings in its result.json
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="evidence"):
        cfg = compose("train", overrides=["model=recnn", "scene=tiny", "data=tiny", "renderer=numba",
                                          f"data.cache_dir={tiny_checkpoints['cache_dir']}"])
    GlobalHydra.instance().clear()
    config = OmegaConf.to_container(OmegaConf.masked_copy(cfg, ["scene", "data", "renderer"]), resolve=True)
    caches = {json.loads((p / "manifest.json").read_text())["hash"]: json.loads((p / "manifest.json").read_text())
              for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if (p / "manifest.json").is_file()}
    key = mod.trained_on({"config": config})
    assert len(key) == 1 and key[0] in caches, (key, {k: (m["resolution"], m["counts"]) for k, m in caches.items()})
    config["scene"]["shading"]["ambient"] = 0.5
    assert mod.trained_on({"config": config})[0] not in caches
    with pytest.raises(InputError, match="not a finished RecNN run"):
        mod.recnn_row(tmp_path)
    with pytest.raises(InputError, match="--pattern nope: expected one of"):
        mod.pattern_named("nope", 32)


def test_regime_evidence_foveal_fill_against_a_direct_scatter_and_fill(tiny_checkpoints):
    """For FoVolNet's foveal pattern the upsampling is the pull-push fill of the samples scattered to their FR
    positions: the script's PSNR equals that computed directly from the pattern's indices."""
    import torch

    from data_gen.cache_reader import ViewImageCache
    from imls_lightning.core.metrics import psnr_from_mse
    from imls_lightning.models.pull_push import pull_push_inpaint

    mod = _script_module("regime_evidence")
    cache_dir = next(p for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if (p / "manifest.json").is_file())
    cache = ViewImageCache.open(cache_dir)
    pattern = mod.pattern_named("foveal", cache.resolution)
    assert pattern.kind == "foveal" and len(pattern.indices) < cache.resolution ** 2
    got, name = mod.upsampling_psnr(cache, pattern, max_views=2)
    assert name == "pull-push"
    _, images = cache.split("test")
    for value, img in zip(got, images[np.linspace(0, len(images) - 1, 2).round().astype(int)]):
        fr = torch.from_numpy(np.asarray(img, np.float32) / 255.0).permute(2, 0, 1)[None]
        m = fr.shape[-1]
        mask = torch.zeros(1, 1, m * m)
        mask[..., pattern.indices] = 1.0
        mask = mask.view(1, 1, m, m)
        up = pull_push_inpaint(fr * mask, mask)
        assert value == pytest.approx(float(psnr_from_mse(float(torch.mean((up - fr) ** 2)))), abs=1e-3)


def test_retime_orp_runs_the_recorded_point_against_the_recnn_alone(tiny_checkpoints, tmp_path, capsys):
    """scripts/retime_orp.py refuses a checkpoint without a recorded ORP in one line; with one, it times the
    renderer from the checkpoint at that point against the RecNN alone, and its C-share and PSNR are the
    product's own on the same views."""
    import shutil

    from data_gen.cache import ViewImageCache
    from imls_lightning.evaluation.measurement import image_quality, spaced
    from imls_lightning.inference.checkpoints import load_task
    from imls_lightning.inference.operating_point import OperatingPoint, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer

    mod = _script_module("retime_orp")
    ckpt = Path(shutil.copy(tiny_checkpoints["ims_pim"], tmp_path / "ims.ckpt"))  # the record must not touch the fixture's
    fr_size = int(load_task(str(ckpt), expect="IMSTask", what="ims").hparams["fr_size"])
    cache_dir = next(p.parent for p in Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")
                     if ViewImageCache.open(p.parent).images.shape[1] == fr_size)
    # float32 networks, as the direct run below (--half auto measures which precision is faster here)
    args = [str(ckpt), str(cache_dir), "--views", "2", "--repeats", "2", "--warmup", "0", "--half", "false"]
    assert mod.main(args) == 2
    assert "no recorded operating point" in capsys.readouterr().err

    write_operating_point(ckpt, OperatingPoint(mean=0.5, lift=True, c_share=0.5, ipr=0.125, epsilon_db=1.0))
    assert mod.main(args) == 0
    out = capsys.readouterr().out
    rows = {line.split(" | ")[0].lstrip("| "): line.split(" | ") for line in out.splitlines()
            if line.startswith("| ") and "---" not in line and not line.startswith("| method")}
    assert set(rows) == {"RecNN alone", "IML/S + RecNN (recorded ORP)"}, out
    assert "u = 0.5000 (lift True)" in out and "speed-up of IML/S + RecNN over the RecNN alone" in out
    assert "networks: float32\n" in out

    direct = IMLSRenderer.from_checkpoints(str(ckpt))
    cache = ViewImageCache.open(cache_dir)
    test = np.asarray(cache.splits["test"])
    results = [(direct.run(np.asarray(cache.views[r], np.float64)), r) for r in test[spaced(len(test), 2)]]
    share = 100 * np.mean([res.info["c_share"] for res, _ in results])
    psnr = np.mean([image_quality(res.image, np.asarray(cache.images[r]))[0] for res, r in results])
    got = rows["IML/S + RecNN (recorded ORP)"]
    assert float(got[1].rstrip("%")) == pytest.approx(share, abs=0.05)
    assert float(got[-2]) == pytest.approx(psnr, abs=0.01)
    # --blocked: each method's runs back to back; the same pixels, so the same share and PSNR
    assert mod.main(args + ["--blocked"]) == 0
    out = capsys.readouterr().out
    assert "median of 2 back-to-back runs each" in out
    # --half true: the networks under bfloat16 autocast (the evaluation's precision where auto picks it)
    assert mod.main(args[:-1] + ["true"]) == 0
    assert "networks: bfloat16 autocast\n" in capsys.readouterr().out
    blocked = next(line.split(" | ") for line in out.splitlines() if line.startswith("| IML/S + RecNN"))
    assert blocked[1] == got[1] and blocked[-2] == got[-2]

    # the classical two-pass sampler alternated with both, at its own share
    assert mod.main(args + ["--two-pass", "0.8", "--base", "0.3"]) == 0
    out = capsys.readouterr().out
    two = [line.split(" | ") for line in out.splitlines() if line.startswith("| two passes (30% first)")]
    assert len(two) == 1 and abs(float(two[0][1].rstrip("%")) - 80.0) < 8.0, out
    assert "speed-up of two passes (30% first) + fill + RecNN over the RecNN alone" in out

    # the two-pass sampler at a searched point with a share per band (orp_promise --two-pass's rows)
    import json

    views = [np.asarray(cache.views[r], np.float64) for r in test[spaced(len(test), 2)]]
    d = sorted(float(np.linalg.norm(v[:3])) for v in views)
    rows_json = tmp_path / "promise.json"
    rows_json.write_text(json.dumps([{"two_pass": {"share": 0.8, "base": 0.3, "floor": 0.25,
                                                    "by_distance": {"edges": [0.5 * (d[0] + d[1]) if d[1] > d[0] else d[0] + 1],
                                                                    "shares": [0.8, 0.5]}}}]))
    assert mod.main(args + ["--two-pass-from", str(rows_json)]) == 0
    out = capsys.readouterr().out
    assert "| two passes, its searched shares per band (80% / 50%) |" in out, out
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    with pytest.raises(SystemExit, match="expected an evaluation's summary.json or orp_promise.py --two-pass rows"):
        mod.main(args + ["--two-pass-from", str(bad)])

    # --also: a copy of the checkpoint recorded at another point, alternated with the others on the same ray caster
    other = tmp_path / "other"
    other.mkdir()
    copy = Path(shutil.copy(ckpt, other / "ims.ckpt"))
    assert mod.main(args + ["--also", str(copy)]) == 2
    err = capsys.readouterr().err
    assert f"error: --also {copy}: no recorded operating point" in err, err
    write_operating_point(copy, OperatingPoint(mean=0.2, lift=True, c_share=0.2, ipr=0.05, epsilon_db=1.0))
    assert mod.main(args + ["--also", str(copy)]) == 0
    out = capsys.readouterr().out
    also = next(line.split(" | ") for line in out.splitlines() if line.startswith("| IML/S + RecNN (other's record)"))
    assert float(also[1].rstrip("%")) < float(got[1].rstrip("%")), out  # its own, smaller point
    assert "speed-up of IML/S + RecNN (other's record) over the RecNN alone" in out and "; limit " in out

    # --fill: each IML/S product's own mask with the pull-push fill instead of its decoder: the same pixels
    assert mod.main(args + ["--fill"]) == 0
    out = capsys.readouterr().out
    fill = next(line.split(" | ") for line in out.splitlines() if line.startswith("| IMS mask + fill + RecNN (recorded ORP)"))
    assert fill[1] == got[1] and "speed-up of IMS mask + fill + RecNN (recorded ORP) over the RecNN alone" in out, out

    # without empty-space skipping: the same pixels (PSNR to the last digit), other costs
    assert mod.main(args + ["--no-skip-empty"]) == 0
    out = capsys.readouterr().out
    assert "empty-space skipping off" in out
    off = {line.split(" | ")[0].lstrip("| "): line.split(" | ") for line in out.splitlines()
           if line.startswith("| ") and "---" not in line and not line.startswith("| method")}
    assert off["IML/S + RecNN (recorded ORP)"][-2] == got[-2] and off["IML/S + RecNN (recorded ORP)"][1] == got[1]


@pytest.mark.slow  # about 40 s on 2 cores; share_gaps and TwoPassFill are unit-tested in tests/estimate and tests/inference
def test_needed_share_check_scores_the_estimates_masks_with_the_trained_recnn(tiny_checkpoints, tmp_path, capsys):
    """scripts/needed_share_check.py on the tiny cache and RecNN: the same gaps as share_gaps with that RecNN, the
    whole pattern at gap 0, a two-pass variant that keeps its first pass; a folder that is not a run is refused."""
    import torch

    from data_gen.cache_reader import ViewImageCache
    from imls_lightning.estimate.needed_share import share_gaps
    from imls_lightning.inference.checkpoints import load_recnn

    mod = _script_module("needed_share_check")
    run = Path(tiny_checkpoints["recnn"])   # a checkpoint file; a run directory reads its result.json
    recnn, hp = load_recnn(tiny_checkpoints["recnn"])
    cache_dir = next(p.parent for p in Path(tiny_checkpoints["cache_dir"]).rglob("manifest.json")
                     if ViewImageCache.open(p.parent).images.shape[1] == int(hp["fr_size"]))
    out = tmp_path / "check.json"
    mod.main([str(cache_dir), str(run), "--views", "2", "--json", str(out)])
    data = json.loads(out.read_text())
    assert len(data["rows"]) == 20 and data["rows"][-1]["gap_db"] == pytest.approx(0.0, abs=1e-6)
    assert all(np.isfinite(r["gap_db"]) and np.isfinite(r["bound_db"]) for r in data["rows"])
    cache = ViewImageCache.open(cache_dir)
    _, images = cache.split("test")
    frames = [np.asarray(images[i]) for i in data["views"]]
    from imls_lightning.core.patterns import build_pattern

    with torch.inference_mode():
        _, gaps = share_gaps(lambda c: recnn.eval()(c).float(), build_pattern(hp["pattern"], cache.resolution), frames)
    assert [r["gap_db"] for r in data["rows"]] == pytest.approx(gaps.mean(0).tolist(), abs=1e-4)
    mod.main([str(cache_dir), str(run), "--views", "2", "--base", "0.3", "--split", "val", "--json", str(out)])
    data = json.loads(out.read_text())
    assert data["base"] == 0.3 and data["split"] == "val" and min(r["kept"] for r in data["rows"]) >= 0.29
    assert "two passes, the first 30% of C" in capsys.readouterr().out
    # timed against the RecNN alone on the renderer rebuilt from the cache
    mod.main([str(cache_dir), str(run), "--views", "2", "--base", "0.3", "--time", "0.8", "--time-views", "1",
              "--repeats", "1", "--json", str(out)])
    timing = json.loads(out.read_text())["timing"]
    two = timing["methods"]["two passes (30% first) + fill + RecNN"]
    assert abs(two["c_share"] - 0.8) < 0.08 and timing["methods"]["RecNN alone"]["c_share"] == 1.0
    assert timing["speedup"] > 0 and all(np.isfinite(v) for v in two.values())
    assert "speed-up of the two-pass sampler over the RecNN alone" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        mod.main([str(cache_dir), str(run), "--time", "0.8"])
    assert "--time: expected --base too" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        mod.main([str(cache_dir), str(tmp_path), "--views", "2"])
    assert e.value.code == 2 and "no result.json" in capsys.readouterr().err


def test_fovolnet_sizes_chooses_the_cheapest_within_the_bound_at_a_common_epoch(tmp_path, capsys):
    """scripts/fovolnet_sizes.py compares the candidates at the last epoch all of them reached, against the mean
    of the default's seeds, and marks the cheapest within the bound; the test PSNR never enters the choice."""
    mod = _script_module("fovolnet_sizes")
    d = dict(mod.DEFAULT_SIZES)
    w8 = {**d, "features": 8, "base_channels": 8, "filter_channels": 8}
    w4 = {**d, "features": 4, "base_channels": 4, "filter_channels": 4}

    def cand(sizes, curve, test, seed=0):
        return {"sizes": sizes, "seed": seed, "val_psnr": {str(k): v for k, v in curve.items()},
                "result": {"epochs": max(curve) + 1, "test": {"test/fr_psnr": test}}}

    summary = {"scene": "s", "gpu": "g", "candidates": {
        "default": cand(d, {1: 30.0, 3: 31.0}, 31.0),
        "default-seed1": cand(d, {1: 30.2, 3: 31.2}, 31.2, seed=1),
        # w8 is ahead at epoch 5, which the default never reached: compared at epoch 3 it is 0.6 dB behind
        "w8": cand(w8, {1: 29.8, 3: 30.5, 5: 31.5}, 40.0),
        "w4": cand(w4, {1: 29.9, 3: 30.8, 5: 30.9}, 20.0),
    }}
    estimate = {"recnn_ms": 600.0, "bound": [{"share": 0.2, "speedup": 1.5}], "share_for_target": 0.2,
                "candidates": [{"sizes": {k: w8[k] for k in ("features", "base_channels", "filter_channels")},
                                "recnn_ms": 300.0, "bound_20": 1.9, "share_for_target": 0.4},
                               {"sizes": {k: w4[k] for k in ("features", "base_channels", "filter_channels")},
                                "recnn_ms": 250.0, "bound_20": 2.0, "share_for_target": 0.4}]}
    rows, ref, defaults = mod.table(summary, estimate, 0.5)
    assert ref == pytest.approx(31.1) and sorted(defaults) == [31.0, 31.2]
    by = {r["candidate"]: r for r in rows}
    assert set(by) == {"default", "w8", "w4"} and {r["val_epoch"] for r in rows} == {3}
    assert by["w8"]["val_minus_default"] == pytest.approx(-0.6) and by["w4"]["val_minus_default"] == pytest.approx(-0.3)
    assert [r["candidate"] for r in rows if r["chosen"]] == ["w4"]
    (tmp_path / "s.json").write_text(json.dumps(summary))
    (tmp_path / "e.json").write_text(json.dumps(estimate))
    assert mod.main([str(tmp_path / "s.json"), str(tmp_path / "e.json"), "--out", str(tmp_path / "t")]) == 0
    assert "**4 / 4 / 4" in (tmp_path / "t.md").read_text() and (tmp_path / "t.png").stat().st_size > 0
    assert len((tmp_path / "t.csv").read_text().splitlines()) == 4
    estimate["candidates"] = []
    with pytest.raises(SystemExit, match="no candidate with sizes"):
        mod.table(summary, estimate, 0.5)


@pytest.mark.slow
def test_lent_gpu_fovolnet_driver_on_the_tiny_scene(tmp_path):
    """scripts/lent_gpu_fovolnet.py end to end on the tiny scene (CPU): it renders the cache, trains two candidates
    side by side with real Trainer runs, reads their validation curves and packs one bundle per run, within the
    eight files a lent machine sends back."""
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    p = subprocess.run([PY, str(ROOT / "scripts" / "lent_gpu_fovolnet.py"), "--out", str(out), "--deadline", "280",
                        "--scene", "tiny", "--data", "tiny", "--render-workers", "0", "--epochs", "2", "--val-every", "1",
                        "--loader-workers", "0", "--candidates", "w4", "default-seed1"],
                       cwd=tmp_path, env={**env, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cache"]["rc"] == 0
    for name, seed in (("w4", 0), ("default-seed1", 1)):
        row = summary["candidates"][name]
        assert row["rc"] == 0 and row["seed"] == seed and sorted(row["val_psnr"]) == ["0", "1"]
        assert (out / f"run_{name}.tgz").is_file()
    assert summary["candidates"]["w4"]["run"] != summary["candidates"]["default-seed1"]["run"]
    assert len(list(out.iterdir())) <= 8


@pytest.mark.slow
def test_lent_gpu_pair_driver_on_the_tiny_scene(tmp_path):
    """scripts/lent_gpu_pair.py end to end on the tiny scene (CPU): bench-paper's own stage commands, the scene's
    cache, the RecNN, then the IML beside the blue-noise decoder and the sparser RecNN, the IMS's own cache rendered by
    the driver's helper process (from a folder where only PYTHONPATH finds the package, as on a lent machine), the
    IMS once the IML is done; one summary and the runs packed within the eight files a lent machine sends back."""
    import tarfile

    out = tmp_path / "out"
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    p = subprocess.run([PY, str(ROOT / "scripts" / "lent_gpu_pair.py"), "--out", str(out), "--recnn", "enhancenet",
                        "--scene", "tiny", "--data", "tiny", "--deadline", "330", "--render-workers", "1",
                        "--ims-cache-workers", "1", "--recnn-seconds", "40", "--iml-seconds", "40", "--val-every", "1",
                        "--override", "data.crop=null"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=420)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["recnn"] == "enhancenet" and summary["cache"]["rc"] == 0 and "error" not in summary
    assert summary["ims_cache"]["rc"] == 0  # the helper process found the package
    for stage in ("recnn", "iml", "blue_noise", "sparser", "ims"):
        assert summary["stages"][stage]["rc"] == 0, stage
    assert any(k.startswith("ims-enhancenet-tiny-") for k in summary["stages"])
    parts = sorted(out.glob("runs.tgz.*"))
    assert parts and len(list(out.iterdir())) <= 8
    with tarfile.open(fileobj=__import__("io").BytesIO(b"".join(q.read_bytes() for q in parts))) as tar:
        names = tar.getnames()
    assert any(n.startswith("runs/paper/ims-enhancenet-tiny-") and n.endswith(".ckpt") for n in names)


def test_regime_evidence_error_map_draws_truth_and_both_errors(tiny_checkpoints, tmp_path):
    """--error-map: the truth, then |bilinear - truth| x8 and |RecNN - truth| x8 of one test view, side by side
    (the RecNN: the run's best checkpoint); a view outside the test trajectory is refused in one line."""
    import torch
    from PIL import Image

    from data_gen.cache_reader import ViewImageCache

    mod = _script_module("regime_evidence")
    cache_dir = next(p for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if (p / "manifest.json").is_file())
    cache = ViewImageCache.open(cache_dir)
    run = tmp_path / "recnn-run"
    run.mkdir()
    (run / "result.json").write_text(json.dumps({"best_checkpoint": str(tiny_checkpoints["recnn"])}))
    pattern = mod.pattern_named("downsample", cache.resolution)
    png = mod.error_map(cache, run, pattern, tmp_path / "err.png", view=1)
    sheet = np.asarray(Image.open(png))
    m = cache.resolution
    assert sheet.shape == (m, 3 * m, 3)
    _, images = cache.split("test")
    truth = np.asarray(images[1])
    assert np.array_equal(sheet[:, :m], truth)
    fr = torch.from_numpy(truth.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    up = fr[..., ::2, ::2]
    up, _ = mod.upsample_c_image(up, pattern)
    expected = ((up - fr).abs().mean(1)[0].clamp(0, 1 / 8).numpy() * 8 * 255 + 0.5).astype(np.uint8)
    assert np.abs(sheet[:, m:2 * m, 0].astype(int) - expected).max() <= 1
    assert sheet[:, 2 * m:].any()
    with pytest.raises(InputError, match="--error-view 999: expected 0 .. ") as e:
        mod.error_map(cache, run, pattern, tmp_path / "bad.png", view=999)
    assert "\n" not in str(e.value) and not (tmp_path / "bad.png").exists()


def test_regime_contact_sheet_stacks_each_scenes_first_estimate_view(tmp_path):
    """scripts/regime_contact_sheet.py: one labelled row per scene, the first view of the estimate the table names;
    a scene the table lacks is refused in one line."""
    from PIL import Image

    from tests.estimate.test_measure import _cli

    table = tmp_path / "estimates.csv"
    r = _cli(tmp_path, f"table={table}")
    assert r.returncode == 0, r.stderr
    est = json.loads(Path(r.stdout.strip().splitlines()[-1]).read_text())
    sheet = np.asarray(Image.open(est["contact_sheet"]).convert("RGB"))
    mod = _script_module("regime_contact_sheet")
    rows = mod.scene_rows(table, ["tiny", "tiny"])
    view = sheet[: sheet.shape[0] // len(est["bilinear_db_per_view"])]
    assert len(rows) == 2 and rows[0][0].startswith("tiny (32x32x32, bilinear") and np.array_equal(rows[0][1], view)
    out = np.asarray(Image.open(mod.draw(rows, tmp_path / "sheet.png")))
    assert out.shape == (2 * view.shape[0], view.shape[1], 3)
    assert np.array_equal(out[view.shape[0] + 20:, :], view[20:])  # below the label, the estimate's pixels
    with pytest.raises(InputError, match=f"nope: no enhancenet estimate in {table}"):
        mod.scene_rows(table, ["nope"])


def test_estimate_vs_measured_on_the_committed_estimates(tmp_path, capsys):
    """scripts/estimate_vs_measured.py: each prediction is speedup_at on the estimate's own content, the estimate's is
    the slower render; the committed flame_whole estimate stays within 15% of its measured 1.72x."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import estimate_vs_measured as evm

    from imls_lightning.estimate import RenderCost, RenderCurve, speedup_at

    path = ROOT / "benchmarks" / "estimate_check" / "flame_whole_no_skipping.json"
    out = tmp_path / "check.csv"
    (row,) = evm.main([f"{path}:0.304751:1.72167", "--csv", str(out)])
    est = json.loads(path.read_text())
    kw = {"c_render_ms": est["c_render_ms"], "nets_ms": est["nets_ms"], "recnn_ms": est["recnn_ms"]}
    sil = speedup_at(RenderCurve(**est["render_curve"]), 0.304751, **kw)
    model = speedup_at(RenderCost(**est["render_cost"]), 0.304751, **kw, background_density=est["background_density"])
    assert row["silhouette"] == pytest.approx(sil) and row["per_pixel_model"] == pytest.approx(model)
    assert row["slower"] == pytest.approx(min(sil, model)) and abs(row["slower_error"]) < 0.15
    assert "flame_whole (skip_empty=False) at 30.5% of C" in capsys.readouterr().out
    assert out.read_text().splitlines()[0].startswith("estimate,scene,skip_empty,share")
    with pytest.raises(SystemExit, match="expected estimate.json:share:measured"):
        evm.main([f"{path}:0.3"])


def test_estimate_vs_measured_gives_the_reading_its_interval_over_the_estimates_views(tmp_path, capsys):
    """An estimate that kept its views' times (the committed 18-view seed_whole estimate): the row's reading carries
    estimate_interval's 95% interval at the row's share and sharpness, on stdout and in the CSV."""
    import csv

    sys.path.insert(0, str(ROOT / "scripts"))
    import estimate_vs_measured as evm

    from imls_lightning.estimate import estimate_interval

    path = ROOT / "benchmarks" / "estimate_check" / "seed_whole_estimate_18_views.json"
    out = tmp_path / "rows.csv"
    (row,) = evm.main(["--sharpness", "3", "--csv", str(out), f"{path}:0.374953:2.02242"])
    est = json.loads(path.read_text())
    interval = estimate_interval(est, 0.374953, 3.0)
    assert row["views"] == len(est["per_view"]) == 18 and row["seconds"] == est["seconds"]
    assert (row["row_reading_low"], row["row_reading_high"]) == (pytest.approx(interval.low), pytest.approx(interval.high))
    assert row["row_reading_low"] < row["row_reading"] < row["row_reading_high"]
    assert row["row_reading"] == pytest.approx(interval.speedup, rel=1e-9)
    assert f"95% over its 18 views {interval.low:.2f}-{interval.high:.2f}x" in capsys.readouterr().out
    (written,) = list(csv.DictReader(out.open()))
    assert float(written["row_reading_low"]) == pytest.approx(interval.low, rel=1e-3) and written["views"] == "18"


def test_ims_mask_shape_script_on_real_checkpoints(tiny_checkpoints, capsys):
    """scripts/ims_mask_shape.py: densities in [0, 1] that account for the share, the rings against a direct distance,
    and the timed ratios, on the tiny scene's real IMS (target=pim)."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import ims_mask_shape as ims

    from data_gen.cache_reader import ViewImageCache

    caches = [p for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if p.is_dir() and p.name.startswith("tiny-")]
    cache = next(p for p in caches if ViewImageCache.open(p).resolution == 32)
    rows = ims.main(["--ims", str(tiny_checkpoints["ims_pim"]), "--cache", str(cache), "--mean", "0.4", "--views", "2",
                     "--time", "--repeats", "1", "skip_empty=false"])
    assert len(rows) == 2 and len(capsys.readouterr().out.strip().splitlines()) == 2
    for row in rows:
        assert 0 < row["share"] <= 1 and 0 <= row["object"] <= 1
        dens = [v for k, v in row.items() if k.startswith("density_") and v is not None]
        assert dens and all(0 <= v <= 1 for v in dens)
        assert all(np.isfinite(row[k]) and row[k] > 0 for k in ("mask_ms", "pattern_ratio", "silhouette_4_ratio"))
    on = np.zeros(16, bool)
    on[5] = True                                      # a 4x4 C grid, the object at (1, 1)
    d = ims.distance_to_object(on, 4, 16).reshape(4, 4)
    yy, xx = np.mgrid[0:4, 0:4]
    assert (d == np.maximum(abs(yy - 1), abs(xx - 1))).all()
    with pytest.raises(SystemExit, match="--views=0"):
        ims.main(["--ims", "x", "--cache", str(cache), "--views", "0"])


def test_mask_sharpness_script_on_real_checkpoints(tiny_checkpoints, capsys):
    """scripts/mask_sharpness.py: one row per (sharpness, mean value) on the tiny scene's real IMS (target=pim): shares
    in (0, 1] that grow with the mean, gaps that reach 0 where the mask takes the whole pattern, finite render times;
    bad arguments are one-line exits."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import mask_sharpness as ms

    from data_gen.cache_reader import ViewImageCache

    caches = [p for p in Path(tiny_checkpoints["cache_dir"]).iterdir() if p.is_dir() and p.name.startswith("tiny-")]
    cache = next(p for p in caches if ViewImageCache.open(p).resolution == 32)
    rows = ms.main(["--ims", str(tiny_checkpoints["ims_pim"]), "--cache", str(cache), "--views", "2", "--sharpness", "1", "3",
                    "--means", "0.02", "1.0", "--time", "--repeats", "1", "skip_empty=false"])
    assert [(r["sharpness"], r["mean"]) for r in rows] == [(1.0, 0.02), (1.0, 1.0), (3.0, 0.02), (3.0, 1.0)]
    assert len(capsys.readouterr().out.strip().splitlines()) == 4
    for r in rows:
        assert 0 < r["share"] <= 1 and np.isfinite(r["gap_db"]) and np.isfinite(r["render_ms"]) and r["render_ms"] > 0
    for lo, hi in ((rows[0], rows[1]), (rows[2], rows[3])):
        assert hi["share"] == pytest.approx(1.0) and lo["share"] < 1.0 and abs(hi["gap_db"]) < 1e-9
    for bad, msg in ((["--views", "0"], "--views=0"), (["--sharpness", "0.5"], "--sharpness=0.5: expected a number in [1, 8]"),
                     (["--means", "2"], "--means=2.0: expected")):
        with pytest.raises(SystemExit, match=re.escape(msg)):
            ms.main(["--ims", str(tiny_checkpoints["ims_pim"]), "--cache", str(cache), *bad])


def test_object_floor_raises_a_bands_u_to_the_predicted_object_plus_its_margin():
    """``u = max(u_band, object + margin)``, the object being the share of the pattern's pixels whose PIM' exceeds tau
    (a direct count), at most 1; margin None leaves the bands' u."""
    import torch

    mod = _script_module("object_floor")

    class Gen(torch.nn.Module):  # PIM' = (g + 1) / 2 of view k: the first 4k of 16 pixels at 0.9, the rest at 0.05
        def forward(self, v):
            g = torch.full((v.shape[0], 1, 4, 4), -0.9)
            for k in range(v.shape[0]):
                g[k, 0].view(-1)[: 4 * int(v[k, 0])] = 0.8
            return g

    valid = torch.ones(4, 4, dtype=torch.bool)
    valid[0, 0] = False  # a padded C-pixel does not count
    views = torch.zeros(3, 9)
    views[:, 0] = torch.tensor([0.0, 2.0, 4.0])
    band = lambda v: torch.full((v.shape[0],), 0.3)  # noqa: E731
    pim = (Gen()(views)[:, 0] + 1) / 2
    direct = torch.stack([(pim[k][valid] > 0.2).float().mean() for k in range(3)])
    floor = mod.ObjectFloor(band, Gen(), valid, 0.1, 0.2)
    assert torch.allclose(floor.object_fraction(views), direct)
    assert torch.allclose(floor(views), torch.maximum(torch.full((3,), 0.3), (direct + 0.1).clamp(max=1.0)))
    assert float(floor(views)[2]) == 1.0  # the whole pattern is object: at most 1
    assert torch.equal(mod.ObjectFloor(band, Gen(), valid, None, 0.2)(views), torch.full((3,), 0.3))


def test_object_floor_chooses_the_smallest_margin_whose_quarters_stay_bounded():
    """The point is chosen as the ORP search chooses: every quarter's one-sided 95% bound on the mean gap (a direct
    formula) within epsilon; of those, the smallest share of C."""
    mod = _script_module("object_floor")
    rng = np.random.default_rng(0)
    gaps, dist = rng.normal(0.5, 0.4, 40), rng.uniform(3, 5, 40)
    got = mod.quarter_bounds(gaps, dist, 0.95, 30)
    q = np.array_split(np.argsort(dist, kind="stable"), 4)
    # mean + z s sqrt(1/n + 1/m): 10 views of a quarter bound the mean of 30 new ones
    want = [gaps[p].mean() + 1.6448536269514722 * gaps[p].std(ddof=1) * np.sqrt(1 / 10 + 1 / 30) for p in q]
    assert got == pytest.approx(want, rel=1e-9)

    def row(m, bounds, share):
        return {"margin": m, "quarter_bounds_db": bounds, "test_c_share": share}

    rows = [row(None, [1.3, 0.5, 0.4, 0.1], 0.30), row(0.0, [1.1, 0.5, 0.4, 0.1], 0.31), row(0.05, [0.9, 0.5, 0.4, 0.1], 0.34),
            row(0.1, [0.5, 0.4, 0.3, 0.1], 0.38)]
    assert mod.choose(rows, 1.0) == 2  # the cheapest that holds
    assert mod.choose(rows[:2], 1.0) is None
    assert mod.choose([row(None, [0.5, 0.4, 0.3, 0.1], 0.3)], 1.0) == 0  # the bands alone already keep it
    # a joint search: lower bands under a floor may hold at a smaller share than the bands with a floor
    assert mod.choose(rows + [row(0.1, [0.9, 0.6, 0.2, 0.1], 0.33)], 1.0) == 4


def test_estimate_vs_measured_reads_the_row_and_its_own_times():
    """With a row's metrics.csv: the row's render fraction is the mean over its timed views of the product's
    selective render over the mean of the RecNN alone's; the estimate's fraction at the share is read off the curve
    of the sharpness the row kept, and put on the row's own stage times; the row's reading is estimated_speedup's."""
    import csv

    sys.path.insert(0, str(ROOT / "scripts"))
    import estimate_vs_measured as evm

    from imls_lightning.estimate import RenderCurve, speedup_from_estimate

    est_path = ROOT / "benchmarks" / "seed_whole" / "estimate.json"
    metrics = ROOT / "benchmarks" / "seed_whole" / "eval_metrics.csv"
    (row,) = evm.main(["--sharpness", "3", f"{est_path}:0.342873:2.55588:{metrics}"])
    est = json.loads(est_path.read_text())
    assert row["row_reading"] == pytest.approx(speedup_from_estimate(est, 0.342873, 3.0))
    assert row["row_reading"] == pytest.approx(2.17598, rel=1e-4)   # the row's estimated_speedup in paper_scale.csv
    assert "row_reading_low" not in row and row["views"] == ""   # an estimate without per-view times has no interval
    with open(metrics, newline="") as f:
        timed = [r for r in csv.DictReader(f) if r["total_ms"]]

    def mean(method, col):
        return np.mean([float(r[col]) for r in timed if r["method"] == method])
    render, whole = mean("imls", "selective_render_ms"), mean("recnn", "selective_render_ms")
    assert row["row_render_fraction"] == pytest.approx(render / whole)
    frac = RenderCurve(**est["by_sharpness"]["3"]["render_curve"]).render_ms(0.342873) / est["c_render_ms"]
    assert row["estimate_render_fraction"] == pytest.approx(frac)
    nets = mean("imls", "importance_ms") + mean("imls", "decoder_ms")
    assert row["on_row_times"] == pytest.approx((whole + mean("recnn", "recnn_ms")) /
                                                (nets + frac * whole + mean("recnn", "recnn_ms")))
    # the row's own times give back its speed-up with its own fraction (a ratio of means)
    assert (mean("recnn", "total_ms") / mean("imls", "total_ms")) == pytest.approx(2.55588, rel=1e-3)


def test_object_floor_by_band_script_refuses_bad_arguments_and_an_evaluation_without_bands(tmp_path, capsys):
    """scripts/object_floor_by_band.py: margins and tail outside [0, 1] are argparse errors; an evaluation whose ORP has
    no bands of camera distance (or no lifted masks) is refused in one line before any network is loaded."""
    import json

    mod = _script_module("object_floor_by_band")
    ev = tmp_path / "eval"
    ev.mkdir()
    (ev / "config.yaml").write_text("settings: {}\n")
    for bad in (["--tail", "1.5"], ["--margins", "-0.1"]):
        with pytest.raises(SystemExit):
            mod.main([str(ev), "--out", str(tmp_path / "o"), *bad])
        assert "--margins and --tail must lie in [0, 1]" in capsys.readouterr().err
    (ev / "summary.json").write_text(json.dumps({"orp": {"found": True, "lift": True, "by_distance": None}}))
    with pytest.raises(SystemExit, match="expected an ORP found by distance bands with lifted masks"):
        mod.main([str(ev), "--out", str(tmp_path / "o")])
    assert not (tmp_path / "o").exists()


def test_measure_net_options_times_each_set_on_the_estimates_networks(tmp_path, capsys):
    """Every asked option set gets a row of the three stages IML/S runs and their sum, from the networks the estimate
    builds (a foveal pattern and a FoVolNet of given sizes here); a bad override or share is one line."""
    mod = _script_module("measure_net_options")
    out = tmp_path / "options.md"
    args = ["--rounds", "2", "--repeats", "1", "--sets", "float32", "bfloat16", "--out", str(out), "--",
            "resolution=64", "recnn=fovolnet", "++recnn.net.features=4", "++recnn.net.base_channels=4",
            "++recnn.net.filter_channels=4", "++recnn.net.depth=2", "++recnn.net.levels=2", "++recnn.net.kernel_size=3",
            "iml.depth=2", "iml.base_channels=4", "ims.layers=5", "ims.base_channels=4"]
    assert mod.main(args) == 0
    text = out.read_text()
    assert "foveal pattern 64^2 -> 32^2" in text and "fovolnet (features=4" in text
    rows = [line for line in text.splitlines() if line.startswith("| float32") or line.startswith("| bfloat16")]
    assert len(rows) == 2 and rows[0].split(" | ")[5] == "1.00x"
    for row in rows:  # the networks column is the sum of the three stages
        ims, dec, rec, total = (float(x) for x in row.split(" | ")[1:5])
        assert ims > 0 and dec > 0 and rec > 0 and abs(ims + dec + rec - total) < 0.15
    # the product path on the tiny scene: the RecNN alone against IML/S + RecNN, both option sets, real ray casts
    assert mod.main(["--rounds", "1", "--repeats", "1", "--sets", "float32", "bfloat16", "--product-views", "2",
                     "--product-repeats", "1", "--share", "0.5", "--out", str(out), "--", "scene=tiny", *args[args.index("--") + 1:]]) == 0
    text = out.read_text()
    assert "The product path on 2 views of scene tiny" in text
    product = [line for line in text.split("The product path")[1].splitlines() if line.startswith(("| float32", "| bfloat16"))]
    assert len(product) == 2
    for row in product:
        cells = row.strip("| ").split(" | ")
        alone, imls, speedup = float(cells[3]), float(cells[8]), float(cells[9].rstrip("x"))
        assert alone > 0 and imls > 0
        # the ratio of the mean totals, which the table prints rounded to whole ms
        assert abs(speedup - alone / imls) <= 0.5 / imls * (1 + alone / imls) + 0.01, row
    with pytest.raises(SystemExit, match="^Could not override 'recnn.net.nonsense'"):
        mod.main(["--", "recnn=fovolnet", "recnn.net.nonsense=3"])
    with pytest.raises(SystemExit, match=r"--share=0.0: expected a share of C in \(0, 1\]"):
        mod.main(["--share", "0"])
