"""DQN with a dueling head and prioritized replay (:mod:`pipeline.learn.dqn.model`,
:mod:`pipeline.learn.dqn.prioritized`)."""
