#!/bin/bash
# flame_whole's EnhanceNet row of paper_scale.csv with the ORP searched at three IMS mask sharpnesses (1: the paper's
# masks, 1.5, 2; conf/evaluate.yaml ims_sharpness): the same networks and renderer (no empty-space skipping) as
# row_no_skipping.sh, every training stage reused; needs the cores to itself. The log: logs/flame_whole_row_sharpness.log
cd "$(dirname "$0")/../.." && source .venv/bin/activate
python -m imls_lightning.bench_paper scene=flame_whole recnns=[enhancenet] adaptive=null skip_empty=false \
  'evaluate=["max_views=null","timed_views=6","repeats=10","warmup=1","sweep_views=2","grid_views=3","orp_max_views=40","orp_views=path","orp_strata=4","orp_by_distance=true","options.half=auto","ims_sharpness=[1.0,1.5,2.0]"]'
echo "[row] rc=$? at $(date)"
