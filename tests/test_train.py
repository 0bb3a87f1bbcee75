"""End-to-end training through Hydra: the DataModule, RecNN and IML tasks, resume/reuse, errors."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


def _run(args, tmp, check=True, timeout=300, subprocess_=False):
    """``python -m imls_lightning.train`` on the tiny scene: in this process (:func:`tests.cli.run_in_process`; a
    subprocess spends 6-9 s importing before its first setting), or with ``subprocess_=True`` as a real one, for
    what only a process shows: its one-line stderr and exit status as a shell sees them."""
    common = [*args, "scene=tiny", "data=tiny", "renderer=numba", f"paths.runs_dir={tmp}/runs", f"data.cache_dir={tmp}/cache",
              "trainer.enable_progress_bar=false"]
    if not subprocess_:
        from tests.cli import run_in_process

        p = run_in_process("imls_lightning.train", common)
        if check and p.returncode != 0:
            raise AssertionError(f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-3000:]}")
        return p
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    p = subprocess.run([PY, "-m", "imls_lightning.train", *common], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"exit {p.returncode}\nSTDOUT:\n{p.stdout[-3000:]}\nSTDERR:\n{p.stderr[-3000:]}")
    return p


def _last_line(p) -> str:
    return p.stdout.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("train")


@pytest.fixture(scope="module")
def recnn_ckpt(work):
    """A real (2-epoch) EnhanceNet run on the tiny scene."""
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=2", "recnn.net.channels=8", "recnn.net.blocks=2"], work)
    ckpt = Path(_last_line(p))
    assert ckpt.is_file() and ckpt.suffix == ".ckpt"
    return ckpt


def test_failed_run_leaves_no_empty_run_folder(tmp_path):
    """A failed run left an empty run folder (only Hydra's .hydra/ and log) behind (issue 17, minor)."""
    p = _run(["model=iml", "model.depth=0"], tmp_path, check=False, subprocess_=True)  # the log a process leaves
    _one_line_error(p, "model.depth=0")
    assert not (tmp_path / "runs").exists() or list((tmp_path / "runs").iterdir()) == []


# ---- RecNN ------------------------------------------------------------------------------------
def test_smoke_recnn_checkpoint_reloads_with_identical_output(recnn_ckpt):
    from imls_lightning.inference.checkpoints import load_task

    task = load_task(recnn_ckpt, expect="RecNNTask")
    again = load_task(recnn_ckpt, expect="RecNNTask")
    c = torch.rand(2, 3, task.pattern.c_size, task.pattern.c_size)
    with torch.no_grad():
        torch.testing.assert_close(task(c), again(c), rtol=0, atol=0)
    # training changed the weights away from a fresh init
    fresh = type(task)(**task.hparams)
    assert any(not torch.equal(a, b) for a, b in zip(task.state_dict().values(), fresh.state_dict().values()))
    result = json.loads((recnn_ckpt.parent.parent / "result.json").read_text())
    assert result["epochs"] >= 1 and np.isfinite(result["test"]["test/fr_psnr"])


def test_smoke_rerun_reuses_finished_run(work, recnn_ckpt):
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=2", "recnn.net.channels=8", "recnn.net.blocks=2"], work)
    assert Path(_last_line(p)) == recnn_ckpt.resolve()
    assert "already finished" in p.stdout


def test_finished_run_records_its_cache_and_reuse_is_checked_against_it(work, recnn_ckpt):
    """A run records the caches it trained on by content (the key of the cache's manifest); cache_problem finds
    nothing for the same settings and names both keys when the recorded one is not what the settings give now."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.training.fit import cache_problem

    result = json.loads((recnn_ckpt.parent.parent / "result.json").read_text())
    manifests = [json.loads(p.read_text())["hash"] for p in (work / "cache").glob("*/manifest.json")]
    assert len(result["caches"]) == 1 and result["caches"][0] in manifests
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="cache_problem"):
        cfg = compose("train", overrides=["model=recnn", "recnn=enhancenet", "scene=tiny", "data=tiny", "renderer=numba",
                                          f"data.cache_dir={work}/cache"])
    GlobalHydra.instance().clear()
    assert cache_problem(result["caches"], cfg) is None
    problem = cache_problem(["000000000000"], cfg)
    assert problem.startswith("it trained on cache 000000000000, these settings now give ") and result["caches"][0] in problem


def test_smoke_resume_continues_from_last_ckpt(work, recnn_ckpt, tmp_path):
    # more epochs = same settings hash (trainer limits do not change the run's identity): resumes.
    # On a copy of the shared runs, so that the other tests keep their checkpoint.
    import shutil

    for sub in ("runs", "cache"):
        shutil.copytree(work / sub, tmp_path / sub)
    run_dir = tmp_path / "runs" / recnn_ckpt.parent.parent.name
    (run_dir / "result.json").unlink()
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=3", "recnn.net.channels=8", "recnn.net.blocks=2"], tmp_path)
    assert "resuming from" in p.stdout and str(run_dir / "checkpoints" / "last.ckpt") in p.stdout
    assert json.loads((run_dir / "result.json").read_text())["epochs"] == 3
    # the log keeps the epochs before the resume (Lightning's CSVLogger deleted metrics.csv)
    import csv

    rows = list(csv.DictReader((run_dir / "csv" / "metrics.csv").open(newline="")))
    assert sorted({int(r["epoch"]) for r in rows if r.get("val/loss")}) == [0, 1, 2]


def test_smoke_longer_schedule_continues_a_finished_run(work, recnn_ckpt, tmp_path):
    """A finished run asked for more epochs was returned as it was: trainer limits are not part of the
    run's identity, so `trainer.max_epochs=10` silently gave the 3-epoch network."""
    run_dir = _copy_runs(work, tmp_path, recnn_ckpt)
    args = ["model=recnn", "recnn=enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2"]
    p = _run(args + ["trainer.max_epochs=3"], tmp_path)
    assert "finished 2 epochs; continuing to trainer.max_epochs=3" in p.stdout, p.stdout[-2000:]
    assert f"resuming from {run_dir / 'checkpoints' / 'last.ckpt'}" in p.stdout
    result = json.loads((run_dir / "result.json").read_text())
    assert (result["epochs"], result["max_epochs"], result["stopped_early"]) == (3, 3, False)
    # a shorter limit: the run is finished and returned as it is (the same limit: test_smoke_rerun_reuses_finished_run)
    again = _run(args + ["trainer.max_epochs=1"], tmp_path)
    assert "already finished" in again.stdout and _last_line(again) == _last_line(p)


def test_smoke_time_boxed_run_counts_as_finished(work, recnn_ckpt, tmp_path):
    """`trainer.max_time` time-boxes a stage (training on a lent GPU machine); the run it stops is
    finished, so the machine that evaluates it reuses it instead of training on."""
    run_dir = _copy_runs(work, tmp_path, recnn_ckpt)
    args = ["model=recnn", "recnn=enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2", "trainer.max_epochs=1000"]
    p = _run(args + ["trainer.max_time=00:00:00:01"], tmp_path)
    result = json.loads((run_dir / "result.json").read_text())
    assert (result["stopped_early"], result["stopped_by"], result["max_epochs"]) == (True, "max_time", 1000), p.stdout[-2000:]
    assert 2 <= result["epochs"] < 1000
    again = _run(args, tmp_path)
    assert "already finished" in again.stdout and _last_line(again) == _last_line(p)


def test_epochs_to_extend():
    from omegaconf import OmegaConf

    from imls_lightning.training.fit import epochs_to_extend

    cfg = OmegaConf.create({"trainer": {"max_epochs": 10}})
    assert epochs_to_extend({"epochs": 3}, cfg) == 10  # a run from before max_epochs was recorded
    assert epochs_to_extend({"epochs": 3, "max_epochs": 3}, cfg) == 10
    assert epochs_to_extend({"epochs": 10, "max_epochs": 10}, cfg) is None
    assert epochs_to_extend({"epochs": 12, "max_epochs": 30}, cfg) is None
    assert epochs_to_extend({"epochs": 4, "max_epochs": 5, "stopped_early": True}, cfg) is None  # it would stop again
    assert epochs_to_extend({"epochs": 3}, OmegaConf.create({"trainer": {"max_epochs": -1}})) is None


def _copy_runs(work, tmp_path, recnn_ckpt) -> Path:
    import shutil

    for sub in ("runs", "cache"):
        shutil.copytree(work / sub, tmp_path / sub)
    return tmp_path / "runs" / recnn_ckpt.parent.parent.name


def _truncate(path: Path) -> None:
    os.truncate(path, path.stat().st_size // 2)


def test_truncated_last_ckpt_falls_back_to_newest_intact_checkpoint(work, recnn_ckpt, tmp_path):
    """A truncated last.ckpt gave a traceback on every rerun (issue 17, 6)."""
    run_dir = _copy_runs(work, tmp_path, recnn_ckpt)
    (run_dir / "result.json").unlink()
    _truncate(run_dir / "checkpoints" / "last.ckpt")
    best = run_dir / "checkpoints" / recnn_ckpt.name
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=3", "recnn.net.channels=8", "recnn.net.blocks=2"], tmp_path)
    warnings = [ln for ln in p.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "last.ckpt: not a loadable checkpoint" in warnings[0] and str(best) in warnings[0], p.stderr[-2000:]
    assert f"resuming from {best}" in p.stdout
    assert json.loads((run_dir / "result.json").read_text())["epochs"] == 3


def test_truncated_best_checkpoint_of_finished_run_is_not_trusted(work, recnn_ckpt, tmp_path):
    """A truncated best checkpoint with result.json beside it was reused (issue 17, 6)."""
    run_dir = _copy_runs(work, tmp_path, recnn_ckpt)
    best = run_dir / "checkpoints" / recnn_ckpt.name
    result = json.loads((run_dir / "result.json").read_text())
    (run_dir / "result.json").write_text(json.dumps({**result, "best_checkpoint": str(best)}))  # the copy's own
    _truncate(best)
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=2", "recnn.net.channels=8", "recnn.net.blocks=2"], tmp_path)
    assert "already finished" not in p.stdout
    assert any(ln.startswith("warning:") and "training it again" in ln for ln in p.stderr.splitlines()), p.stderr[-2000:]
    from imls_lightning.base.config import checkpoint_problem

    assert checkpoint_problem(_last_line(p)) is None


def test_exception_resume_checkpoint_of_another_model(work, recnn_ckpt, tmp_path):
    """resume= with a checkpoint of another model ended in a traceback (issue 17, 11)."""
    p = _run(["model=recnn", "recnn=enhancenet", "trainer.max_epochs=1", "recnn.net.channels=4", "recnn.net.blocks=1",
              f"resume={recnn_ckpt}"], tmp_path, check=False)  # a channels=8 net resumed into a channels=4 one
    _one_line_error(p, f"resume={recnn_ckpt}", "do not fit the network")


def test_exception_resume_not_a_checkpoint_is_refused_before_lightning_starts(tmp_path):
    """resume=<a text file> was refused after Lightning's start-up lines (the seed, "GPU available", ...;
    issue 33): the error is the first line on stderr, and nothing was set up."""
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    p = _run(["model=recnn", f"resume={text}"], tmp_path, check=False)
    _one_line_error(p, f"resume={text}", "not a loadable checkpoint")
    assert p.stderr.splitlines()[0].startswith(f"error: resume={text}: "), p.stderr[-2000:]
    assert "GPU available" not in p.stdout + p.stderr and "Seed set" not in p.stdout + p.stderr
    assert not (tmp_path / "runs").exists() or list((tmp_path / "runs").iterdir()) == []


def test_exception_resume_text_or_truncated_file(recnn_ckpt, tmp_path):
    """resume=<a text file> ended in a traceback (issue 17, 11); in process (the CLI path is the test above)."""
    from omegaconf import OmegaConf

    from imls_lightning.base.errors import InputError
    from imls_lightning.inference.checkpoints import load_task
    from imls_lightning.tasks.iml import IMLTask
    from imls_lightning.training.fit import _resume_path

    task = load_task(recnn_ckpt, expect="RecNNTask")
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    cut = tmp_path / "cut.ckpt"
    cut.write_bytes(recnn_ckpt.read_bytes()[:5000])
    for bad in (text, cut):
        with pytest.raises(InputError, match=f"^resume={bad}: not a loadable checkpoint"):
            _resume_path(OmegaConf.create({"resume": str(bad)}), tmp_path, task)
    with pytest.raises(InputError, match=f"^resume={recnn_ckpt}: is a RecNNTask checkpoint, this run trains a IMLTask"):
        _resume_path(OmegaConf.create({"resume": str(recnn_ckpt)}), tmp_path, IMLTask({"kind": "downsample", "factor": 2}, 32, depth=2))
    assert _resume_path(OmegaConf.create({"resume": str(recnn_ckpt)}), tmp_path, task) == str(recnn_ckpt)


def test_smoke_fovolnet_fast_dev_run(work):
    p = _run(["model=recnn", "recnn=fovolnet", "trainer.fast_dev_run=true"], work)
    ckpt = Path(_last_line(p))
    assert ckpt.name == "fast_dev_run.ckpt" and ckpt.is_file()
    from imls_lightning.inference.checkpoints import load_task

    task = load_task(ckpt, expect="RecNNTask")
    assert task.pattern.kind == "foveal"


# ---- IML --------------------------------------------------------------------------------------
def test_smoke_iml_standalone_and_end_to_end(work, recnn_ckpt):
    from imls_lightning.inference.checkpoints import load_task

    p = _run(["model=iml", "recnn=enhancenet", "model.mode=standalone", "model.depth=3", "model.base_channels=8",
              "trainer.max_epochs=1"], work)
    sa = load_task(Path(_last_line(p)), expect="IMLTask")
    assert sa.recnn is None  # standalone never builds the RecNN
    p = _run(["model=iml", "recnn=enhancenet", "model.mode=end_to_end", f"recnn.checkpoint={recnn_ckpt}",
              "model.depth=3", "model.base_channels=8", "trainer.max_epochs=1"], work)
    e2e = load_task(Path(_last_line(p)), expect="IMLTask")
    assert e2e.recnn is not None
    # frozen by default: the RecNN inside equals the checkpoint it started from
    rec = load_task(recnn_ckpt, expect="RecNNTask")
    for (k, a), b in zip(e2e.recnn.state_dict().items(), rec.net.state_dict().values()):
        torch.testing.assert_close(a, b, msg=k)
    res = json.loads((Path(_last_line(p)).parent.parent / "result.json").read_text())
    for key in ("test/ipr", "test/c_share", "test/c_psnr", "test/fr_psnr"):
        assert np.isfinite(res["test"][key]), key


def test_smoke_standalone_decoder_attaches_to_off_the_shelf_recnn(work, recnn_ckpt):
    """The paper's off-the-shelf case: a decoder trained without the RecNN feeds a separately trained one."""
    from imls_lightning.models.iml import IMLRecNN
    from imls_lightning.inference.checkpoints import load_task

    p = _run(["model=iml", "recnn=enhancenet", "model.mode=standalone", "model.depth=3", "model.base_channels=8",
              "trainer.max_epochs=1"], work)
    iml = load_task(Path(_last_line(p)), expect="IMLTask")
    rec = load_task(recnn_ckpt, expect="RecNNTask")
    assert iml.pattern.fingerprint() == rec.pattern.fingerprint()
    net = IMLRecNN(iml.iml, rec.net).eval()
    c = torch.rand(2, 3, iml.pattern.c_size, iml.pattern.c_size)
    with torch.no_grad():
        out = net(c, hard=True)
        im = iml.iml.importance(c, hard=True)
        direct = rec.net(iml.iml.decode(im * c, im))
    assert out.shape == (2, 3, iml.pattern.fr_size, iml.pattern.fr_size) and torch.isfinite(out).all()
    torch.testing.assert_close(out, direct)


# ---- errors -----------------------------------------------------------------------------------
def _one_line_error(p, *needles):
    assert p.returncode == 2, (p.returncode, p.stderr[-2000:])
    assert "Traceback" not in p.stderr
    err = [ln for ln in p.stderr.splitlines() if ln.startswith("error:")]
    assert len(err) == 1, p.stderr[-2000:]
    for n in needles:
        assert n in err[0], err[0]


def test_exception_end_to_end_without_recnn_checkpoint(work):
    p = _run(["model=iml", "model.mode=end_to_end", "trainer.fast_dev_run=true"], work, check=False, subprocess_=True)
    _one_line_error(p, "recnn.checkpoint")


def test_exception_recnn_checkpoint_of_other_pattern(work, recnn_ckpt):
    p = _run(["model=iml", "recnn=fovolnet", "model.mode=end_to_end", f"recnn.checkpoint={recnn_ckpt}",
              "trainer.fast_dev_run=true"], work, check=False)
    _one_line_error(p, "recnn.checkpoint", "pattern")


def test_exception_missing_checkpoint_file(work):
    p = _run(["model=iml", "model.mode=end_to_end", "recnn.checkpoint=/nonexistent/x.ckpt", "trainer.fast_dev_run=true"], work, check=False,
             subprocess_=True)
    _one_line_error(p, "recnn.checkpoint=/nonexistent/x.ckpt", "not found")


@pytest.mark.parametrize("override,needle", [
    ("model.mean=0.001", "mean"),
    ("model.mean=2", "mean"),
    ("model.alpha=0", "alpha"),
    ("model.mode=both", "model.mode"),
    ("model.lr=-1", "model.lr"),
])
def test_exception_bad_iml_settings(work, override, needle):
    p = _run(["model=iml", override, "trainer.fast_dev_run=true"], work, check=False)
    _one_line_error(p, needle)


def test_smoke_chunked_training_continues_where_the_last_chunk_stopped(tmp_path):
    """chunk_minutes: each run of the command trains one chunk (an epoch here), exits 3 and records the run as
    unfinished; the same command continues from last.ckpt, and the last chunk finishes the schedule."""
    args = ["model=recnn", "recnn=enhancenet", "recnn.net.channels=4", "recnn.net.blocks=1", "trainer.max_epochs=3",
            "chunk_minutes=0.0001"]
    first = _run(args, tmp_path, check=False)
    assert first.returncode == 3, first.stderr[-2000:]
    assert "run the same command again to continue" in first.stderr.strip().splitlines()[-1]
    run_dir = next((tmp_path / "runs").glob("recnn-*"))
    r1 = json.loads((run_dir / "result.json").read_text())
    assert (r1["unfinished"], r1["stopped_by"], r1["stopped_early"], r1["epochs"]) == (True, "chunk", False, 1)
    assert r1["test"] == {}  # no test pass on a chunk
    second = _run(args, tmp_path, check=False)
    assert second.returncode == 3 and "resuming from" in second.stdout
    assert json.loads((run_dir / "result.json").read_text())["epochs"] == 2
    last = _run(args, tmp_path)  # epoch 3 is the schedule's last: the chunk cannot stop it
    r3 = json.loads((run_dir / "result.json").read_text())
    assert (r3["unfinished"], r3["epochs"]) == (False, 3) and r3["test"] and Path(_last_line(last)).is_file()
    assert "already finished" in _run(args, tmp_path).stdout


def test_smoke_a_chunk_whose_best_checkpoint_gave_way_continues_from_last_ckpt(tmp_path):
    """A chunk's record names its best checkpoint; the next chunk's better epoch replaces it (the top-k keeps one).
    Interrupted then, the run was trained again from the start, losing every chunk, because that file was gone."""
    args = ["model=recnn", "recnn=enhancenet", "recnn.net.channels=4", "recnn.net.blocks=1", "trainer.max_epochs=2",
            "chunk_minutes=0.0001"]
    assert _run(args, tmp_path, check=False).returncode == 3
    run_dir = next((tmp_path / "runs").glob("recnn-*"))
    record = json.loads((run_dir / "result.json").read_text())
    Path(record["best_checkpoint"]).unlink()  # what the interrupted next chunk's top-k did
    again = _run(args, tmp_path)
    assert "training it again" not in again.stderr, again.stderr[-2000:]
    assert f"resuming from {run_dir / 'checkpoints' / 'last.ckpt'}" in again.stdout
    r = json.loads((run_dir / "result.json").read_text())
    assert (r["unfinished"], r["epochs"]) == (False, 2) and Path(_last_line(again)).is_file()


def test_smoke_an_interrupted_continuation_of_a_finished_run_goes_on_from_last_ckpt(work, recnn_ckpt, tmp_path):
    """rt_plumes's IMS, 3 epochs finished, was continued to 10 and stopped after epoch 5; its record still said
    "finished 3 epochs, best epoch002" and that file had given way to epoch004's, so the next call trained the IMS
    again from the start. A continuation now marks the record as a run in progress before it trains."""
    import signal
    import time

    run_dir = _copy_runs(work, tmp_path, recnn_ckpt)
    args = ["model=recnn", "recnn=enhancenet", "recnn.net.channels=8", "recnn.net.blocks=2"]
    last = run_dir / "checkpoints" / "last.ckpt"
    before = last.stat().st_mtime_ns
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.train", *args, "trainer.max_epochs=6", "scene=tiny", "data=tiny", "renderer=numba",
           f"paths.runs_dir={tmp_path}/runs", f"data.cache_dir={tmp_path}/cache", "trainer.enable_progress_bar=false"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    while last.stat().st_mtime_ns == before and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)  # after the continuation's first epoch: no handler runs, as at a session's end
    proc.wait()
    record = json.loads((run_dir / "result.json").read_text())
    assert (record["unfinished"], record["stopped_by"], record["epochs"]) == (True, "continuing", 2), record
    again = _run(args + ["trainer.max_epochs=6"], tmp_path)
    assert "training it again" not in again.stderr and "was continuing after 2 epochs" in again.stdout, again.stdout[-2000:]
    assert f"resuming from {last}" in again.stdout
    r = json.loads((run_dir / "result.json").read_text())
    assert (r["unfinished"], r["stopped_by"], r["epochs"], r["max_epochs"]) == (False, None, 6, 6)


def test_chunk_timer_stops_only_when_the_next_epoch_would_overrun(monkeypatch):
    from types import SimpleNamespace

    from imls_lightning.training import callbacks

    def run(times, epoch, max_epochs=10):
        clock = iter(times)  # train start, epoch start, epoch end
        monkeypatch.setattr(callbacks.time, "perf_counter", lambda: next(clock))
        t = callbacks.ChunkTimer(100 / 60)  # a 100 s chunk
        tr = SimpleNamespace(max_epochs=max_epochs, current_epoch=epoch, should_stop=False)
        t.on_train_start(tr, None)
        t.on_train_epoch_start(tr, None)
        t.on_train_epoch_end(tr, None)
        assert tr.should_stop == t.stopped
        return t.stopped

    assert not run([0.0, 40.0, 70.0], 0)       # 70 s done + 30 s for the next epoch: within 100 s
    assert run([0.0, 40.0, 75.0], 0)           # 75 + 35 > 100: stop now, not mid-way through the next
    assert not run([0.0, 40.0, 99.0], 9)       # the schedule's last epoch is never cut


@pytest.mark.parametrize("value", ["0", "-1", "abc", "inf"])
def test_exception_bad_chunk_minutes(tmp_path, value):
    p = _run(["model=recnn", f"chunk_minutes={value}", "trainer.max_epochs=1"], tmp_path, check=False)
    _one_line_error(p, f"chunk_minutes=")
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # no run folder left behind


@pytest.mark.slow
def test_smoke_a_volume_replaced_at_the_same_path_is_never_served_the_old_run(tmp_path):
    """A run's directory is the hash of its settings, and a volume file is named by its path there: a volume
    replaced at the same path was served the networks trained on the old one. The run now records its caches by
    content and is trained again, in one line, when the volume changed; unchanged, it is reused."""
    rng = np.random.default_rng(0)
    vol = tmp_path / "blob_16x16x16_float32.raw"
    z, y, x = np.mgrid[-1:1:16j, -1:1:16j, -1:1:16j]
    vol.write_bytes(np.exp(-4 * (x * x + y * y + z * z)).astype(np.float32).tobytes())
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="2")
    cmd = [PY, "-m", "imls_lightning.train", "model=recnn", "recnn=enhancenet", "recnn.net.channels=4", "recnn.net.blocks=1",
           "scene=file", f"scene.volume.path={vol}", "data=tiny", "data.num_views=8", "data.test_views=2", "renderer=numba",
           "trainer.max_epochs=1", f"paths.runs_dir={tmp_path}/runs", f"data.cache_dir={tmp_path}/cache",
           "trainer.enable_progress_bar=false"]

    def run():
        p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
        return p, json.loads((Path(_last_line(p)).parent.parent / "result.json").read_text())

    first, r1 = run()
    assert len(r1["caches"]) == 1 and len(list((tmp_path / "cache").glob("blob-*"))) == 1
    same, r2 = run()
    assert "already finished" in same.stdout and r2["caches"] == r1["caches"]
    vol.write_bytes((rng.random((16, 16, 16)) ** 4).astype(np.float32).tobytes())  # another volume, same path
    other, r3 = run()
    assert "already finished" not in other.stdout
    warn = [line for line in other.stderr.splitlines() if "trained on cache" in line]
    assert len(warn) == 1 and r1["caches"][0] in warn[0] and "training it again from the start" in warn[0], other.stderr[-2000:]
    # the same run folder, trained again (Lightning keeps the old checkpoint beside the new one's -v1 name)
    assert r3["caches"] != r1["caches"] and Path(_last_line(other)).parent == Path(_last_line(first)).parent
