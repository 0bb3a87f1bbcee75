#!/bin/bash
# rt_plumes's FoVolNet row of paper_scale.csv by seed_whole's FoVolNet protocol (benchmarks/whole_scene_fovolnet_row.sh,
# the FoVolNet size chosen on rayleigh_taylor, 8 / 8 / 8 channels and 2 kernel levels). The cache is the scene's own
# (both patterns' pixels are subsets of the same FR renders). TRAIN_ONLY=1 stops before the evaluation.
#   TRAIN_ONLY=1 bash benchmarks/rt_plumes/fovolnet_row.sh > logs/rt_plumes_fovolnet_row.log 2>&1
exec bash "$(dirname "$0")/../whole_scene_fovolnet_row.sh" rt_plumes "$@"
