"""The private stable-baselines3 hooks the training loop drives exist as it uses them, in the pinned range."""

from __future__ import annotations

import inspect
import re
import tomllib
from pathlib import Path

import stable_baselines3
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from pipeline.learn.dqn.model import PerDQN

ROOT = Path(__file__).resolve().parents[2]


def _pinned_range() -> tuple[tuple[int, ...], tuple[int, ...]]:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    spec = next(d for d in deps if d.startswith("stable-baselines3"))
    low = re.search(r">=\s*([\d.]+)", spec)
    high = re.search(r"<\s*([\d.]+)", spec)
    assert low and high, f"stable-baselines3 must be pinned to a tested range, got {spec!r}"
    return tuple(map(int, low.group(1).split("."))), tuple(map(int, high.group(1).split(".")))


def test_installed_release_is_inside_the_pinned_range():
    low, high = _pinned_range()
    installed = tuple(int(p) for p in re.findall(r"\d+", stable_baselines3.__version__)[:3])
    assert low <= installed[: len(low)] and installed[: len(high)] < high, (stable_baselines3.__version__, low, high)


def test_setup_learn_takes_the_arguments_the_loop_passes():
    params = inspect.signature(BaseAlgorithm._setup_learn).parameters
    for name in ("total_timesteps", "callback", "reset_num_timesteps"):
        assert name in params, f"SB3 _setup_learn lost {name!r}: {list(params)}"


def test_the_loop_hooks_exist_on_every_algorithm():
    for cls in (SAC, PerDQN, PPO):
        assert callable(getattr(cls, "_setup_learn", None)), cls
        assert callable(getattr(cls, "_update_current_progress_remaining", None)), cls
    for cls in (SAC, PerDQN):
        assert issubclass(cls, OffPolicyAlgorithm)
        assert inspect.signature(cls._on_step).parameters.keys() == {"self"}, cls


def test_progress_remaining_is_what_the_schedules_read():
    """SB3's schedules read ``_current_progress_remaining``; the loop sets it directly."""
    source = inspect.getsource(BaseAlgorithm._update_current_progress_remaining)
    assert "self._current_progress_remaining" in source
    source = inspect.getsource(BaseAlgorithm._update_learning_rate)
    assert "_current_progress_remaining" in source


def test_only_the_adapter_calls_sb3_s_protected_members():
    """``pipeline/learn/sb3.py`` is the one module that reaches into SB3 (and ``dqn.py``, a subclass of SB3's DQN
    overriding its ``train()`` as SB3's own algorithms do)."""
    hooks = re.compile(r"\._(setup_learn|on_step|current_progress_remaining|custom_logger|update_learning_rate)\b")
    allowed = {"pipeline/learn/sb3.py", "pipeline/learn/dqn/model.py"}
    reaching = {
        path.relative_to(ROOT).as_posix()
        for path in (ROOT / "pipeline").rglob("*.py")
        if hooks.search(path.read_text(encoding="utf-8"))
    }
    assert reaching <= allowed and "pipeline/learn/sb3.py" in reaching, reaching - allowed
