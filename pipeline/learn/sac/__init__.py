"""SAC: the robots' learners stepped as one batched network (:mod:`pipeline.learn.sac.batched`)."""
