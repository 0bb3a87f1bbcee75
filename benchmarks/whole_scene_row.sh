#!/bin/bash
# A whole-framed scene's EnhanceNet row of paper_scale.csv by flame_whole's protocol (benchmarks/flame_whole/row_decoder.sh):
# the before-training estimate, the cache, every training stage in 30-minute chunks (the IMS's decoder stage included),
# then the evaluation on the faster ray caster (empty-space skipping; SKIP_EMPTY=false for the old rows' protocol), the
# RecNN alone and IML/S timed on both ray casters, the methods interleaved on 12 views, gamma = 3 masks.
# A stage that stops after its chunk exits with status 3: the loop runs the same command again, which resumes it.
# TRAIN_ONLY=1 stops after the training stages (the evaluation needs the cores to itself: run it alone later);
# TIMED_VIEWS=N times N of the test views instead of 12 (the PSNR is always on all 120), FLOORS=a,b,...
# searches those object-floor margins instead of 0-0.2; FLOOR_BY_BAND=1 keeps a margin per band of camera distance
# (orp_object_floor_by_band, at most FLOOR_TAIL=0.1 of a band's validation views over 1 dB); IML_EPOCHS=N and IMS_EPOCHS=N
# train the IML and the IMS N epochs instead of 15 and 10 (epochs are outside a run's identity: a later call with more
# continues the same run; flame_whole's curves peaked by epoch 3 of 5, so it takes 5 and 5). EVAL_EXTRA="k=v ...": more
# evaluation settings (e.g. las_searched=true: LAS at the product's promise beside LAS at equal IPR).
# The IML trains 15 epochs and the IMS 10 instead of the schedule's 5 (seed_whole's curves still rose at 5; see its row.sh).
# After the ORP search, the object floor's margin (orp_object_floor) is chosen on the cache's validation views: a view's
# share near its own object's fraction lost seed_whole's promise on a quarter of its test views.
# The settings both whole-scene rows share, and the loop over chunks, are in benchmarks/row_protocol.sh.
#   bash benchmarks/whole_scene_row.sh SCENE [overrides...]
scene=${1:?usage: whole_scene_row.sh SCENE [overrides...]}; shift
cd "$(dirname "$0")/.." && source .venv/bin/activate && source benchmarks/row_protocol.sh
extra=()
[ "${TRAIN_ONLY:-0}" = 1 ] && extra+=(train_only=true)
eval_extra=""
[ "${FLOOR_BY_BAND:-0}" = 1 ] && eval_extra=',"orp_object_floor_by_band=true","orp_object_floor_tail='"${FLOOR_TAIL:-0.1}"'"'
for o in ${EVAL_EXTRA:-}; do eval_extra+=',"'"$o"'"'; done
run_in_chunks python -m imls_lightning.bench_paper scene="$scene" recnns=[enhancenet] adaptive=null skip_empty="${SKIP_EMPTY:-true}" "${extra[@]}" "$@" \
  'stages.iml=['"$IML_SETTINGS"',"trainer.max_epochs='"${IML_EPOCHS:-15}"'"]' \
  'stages.ims=['"$IMS_SETTINGS"',"trainer.max_epochs='"${IMS_EPOCHS:-10}"'","model.monitor=val/fr_psnr"]' \
  'stages.las=['"$LAS_SETTINGS"']' \
  'evaluate=['"$EVAL_SETTINGS"',"ims_sharpness=[3.0]","orp_object_floor=['"${FLOORS:-0.0,0.02,0.04,0.06,0.08,0.1,0.12,0.14,0.16,0.2}"']"'"$eval_extra"']'
