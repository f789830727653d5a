"""The benchmark: the training matrix as Ray tasks (:mod:`pipeline.bench.sweep`), its trials
(:mod:`pipeline.bench.trials`), statistics across seeds with rliable (:mod:`pipeline.bench.stats`) and the
report (:mod:`pipeline.bench.sweep_report`)."""
