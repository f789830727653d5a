"""Recordings for calibration tests: an excitation controller that drives, turns, stops and stands still.

:class:`ExcitationRuntime` quacks like :class:`~pipeline.policy.runtime.PolicyRuntime` for the deploy
runner: each robot runs through random phases of 0.6 to 2 s (stand still, drive toward the goal with
the scripted controller's obstacle avoidance, turn in place, drive a random arc), so a recording holds
steps in both command channels, turns above 0.1 rad/s and stationary spans of a second or more.
:func:`record_twin_session` deploys it against the hardware twin over DDS on loopback;
:func:`simulate_session` writes the same session layout from the simulator alone (no network),
for fast tests of the calibration's inputs and error paths.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.core.actions import ActionCodec
from pipeline.core.observation import ObservationBuilder, ObservationLayout
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import Scenario, load_scenario
from pipeline.mappings import from_mapping, to_mapping
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.spec import PolicySpec
from pipeline.record.session import SessionLog, dumps, session_metadata
from tests.policy_helpers import spec_mapping

POLICY_BEAMS = 36
PHASES = ("stand", "goal", "turn", "arc")
PHASE_WEIGHTS = (0.2, 0.3, 0.2, 0.3)


class ExcitationRuntime:
    """A stand-in policy runtime whose robots alternate standing, goal seeking, turning and arcs.

    `mode` "excite" runs the random phases; "still" commands zero velocity throughout (a recording
    without motion).
    """

    def __init__(
        self,
        scenario: Scenario,
        seed: int = 0,
        max_steps: int = 150,
        v_max_mps: float = 0.4,
        w_max_radps: float = 0.2,
        mode: str = "excite",
    ) -> None:
        from pipeline.policy.scripted import GoToGoalController

        self.scenario = scenario
        self.robots = scenario.robot_names
        self.layout = ObservationLayout("rich", POLICY_BEAMS)
        self.codec = ActionCodec("continuous", v_max_mps, w_max_radps)
        self.controller = GoToGoalController(self.layout, self.codec)
        self.rng = np.random.default_rng(seed)
        self.mode = mode
        self.name = f"excitation/{mode}"
        self.session_extra: dict[str, str] = {}  # the policy itself drives
        n = scenario.n_robots
        self._phase = ["stand"] * n
        self._left = np.zeros(n, dtype=int)
        self._cmd = np.zeros((n, 2))
        world = {
            "lidar": {"range_min_m": 0.12, "range_max_m": 5.0, "reduction": "sector_min"},
            "actions": {"v_max_mps": v_max_mps, "w_max_radps": w_max_radps},
            "max_steps": max_steps,
            "progress_distance": "euclidean",
        }
        mapping = spec_mapping("0" * 64, "continuous", n, "rich", POLICY_BEAMS, scenario.name, world)
        self.spec = from_mapping(PolicySpec, mapping, "<excitation runtime>")
        self.document = to_mapping(self.spec)
        angles = 2 * math.pi * np.arange(POLICY_BEAMS) / POLICY_BEAMS
        self._front = np.abs(np.angle(np.exp(1j * angles))) <= math.radians(40)

    def check_fits(self, robots: Sequence[str], layout: ObservationLayout, *args: object) -> None:
        if tuple(robots) != tuple(self.robots) or layout != self.layout:
            raise PolicyMismatch(self.name, [f"built for {self.robots} and {self.layout}"])

    def _new_phase(self, i: int) -> None:
        phase = str(self.rng.choice(PHASES, p=PHASE_WEIGHTS))
        self._phase[i] = phase
        self._left[i] = int(self.rng.integers(6, 21))
        if phase == "turn":
            self._cmd[i] = (0.0, float(self.rng.choice([-1, 1]) * self.rng.uniform(0.08, 1.0) * self.codec.w_max_radps))
        elif phase == "arc":
            self._cmd[i] = (
                float(self.rng.uniform(0.25, 1.0) * self.codec.v_max_mps),
                float(self.rng.uniform(-1.0, 1.0) * self.codec.w_max_radps),
            )
        else:
            self._cmd[i] = 0.0

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) (v m/s, w rad/s) for observations (n_robots, layout.size)."""
        n = len(obs)
        if self.mode == "still":
            return np.zeros((n, 2))
        goal = self.controller.commands(obs)
        ranges = obs[:, self.layout.slices["ranges"]].astype(np.float64)
        front = np.where(self._front[None], ranges, np.inf).min(axis=1)
        out = np.zeros((n, 2))
        for i in range(n):
            if self._left[i] <= 0:
                self._new_phase(i)
            self._left[i] -= 1
            phase = self._phase[i]
            if phase == "goal":
                out[i] = goal[i]
            elif phase == "arc":
                out[i] = self._cmd[i]
                out[i, 0] *= float(np.clip((front[i] - 0.3) / 0.4, 0.0, 1.0))
            else:
                out[i] = self._cmd[i]
        return out

    def actions(self, obs: np.ndarray) -> np.ndarray:
        return self.codec.encode(self.commands(obs))


TWIN_EPISODES = 8
TWIN_STEPS = 120
TWIN_TIME_SCALE = 2.0
"""The twin sessions of the bundled profiles (tests/integration/conftest.py::twin_session): 8 episodes of 12 s of
twin time at 2x. The wheel-level twin with its lidar keeps real time at 3x on a 2-core host with the runner beside
it; at 2x the host's scheduling jitter (which the receive times carry, scaled by the time scale) stays well under the
profiles' network jitter."""


