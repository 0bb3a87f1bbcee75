#!/bin/bash
# flame_whole, EnhanceNet: the full protocol without the blue-noise decoder and LAS (not trained yet), on the ray
# caster without empty-space skipping; the training loop is paused (SIGSTOP) meanwhile; the checkpoints are those of `make bench-paper scene=flame_whole recnns=[enhancenet] train_only=true`
cd "$(dirname "$0")/../.." && source .venv/bin/activate
python -m imls_lightning.evaluate scene=flame_whole data=paper_cpu renderer=numba data.cache_dir=cache paths.runs_dir=runs/paper \
  checkpoints.ims=runs/paper/ims-enhancenet-flame_whole-ded2f6f6/checkpoints/epoch001.ckpt \
  checkpoints.recnn=runs/paper/recnn-enhancenet-flame_whole-a28aacd7/checkpoints/epoch019.ckpt \
  checkpoints.iml=runs/paper/iml-enhancenet-flame_whole-6bc96233/checkpoints/epoch003.ckpt \
  checkpoints.recnn_sparser=runs/paper/recnn-enhancenet-flame_whole-de12f30a/checkpoints/epoch019.ckpt \
  progress=False reuse=true max_views=null timed_views=6 repeats=10 warmup=1 sweep_views=2 grid_views=3 orp_max_views=40 \
  orp_views=path orp_strata=4 orp_by_distance=true options.half=auto renderer.skip_empty=false
echo "[eval] rc=$? at $(date)"
