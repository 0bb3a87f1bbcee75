"""Shared fixtures: tiny analytic volumes and scenes, and the real-volume folder (skipped if absent)."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
VOLUMES_DIR = Path(os.environ.get("IMLS_VOLUMES_DIR", ROOT.parent / "shared" / "volumes"))


@pytest.fixture(scope="session")
def volumes_dir() -> Path:
    """``../shared/volumes`` (or ``$IMLS_VOLUMES_DIR``); skips the test cleanly when it is absent."""
    if not VOLUMES_DIR.is_dir():
        pytest.skip(f"real volumes not available: {VOLUMES_DIR} does not exist (set IMLS_VOLUMES_DIR)")
    return VOLUMES_DIR


@pytest.fixture(scope="session")
def blob_volume():
    """A small anisotropic analytic volume (no reader or generator involved)."""
    from imls_lightning.render.volume import Volume

    z, y, x = np.mgrid[-1:1:24j, -1:1:32j, -1:1:40j]
    d = np.exp(-3 * (x * x + y * y + z * z)) + 0.25 * np.sin(6 * x) * np.cos(5 * y)
    d = d.astype(np.float32)
    return Volume(d, (1.0, 1.0, 1.5), (float(d.min()), float(d.max())), "blob", "test:blob")


@pytest.fixture(scope="session")
def blob_scene(blob_volume):
    from imls_lightning.render.scene import Scene, TransferFunction

    tf = TransferFunction(
        [[0.0, 0.1, 0.2, 0.9], [0.5, 1.0, 0.6, 0.1], [1.0, 1.0, 1.0, 1.0]],
        [[0.0, 0.0], [0.55, 0.0], [0.7, 0.4], [1.0, 0.9]],
    )
    return Scene("blob", blob_volume, tf)


@pytest.fixture(scope="session")
def tiny_checkpoints(tmp_path_factory) -> dict:
    """Real checkpoints on ``scene=tiny data=tiny renderer=numba``, trained once per session in this
    process through :func:`imls_lightning.training.fit.train` (the train CLI's body) with
    ``trainer.fast_dev_run=true`` and small networks: RecNN (EnhanceNet) -> IML end to end with it ->
    IMS on the IML's labels (``ims``: target=im, ``ims_pim``: target=pim), the blue-noise decoder
    (``blue``: an IML with importance=uniform), and LAS. About 30 s on 2 cores.

    Returns ``{"recnn", "iml", "ims", "ims_pim", "blue", "las", "recnn_sparser" (pattern.factor=4): Path of the .ckpt,
    "cache_dir", "runs_dir": Path}``.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.train import train

    base = tmp_path_factory.mktemp("tiny_checkpoints")
    common = ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={base / 'cache'}",
              f"paths.runs_dir={base / 'runs'}", "logger=none", "test=false", "trainer.fast_dev_run=true",
              "trainer.enable_progress_bar=false", "trainer.enable_model_summary=false",
              "recnn=enhancenet", "recnn.net.channels=4", "recnn.net.blocks=1"]

    def run(name: str, overrides: list[str]) -> Path:
        GlobalHydra.instance().clear()
        with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="tiny_checkpoints"):
            cfg = compose("train", overrides=[*common, f"paths.output_dir={base / 'runs' / name}", *overrides])
        path = Path(train(cfg)["best_checkpoint"])
        assert path.is_file(), path
        return path

    recnn = run("recnn", ["model=recnn"])
    # the same RecNN on a sparser pattern of its own (EnhanceNet 4x: a quarter of the C-pixels), the front's alternative
    recnn_sparser = run("recnn_sparser", ["model=recnn", "pattern.factor=4"])
    iml = run("iml", ["model=iml", "model.mode=end_to_end", f"recnn.checkpoint={recnn}", "model.depth=2",
                      "model.base_channels=4"])
    # bce instead of the perceptual loss: no VGG16 to load, same networks
    ims = run("ims", ["model=ims", f"iml.checkpoint={iml}", "model.layers=5", "model.base_channels=8",
                      "model.disc_base_channels=8", "model.loss.perceptual.weight=0", "model.loss.bce=1"])
    # the product's IMS (regresses PIM', so one IMS serves every mean value: the ORP search needs it), trained on views
    # of a seed of its own as the row protocol's is: the validation views the object floor is chosen on stay unseen
    ims_pim = run("ims_pim", ["model=ims", f"iml.checkpoint={iml}", "data.seed=100", "model.layers=5", "model.base_channels=8",
                              "model.target=pim", "model.loss.mse=1.0", "model.loss.perceptual.weight=0",
                              "model.loss.adversarial=0"])
    # the untrained-mask baseline: the blue-noise mask with a decoder trained for it
    blue = run("blue", ["model=iml", "model.mode=end_to_end", f"recnn.checkpoint={recnn}", "model.depth=2",
                        "model.base_channels=4", "model.importance=uniform"])
    las = run("las", ["model=las", "model.low_res=16", "model.importance_channels=4", "model.importance_blocks=1",
                      "model.recon_channels=4", "model.recon_blocks=1"])
    return {"recnn": recnn, "iml": iml, "ims": ims, "ims_pim": ims_pim, "blue": blue, "las": las, "recnn_sparser": recnn_sparser,
            "cache_dir": base / "cache", "runs_dir": base / "runs"}


