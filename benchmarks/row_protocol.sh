#!/bin/bash
# The whole-framed scenes' row protocol, one home for what the EnhanceNet and FoVolNet rows share (sourced by
# benchmarks/whole_scene_row.sh and benchmarks/whole_scene_fovolnet_row.sh from the repository root):
#   IML_SETTINGS   the IML end to end at the paper-regime size (its epochs are the row's own; the blue-noise decoder
#                  trains the same network);
#   IMS_SETTINGS   the IMS regressing PIM' with its decoder fine-tuned every 4th step (epochs and monitor follow), on
#                  1,500 views of a seed of their own (data.seed=100): with the cache's seed, the first 400 of them
#                  shared their eye directions with the cache's views, so the 40 validation views the object floor is
#                  chosen on were directions the IMS had trained on (the evaluation now refuses such an overlap);
#   LAS_SETTINGS   LAS by the paper's protocol: a 64^2 low-res input at 512^2 (was 128^2), trained 3 epochs;
#   EVAL_SETTINGS  the evaluation: every test view, TIMED_VIEWS (default 12) timed 10 times interleaved, the ORP
#                  searched on 40 views of 4 exploratory paths per band of camera distance, networks at half=auto;
#   run_in_chunks CMD...  runs CMD again while it exits with status 3 (a stage trained one 30-minute chunk), at most
#                  20 passes; it returns CMD's last status.
IML_SETTINGS='"model.mode=end_to_end","model.mean=0.2","model.mean_range=[0.05,0.6]","model.depth=4","model.base_channels=8"'
IMS_SETTINGS='"data.num_views=1500","data.train_pixels=pattern","data.val_fraction=0.02","model.target=pim","model.loss.mse=1.0","model.loss.perceptual.weight=0.0","model.loss.adversarial=0.0","model.layers=7","model.base_channels=16","model.max_channels=256","model.betas=[0.9,0.999]","model.decoder_lr=1.0e-3","model.decoder_every=4","model.decoder_mean_range=[0.1,1.0]","data.seed=100"'
LAS_SETTINGS='"model.low_res=64","trainer.max_epochs=3"'
EVAL_SETTINGS='"max_views=null","timed_views='"${TIMED_VIEWS:-12}"'","repeats=10","warmup=1","sweep_views=2","grid_views=3","orp_max_views=40","orp_views=path","orp_strata=4","orp_by_distance=true","options.half=auto"'

run_in_chunks() {
  local i rc
  for i in $(seq 1 20); do
    "$@"
    rc=$?; echo "[row] pass $i rc=$rc at $(date)"
    [ $rc -eq 3 ] || return $rc
  done
  return $rc
}
