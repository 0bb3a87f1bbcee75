#!/bin/bash
# flame_whole's EnhanceNet row of paper_scale.csv: the estimate and the evaluation on the ray caster without
# empty-space skipping (every training stage is reused from logs/flame_whole_train.sh); needs the cores to itself
cd "$(dirname "$0")/../.." && source .venv/bin/activate
python -m imls_lightning.bench_paper scene=flame_whole recnns=[enhancenet] adaptive=null skip_empty=false
echo "[row] rc=$? at $(date)"
