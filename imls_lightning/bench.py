"""``make bench``: the project's reference benchmark, the paper's ORP and LAS tables on this machine.

For every scene of ``scenes`` and every RecNN of ``recnns`` (``conf/pipelines/bench.yaml``) it runs the
commands a user would type, through the real CLIs (:func:`imls_lightning.pipelines.stages.run_stage`):

1. ``python -m imls_lightning.train model=recnn ...``                   the RecNN (renders the cache first)
2. ``python -m imls_lightning.train -m model=iml hydra/sweeper=orp ...``  the ORP search; ``orp.yaml``
   in a fixed sweep directory ``<runs_dir>/orp/<scene>-<recnn>-<hash of the sweep's arguments>``
3. ``python -m imls_lightning.train model=ims iml.checkpoint=<the ORP's IML> ...``
4. ``python -m imls_lightning.train model=las ...``                     once per scene (LAS ignores the RecNN)
5. ``python -m imls_lightning.evaluate ... reuse=true``                 every method on the 120-view
   trajectory, LAS at ``las_iprs`` and IML/S at the matching inference means (the sweep)

and writes ``BENCHMARKS.md`` (``output``): the paper's ORP table (ORP, average rendering latency,
speed-up over the RecNN alone, super-resolution and foveated) and its LAS comparison table
(full ray-cast latency; LAS and IML/S latency at three IPRs, speed-up, PSNR / SSIM), with their
details, the stage times, the machine and the command. It is rewritten (atomically) after every
scene x RecNN pair, marked partial until the end; then it is printed, and its path is the last line
of stdout.

Resuming: every stage reuses finished work - a finished training returns at once, a finished
``orp.yaml`` (with ``context.finished``) is read instead of sweeping again (an unfinished sweep
reuses its finished IML runs), the evaluation runs with ``reuse=true`` - so running the same command
again after an interruption continues where it stopped. Stage times are kept in
``<runs_dir>/bench_times.json``, keyed by each stage's result, so the table of stage times of a
resumed benchmark still shows what each result cost when it was made.

Any scene: every scene override that ``python -m data_gen`` accepts (``scene.volume.path=...``,
``scene.sample_distance_voxels=...``, ...) applies to every scene benchmarked and is passed to every
stage's command (:func:`imls_lightning.pipelines.stages.split_scene_overrides`); ``scene=NAME`` benchmarks that one
preset instead of ``scenes``. ``dry_run=true`` prints the stage commands instead of running them.

Example:
    python -m imls_lightning.bench                                        # the full benchmark (make bench)
    python -m imls_lightning.bench scenes=[mri_head] recnns=[enhancenet]  # one scene, one RecNN
    python -m imls_lightning.bench scene=file scene.volume.path=/data/my_head.nii.gz   # your own volume
"""
from __future__ import annotations

import sys
import time

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import checked_command_line, cli_errors

from .pipelines.bench import bench
from .base.paths import CONF_DIR, log
from .pipelines.stages import StageFailed, split_scene_overrides

__all__ = ["main"]


def main() -> None:
    """``python -m imls_lightning.bench``: the scene overrides leave the command line before Hydra
    composes the pipeline's config (:func:`imls_lightning.pipelines.stages.split_scene_overrides`); the Hydra entry
    point gets them through its closure (no module state)."""
    sys.argv[1:], scene_overrides = split_scene_overrides(sys.argv[1:])

    @checked_command_line(f"{CONF_DIR}/pipelines", "bench")
    @hydra.main(version_base="1.3", config_path=f"{CONF_DIR}/pipelines", config_name="bench")
    @cli_errors
    def _main(cfg: DictConfig) -> None:
        t0 = time.perf_counter()
        try:
            path = bench(cfg, scene_overrides)
        except StageFailed as err:
            print(f"error: {err}", file=sys.stderr, flush=True)
            print(f"[bench] partial tables (if any): {cfg.output}; run the same command again to resume", file=sys.stderr, flush=True)
            sys.exit(1)
        if path is None:  # dry_run
            return
        print(path.read_text(), flush=True)
        log(f"[bench] finished in {(time.perf_counter() - t0) / 60:.1f} min")
        print(path, flush=True)

    _main()


if __name__ == "__main__":
    main()
