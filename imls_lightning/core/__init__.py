"""The method's formulas, free of training and I/O: compaction of a sampling pattern's pixels
(:mod:`.compaction`), importance normalization and rejection sampling with the one mean-value search
(:mod:`.importance`), sampling patterns and the plastic / blue-noise rank patterns (:mod:`.patterns`,
:mod:`.rank_patterns`), the image metrics every report and training log shares (:mod:`.metrics`), the untrained
importance of a C-Image's pixels (:mod:`.unpredictability`), and the operating-point searches' primitives, the smallest
setting of any knob whose gap stays within epsilon, over measured settings or by bisection (:mod:`.smallest_within`)."""
