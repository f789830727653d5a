"""The simulated world: MuJoCo physics, lidar by mj_multiRay, odometry and ground truth."""

from __future__ import annotations

import math
from collections import deque

import mujoco
import numpy as np

from pipeline.core.evader import Evader
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import Scenario
from pipeline.params import WorldConfig
from pipeline.sim.model import GROUP_LIDAR_ONLY, GROUP_ROBOT, GROUP_STATIC, build_model, lidar_directions
from pipeline.sim.noise import OdometryDrift, RealLidar, beam_factors, noisy_ranges


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return np.asarray((a + np.pi) % (2 * np.pi) - np.pi)


def deadband_body(target: np.ndarray, separation_m: float, deadband_mps: float) -> np.ndarray:
    """Body velocities (n, 2) (v m/s, w rad/s) that the wheels deliver of targets (n, 2): each wheel's rim speed by
    the geometry (`separation_m` between the wheels), zero where it is under `deadband_mps` (the motors do not turn
    under the deadband)."""
    half = separation_m / 2
    wheels = np.stack([target[:, 0] - half * target[:, 1], target[:, 0] + half * target[:, 1]], axis=1)
    wheels[np.abs(wheels) < deadband_mps] = 0.0
    return np.stack([wheels.mean(axis=1), (wheels[:, 1] - wheels[:, 0]) / (2 * half)], axis=1)


