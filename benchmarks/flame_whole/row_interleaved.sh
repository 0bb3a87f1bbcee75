#!/bin/bash
# flame_whole's EnhanceNet row of paper_scale.csv, its ORP searched at four IMS mask sharpnesses (1: the paper's
# masks, 2, 3, 4; the fastest on the search views kept), its methods timed interleaved run by run (conf/evaluate.yaml
# timing, the default) on 12 views;
# the same networks and renderer (no empty-space skipping) as row_sharpness.sh. The estimate renders a curve per
# sharpness (its sharpness= comes from ims_sharpness). Needs the cores to itself. Log: logs/flame_whole_row_interleaved.log
cd "$(dirname "$0")/../.." && source .venv/bin/activate
python -m imls_lightning.bench_paper scene=flame_whole recnns=[enhancenet] adaptive=null skip_empty=false \
  'evaluate=["max_views=null","timed_views=12","repeats=10","warmup=1","sweep_views=2","grid_views=3","orp_max_views=40","orp_views=path","orp_strata=4","orp_by_distance=true","options.half=auto","ims_sharpness=[1.0,2.0,3.0,4.0]"]'
echo "[row] rc=$? at $(date)"
