"""Training on stable-baselines3: the multi-robot loop, SAC / dueling-PER DQN / PPO learners in the three
multi-agent modes, weight selection, checkpoints and progress.

``sb3.py``, the one adapter to SB3's protected members, steps SB3 algorithms from a loop of its own through
``_setup_learn``, ``_on_step`` and ``_current_progress_remaining`` (``learners.py`` drives them); pyproject.toml
pins stable-baselines3 to the minor release these were tested with, and tests/unit/test_learners_sb3.py fails when
they change.
"""
