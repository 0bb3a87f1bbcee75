#!/bin/bash
# seed_whole's EnhanceNet row re-timed with its networks in float32 and in bfloat16, back to back in one sitting, at
# the row's own operating point (orp_from: nothing searched again): what the networks' precision moves, in speed and
# in PSNR. 40 test views (8 of them timed); about 25 min a precision on 2 cores. Needs the row's finished evaluation
# (benchmarks/seed_whole/row.sh); its networks are the ones that evaluation's config.yaml names, as orp_from demands.
# Log: logs/seed_whole_precision.log.
#   bash benchmarks/seed_whole/precision_ablation.sh [EVAL_DIR]
cd "$(dirname "$0")/../.." && source .venv/bin/activate
R=${IMLS_RUNS_DIR:-runs}/paper
row=${1:-$R/eval/seed_whole-enhancenet-76f9cec2}
ck() { python -c "from omegaconf import OmegaConf as O; print(O.load('$row/config.yaml').checkpoints.$1)"; }
common=(scene=seed_whole data=paper_cpu renderer=numba data.cache_dir=cache paths.runs_dir=$R
  checkpoints.ims="$(ck ims)" checkpoints.recnn="$(ck recnn)" checkpoints.iml="$(ck iml)"
  orp_from=$row renderer.skip_empty=false 'ims_sharpness=[3.0]'
  progress=False max_views=${MAX_VIEWS:-40} timed_views=${TIMED:-8} repeats=10 warmup=1 sweep_views=1 grid_views=1
  two_pass.base=null 'shares=[0.2]' 'front_shares=[1.0]' 'mean_values=[0.4]')
for half in false true; do
  echo "=== half=$half $(date)"
  python -m imls_lightning.evaluate "${common[@]}" options.half=$half output_dir=$R/eval/seed_whole-precision-half_$half || exit $?
done
echo "=== done $(date)"
