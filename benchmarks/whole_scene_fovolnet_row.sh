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
#   bash benchmarks/whole_scene_fovolnet_row.sh SCENE [overrides...]     (log: logs/SCENE_fovolnet_row.log)
scene=${1:?usage: whole_scene_fovolnet_row.sh SCENE [overrides...]}; shift
cd "$(dirname "$0")/.." && source .venv/bin/activate
extra=()
[ "${TRAIN_ONLY:-0}" = 1 ] && extra+=(train_only=true)
[ "${SPARSER:-0}" = 1 ] || extra+=(++stages.recnn_sparser=null)
for i in $(seq 1 20); do
  python -m imls_lightning.bench_paper scene="$scene" 'recnns=[fovolnet]' adaptive=null skip_empty=false "${extra[@]}" "$@" \
    'stages.recnn=["trainer.max_epochs='"${RECNN_EPOCHS:-8}"'"]' \
    'stages.iml=["model.mode=end_to_end","model.mean=0.2","model.mean_range=[0.05,0.6]","model.depth=4","model.base_channels=8","trainer.max_epochs='"${IML_EPOCHS:-4}"'"]' \
    'stages.blue_noise=["model.mode=end_to_end","model.mean=0.2","model.mean_range=[0.05,0.6]","model.depth=4","model.base_channels=8","trainer.max_epochs=2"]' \
    'stages.ims=["data.num_views=1500","data.train_pixels=pattern","data.val_fraction=0.02","model.target=pim","model.loss.mse=1.0","model.loss.perceptual.weight=0.0","model.loss.adversarial=0.0","model.layers=7","model.base_channels=16","model.max_channels=256","model.betas=[0.9,0.999]","model.decoder_lr=1.0e-3","model.decoder_every=4","model.decoder_mean_range=[0.1,1.0]","trainer.max_epochs='"${IMS_EPOCHS:-4}"'","model.monitor=val/fr_psnr"]' \
    'stages.ims_decoder=["model.decoder_lr=3.0e-4","model.decoder_mean_range='"${IMS_DECODER_RANGE:-[0.1,0.5]}"'","model.decoder_lift=true","trainer.max_epochs='"${IMS_DECODER_EPOCHS:-2}"'","model.monitor=val/decoder_fr_psnr"]' \
    'evaluate=["max_views=null","timed_views='"${TIMED_VIEWS:-12}"'","repeats=10","warmup=1","sweep_views=2","grid_views=3","orp_max_views=40","orp_views=path","orp_strata=4","orp_by_distance=true","options.half=auto","options.compile=auto","ims_sharpness=[3.0]","orp_object_floor=['"${FLOORS:-0.0,0.04,0.08,0.12,0.16,0.2}"']"]'
  rc=$?; echo "[row] pass $i rc=$rc at $(date)"
  [ $rc -eq 3 ] || exit $rc
done
