#!/bin/bash
# seed_whole's FoVolNet row of paper_scale.csv (benchmarks/whole_scene_fovolnet_row.sh: the protocol and its settings,
# RECNN_EPOCHS, IML_EPOCHS, IMS_EPOCHS, IMS_DECODER_EPOCHS, IMS_DECODER_RANGE, TRAIN_ONLY, SPARSER, TIMED_VIEWS, FLOORS).
#   bash benchmarks/seed_whole/fovolnet_row.sh [overrides...]        (log: tee it to logs/seed_whole_fovolnet_row.log)
exec bash "$(dirname "$0")/../whole_scene_fovolnet_row.sh" seed_whole "$@"
