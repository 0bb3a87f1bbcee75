#!/bin/bash
# rt_plumes's EnhanceNet row of paper_scale.csv by seed_whole's protocol (benchmarks/whole_scene_row.sh; TRAIN_ONLY=1
# stops before the evaluation). Run it as `bash benchmarks/rt_plumes/row.sh > logs/rt_plumes_row.log 2>&1`.
exec bash "$(dirname "$0")/../whole_scene_row.sh" rt_plumes "$@"
