#!/bin/bash
# flame_whole's EnhanceNet row of paper_scale.csv with the IMS's decoder stage (stages.ims_decoder of
# conf/pipelines/bench_paper.yaml: the decoder alone trained further on the masks the evaluation runs, sharpened to
# gamma = 3 and lifted). gamma = 3 alone: the sharpness last stop's timed search kept among {1, 2, 3, 4} on the search
# views (row_interleaved.sh). Every other network reused; no empty-space skipping; methods timed interleaved on 12
# views. Needs the cores to itself. Log: logs/flame_whole_row_decoder.log
cd "$(dirname "$0")/../.." && source .venv/bin/activate
python -m imls_lightning.bench_paper scene=flame_whole recnns=[enhancenet] adaptive=null skip_empty=false "$@" \
  'evaluate=["max_views=null","timed_views=12","repeats=10","warmup=1","sweep_views=2","grid_views=3","orp_max_views=40","orp_views=path","orp_strata=4","orp_by_distance=true","options.half=auto","ims_sharpness=[3.0]"]'
rc=$?; echo "[row] rc=$rc at $(date)"; exit $rc
