"""Multi-robot navigation in MuJoCo: an array-level core and its PettingZoo ParallelEnv.

Per control step: actions are decoded by core's action codec (robots that are done get zero
velocity), MuJoCo advances one control period, the simulated lidar produces a LaserScan-shaped
scan that core reduces to the policy's beams, core's judge decides goal/collision/timeout and
the reward, and core's layout builds the observations; these parts come from pipeline.mdp, as on a
fleet. Nothing of the MDP is computed here.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

from pipeline.core.judge import JudgeStep
from pipeline.core.layouts import draw_layout
from pipeline.core.network import LinkSettings, MessageStream, observed_scans, stand_still
from pipeline.core.scenario import Scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.mdp import mdp_parts
from pipeline.params import WorldConfig
from pipeline.sim.world import SimWorld

NETWORK_STREAM = 0x6E6574
"""Mixed into an episode's seed for the network's own generator."""


@dataclass(frozen=True)
class SimStep:
    """One control step of the array-level sim: obs (n_robots, obs_size) float32, the judgement."""

    obs: np.ndarray
    judge: JudgeStep


class NetworkedSensors:
    """Each robot's scans and odometry through the world's network (:class:`pipeline.core.network.MessageStream`),
    with its own generator (seeded from the episode's seed), so that an ideal link leaves every other draw as it
    was. What a stale robot observes and does is core's rule, the same as on a fleet."""

    def __init__(self, n_robots: int, world: WorldConfig) -> None:
        self.n = n_robots
        self.period_ns = round(world.control_period_s * NS_PER_S)
        self.plays = (
            world.network.plays
            or world.lidar.scan_drop_prob > 0
            or any(k.startswith("network.") for k in world.randomize.ranges())
        )
        self.settings = world.network
        self.rng = np.random.default_rng(0)
        self.stale = np.zeros(n_robots, dtype=bool)
        self.t_ns = 0
        self.scans: MessageStream | None = None
        self.odometry: MessageStream | None = None

    def reset(self, world: WorldConfig, seed: int | None) -> None:
        """A new episode in `world` (its draw, when the network is randomized)."""
        if not self.plays:
            return
        if seed is not None:
            self.rng = np.random.default_rng([seed, NETWORK_STREAM])
        net = world.network
        self.settings = net
        link = {
            "loss_prob": net.loss_prob,
            "burst_len": net.burst_len,
            "delay_s": net.delay_s,
            "jitter_s": net.jitter_s,
        }
        drop = world.lidar.scan_drop_prob
        self.scans = MessageStream(LinkSettings(net.scan_rate_hz, **link, drop_prob=drop), self.n, self.period_ns)
        self.odometry = MessageStream(LinkSettings(net.odom_rate_hz, **link), self.n, self.period_ns)
        self.stale = np.zeros(self.n, dtype=bool)
        self.t_ns = 0

    def receive(self, scans: np.ndarray, pose: np.ndarray, first: bool) -> tuple[list[np.ndarray], np.ndarray]:
        """The scans (as the policy observes them) and poses (n, 3) that have reached the controller now, given the
        sensors' readings now; `first`: the episode's start, when every robot's data is fresh."""
        assert self.scans is not None and self.odometry is not None
        if first:
            self.scans.reset(0, list(scans), self.rng)
            self.odometry.reset(0, list(pose), self.rng)
        else:
            self.t_ns += self.period_ns
            self.scans.step(self.t_ns, list(scans), self.rng)
            self.odometry.step(self.t_ns, list(pose), self.rng)
        net = self.settings
        self.stale = (self.scans.ages_ns(self.t_ns) > round(net.scan_stale_s * NS_PER_S)) | (
            self.odometry.ages_ns(self.t_ns) > round(net.odom_stale_s * NS_PER_S)
        )
        latest = [s for s in self.scans.latest if s is not None]
        poses = np.stack([p for p in self.odometry.latest if p is not None])
        return observed_scans(latest, self.stale, net.stale_scan), poses


class MultiRobotSim:
    """Array-level multi-robot episode: the one implementation every env view steps."""

    def __init__(self, scenario: Scenario, world: WorldConfig) -> None:
        self.scenario = scenario
        self.world_config = world
        self.world = SimWorld(scenario, world)
        self.mdp = mdp_parts(scenario, world)
        self.layout = self.mdp.layout
        self.codec = self.mdp.codec
        self.observer = self.mdp.observer
        self.judge = self.mdp.judge
        self._observe_truth = self.mdp.definition.observed_pose == "ground_truth"
        self.n = scenario.n_robots
        self._others = np.array([[j for j in range(self.n) if j != i] for i in range(self.n)], dtype=np.intp).reshape(
            self.n, self.n - 1
        )
        """Row i: the indices of every robot but i, in order (:meth:`others_in_frame`)."""
        self.obs_low, self.obs_high = self.observer.low, self.observer.high
        self.raw_scan = np.zeros((self.n, world.lidar.sim_beams))
        self.ranges = np.zeros((self.n, world.lidar.beams))
        self.obs = np.zeros((self.n, self.layout.size), dtype=np.float32)
        self.last_cmd = np.zeros((self.n, 2))
        self._seeded = False
        self.network = NetworkedSensors(self.n, world)
        """The network between the sensors and the policy (:mod:`pipeline.core.network`); idle on an ideal link."""
        self.stale = np.zeros(self.n, dtype=bool)
        """(n_robots,) robots whose latest scan or odometry is older than its staleness limit: they stand still."""
        self.random_layouts = scenario.layouts is not None and world.layouts == "random"
        """Each episode draws its layout from the scenario's ranges, by its seed (:mod:`pipeline.core.layouts`)."""
        self.episode_layout = scenario
        """The layout of the current episode (the scenario itself without random layouts)."""

    def _track(self) -> None:
        """A pursuit's goals are where its target is now."""
        target = self.world.target_xy
        if target is not None:
            self.mdp.track(target)

    def _observe(self, first: bool = False) -> np.ndarray:
        self.raw_scan = self.world.scan()
        pose = self.world.truth if self._observe_truth else self.world.odometry.pose
        scans: np.ndarray | list[np.ndarray] = self.raw_scan
        if self.network.plays:
            scans, pose = self.network.receive(self.raw_scan, pose, first)
            self.stale = self.network.stale
        observed = self.observer.build(scans, self.world.scan_geometry, pose)
        self.ranges, self.obs = observed.ranges, observed.obs
        return self.obs

    def reset(self, seed: int | None = None, starts: np.ndarray | None = None) -> np.ndarray:
        """Start an episode (at the scenario's starts, or at `starts` (n_robots, 3)); returns observations.

        With random layouts the episode's layout is drawn from `seed` (its starts unless `starts` is given)."""
        if seed is None and (not self._seeded or self.random_layouts):
            seed = int(np.random.SeedSequence().generate_state(1)[0])
        if seed is not None:
            self._seeded = True
        if self.random_layouts and seed is not None:
            self.episode_layout = draw_layout(self.scenario, seed)
            self.world.use_layout(self.episode_layout)
            self.mdp.use_layout(self.episode_layout)
        self.world.reset(seed, starts)
        self.network.reset(self.world.world, seed)  # the episode's draw of the network, when it is randomized
        self.stale = np.zeros(self.n, dtype=bool)
        self._track()
        self.judge.reset(self.world.truth)
        self.last_cmd = np.zeros((self.n, 2))
        self.observer.forget()
        return self._observe(first=True).copy()

    def path_bearing(self, ahead_m: float) -> np.ndarray:
        """(n_robots,) the bearing (rad, robot frame) of the point `ahead_m` along each robot's way to its goal
        (:meth:`EpisodeJudge.path_point`, from the true poses and the episode's map): what a planner that knows
        the map would steer at. Training's imitation teacher reads it; no policy does."""
        truth = self.world.truth
        d = self.judge.path_point(truth, ahead_m) - truth[:, :2]
        return np.asarray(np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - truth[:, 2]))))

    def others_in_frame(self) -> np.ndarray:
        """(n_robots, n_robots - 1, 2) where the other robots are (m, robot i's frame, from the true poses), in
        robot order: what a teacher that sees every robot knows. Training's imitation teacher reads it; no policy
        does."""
        truth = self.world.truth
        d = truth[self._others, :2] - truth[:, None, :2]
        c, s = np.cos(truth[:, 2])[:, None], np.sin(truth[:, 2])[:, None]
        return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)

    def step(self, actions: np.ndarray) -> SimStep:
        """Advance one control period with policy actions for every robot (done robots are ignored)."""
        cmd = self.codec.decode(actions)
        cmd[self.judge.done] = 0.0
        stand_still(cmd, self.stale)  # as on a fleet: a robot without fresh data waits for it
        self.last_cmd = cmd
        self.observer.remember(cmd)
        self.world.step(cmd)
        self._track()
        obs = self._observe()
        judged = self.judge.step(self.world.odometry.pose, self.world.truth, self.ranges)
        return SimStep(obs=obs.copy(), judge=judged)


