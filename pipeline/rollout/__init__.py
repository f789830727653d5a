"""Rollouts: the episode loops that drive an exported policy in a world and record every message.

- :mod:`pipeline.rollout.tally`: one episode's bookkeeping (arrivals, path, result), shared by sim and fleet.
- :mod:`pipeline.rollout.sim`: episodes in the simulated world (the ``eval_sim`` and ``scripted_eval`` stages).
- :mod:`pipeline.rollout.runner`: episodes on a fleet over ROS 2 topics (the deploy runner), with its parts
  :mod:`~pipeline.rollout.link`, :mod:`~pipeline.rollout.handshake` and :mod:`~pipeline.rollout.watch`.
- :mod:`pipeline.rollout.deployment`: a whole deployment: checks, the twin process, the session's files.
- :mod:`pipeline.rollout.outputs`: the files beside a session (metrics, episodes, paths picture).

Rollouts sit above the simulator, the policy runtime, the recorder and the transport, and import
nothing from training; training's weight selection runs its episodes through this package.
"""
