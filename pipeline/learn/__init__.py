"""Training on stable-baselines3: the multi-robot loop, SAC / dueling-PER DQN / PPO learners in the three
multi-agent modes, weight selection, checkpoints and progress.

As in stable-baselines3, what every algorithm shares is in ``common/`` (the worlds, the modes' streams, n-step
windows, scaling, the learning curve) and each algorithm family with code of its own has a package: ``sac/`` (the
batched SAC step), ``dqn/`` (the dueling head with prioritized replay); PPO is SB3's own. ``learners.py`` wraps each
model for the loop and ``trainer.py`` runs it.

``sb3.py``, the one adapter to SB3's protected members, steps SB3 algorithms from a loop of its own through
``_setup_learn``, ``_on_step`` and ``_current_progress_remaining`` (``learners.py`` drives them); pyproject.toml
pins stable-baselines3 to the minor release these were tested with, and tests/unit/test_learners_sb3.py fails when
they change.
"""
