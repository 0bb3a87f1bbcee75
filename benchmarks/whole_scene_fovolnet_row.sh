#!/bin/bash
# A whole-framed scene's FoVolNet row of paper_scale.csv, trained on 2 CPU cores (issue 31's FoVolNet goal: 1.5x within
# 1 dB), by seed_whole's FoVolNet protocol (its row was the first; benchmarks/seed_whole/fovolnet_row.sh calls this).
# FoVolNet at bench-paper's chosen size (8 / 8 / 8 channels, 2 kernel levels of 3x3) trains on whole 512^2 images;
# the epochs are cut to what a 3-hour sitting holds (RECNN_EPOCHS, IML_EPOCHS, IMS_EPOCHS, IMS_DECODER_EPOCHS). Epochs are outside a run's
# identity: a later call with more continues the same runs from last.ckpt. Every stage trains in 30-minute chunks
# (exit status 3: the loop runs the same command again). TRAIN_ONLY=1 stops before the evaluation, which needs the
# cores to itself. The sparser-pattern FoVolNet (what a user would do instead) is skipped unless SPARSER=1.
# IMS_DECODER_RANGE: the means the IMS decoder trains on (default [0.1,0.5], bench-paper's; [0.2,0.9] was tried,
# BENCHMARKS.md "seed_whole's FoVolNet row").
# The settings both whole-scene rows share, and the loop over chunks, are in benchmarks/row_protocol.sh.
#   bash benchmarks/whole_scene_fovolnet_row.sh SCENE [overrides...]     (log: logs/SCENE_fovolnet_row.log)
scene=${1:?usage: whole_scene_fovolnet_row.sh SCENE [overrides...]}; shift
cd "$(dirname "$0")/.." && source .venv/bin/activate && source benchmarks/row_protocol.sh
extra=()
[ "${TRAIN_ONLY:-0}" = 1 ] && extra+=(train_only=true)
[ "${SPARSER:-0}" = 1 ] || extra+=(++stages.recnn_sparser=null)
run_in_chunks python -m imls_lightning.bench_paper scene="$scene" 'recnns=[fovolnet]' adaptive=null skip_empty=false "${extra[@]}" "$@" \
  'stages.recnn=["trainer.max_epochs='"${RECNN_EPOCHS:-8}"'"]' \
  'stages.iml=['"$IML_SETTINGS"',"trainer.max_epochs='"${IML_EPOCHS:-4}"'"]' \
  'stages.blue_noise=['"$IML_SETTINGS"',"trainer.max_epochs=2"]' \
  'stages.ims=['"$IMS_SETTINGS"',"trainer.max_epochs='"${IMS_EPOCHS:-4}"'","model.monitor=val/fr_psnr"]' \
  'stages.ims_decoder=["model.decoder_lr=3.0e-4","model.decoder_mean_range='"${IMS_DECODER_RANGE:-[0.1,0.5]}"'","model.decoder_lift=true","trainer.max_epochs='"${IMS_DECODER_EPOCHS:-2}"'","model.monitor=val/decoder_fr_psnr"]' \
  'evaluate=['"$EVAL_SETTINGS"',"options.compile=auto","ims_sharpness=[3.0]","orp_object_floor=['"${FLOORS:-0.0,0.04,0.08,0.12,0.16,0.2}"']"]'