class MultiRobotEnv(ParallelEnv[str, np.ndarray, np.ndarray]):
    """PettingZoo ParallelEnv: agents robot_1..N navigating to their goal squares.

    A robot leaves `agents` when it reaches its goal or collides (it then stands still); all leave
    at the step limit. Each info holds the reward terms (they sum exactly to the reward), the
    robot's flags and its ground-truth and odometry poses.
    """

    metadata = {"name": "mrl_navigation_v0", "render_modes": ["rgb_array"], "render_fps": 10, "is_parallelizable": True}

    def __init__(self, scenario: Scenario, world: WorldConfig, render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} is not supported; allowed: None, 'rgb_array'")
        self.render_mode = render_mode
        self.sim = MultiRobotSim(scenario, world)
        self.possible_agents = list(scenario.robot_names)
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._obs_space = gymnasium.spaces.Box(self.sim.obs_low, self.sim.obs_high, dtype=np.float32)
        if self.sim.codec.kind == "continuous":
            self._act_space: gymnasium.Space[Any] = gymnasium.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        else:
            self._act_space = gymnasium.spaces.Discrete(self.sim.codec.n_discrete)

    @functools.cache  # noqa: B019 - one space object per agent, as PettingZoo requires
    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._obs_space

    @functools.cache  # noqa: B019
    def action_space(self, agent: str) -> gymnasium.Space[Any]:
        return self._act_space

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        obs = self.sim.reset(seed)
        self.agents = list(self.possible_agents)
        infos = {a: self._info(i) for a, i in self._index.items()}
        return {a: obs[i] for a, i in self._index.items()}, infos

    def _info(self, i: int, judged: JudgeStep | None = None) -> dict[str, Any]:
        info: dict[str, Any] = {
            "truth_pose": self.sim.world.truth[i].copy(),
            "odom_pose": self.sim.world.odometry.pose[i].copy(),
        }
        if judged is not None:
            info["terms"] = judged.robot_terms(i)
            info["reached"] = bool(judged.reached[i])
            info["collided"] = bool(judged.collided[i])
            info["team_success"] = judged.team_success
            info["events"] = [e for r, e in judged.events if r in (i, -1)]
        return info

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        if not self.agents:
            raise RuntimeError("step() called after every agent is done; call reset()")
        unknown = set(actions) - set(self.possible_agents)
        if unknown:
            raise KeyError(f"actions for unknown agents {sorted(unknown)}; agents are {self.possible_agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise KeyError(f"no action for live agents {missing}; every agent in env.agents needs one")
        codec = self.sim.codec
        if codec.kind == "continuous":
            batch: np.ndarray = np.zeros((self.sim.n, 2))  # (0, 0) is zero velocity
        else:
            batch = np.zeros(self.sim.n, dtype=np.int64)
        for a, act in actions.items():
            batch[self._index[a]] = act
        result = self.sim.step(batch)
        judged = result.judge
        live = self.agents
        obs = {a: result.obs[self._index[a]] for a in live}
        rewards = {a: float(judged.reward[self._index[a]]) for a in live}
        terms = {a: bool(judged.done[self._index[a]]) for a in live}
        truncs = {a: judged.truncated for a in live}
        infos = {a: self._info(self._index[a], judged) for a in live}
        self.agents = [a for a in live if not (terms[a] or truncs[a])]
        return obs, rewards, terms, truncs, infos

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        from pipeline.sim.render import render_top_down

        return render_top_down(self.sim)

    def state(self) -> np.ndarray:
        """The joint observation (n_robots * obs_size,)."""
        return self.sim.obs.reshape(-1).copy()

    def close(self) -> None:
        pass