def record_twin_session(
    out: Path,
    profile: str | Path,
    episodes: int,
    time_scale: float = 5.0,
    seed: int = 0,
    scenario: str = "obstacles",
    mode: str = "excite",
    max_steps: int = 150,
) -> Path:
    """Deploy the excitation runtime against the hardware twin (DDS on loopback) into `out` as the deploy stage does
    (session.mcap beside the deployment's own episodes.csv and metrics.json); the recording's path. The twin's record
    of each stamped message's hand-over goes beside the folder (:func:`link_record_of`)."""
    from pipeline.rollout.deployment import DeployRequest, deploy_session
    from pipeline.ros.fleet import load_fleet
    from tests.integration.conftest import write_fleet

    out.mkdir(parents=True, exist_ok=True)
    fleet_file = write_fleet(
        out / "fleet.yaml", scenario=scenario, twin={"profile": str(profile), "time_scale": time_scale, "seed": seed}
    )
    fleet = load_fleet(fleet_file)
    runtime = ExcitationRuntime(load_scenario(scenario), seed=seed, mode=mode, max_steps=max_steps)
    recording = out / "session.mcap"
    request = DeployRequest(episodes=episodes, seed=seed * 100 + 1, recording=recording, progress=False)
    link = ["--link-record", str(link_record_of(recording))]
    deploy_session(runtime, fleet, str(fleet_file), request, out, twin_extra_args=link)  # type: ignore[arg-type]
    return recording


def link_record_of(recording: Path) -> Path:
    """Where :func:`record_twin_session` keeps the twin's link record of `recording` (``--link-record``): beside the
    deployment's folder, which holds the deployment's files only."""
    return recording.parent.with_name(f"{recording.parent.name}_link.npz")


def simulate_session(
    path: Path,
    world_overrides: dict[str, Any],
    episodes: int = 2,
    steps: int = 80,
    seed: int = 0,
    scenario: str | Scenario = "obstacles",
    mode: str = "excite",
    omit: Sequence[str] = (),
    profile: str = "simulated",
    beams: int = 360,
    commands: Callable[[np.ndarray, int], np.ndarray] | None = None,
    tf_static: bool = False,
) -> Path:
    """A session recording in the deployment layout made by the simulator alone, without a network.

    Every 20 ms: the command (sent at the tick), ground truth and odometry; scans every 100 ms;
    one policy step every 100 ms. Topics whose name ends with an entry of `omit` are not written.
    With `tf_static`, a ``/tf_static`` message gives each robot's ``base_link -> laser`` (the world's mount).
    """
    from pipeline.params import world_config
    from pipeline.sim.world import SimWorld

    scen = load_scenario(scenario)
    base = {
        "control_period_s": 0.02,
        "physics_timestep_s": 0.005,
        "max_steps": 100_000,
        "lidar": {
            "beams": beams,
            "sim_beams": beams,
            "range_min_m": 0.12,
            "range_max_m": 8.0,
            "robot_radius_seen_m": 0.0,
        },
    }
    merged = {**base, **world_overrides, "lidar": {**base["lidar"], **world_overrides.get("lidar", {})}}  # type: ignore[dict-item]
    world = SimWorld(scen, world_config(merged))
    runtime = ExcitationRuntime(scen, seed=seed, mode=mode)
    geometry = ScanGeometry(beams, 0.0, 2 * math.pi / beams, 0.12, 8.0)
    builder = ObservationBuilder(scen, runtime.layout, 0.12, 5.0)
    names = scen.robot_names
    session = session_metadata(
        "real", scen.name, names, 0.1, runtime.document, profile=profile, extra={"time_scale": "1.0"}
    )
    documents = {"scenario": dumps(to_mapping(scen)), "policy": dumps(runtime.document)}
    t = 1_000_000_000
    with SessionLog(path, names, session, documents) as log:
        if tf_static:
            from pipeline.messages import convert as C
            from pipeline.messages.topics import TF_MESSAGE, QosProfile, TopicSpec

            lidar = world.world.lidar
            mount = np.array([*(lidar.mount_xy_m or (0.0, 0.0)), lidar.mount_yaw_rad])
            statics = [(f"{ns}/base_link", f"{ns}/laser", mount) for ns in names]
            spec = TopicSpec("/tf_static", TF_MESSAGE, QosProfile("reliable", "transient_local", 1))
            log.recorder.write(spec, C.tf_message(t, statics), t)

        def keep(topic: str) -> bool:
            return not any(topic.endswith(o) for o in omit)

        for episode in range(episodes):
            world.reset(seed * 1000 + episode)
            scans = world.scan()
            cmd = np.zeros((scen.n_robots, 2))
            if keep("/mrl/episode"):
                log.start_episode(t, episode, seed * 1000 + episode)
            for tick in range(steps * 5):
                if tick % 5 == 0:
                    obs = builder.build(list(scans), geometry, world.odometry.pose).obs
                    cmd = commands(world.truth, tick) if commands is not None else runtime.commands(obs)
                for i, ns in enumerate(names):
                    if keep(f"/{ns}/cmd_vel"):
                        log.cmd_vel(t, ns, float(cmd[i, 0]), float(cmd[i, 1]))
                world.step(cmd)
                vel = world.body_velocity()
                for i, ns in enumerate(names):
                    if keep(f"/{ns}/ground_truth"):
                        log.ground_truth(t, ns, world.truth[i])
                    if keep(f"/{ns}/odom"):
                        log.odom(t, ns, world.odometry.pose[i], (float(vel[i, 0]), float(vel[i, 1])))
                if tick % 5 == 0:
                    scans = world.scan()
                    for i, ns in enumerate(names):
                        if keep(f"/{ns}/scan"):
                            log.scan(t, ns, scans[i], geometry)
                t += 20_000_000
            if keep("/mrl/episode"):
                log.event(t, episode, steps, "end", detail="incomplete")
            t += 500_000_000
    return path


__all__ = ["ExcitationRuntime", "record_twin_session", "simulate_session"]
