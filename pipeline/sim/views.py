"""Gymnasium views of the multi-robot sim for single-agent learners (stable-baselines3).

``JointEnv``: the robots as one agent (centralized control). Observation: every robot's
observation concatenated (n_robots * obs_size); a robot that is done keeps its last one.
Action: every robot's continuous action concatenated (n_robots * 2), or for discrete actions
one joint index over all combinations (k ** n_robots, robot_1 the most significant digit).
Reward: the sum over robots. Terminated when every robot is done.

``RobotEnv``: one robot learns; its teammates act by a given function of their observations
(by default they stand still). Terminated when that robot is done.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np

from pipeline.core.scenario import Scenario
from pipeline.params import WorldConfig
from pipeline.sim.env import MultiRobotSim

TeammatePolicy = Callable[[np.ndarray], np.ndarray]
"""Maps observations (n_robots, obs_size) to actions for all robots ((n, 2) or (n,))."""


def _info(sim: MultiRobotSim, judged: Any = None) -> dict[str, Any]:
    info: dict[str, Any] = {"truth_pose": sim.world.truth.copy(), "odom_pose": sim.world.odometry.pose.copy()}
    if judged is not None:
        info.update(
            terms={k: v.copy() for k, v in judged.terms.items()},
            reached=judged.reached.copy(),
            collided=judged.collided.copy(),
            team_success=judged.team_success,
        )
    return info


class JointEnv(gymnasium.Env[np.ndarray, Any]):
    """All robots as one agent over the joint observation and joint action."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, scenario: Scenario, world: WorldConfig, render_mode: str | None = None) -> None:
        self.sim = MultiRobotSim(scenario, world)
        self.render_mode = render_mode
        n = self.sim.n
        self.observation_space = gymnasium.spaces.Box(
            np.tile(self.sim.obs_low, n), np.tile(self.sim.obs_high, n), dtype=np.float32
        )
        codec = self.sim.codec
        if codec.kind == "continuous":
            self.action_space = gymnasium.spaces.Box(-1.0, 1.0, shape=(2 * n,), dtype=np.float32)
        else:
            self.action_space = gymnasium.spaces.Discrete(codec.n_discrete**n)
        self._joint = self.sim.obs.copy()

    def split_action(self, action: Any) -> np.ndarray:
        """Per-robot actions ((n, 2) or (n,)) from one joint action."""
        n, codec = self.sim.n, self.sim.codec
        if codec.kind == "continuous":
            return np.asarray(action, dtype=np.float64).reshape(n, 2)
        index, k = int(action), codec.n_discrete
        digits = [(index // k ** (n - 1 - i)) % k for i in range(n)]
        return np.array(digits, dtype=np.int64)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._joint = self.sim.reset(seed)
        return self._joint.reshape(-1).copy(), _info(self.sim)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        result = self.sim.step(self.split_action(action))
        judged = result.judge
        active = judged.active
        self._joint[active] = result.obs[active]
        reward = float(judged.reward.sum())
        return (
            self._joint.reshape(-1).copy(),
            reward,
            bool(judged.done.all()),
            judged.truncated,
            _info(self.sim, judged),
        )

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from pipeline.sim.render import render_top_down

        return render_top_down(self.sim)


class RobotEnv(gymnasium.Env[np.ndarray, Any]):
    """One robot of the team as a single agent; teammates follow `teammates` (default: stand still)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        scenario: Scenario,
        world: WorldConfig,
        robot: int = 0,
        teammates: TeammatePolicy | None = None,
        render_mode: str | None = None,
    ) -> None:
        self.sim = MultiRobotSim(scenario, world)
        if not 0 <= robot < self.sim.n:
            raise ValueError(f"robot index {robot} out of range: the scenario has {self.sim.n} robots")
        self.robot = robot
        self.teammates = teammates
        self.render_mode = render_mode
        self.observation_space = gymnasium.spaces.Box(self.sim.obs_low, self.sim.obs_high, dtype=np.float32)
        codec = self.sim.codec
        if codec.kind == "continuous":
            self.action_space: gymnasium.Space[Any] = gymnasium.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
            self._still: np.ndarray = codec.for_scenario(scenario).encode(np.zeros((self.sim.n, 2)))
        else:
            self.action_space = gymnasium.spaces.Discrete(codec.n_discrete)
            if "stop" not in codec.discrete_set and teammates is None:
                raise ValueError(
                    "discrete teammates cannot stand still without a 'stop' action: "
                    "add 'stop' to actions.discrete_set or pass a teammates policy"
                )
            self._still = np.full(self.sim.n, codec.discrete_set.index("stop") if "stop" in codec.discrete_set else 0)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        return self.sim.reset(seed)[self.robot].copy(), _info(self.sim)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        joint = self._still.copy() if self.teammates is None else np.array(self.teammates(self.sim.obs))
        joint[self.robot] = action
        result = self.sim.step(joint)
        judged = result.judge
        i = self.robot
        info = _info(self.sim, judged)
        info["robot_terms"] = judged.robot_terms(i)
        return (result.obs[i].copy(), float(judged.reward[i]), bool(judged.done[i]), judged.truncated, info)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from pipeline.sim.render import render_top_down

        return render_top_down(self.sim)
