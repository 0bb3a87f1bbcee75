"""Export of the IML/S + RecNN networks (imls_lightning.inference.export; the CLI imls_lightning.export):
TorchScript and ONNX files that render the same images as IMLSRenderer, the loader, the CLI and its errors.

Fast tests build IMS checkpoints in-process (real tasks, random weights; the generator's output
bias is set so that about half of the C-Image is important: an empty or full IM would hide a
wrong network). The slow test trains the real chain through the train CLI (fast_dev_run)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError
from imls_lightning.render import make_renderer
from data_gen.scenes import build_scene
from data_gen.views import sample_training_views
from imls_lightning.export import parse_args
from imls_lightning.inference.export import ExportedIMLSRenderer, IMPredictor, export_renderer, onnx_available
from imls_lightning.evaluation.timing import timed
from imls_lightning.core.operating_point import OperatingPoint
from imls_lightning.inference.pipeline import IMLSRenderer
from imls_lightning.inference.checkpoints import load_task
from imls_lightning.tasks.iml import IMLTask
from imls_lightning.tasks.ims import IMSTask
from imls_lightning.tasks.recnn import RecNNTask

ROOT = Path(__file__).resolve().parents[1]
FR = 32
PATTERNS = {
    "enhancenet": ({"kind": "downsample", "factor": 2},
                   {"_target_": "imls_lightning.models.enhancenet.EnhanceNet", "channels": 4, "blocks": 1}),
    # n = 16, K < 256: a zero-padded C-Image (the IM must stay False on the padding)
    "fovolnet": ({"kind": "foveal", "c_size": 16, "sigma": 0.1},
                 {"_target_": "imls_lightning.models.fovolnet.FoVolNet", "features": 4, "depth": 2, "base_channels": 4,
                  "filter_channels": 4, "levels": 2}),
}
LOSS = {"bce": 1.0, "perceptual": 0.0, "adversarial": 0.01}

pytestmark = pytest.mark.filterwarnings("ignore:.*LeafSpec.*", "ignore:.*does not have many workers.*")


def _save(task, path: Path) -> str:
    tr = L.Trainer(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                   enable_model_summary=False, max_steps=0)
    tr.strategy.connect(task)
    tr.save_checkpoint(path)
    return str(path)


def _views(n: int, seed: int) -> np.ndarray:
    return sample_training_views(n, (3.0, 4.5), seed=seed).astype(np.float32)


def make_ims_task(recnn: str, target: str = "im", with_recnn: bool = True) -> tuple[IMSTask, RecNNTask]:
    pattern, net = PATTERNS[recnn]
    torch.manual_seed(0)
    rec = RecNNTask(net, pattern, FR)
    iml = IMLTask(pattern, FR, mode="end_to_end", depth=2, base_channels=4, recnn_hparams=dict(rec.hparams))
    ims = IMSTask(pattern, FR, dict(iml.hparams), target=target, layers=5, base_channels=8, disc_base_channels=8,
                  loss=LOSS, recnn_hparams=dict(rec.hparams) if with_recnn else None)
    ims.iml.load_state_dict(iml.iml.state_dict())
    if with_recnn:
        ims.recnn.load_state_dict(rec.net.state_dict())
    ims._fit_view_normalization(torch.from_numpy(_views(64, 1)))
    ims.view_norm_fitted.fill_(True)
    ims.eval()
    # centre the generator's output on the decision threshold: a mixed IM on every view
    last = ims.generator.net[-2]
    with torch.no_grad():
        g = ims.generator(torch.from_numpy(_views(16, 2)))
        thr = 0.0 if target == "im" else 0.5  # pim: (g + 1) / 2 > P, P uniform in (0, 1]
        last.bias -= torch.atanh(g.clamp(-0.999, 0.999)).median() - float(np.arctanh(thr))
    return ims, rec


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    root = tmp_path_factory.mktemp("export_ckpts")
    out = {}
    for name in PATTERNS:
        ims, rec = make_ims_task(name)
        out[name] = _save(ims, root / f"ims_{name}.ckpt")
        out[f"{name}_recnn"] = _save(rec, root / f"recnn_{name}.ckpt")
    ims, _ = make_ims_task("enhancenet", with_recnn=False)
    out["standalone"] = _save(ims, root / "ims_standalone.ckpt")
    return out


@pytest.fixture(scope="module")
def renderer():
    scene = build_scene(OmegaConf.load(ROOT / "conf" / "scene" / "tiny.yaml"))
    return make_renderer(scene, {"name": "numba", "threads": 1})


def _compare(ref: IMLSRenderer, exp: ExportedIMLSRenderer, views, tol: int) -> list[int]:
    """Render every view both ways; returns the IM sizes (checked equal) and checks the images."""
    sizes = []
    for v in views:
        a, b = ref.run(v), exp.run(v)
        assert torch.equal(a.info["im"], b.info["im"])
        diff = np.abs(a.image.astype(np.int16) - b.image.astype(np.int16)).max()
        assert diff <= tol, diff
        assert a.info["rendered_pixels"] == b.info["rendered_pixels"]
        img, timings = timed(exp).render(v)
        assert img.shape == (FR, FR, 3) and img.dtype == np.uint8
        assert set(timings) == {"importance", "selective_render", "decoder", "recnn", "total"}
        sizes.append(int(b.info["im"].sum()))
    return sizes


@pytest.mark.parametrize("recnn", list(PATTERNS))
def test_torchscript_export_renders_the_same_images_within_one_level(ckpts, renderer, tmp_path, recnn):
    """The IM is bitwise the same; the image within one 8-bit level: TorchScript's profiling executor
    fuses the refine decoder's elementwise blend after the first calls, and fused float arithmetic may
    round differently."""
    out = export_renderer(ckpts[recnn], tmp_path / "ts", format="torchscript")
    meta = json.loads((out / "export.json").read_text())
    assert meta["format"] == "torchscript" and sorted(meta["files"]) == ["decoder", "im", "recnn"]
    assert all((out / f).is_file() for f in meta["files"].values())
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left behind
    ref = IMLSRenderer.from_checkpoints(ckpts[recnn], renderer=renderer, opts=None)
    exp = ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu")
    assert exp.pattern.fingerprint() == ref.pattern.fingerprint()
    assert isinstance(exp.decoder.packed, torch.jit.ScriptModule)  # the decoder runs as TorchScript
    sizes = _compare(ref, exp, _views(4, 7), tol=1)
    valid = ref.pattern.count
    assert all(0 < s < valid for s in sizes), (sizes, valid)  # a mixed IM: the networks really ran


@pytest.mark.parametrize("recnn", list(PATTERNS))
def test_onnx_export_renders_the_same_images_within_one_level(ckpts, renderer, tmp_path, recnn):
    if not onnx_available():
        pytest.skip("onnx not installed (pip install imls-lightning[export])")
    pytest.importorskip("onnxruntime")
    import onnx

    out = export_renderer(ckpts[recnn], tmp_path / "onnx", format="onnx")
    for f in ("im.onnx", "decoder.onnx", "recnn.onnx"):
        onnx.checker.check_model(onnx.load(str(out / f)))
    ref = IMLSRenderer.from_checkpoints(ckpts[recnn], renderer=renderer)
    exp = ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu")
    sizes = _compare(ref, exp, _views(4, 7), tol=1)
    assert all(0 < s < ref.pattern.count for s in sizes)


@pytest.mark.parametrize("target", ["im", "pim"])
def test_im_predictor_is_the_tasks_thresholding(target):
    ims, _ = make_ims_task("fovolnet", target=target)
    pred = IMPredictor(ims.mask_head).eval()
    views = torch.from_numpy(_views(8, 3))
    with torch.no_grad():
        want = ims.predict_im(views)
        got = pred(views)
        traced = torch.jit.trace(pred, (views[:1],), check_trace=False)
        again = traced(views)
    assert got.dtype == torch.bool and torch.equal(got, want) and torch.equal(again, want)
    assert not got[:, :, ~ims.pattern.valid].any()  # padding is never important
    assert 0 < int(want.sum()) < want[:, :, ims.pattern.valid].numel()


def _low_pim_ims(recnn: str, shift: float) -> IMSTask:
    """A ``target=pim`` IMS whose PIM' sits low (the generator's pre-tanh output lowered by ``shift``):
    at a mean value above the trained one the plain rescale saturates short of u, so the lift works
    (``shift=8``: every PIM' is 0, only the lift's blue-noise floor samples)."""
    ims, _ = make_ims_task(recnn, target="pim")
    with torch.no_grad():
        ims.generator.net[-2].bias -= shift
    return ims


# the thresholding itself is checked against the reference on both kinds of pattern in tests/models/test_ims.py;
# here the export of it: a padded (foveal) pattern, with the rescale's lift and with only the floor sampling
@pytest.mark.parametrize("recnn, shift", [("fovolnet", 3.0), ("fovolnet", 8.0)])
def test_im_predictor_at_a_mean_is_the_tasks_rescale_and_lift(recnn, shift):
    """At another mean value the exported IM is the mask head's (IMSTask.predict_im's) bit for bit, plain
    and lifted (the lift in tensor operations only: the trace of one view serves a batch)."""
    ims = _low_pim_ims(recnn, shift)
    views = torch.from_numpy(_views(8, 3))
    k = ims.pattern.count
    for lift in (False, True):
        for u in (0.05, 0.35, 0.95):  # below and above the trained mean (0.1)
            pred = IMPredictor(ims.mask_head, OperatingPoint(share=u, lift=lift)).eval()
            with torch.no_grad():
                want = ims.predict_im(views, mean=u, lift=lift)
                traced = torch.jit.trace(pred, (views[:1],), check_trace=False)
                assert torch.equal(pred(views), want) and torch.equal(traced(views), want), (lift, u)
            if lift and u > 0.1:  # the lift reaches u's share, which the rescale alone does not
                assert float(want.sum()) / (8 * k) == pytest.approx(u, abs=0.02)
    assert float(ims.predict_im(views, mean=0.95).sum()) / (8 * k) < 0.5  # the paper's rescale unless asked


def test_export_carries_the_recorded_operating_point(renderer, tmp_path, capsys):
    """export.json carries the evaluation's record; the exported renderer thresholds at its mean value
    (lifted) by default, the same IMs as IMLSRenderer.from_checkpoints; mean= overrides it."""
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ims = _low_pim_ims("enhancenet", 3.0)
    ckpt = _save(ims, tmp_path / "ims_pim.ckpt")
    point = ORPRecord(mean=0.6, lift=True, c_share=0.6, ipr=0.15, epsilon_db=1.0, gap_db=0.8, views=4)
    write_operating_point(ckpt, point)
    out = export_renderer(ckpt, tmp_path / "ts")
    meta = json.loads((out / "export.json").read_text())
    assert (meta["mean"], meta["lift"], meta["trained_mean"]) == (0.6, True, pytest.approx(0.1))
    assert meta["operating_point"]["mean"] == 0.6 and meta["operating_point"]["gap_db"] == 0.8
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer)
    assert ref.mean == 0.6 and ref.record == point
    exp = ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu")
    assert exp.mean == 0.6 and exp.record["c_share"] == 0.6
    sizes = _compare(ref, exp, _views(3, 7), tol=1)
    assert np.mean(sizes) / ref.pattern.count == pytest.approx(0.6, abs=0.05)
    assert "operating point u = 0.600 (masks lifted)" in capsys.readouterr().err
    # an explicit mean value overrides the record
    out = export_renderer(ckpt, tmp_path / "trained", mean="trained")
    meta = json.loads((out / "export.json").read_text())
    assert meta["mean"] == pytest.approx(0.1) and meta["operating_point"] is None and not meta["lift"]
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer, mean="trained")
    trained = _compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), _views(2, 7), tol=1)
    assert np.mean(trained) / ref.pattern.count < 0.3  # PIM' low: the trained mean renders little
    assert parse_args(["ims_checkpoint=a", "out=b", "mean=0.4"])["mean"] == "0.4"
    with pytest.raises(InputError, match=r"^mean=2: expected a number in \[0.01, 1\]"):
        export_renderer(ckpt, tmp_path / "bad", mean=2)
    # share is the documented name (mean its older one): the same export, its own name in messages, not both at once
    by_share = json.loads((export_renderer(ckpt, tmp_path / "share", share="trained") / "export.json").read_text())
    assert by_share["mean"] == meta["mean"] and parse_args(["ims_checkpoint=a", "out=b", "share=0.4"])["share"] == "0.4"
    with pytest.raises(InputError, match=r"^share=2: expected a number in \[0.01, 1\]"):
        export_renderer(ckpt, tmp_path / "bad", share=2)
    from imls_lightning.inference.operating_point import share_setting

    with pytest.raises(InputError, match=r"^share=0.4 and mean=0.3: set one"):
        share_setting(parse_args(["ims_checkpoint=a", "out=b", "share=0.4", "mean=0.3"]))


def test_export_runs_a_point_recorded_with_the_fill_as_decoder(renderer, tmp_path):
    """A point whose search kept the pull-push fill (orp_decoders) is exported as it runs: the decoder network is the
    fill (its traced module gives the fill's output), export.json says so, and the exported renderer renders the same
    images as IMLSRenderer.from_checkpoints."""
    from imls_lightning.inference.export import PackedDecoder
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point
    from imls_lightning.models.iml import FillDecoder

    ims = _low_pim_ims("enhancenet", 3.0)
    ckpt = _save(ims, tmp_path / "ims_pim.ckpt")
    write_operating_point(ckpt, ORPRecord(mean=0.6, lift=True, c_share=0.6, ipr=0.15, epsilon_db=1.0, decoder="fill"))
    out = export_renderer(ckpt, tmp_path / "ts")
    meta = json.loads((out / "export.json").read_text())
    assert meta["decoder"] == "fill" and meta["operating_point"]["decoder"] == "fill"
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer)
    assert ref.point.decoder == "fill" and isinstance(ref.decoder, FillDecoder)
    packed = torch.rand(2, 4, ims.pattern.c_size, ims.pattern.c_size)
    packed[:, 3] = (packed[:, 3] > 0.5).float()
    traced = torch.jit.load(str(out / meta["files"]["decoder"]))
    torch.testing.assert_close(traced(packed), PackedDecoder(FillDecoder(ims.pattern))(packed))
    exp = ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu")
    assert exp.point.decoder == "fill"
    _compare(ref, exp, _views(2, 13), tol=1)


def test_export_runs_a_point_recorded_by_camera_distance(renderer, tmp_path):
    """A point recorded with orp_by_distance is exported as it runs: the im network picks each view's band's mean
    value (the same IMs as IMLSRenderer.from_checkpoints), and export.json carries the bands."""
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ims = _low_pim_ims("enhancenet", 3.0)
    ckpt = _save(ims, tmp_path / "ims_pim.ckpt")
    views = _views(6, 11)
    d = np.linalg.norm(views[:, :3], axis=1)
    edge = float(np.median(d))
    bands = {"edges": [edge], "means": [0.9, 0.3], "c_shares": [0.9, 0.3], "gaps_db": [0.7, 0.4], "views": [5, 5]}
    write_operating_point(ckpt, ORPRecord(mean=0.9, lift=True, c_share=0.8, ipr=0.2, epsilon_db=1.0, by_distance=bands))
    out = export_renderer(ckpt, tmp_path / "ts")
    meta = json.loads((out / "export.json").read_text())
    assert meta["by_distance"] == bands and meta["operating_point"]["by_distance"] == bands and meta["mean"] == 0.9
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer)
    sizes = np.array(_compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), views, tol=1))
    share = sizes / ref.pattern.count
    near, far = share[d < edge], share[d >= edge]
    assert near.min() > 0.8 and far.max() < 0.4, share  # lifted: each view's share reaches its band's u


def test_export_runs_a_point_recorded_with_an_object_floor(renderer, tmp_path):
    """A point recorded with an object floor is exported as it runs: the im network raises each view's u to its object
    plus the margin (the same IMs as IMLSRenderer.from_checkpoints, whose head carries the floor), and export.json
    says so."""
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ims = _low_pim_ims("enhancenet", 3.0)
    ckpt = _save(ims, tmp_path / "ims_pim.ckpt")
    floor = {"margin": 0.3, "tau": 0.01, "c_share": 0.5, "gap_db": 0.4, "gap_bound_db": 0.9, "views": 8}
    write_operating_point(ckpt, ORPRecord(mean=0.05, lift=True, c_share=0.05, ipr=0.01, epsilon_db=1.0, object_floor=floor))
    out = export_renderer(ckpt, tmp_path / "ts")
    meta = json.loads((out / "export.json").read_text())
    assert meta["object_floor"] == {"margin": 0.3, "tau": 0.01} and meta["operating_point"]["object_floor"] == floor
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer)
    assert ref.point.object_floor == (0.3, 0.01)
    views = _views(4, 12)
    share = np.array(_compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), views, tol=1)) / ref.pattern.count
    assert share.min() > 0.25, share  # the floor, not u = 0.05, sets the share


def test_export_runs_a_point_floored_per_band(renderer, tmp_path):
    """A by-distance point with an object-floor margin per band is exported as it runs: the im network gives each view
    its band's mean value and margin (the same IMs as IMLSRenderer.from_checkpoints), and export.json carries the
    margins."""
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ims = _low_pim_ims("enhancenet", 3.0)
    ckpt = _save(ims, tmp_path / "ims_pim.ckpt")
    views = _views(6, 13)
    d = np.linalg.norm(views[:, :3], axis=1)
    edge = float(np.median(d))
    bands = {"edges": [edge], "means": [0.05, 0.05]}
    floor = {"margin": 0.3, "tau": 0.01, "band_margins": [0.3, None]}
    write_operating_point(ckpt, ORPRecord(mean=0.05, lift=True, c_share=0.05, ipr=0.01, epsilon_db=1.0, by_distance=bands,
                                               object_floor=floor))
    out = export_renderer(ckpt, tmp_path / "ts")
    meta = json.loads((out / "export.json").read_text())
    assert meta["floor_margins"] == [0.3, None] and meta["operating_point"]["object_floor"] == floor
    ref = IMLSRenderer.from_checkpoints(ckpt, renderer=renderer)
    share = np.array(_compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), views, tol=1)) / ref.pattern.count
    assert share[d < edge].min() > 0.25 and share[d >= edge].max() < 0.15, share  # the near band floored, the far not


def test_standalone_ims_needs_recnn_checkpoint(ckpts, renderer, tmp_path):
    with pytest.raises(InputError, match="recnn_checkpoint=<RecNN .ckpt>"):
        export_renderer(ckpts["standalone"], tmp_path / "a")
    assert not (tmp_path / "a").exists()
    out = export_renderer(ckpts["standalone"], tmp_path / "b", recnn_checkpoint=ckpts["enhancenet_recnn"])
    assert json.loads((out / "export.json").read_text())["recnn_source"] == "recnn_checkpoint"
    ref = IMLSRenderer.from_checkpoints(ckpts["standalone"], renderer=renderer, recnn_checkpoint=ckpts["enhancenet_recnn"])
    _compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), _views(2, 5), tol=1)
    with pytest.raises(InputError, match="another sampling pattern"):
        export_renderer(ckpts["standalone"], tmp_path / "c", recnn_checkpoint=ckpts["fovolnet_recnn"])


def test_exceptions(ckpts, tmp_path):
    with pytest.raises(InputError, match="format=tflite: expected one of torchscript, onnx"):
        export_renderer(ckpts["enhancenet"], tmp_path / "x", format="tflite")
    with pytest.raises(InputError, match="ims_checkpoint=.*not found"):
        export_renderer(tmp_path / "nope.ckpt", tmp_path / "x")
    with pytest.raises(InputError, match="is a RecNNTask checkpoint, expected a IMSTask"):
        export_renderer(ckpts["enhancenet_recnn"], tmp_path / "x")
    out = export_renderer(ckpts["enhancenet"], tmp_path / "ok")
    with pytest.raises(InputError, match="already exists"):
        export_renderer(ckpts["enhancenet"], out)
    (tmp_path / "notexport").mkdir()
    with pytest.raises(InputError, match="not an export directory"):
        export_renderer(ckpts["enhancenet"], tmp_path / "notexport", overwrite=True)
    with pytest.raises(InputError, match="not an export directory"):
        ExportedIMLSRenderer.load(tmp_path / "notexport", renderer=object())
    # overwrite replaces a previous export whole (here: with the other RecNN's)
    export_renderer(ckpts["fovolnet"], out, overwrite=True)
    assert json.loads((out / "export.json").read_text())["pattern"]["kind"] == "foveal"
    np.save(out / "pattern_indices.npy", np.arange(5, dtype=np.int64))
    with pytest.raises(InputError, match="does not match export.json"):
        ExportedIMLSRenderer.load(out, renderer=object())
    for argv, needle in ((["out=x"], "ims_checkpoint: missing"), (["ims_checkpoint=a", "out=b", "fmt=onnx"], "argument 'fmt=onnx'"),
                         (["ims_checkpoint=a", "out=b", "overwrite=maybe"], "overwrite=maybe")):
        with pytest.raises(InputError, match=needle):
            parse_args(argv)
    assert parse_args(["ims_checkpoint=a", "out=b", "format=onnx"])["format"] == "onnx"


def test_cli_exports_and_errors_in_one_line(ckpts, tmp_path, capsys):
    from imls_lightning.export import main

    cmd = [sys.executable, "-m", "imls_lightning.export", f"ims_checkpoint={ckpts['enhancenet']}", f"out={tmp_path / 'e'}"]
    p = subprocess.run(cmd, cwd=ROOT, env=dict(os.environ, PYTHONUNBUFFERED="1"), capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip().splitlines()[-1] == str(tmp_path / "e") and "[export] recnn:" in p.stderr
    # the same entry point in-process (a second interpreter start costs ~10 s here)
    with pytest.raises(SystemExit) as exc:
        main([f"ims_checkpoint={ckpts['enhancenet']}", f"out={tmp_path / 'f'}", "format=jpeg"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert [ln for ln in err.splitlines() if ln.startswith("error:")] == ["error: format=jpeg: expected one of torchscript, onnx"]
    assert not (tmp_path / "f").exists()


# ------------------------------------------------------------------------------------------
# the real chain: RecNN -> IML end-to-end -> IMS through the train CLI, then the export CLI
# ------------------------------------------------------------------------------------------
def _train(args: list[str], tmp: Path) -> str:
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [sys.executable, "-m", "imls_lightning.train", "scene=tiny", "data=tiny", "renderer=numba", "logger=none",
           "++trainer.fast_dev_run=true", "trainer.enable_progress_bar=false", f"paths.runs_dir={tmp / 'runs'}",
           f"data.cache_dir={tmp / 'cache'}", "recnn=enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2", *args]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-3000:]
    return p.stdout.strip().splitlines()[-1]


@pytest.mark.slow
def test_cli_chain_train_then_export_both_formats(tmp_path, renderer):
    rec = _train(["model=recnn"], tmp_path)
    iml = _train(["model=iml", "model.mode=end_to_end", f"recnn.checkpoint={rec}", "model.depth=2", "model.base_channels=8"], tmp_path)
    ims = _train(["model=ims", f"iml.checkpoint={iml}", "model.layers=5", "model.base_channels=8",
                  "model.loss.perceptual.weight=0", "model.loss.bce=1"], tmp_path)
    assert load_task(ims, expect="IMSTask").recnn is not None
    formats = ["torchscript"] + (["onnx"] if onnx_available() else [])
    ref = IMLSRenderer.from_checkpoints(ims, renderer=renderer)
    for fmt in formats:
        out = tmp_path / f"export_{fmt}"
        p = subprocess.run([sys.executable, "-m", "imls_lightning.export", f"ims_checkpoint={ims}", f"format={fmt}", f"out={out}"],
                           cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-3000:]
        if fmt == "onnx":
            pytest.importorskip("onnxruntime")
        _compare(ref, ExportedIMLSRenderer.load(out, renderer=renderer, device="cpu"), _views(4, 9), tol=1)