class SimWorld:
    """N differential-drive robots in a scenario, stepped one control period at a time.

    Commands are (n_robots, 2) (v m/s, w rad/s). All randomness (lidar noise, odometry errors, the
    draws of domain randomization) comes from one generator seeded at reset, so a seed fixes a
    rollout to the bit. With ``world.randomize`` ranges, each episode runs in its own world: the
    ranged keys are drawn at reset (`world`, `draws`), in the ranges' fixed order.
    """

    def __init__(self, scenario: Scenario, world: WorldConfig) -> None:
        self.scenario = scenario
        self.base_world = world
        self._ranges = world.randomize.ranges()
        self.draws: dict[str, float] = {}
        self.world = world
        self.model, self.index = build_model(scenario, world)
        self.data = mujoco.MjData(self.model)
        self.n = scenario.n_robots
        lidar = world.lidar
        # the layout as a LaserScan carries it (float32), so a recorded scan reduces exactly the same way
        f32 = np.float32
        self.scan_geometry = ScanGeometry(
            lidar.sim_beams,
            0.0,
            float(f32(2 * math.pi / lidar.sim_beams)),
            float(f32(lidar.range_min_m)),
            float(f32(lidar.range_max_m)),
        )
        self._dirs = lidar_directions(lidar.sim_beams)
        self._beam_dirs = np.zeros((self.n, lidar.sim_beams, 3))  # every robot's ray directions, z stays 0
        self._pnt = np.zeros(3)
        self._geomid = np.zeros(lidar.sim_beams, dtype=np.int32)
        self._dist = np.zeros(lidar.sim_beams)
        group = np.zeros(6, dtype=np.uint8)
        group[GROUP_STATIC] = 1
        if lidar.robot_radius_seen_m > 0:
            group[GROUP_LIDAR_ONLY] = 1
        else:
            group[GROUP_ROBOT] = 1
        self._geomgroup = group
        self._ctrl_v = self.index.ctrl[:, 0]
        self._ctrl_w = self.index.ctrl[:, 2]
        self._qpos = self.index.qpos
        self._kv = (
            self.model.actuator_gainprm[self._ctrl_v, 0].copy(),
            self.model.actuator_gainprm[self._ctrl_w, 0].copy(),
        )
        self.odometry = OdometryDrift(world.odometry.drift_per_m, world.actuation.yaw_rate_per_mps)
        self._real_lidar: RealLidar | None = None
        self.surfaces = np.zeros((0, 0), dtype=np.int32)
        """(n_robots, sim_beams) what each ray of the last `true_ranges` hit (a geom id, -1 for nothing)."""
        self._use(world)
        self.rng = np.random.default_rng(0)
        self._pending: deque[tuple[int, np.ndarray]] = deque()
        self._substep = 0
        self.truth = scenario.starts.copy()
        self.evader = Evader(scenario) if scenario.target is not None else None
        """A pursuit's target, stepped once per control period after the robots."""

    @property
    def time_s(self) -> float:
        return float(self.data.time)

    def use_layout(self, layout: Scenario) -> None:
        """Move the boxes to `layout`'s and start the robots at its starts from the next reset (the same room,
        robots and box sizes: a layout drawn from this world's scenario)."""
        for k, box in enumerate(layout.obstacles):
            gid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f"box_{k}")
            self.model.geom_pos[gid, :2] = (box.x_m, box.y_m)
            self.model.geom_quat[gid] = (math.cos(box.yaw_rad / 2), 0.0, 0.0, math.sin(box.yaw_rad / 2))
        self.scenario = layout

    def _use(self, world: WorldConfig) -> None:
        """Take the dynamics and sensor settings of `world` (the episode's draw)."""
        self.world = world
        act = world.actuation
        self.mount_yaw_rad = world.lidar.mount_yaw_rad
        self._gain = np.array([act.linear_gain, act.angular_gain])
        self._wheels = act.deadband_radps > 0
        self.odometry.drift_per_m = world.odometry.drift_per_m
        self.odometry.unseen_yaw_per_m = act.yaw_rate_per_mps  # the encoders count the wheels' arc as straight
        if world.actuation.time_constant_s != self.base_world.actuation.time_constant_s or self._ranges:
            scale = self.base_world.actuation.time_constant_s / act.time_constant_s
            for ids, kv in zip((self._ctrl_v, self._ctrl_w), self._kv, strict=True):
                self.model.actuator_gainprm[ids, 0] = kv * scale
                self.model.actuator_biasprm[ids, 2] = -kv * scale

    def _draw(self) -> None:
        """Draw the randomized keys of this episode from the generator, in the ranges' order."""
        self.draws = {key: float(self.rng.uniform(low, high)) for key, (low, high) in self._ranges.items()}
        self._use(self.base_world.with_values(self.draws))

    def reset(self, seed: int | None = None, starts: np.ndarray | None = None) -> None:
        """Place every robot at its start (or at `starts`, (n, 3)), at rest; reseed the noise when `seed` is given.

        With randomization on, the episode's draws come first from the (reseeded) generator.
        """
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        if self._ranges:
            self._draw()
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._qpos] = self.scenario.starts if starts is None else starts
        if self.evader is not None:
            self.evader.reset(self.scenario)  # the episode's layout: its target start and boxes
            self._place_target()
        mujoco.mj_forward(self.model, self.data)
        self._pending.clear()
        self._substep = 0
        self.truth = self.read_truth()
        self.odometry.reset(self.truth, self.rng)
        lidar = self.world.lidar
        self._real_lidar = None
        real = lidar.range_step_m > 0 or lidar.beam_noise_spread > 0 or lidar.mixed_pixel_prob > 0
        if real or lidar.no_return != "inf":
            no_return = {"inf": math.inf, "zero": 0.0, "max": lidar.range_max_m, "nan": math.nan}[lidar.no_return]
            factor = beam_factors(lidar.beam_noise_spread, (self.n, lidar.sim_beams), self.rng)
            self._real_lidar = RealLidar(lidar.range_step_m, factor, lidar.mixed_pixel_prob, no_return)

    def read_truth(self) -> np.ndarray:
        """(n_robots, 3) ground-truth x, y (m), yaw (rad) in [-pi, pi)."""
        pose = self.data.qpos[self._qpos]
        pose[:, 2] = wrap_angle(pose[:, 2])
        return np.asarray(pose)

    def _apply(self, cmd: np.ndarray) -> None:
        target = cmd * self._gain
        act = self.world.actuation
        for c, limit in enumerate((act.max_linear_mps, act.max_angular_radps)):
            if limit is not None:
                target[:, c] = np.clip(target[:, c], -limit, limit)
        if self._wheels:
            target = deadband_body(target, act.wheel_separation_m, act.deadband_radps * act.wheel_radius_m)
        if act.yaw_rate_per_mps != 0.0:
            target = target.copy()
            target[:, 1] += act.yaw_rate_per_mps * target[:, 0]
        self.data.ctrl[self._ctrl_v] = target[:, 0]
        self.data.ctrl[self._ctrl_w] = target[:, 1]

    def step(self, cmd: np.ndarray) -> None:
        """Run one control period with commands (n_robots, 2) (v m/s, w rad/s)."""
        substeps = self.world.substeps
        delay = self.world.delay_substeps
        if delay == 0:
            self._apply(cmd)
            mujoco.mj_step(self.model, self.data, nstep=substeps)
        else:
            self._pending.append((self._substep + delay, np.array(cmd, dtype=np.float64)))
            end = self._substep + substeps
            now = self._substep
            while now < end:
                while self._pending and self._pending[0][0] <= now:
                    self._apply(self._pending.popleft()[1])
                nxt = min(end, self._pending[0][0]) if self._pending else end
                mujoco.mj_step(self.model, self.data, nstep=nxt - now)
                now = nxt
        self._substep += substeps
        prev = self.truth
        self.truth = self.read_truth()  # from qpos: no kinematics needed
        if self.evader is not None:  # the target moves before the one kinematics pass the scans read
            self.evader.step(self.world.control_period_s, self.truth)
            self._place_target()
        mujoco.mj_kinematics(self.model, self.data)
        self.odometry.update(prev, self.truth)

    def _place_target(self) -> None:
        """Move the target's mocap body to the evader (positions follow at the next kinematics pass)."""
        if self.evader is not None:
            self.data.mocap_pos[0, :2] = self.evader.xy

    @property
    def target_xy(self) -> np.ndarray | None:
        """A pursuit's target position (2,), None otherwise."""
        return None if self.evader is None else self.evader.xy.copy()

    def body_velocity(self) -> np.ndarray:
        """(n_robots, 2) true forward speed (m/s) and yaw rate (rad/s) in each robot's frame."""
        qvel = self.data.qvel[self.index.qvel]
        yaw = self.truth[:, 2]
        forward = np.cos(yaw) * qvel[:, 0] + np.sin(yaw) * qvel[:, 1]
        return np.stack([forward, qvel[:, 2]], axis=1)

    def true_ranges(self) -> np.ndarray:
        """(n_robots, sim_beams) exact ranges (m) to the nearest visible geom; +inf where none within range_max."""
        lidar = self.world.lidar
        out = np.empty((self.n, lidar.sim_beams))
        if self.surfaces.shape != out.shape:
            self.surfaces = np.zeros(out.shape, dtype=np.int32)
        dx, dy = lidar.mount_xy_m
        # every robot's beam directions in one pass (the same products as one robot at a time: cos and sin from math)
        yaws = [float(yaw) + self.mount_yaw_rad for yaw in self.truth[:, 2]]
        cs = np.array([[math.cos(yaw), math.sin(yaw)] for yaw in yaws])
        c, s = cs[:, 0, None], cs[:, 1, None]
        beam_dirs = self._beam_dirs
        beam_dirs[:, :, 0] = c * self._dirs[None, :, 0] - s * self._dirs[None, :, 1]
        beam_dirs[:, :, 1] = s * self._dirs[None, :, 0] + c * self._dirs[None, :, 1]
        vecs = beam_dirs.reshape(self.n, -1)
        for i in range(self.n):
            x, y, yaw = self.truth[i]
            if dx != 0.0 or dy != 0.0:
                cb, sb = math.cos(yaw), math.sin(yaw)
                x, y = x + cb * dx - sb * dy, y + sb * dx + cb * dy
            self._pnt[:] = (x, y, lidar.height_m)
            mujoco.mj_multiRay(
                self.model,
                self.data,
                self._pnt,
                vecs[i],
                self._geomgroup,
                1,
                int(self.index.body[i]),
                self._geomid,
                self._dist,
                None,
                lidar.sim_beams,
                lidar.range_max_m,
            )
            out[i] = self._dist
            self.surfaces[i] = self._geomid
        out[(out < 0) | (out > self.world.lidar.range_max_m)] = np.inf
        return out

    def scan(self) -> np.ndarray:
        """(n_robots, sim_beams) measured ranges (m) with the configured noise; LaserScan-shaped.

        Values are rounded to float32, as a LaserScan carries them, so a recorded scan rebuilds the
        very observation the simulator gave the policy.
        """
        lidar = self.world.lidar
        noisy = noisy_ranges(
            self.true_ranges(),
            self.rng,
            lidar.noise_sigma_m,
            lidar.dropout_prob,
            lidar.bias_m,
            lidar.noise_per_m,
            self._real_lidar,
            self.surfaces,
        )
        return noisy.astype(np.float32).astype(np.float64)
