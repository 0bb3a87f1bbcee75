"""``python -m imls_lightning.size_search``: model only what a scene requires (issue 19, lever 1).

A Hydra multirun sweep (Hydra's basic sweeper; ``conf/pipelines/size_search.yaml`` lists the default
grid) over the network sizes of the product's three networks:

* ``size.recnn_channels`` / ``size.recnn_blocks``: the RecNN (EnhanceNet / FoVolNet width and depth);
* ``size.decoder_depth`` / ``size.decoder_width``: the IML's U-Net decoder (and encoder);
* ``size.ims_layers`` / ``size.ims_width``: the IMS generator.

Each job is one candidate. It runs the demo's stages with those sizes through the real CLIs
(:func:`imls_lightning.pipelines.demo.demo`; a stage whose settings match a finished run reuses it), and the
evaluation searches the ORP on the product path, so the mean value is searched per candidate too.
The job writes its record to ``<output_dir>/<scene>/jobs/<name>.json`` and returns it.

The sweep's end (:class:`~imls_lightning.pipelines.size_search.SizeFront`, a Hydra callback) reads every record of the scene and writes

* ``pareto.csv`` / ``pareto.md`` / ``pareto.png``: every candidate's latency and PSNR on the product
  path, its feasibility and whether it is on the latency-PSNR Pareto front;
* ``conf/pipelines/experiment/<scene>_fast.yaml``: the chosen sizes, the fastest candidate meeting
  both bounds: its RecNN within ``recnn_bound_db`` (0.5 dB) of the reference RecNN (the paper's size,
  trained once per scene on the same schedule, both scored by Lightning's test pass on the test
  trajectory), and an ORP within ``epsilon_db`` of its own RecNN alone. Reuse it with
  ``python -m imls_lightning.demo +experiment=<scene>_fast`` (or ``bench_paper``).

Example:
    python -m imls_lightning.size_search                                   # flame, the default grid
    python -m imls_lightning.size_search scene=ct_head 'size.decoder_width=8,16'
"""
from __future__ import annotations

import sys
from typing import Any

import hydra
from omegaconf import DictConfig

from imls_lightning.base.errors import cli_errors

from .base.paths import CONF_DIR
from .pipelines.size_search import size_job, summarize
from .pipelines.stages import run_pipeline, split_scene_overrides

__all__ = ["main"]


def main() -> None:
    """``python -m imls_lightning.size_search``: scene overrides as for the demo (:func:`~imls_lightning.pipelines.stages.split_scene_overrides`);
    every job of the sweep gets them through the entry point's closure (no module state)."""
    sys.argv[1:], scene_overrides = split_scene_overrides(sys.argv[1:])

    @hydra.main(version_base="1.3", config_path=f"{CONF_DIR}/pipelines", config_name="size_search")
    @cli_errors
    def _main(cfg: DictConfig) -> Any:
        if bool(cfg.get("summarize_only", False)):
            return run_pipeline(lambda: summarize(cfg).get("md"))
        record: dict[str, Any] = {}

        def body():
            record.update(size_job(cfg, scene_overrides))
            return record.get("report")

        run_pipeline(body)
        return record

    _main()


if __name__ == "__main__":
    main()
