"""``make demo`` (``python -m imls_lightning.demo``): its config composes with overrides, and the
whole pipeline runs through the real CLIs on ``scene=tiny`` and is reused when run again."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def _overrides(key: str, *items: str) -> str:
    """``key=['a=1','b=2']``: list elements holding '=' must be quoted in Hydra's override grammar."""
    return f"{key}=[" + ",".join(f"'{i}'" for i in items) + "]"


def test_demo_config_takes_scene_data_and_recnn_overrides():
    # the pipeline configs live apart from conf/'s groups, so scene=/data=/recnn= set plain keys
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf" / "pipelines"), version_base="1.3", job_name="test_demo"):
        cfg = compose("demo", overrides=["scene=marschner_lobb", "data=tiny", "recnn=fovolnet", "renderer=vtk",
                                         _overrides("stages.recnn", "trainer.max_epochs=1")])
        default = compose("demo")
    assert (cfg.scene, cfg.data, cfg.recnn, cfg.renderer) == ("marschner_lobb", "tiny", "fovolnet", "vtk")
    assert list(cfg.stages.recnn) == ["trainer.max_epochs=1"]
    assert (default.scene, default.data, default.recnn, default.renderer) == ("flame", "small", "enhancenet", "numba")
    for stage in ("recnn", "iml", "ims", "las", "blue_noise"):
        assert list(default.stages[stage]), stage


TINY = ["scene=tiny", "data=tiny", "progress=false",
        _overrides("stages.recnn", "trainer.max_epochs=1", "recnn.net.channels=4", "recnn.net.blocks=1"),
        _overrides("stages.iml", "model.mode=end_to_end", "model.depth=2", "model.base_channels=4", "trainer.max_epochs=1"),
        _overrides("stages.ims", "model.target=pim", "model.loss.mse=1.0", "model.loss.perceptual.weight=0.0",
                   "model.loss.adversarial=0.0", "model.layers=3", "model.base_channels=8", "trainer.max_epochs=1"),
        _overrides("stages.las", "model.low_res=8", "trainer.max_epochs=1"),
        _overrides("stages.blue_noise", "model.mode=end_to_end", "model.depth=2", "model.base_channels=4", "trainer.max_epochs=1"),
        _overrides("evaluate", "max_views=2", "timed_views=1", "repeats=10", "warmup=0", "sweep_views=1", "grid_views=1")]


