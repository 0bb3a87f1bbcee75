#!/bin/bash
# What a user would do instead, beside seed_whole's FoVolNet row: the same FoVolNet trained the same way (16 epochs) on a
# sparser foveal pattern of its own (half the C-pixels, pattern.c_size_ratio=0.3536), timed in one run with the RecNN
# alone and IML/S + RecNN at the row's operating point. The point is not searched again: orp_from takes the row's
# (the set of checkpoints is part of an evaluation's identity, so the baseline needs a run of its own). VIEWS test
# views, all timed (default 12: the row's timed views; SWEEP_VIEWS of them, default 2, put every method on the front); it
# resumes per view like every evaluation.
#   SPARSER_CKPT=runs/paper/recnn-fovolnet-seed_whole-9d0f57fc/checkpoints/epochNNN.ckpt \
#     bash benchmarks/seed_whole/fovolnet_sparser_eval.sh      (log: logs/seed_whole_fovolnet_sparser_eval.log)
cd "$(dirname "$0")/../.." && source .venv/bin/activate
row=${ROW:-runs/paper/eval/seed_whole-fovolnet-fe3b4c74}
[ -f "$row/config.yaml" ] || { echo "ROW=$row: expected the row's finished evaluation folder" >&2; exit 2; }
[ -f "${SPARSER_CKPT:-}" ] || { echo "SPARSER_CKPT=${SPARSER_CKPT:-}: expected the sparser FoVolNet's checkpoint" >&2; exit 2; }
ck() { python -c "import sys,yaml; print(yaml.safe_load(open('$row/config.yaml'))['checkpoints']['$1'])"; }
exec python -m imls_lightning.evaluate scene=seed_whole data=paper_cpu renderer=numba data.cache_dir=cache paths.runs_dir=runs/paper \
  checkpoints.ims="$(ck ims)" checkpoints.recnn="$(ck recnn)" checkpoints.iml="$(ck iml)" checkpoints.blue_noise="$(ck blue_noise)" \
  checkpoints.recnn_sparser="$SPARSER_CKPT" orp_from="$row" progress=False reuse=true \
  max_views=${VIEWS:-12} timed_views=${VIEWS:-12} repeats=10 warmup=1 sweep_views=${SWEEP_VIEWS:-2} grid_views=1 shares=null \
  orp_max_views=40 orp_views=path orp_strata=4 orp_by_distance=true options.half=auto options.compile=auto \
  'ims_sharpness=[3.0]' 'orp_object_floor=[0.0,0.04,0.08,0.12,0.16,0.2]' renderer.skip_empty=false
