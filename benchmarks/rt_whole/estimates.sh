#!/bin/bash
# rayleigh_taylor framed whole: the before-training estimate at two framings, the cores to itself.
cd "$(dirname "$0")/../.." && source .venv/bin/activate
for d in "4.5,6.3" "6.0,8.4"; do
  tag=${d/,/-}
  echo "[rt] estimate at $d, $(date)"
  python -m imls_lightning.estimate scene=rayleigh_taylor recnn=enhancenet renderer=numba runs_dir=runs/paper \
    recnn.net.channels=16 recnn.net.blocks=4 iml.depth=4 iml.base_channels=8 ims.layers=7 ims.base_channels=16 \
    ims.max_channels=256 renderer.skip_empty=false 'sharpness=[3.0]' recnn_lead.steps=600 \
    "scene.camera_distance=[$d]" > logs/rt_estimate_$tag.log 2>&1
  rc=$?; echo "[rt] rc=$rc $(date)"; p=$(tail -1 logs/rt_estimate_$tag.log); echo "$p"
  [ $rc -eq 0 ] && cp "$p" benchmarks/rt_whole/estimate_distance_${tag}_skip_empty_off.json
done