def test_smoke_demo_pipeline_on_tiny_and_reuse(tmp_path):
    """train_only trains every stage and evaluates nothing; the full run then reuses all six trainings."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.demo", *TINY, f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache"]
    # train_only (train on a GPU machine, evaluate elsewhere): every training stage, no evaluation
    p = subprocess.run([*cmd, "train_only=true"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    assert "[demo] LAS done in" in p.stderr and "[demo] evaluation" not in p.stderr and "train_only: trained in" in p.stderr
    assert not list((tmp_path / "runs").glob("eval/*/report.md"))
    # the full run reuses every training stage train_only finished, then evaluates (the evaluation's own
    # reuse is tested through its CLI: tests/test_evaluate.py)
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    assert p.stderr.count("already finished; reusing it") == 6  # RecNN, sparser RecNN, IML, IMS, blue noise, LAS
    report = Path(p.stdout.strip().splitlines()[-1])
    assert report.name == "report.md" and report.is_file()
    assert (report.parent / "metrics.csv").is_file()
    assert list(report.parent.glob("*.png")), "the report has no figures"
    sheets = list((tmp_path / "cache").rglob("contact_sheet.png"))
    assert len(sheets) == 1
    for stage in ("cache", "RecNN", "RecNN, sparser pattern", "IML", "IMS", "blue-noise decoder", "LAS", "evaluation"):
        assert f"[demo] {stage} done in" in p.stderr, stage
    text = report.read_text()
    for method in ("RecNN", "LAS", "IML/S", "## ORP on the product path", "IML/S mask + fill", "blue noise + decoder",
                   "## Learned parts against untrained baselines, at equal share", "## Speed-quality front",
                   "RecNN alone, sparser pattern"):
        assert method in text, method


@pytest.mark.slow
def test_smoke_demo_adaptive_stage_on_the_evaluations_masks(tmp_path):
    """adaptive=[...]: the per-view mean value after the evaluation, on the evaluation's masks (its orp.lift)."""
    import json

    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.demo", *TINY, f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache"]
    adaptive = _overrides("adaptive", "steps=2", "predictor.epochs=20", "predictor.hidden=8", "repeats=2", "timing_views=1",
                          "tradeoff_means=2")
    p3 = subprocess.run([*cmd, adaptive], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert p3.returncode == 0, p3.stderr[-3000:]
    report = Path(p3.stdout.strip().splitlines()[-1])
    assert "[demo] adaptive mean done in" in p3.stderr and report.name == "report.md"

    lift = str(bool(json.loads((report.parent / "summary.json").read_text())["orp"].get("lift"))).lower()
    assert f"ims_lift={lift}" in p3.stderr
    assert list((tmp_path / "runs").glob("ims-*/adaptive/*/adaptive.md"))


def test_exception_demo_stage_failure_names_the_stage(tmp_path):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.run([PY, "-m", "imls_lightning.demo", "scene=no_such_scene", f"runs_dir={tmp_path}/runs",
                        f"cache_dir={tmp_path}/cache", "progress=false"],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode != 0
    assert "error: demo stage 'cache' failed" in p.stderr and "no_such_scene" in p.stderr
    assert not (tmp_path / "runs").exists()


def test_echo_keeps_carriage_returns_and_returns_the_last_line():
    import io

    from imls_lightning.pipelines.stages import _echo

    class Chunked:  # a pipe that hands out 3 bytes at a time (splits the UTF-8 'é' too)
        def __init__(self, data: bytes):
            self.buf = io.BytesIO(data)

        def read1(self, n: int) -> bytes:
            return self.buf.read(3)

    out = io.StringIO()
    last = _echo(Chunked("epoch\r 50%\r100%\n/run/best é.ckpt\n\n".encode()), out)
    assert last == "/run/best é.ckpt"
    assert out.getvalue() == "  epoch\r   50%\r  100%\n  /run/best é.ckpt\n\n"
    assert _echo(Chunked(b"no newline at the end"), io.StringIO()) == "no newline at the end"


# ---- any scene: the scene overrides of python -m data_gen pass through to every stage ------------
def test_split_scene_overrides_takes_every_scene_key_and_nothing_else():
    from imls_lightning.pipelines import split_scene_overrides

    argv = ["scene=file", "scene.volume.path=/d/my head.nii.gz", "+scene.volume.name=mine", "++scene.view_angle=40",
            "~scene.volume.dims", "scenes=[ct_head]", "data=tiny", "-cn", "scene.x=1", "stages.recnn=['scene.a=1']",
            "scene_overrides=1", "--cfg", "job"]
    own, scene = split_scene_overrides(argv)
    assert scene == ["scene.volume.path=/d/my head.nii.gz", "+scene.volume.name=mine", "++scene.view_angle=40", "~scene.volume.dims"]
    # the value of a Hydra flag (-cn NAME) and keys that merely start with "scene" stay the pipeline's
    assert own == ["scene=file", "scenes=[ct_head]", "data=tiny", "-cn", "scene.x=1", "stages.recnn=['scene.a=1']",
                   "scene_overrides=1", "--cfg", "job"]


def _write_nifti(path: Path, spacing=(1.0, 1.0, 1.5)) -> Path:
    """The procedural tiny volume (32^3) as a NIfTI file of one's own."""
    import nibabel as nib
    import numpy as np

    from data_gen.volumes import load_volume

    vol = load_volume({"kind": "procedural", "generator": "tiny", "seed": 0})
    img = nib.Nifti1Image(np.asarray(vol.data, np.float32).T, np.diag([*spacing, 1.0]))  # (Z, Y, X) -> NIfTI (X, Y, Z)
    img.header.set_zooms(spacing)
    nib.save(img, str(path))
    return path


def _commands(stdout: str) -> list[list[str]]:
    import shlex

    return [shlex.split(line) for line in stdout.strip().splitlines()]


def test_demo_dry_run_passes_scene_overrides_to_every_stage(tmp_path):
    """The user's first try, `demo scene=file scene.volume.path=<my.nii.gz>`, no longer fails with
    "Key 'volume' is not in struct": the overrides follow scene=file in every stage's command."""
    vol = tmp_path / "my volume.nii.gz"  # a space in the path: passed verbatim, never re-parsed
    overrides = [f"scene.volume.path={vol}", "scene.volume.spacing=[1,1,2]", "scene.sample_distance_voxels=1.0",
                 "+scene.volume.name=mine"]
    p = subprocess.run([PY, "-m", "imls_lightning.demo", "scene=file", *overrides, "dry_run=true",
                        f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    cmds = _commands(p.stdout)
    # cache, RecNN, RecNN on a sparser pattern, IML, IMS, blue-noise decoder, LAS, evaluation
    assert [c[2] for c in cmds] == ["data_gen", *["imls_lightning.train"] * 6, "imls_lightning.evaluate"]
    # the sparser RecNN: the RecNN stage's training on EnhanceNet 4x, passed to the evaluation
    recnn, sparser = cmds[1], cmds[2]
    assert sparser == [*recnn, "pattern.factor=4"]
    assert "checkpoints.recnn_sparser=<RecNN,-sparser-pattern>" in cmds[-1]
    for c in cmds:
        i = c.index("scene=file")
        assert c[i + 1:i + 1 + len(overrides)] == overrides, c
    assert not (tmp_path / "runs").exists() and not (tmp_path / "cache").exists()  # nothing ran


def test_bench_dry_run_passes_scene_overrides_and_takes_one_scene(tmp_path):
    p = subprocess.run([PY, "-m", "imls_lightning.bench", "scene=file", "scene.volume.path=/d/engine_64x64x64_uint8.raw",
                        "recnns=[enhancenet]", "dry_run=true", f"runs_dir={tmp_path}/runs", f"output={tmp_path}/B.md"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    cmds = _commands(p.stdout)
    assert len(cmds) == 5  # RecNN, ORP search, IMS, LAS, evaluation: one scene (scene= replaces scenes)
    for c in cmds:
        i = c.index("scene=file")
        assert c[i + 1] == "scene.volume.path=/d/engine_64x64x64_uint8.raw", c
    # the ORP sweep directory is named after the volume, not after the preset "file"
    assert any(a.startswith(f"hydra.sweep.dir={tmp_path}/runs/orp/engine-enhancenet-") for a in cmds[1])
    assert not (tmp_path / "runs").exists() and not (tmp_path / "B.md").exists()


@pytest.mark.parametrize("module", ["imls_lightning.demo", "imls_lightning.bench"])
def test_exception_bad_scene_override_stops_before_any_stage(tmp_path, module):
    p = subprocess.run([PY, "-m", module, "scene=tiny", "scene.volume.pth=/x.nii.gz", f"runs_dir={tmp_path}/runs",
                        f"cache_dir={tmp_path}/cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr
    err = p.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: scene overrides scene.volume.pth=/x.nii.gz (scene=tiny): ")
    assert "scene.volume.pth" in err[0] and "Traceback" not in p.stderr
    assert not (tmp_path / "runs").exists() and not (tmp_path / "cache").exists()


# slow: the default suite took 18 min on an AVX2-only 2-core EPYC (issue 31's machine); make test-all runs it
@pytest.mark.slow
def test_smoke_demo_on_your_own_nifti_file(tmp_path):
    """The whole demo, CI-sized, on a NIfTI file of one's own with scene overrides (auto transfer
    function, an explicit spacing and sample distance): every stage sees the same scene."""
    import json

    vol = _write_nifti(tmp_path / "mine.nii.gz")
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.demo", *TINY, "scene=file", f"scene.volume.path={vol}", "scene.volume.spacing=[1,1,2]",
           "scene.sample_distance_voxels=1.0", "stages.las=null", f"runs_dir={tmp_path}/runs", f"cache_dir={tmp_path}/cache"]
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, f"STDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-5000:]}"
    report = Path(p.stdout.strip().splitlines()[-1])
    assert report.name == "report.md" and report.is_file() and "IML/S" in report.read_text()
    caches = sorted((tmp_path / "cache").glob("mine-*"))
    # the trainings' and evaluation's cache and the ORP's held-out views (a seed of their own): one and the same scene
    assert len(caches) == 2
    ms = [json.loads((c / "manifest.json").read_text()) for c in caches]
    assert ms[0]["settings"]["scene"] == ms[1]["settings"]["scene"] and {x["data"]["seed"] == 0 for x in ms} == {True, False}
    m = ms[0]
    assert m["scene"]["name"] == "mine" and m["scene"]["volume"]["spacing_xyz"] == [1.0, 1.0, 2.0]
    assert m["sample_distance"]["voxels"] == 1.0 and m["scene_config"]["transfer_function"]["auto"] is True
    assert len(list((tmp_path / "runs").glob("*-mine-*"))) == 5  # RecNN, sparser-pattern RecNN, IML, IMS, blue-noise runs


def test_sparser_overrides_train_the_recnn_the_same_way_on_a_quarter_of_c():
    from omegaconf import OmegaConf

    from imls_lightning.base.errors import InputError
    from imls_lightning.pipelines import sparser_overrides

    cfg = OmegaConf.create({"recnn": "fovolnet", "scene": "ct_head",
                            "stages": {"recnn": ["trainer.max_epochs=10", "pattern.c_size_ratio=0.5"], "recnn_sparser": ["seed=3"]},
                            "scene_stages": {"ct_head": {"recnn": ["trainer.max_epochs=20"]}}})
    # the RecNN stage's overrides (its scene entries included), its sparser pattern replacing the same key, then the stage's own
    assert sparser_overrides(cfg) == ["trainer.max_epochs=20", "pattern.c_size_ratio=0.3536", "seed=3"]
    cfg.recnn = "unet"
    with pytest.raises(InputError, match="recnn=unet: no sparser pattern known for it.*stages.recnn_sparser=null"):
        sparser_overrides(cfg)


def test_ims_finetune_overrides_are_the_ims_stages_with_their_own_keys_last():
    from omegaconf import OmegaConf

    from imls_lightning.pipelines import ims_finetune_overrides

    cfg = OmegaConf.create({"scene": "ct_head",
                            "stages": {"ims": ["model.lr=1e-3", "model.layers=7", "trainer.max_epochs=24", "chunk_minutes=30"],
                                       "ims_finetune": ["model.lr=1e-4", "trainer.max_epochs=3"]},
                            "scene_stages": {"ct_head": {"ims_finetune": ["trainer.max_epochs=2"]}}})
    # the generator trains on (no train_generator=false), the IMS stage's networks and chunks, its own rate and epochs
    assert ims_finetune_overrides(cfg) == ["model.lr=1e-4", "model.layers=7", "trainer.max_epochs=2", "chunk_minutes=30"]


def test_ims_decoder_overrides_are_the_ims_stages_with_the_generator_frozen():
    from omegaconf import OmegaConf

    from imls_lightning.pipelines import ims_decoder_overrides

    cfg = OmegaConf.create({"scene": "ct_head", "stages": {"ims": ["model.decoder_lr=1e-3", "trainer.max_epochs=5", "seed=1"],
                                                           "ims_decoder": ["trainer.max_epochs=2"]},
                            "scene_stages": {"ct_head": {"ims": ["seed=4"], "ims_decoder": ["model.decoder_lr=3e-4"]}}})
    # the IMS stage's (its scene entries included), the generator frozen, then the decoder stage's replacing the same keys
    assert ims_decoder_overrides(cfg) == ["model.decoder_lr=3e-4", "trainer.max_epochs=2", "seed=4", "model.train_generator=false"]
    cfg.stages.ims_decoder = ["model.train_generator=true"]  # the stage's own keys come last
    assert ims_decoder_overrides(cfg)[-1] == "model.train_generator=true"


@pytest.mark.parametrize("kind", ["enhancenet", "fovolnet"])
@pytest.mark.parametrize("resolution", [128, 512])
def test_every_kinds_sparser_pattern_builds_with_a_quarter_or_half_of_c(kind, resolution):
    # FoVolNet's first sparser pattern (a C-Image half the side) could not hold its base level at any size
    from omegaconf import OmegaConf

    from imls_lightning.core.patterns import build_pattern
    from imls_lightning.pipelines.stages import SPARSER_PATTERN

    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_sparser"):
        default, sparser = (OmegaConf.to_container(compose("train", overrides=[f"recnn={kind}", *extra]).pattern, resolve=True)
                            for extra in ([], SPARSER_PATTERN[kind]))
    share = build_pattern(sparser, resolution).indices.numel() / build_pattern(default, resolution).indices.numel()
    assert 0.2 <= share <= 0.55, share


def test_stage_overrides_scene_entries_replace_the_same_keys():
    from omegaconf import OmegaConf

    from imls_lightning.pipelines import stage_overrides

    cfg = OmegaConf.create({"scene": "ct_head",
                            "stages": {"iml": ["model.depth=4", "model.base_channels=8", "trainer.max_epochs=12"], "ims": ["a=1"]},
                            "scene_stages": {"ct_head": {"iml": ["model.base_channels=16", "+model.extra=1"]}}})
    assert stage_overrides(cfg, "iml") == ["model.depth=4", "model.base_channels=16", "trainer.max_epochs=12", "+model.extra=1"]
    assert stage_overrides(cfg, "ims") == ["a=1"]  # no entry for this stage
    cfg.scene = "flame"  # no entry for this scene
    assert stage_overrides(cfg, "iml") == ["model.depth=4", "model.base_channels=8", "trainer.max_epochs=12"]


def test_demo_config_ct_head_gets_the_wider_decoder():
    p = subprocess.run([PY, "-m", "imls_lightning.demo", "scene=ct_head", "dry_run=true"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    iml = [ln for ln in p.stdout.splitlines() if "model=iml" in ln]
    assert len(iml) == 2 and all("model.base_channels=16" in ln and "model.base_channels=8" not in ln for ln in iml)


def test_a_stage_that_trained_one_chunk_stops_the_pipeline_with_status_3(tmp_path, capsys):
    """run_stage turns a training stage's exit status 3 (chunk_minutes) into StageUnfinished, and the pipeline
    exits 3 with one line saying how to go on; other failures stay exit 1."""
    from imls_lightning.pipelines import stages as d

    with pytest.raises(d.StageUnfinished, match="run the same command again to continue"):
        d.run_stage("recnn", ["-c", "import sys; print('x'); sys.exit(3)"])
    with pytest.raises(d.StageFailed):
        d.run_stage("recnn", ["-c", "import sys; sys.exit(1)"])
    with pytest.raises(SystemExit) as e:
        d.run_pipeline(lambda: d.run_stage("ims", ["-c", "import sys; sys.exit(3)"]))
    assert e.value.code == 3
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("[pipeline] demo stage 'ims' trained one chunk")


def test_stage_args_is_the_one_builder_of_the_benchmarks_stage_arguments():
    """The demo's and the benchmark's stage commands share their arguments through one builder: the
    benchmark passes its scene, quotes the paths and appends its ``common`` / ``train`` overrides."""
    from omegaconf import OmegaConf

    from imls_lightning.pipelines import stage_args

    cfg = OmegaConf.create({"scene": None, "data": "bench", "renderer": "numba", "cache_dir": "/x y", "runs_dir": "runs",
                            "seed": 3, "progress": False})
    common, train = stage_args(cfg, ["scene.name=a"], scene="ct_head", recnn=False, quote=True, common=["test=false"],
                               train=["trainer.max_epochs=2"])
    assert common == ["scene=ct_head", "scene.name=a", "data=bench", "renderer=numba", "data.cache_dir='/x y'", "test=false"]
    assert train == [*common, "paths.runs_dir=runs", "seed=3", "trainer.max_epochs=2", "trainer.enable_progress_bar=false"]