#: the evaluation settings of the tiny row (fast: few views, one mean value, no sweeps)
ROW_SETTINGS = ["orp_max_views=4", "orp_views=path", "orp_paths=2", "sweep_views=1", "mean_values=[0.1]", "las_iprs=[0.1]",
                "front_shares=[0.5]", "grid_views=1", "warmup=0", "shares=null", "two_pass.base=null"]


@pytest.fixture(scope="session")
def row(tiny_checkpoints, tmp_path_factory):
    """A committed row (conf/row/<name>.yaml) played by the tiny checkpoints: the product's networks copied into a row
    folder with their SHA-256, beside the operating point a finished evaluation chose with them (its summary.json and
    config.yaml). ``{"spec": the row mapping, "folder", "ck": tiny_checkpoints, "chosen": that evaluation's folder}``."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from imls_lightning.base.config import file_hash
    from imls_lightning.evaluation import evaluate

    ck = tiny_checkpoints
    folder = tmp_path_factory.mktemp("row")
    files = {"ims": "ims.ckpt", "las": "las.ckpt"}
    for key, name in files.items():
        shutil.copyfile(ck["ims_pim" if key == "ims" else key], folder / name)
    base = ["scene=tiny", "data=tiny", "renderer=numba", f"data.cache_dir={ck['cache_dir']}", f"paths.runs_dir={ck['runs_dir']}",
            "progress=false", "max_views=2", "timed_views=1", *ROW_SETTINGS]
    GlobalHydra.instance().clear()
    with initialize_config_dir(str(ROOT / "conf"), version_base="1.3", job_name="test_reproduce"):
        cfg = compose("evaluate", overrides=[*base, f"checkpoints.ims={folder / 'ims.ckpt'}", f"checkpoints.las={folder / 'las.ckpt'}",
                                             f"output_dir={folder / 'chosen'}"])
    report = evaluate(cfg)
    (folder / "point").mkdir()
    for f in ("summary.json", "config.yaml"):
        shutil.copyfile(report.parent / f, folder / "point" / f)
    spec = {"name": "tiny_row", "scene": "tiny", "data": "tiny", "dir": str(folder), "point": "point", "trajectory_seed": 7,
            "views": 2, "timed_views": 1, "settings": ROW_SETTINGS,
            "networks": {k: {"file": name, "sha256": file_hash(folder / name, length=64)} for k, name in files.items()}}
    return {"spec": spec, "folder": folder, "ck": ck, "chosen": report.parent}
