#!/usr/bin/env bash
# Issue 31's third bar on this CPU: for each paper-regime scene, the cache and the RecNN stage exactly as
# `make bench-paper` runs them (same commands, so bench-paper reuses both), then the regime evidence on the
# test trajectory. Resumable: a finished cache or run is reused, a half-rendered cache resumes per view.
#   nohup scripts/regime_caches.sh rayleigh_taylor flame_sheets seed_shell > logs/regime_caches.log 2>&1 &
set -u -o pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
for scene in "$@"; do
  echo "=== $scene: cache $(date +%T)"
  cache=$($PY -m data_gen scene=$scene data=paper_cpu renderer=numba data.cache_dir=cache contact_sheet=true progress=False | tail -1) || exit 1
  echo "=== $scene: RecNN $(date +%T) (cache $cache)"
  # the train CLI's last line is the best checkpoint (exit 3: a chunk ended; run this script again to go on)
  ckpt=$($PY -m imls_lightning.train model=recnn scene=$scene data=paper_cpu renderer=numba data.cache_dir=cache recnn=enhancenet \
    paths.runs_dir=runs/paper seed=0 trainer.enable_progress_bar=false recnn.net.channels=16 recnn.net.blocks=4 \
    data.crop=128 trainer.max_epochs=20 chunk_minutes=30 | tail -1) || { echo "RecNN unfinished ($?)"; continue; }
  echo "=== $scene: evidence $(date +%T) (RecNN $ckpt)"
  $PY scripts/regime_evidence.py "$cache" "$(dirname "$(dirname "$ckpt")")" --json logs/evidence_$scene.json
done
echo "=== done $(date +%T)"
