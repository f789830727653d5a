"""The twin's robots at wheel level: MuJoCo bases with two driven wheels in contact with the floor.

Why MuJoCo with real wheel contacts rather than a kinematic model: a kinematic unicycle moves
exactly as its wheels turn, so slip, the effect of unequal wheel radii on the path, the mass a
motor has to accelerate and bumping into boxes would all have to be written as special cases.
With wheels that touch the floor through friction, they follow from the contact model: a wheel
that turns faster than the ground can carry slips, a heavier base lags its motors, a robot that
drives into a box stops. The simulator used for training (:mod:`pipeline.sim`) drives its bodies
by velocity and knows nothing of wheels; nothing here comes from it.

Each robot: a free-jointed chassis (a solid cylinder of the scenario's robot radius and height,
`mass_kg`, inertia of a solid cylinder: I_z = m r^2 / 2, I_x = I_y = m (3 r^2 + h^2) / 12), two
driven wheels (0.2 kg each, hinge joints, radii `wheel_radius_left_m` / `wheel_radius_right_m`,
`wheel_separation_m` apart) and two low-friction spherical casters, front and back. Each wheel's
motor follows a target speed through a deadband, an acceleration limit on its setpoint and a
first-order lag, then a stiff velocity servo (torque limited) turns the wheel; the floor's
sliding friction is `friction`. The room's walls and boxes stand where the profile's ``map``
puts them (boxes moved by `box_offsets_m`, walls moved outward by `wall_offset_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import mujoco
import numpy as np

from pipeline.core.scenario import SPARK_WHEEL_RADIUS_M, SPARK_WHEEL_SEPARATION_M, Scenario
from pipeline.errors import ConfigError, ConfigProblem

WHEEL_MASS_KG = 0.2
WHEEL_WIDTH_M = 0.02
CASTER_RADIUS_M = 0.015
CHASSIS_CLEARANCE_M = 0.02
SERVO_GAIN_NMS = 2.0
"""Velocity servo: torque (N m) per rad/s of wheel speed error."""
MAX_TORQUE_NM = 1.5
MOTOR_ARMATURE_KGM2 = 0.005
"""Rotor inertia seen at the wheel through the gearbox; it also keeps the stiff wheel servo stable at 2 ms steps."""
LIDAR_HEIGHT_M = 0.15
WALL_THICKNESS_M = 0.1


@dataclass(frozen=True)
class BaseParams:
    """The drive base as it really is; the defaults are the ideal nominal SPARK."""

    wheel_radius_left_m: float = SPARK_WHEEL_RADIUS_M
    wheel_radius_right_m: float = SPARK_WHEEL_RADIUS_M
    wheel_separation_m: float = SPARK_WHEEL_SEPARATION_M
    mass_kg: float = 5.0
    motor_time_constant_s: float = 0.0
    deadband_radps: float = 0.0
    max_wheel_accel_radps2: float | None = None
    friction: float = 1.0

    def problems(self) -> list[ConfigProblem]:
        bad = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("motor_time_constant_s", "deadband_radps"):
                if not value >= 0:
                    bad.append(ConfigProblem(f"base.{f.name}", value, "a number >= 0"))
            elif f.name == "max_wheel_accel_radps2":
                if value is not None and not value > 0:
                    bad.append(ConfigProblem(f"base.{f.name}", value, "a number > 0, or null for no limit"))
            elif not value > 0:
                bad.append(ConfigProblem(f"base.{f.name}", value, "a number > 0"))
        return bad


def _box_xml(name: str, x: float, y: float, yaw: float, sx: float, sy: float, h: float) -> str:
    return (
        f'<geom name="{name}" type="box" pos="{x} {y} {h / 2}" euler="0 0 {yaw}" size="{sx / 2} {sy / 2} {h / 2}" '
        'contype="2" conaffinity="2" rgba="0.6 0.5 0.4 1"/>'
    )


def _model_xml(scenario: Scenario, base: BaseParams, offsets: np.ndarray, wall_offset_m: float, dt: float) -> str:
    room = scenario.room
    parts = [
        f'<mujoco model="twin"><option timestep="{dt}" integrator="Euler" cone="elliptic"/>',
        '<default><geom solref="0.004 1" solimp="0.95 0.99 0.001"/></default>',
        "<worldbody>",
        '<geom name="floor" type="plane" size="50 50 0.1" contype="1" conaffinity="1" '
        f'friction="{base.friction} 0.005 0.0001"/>',
    ]
    x0, x1 = room.x_min_m - wall_offset_m, room.x_max_m + wall_offset_m
    y0, y1 = room.y_min_m - wall_offset_m, room.y_max_m + wall_offset_m
    t, h = WALL_THICKNESS_M, 0.5
    cx, cy, lx, ly = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0 + 2 * t, y1 - y0 + 2 * t
    parts += [
        _box_xml("wall_south", cx, y0 - t / 2, 0.0, lx, t, h),
        _box_xml("wall_north", cx, y1 + t / 2, 0.0, lx, t, h),
        _box_xml("wall_west", x0 - t / 2, cy, 0.0, t, ly, h),
        _box_xml("wall_east", x1 + t / 2, cy, 0.0, t, ly, h),
    ]
    for k, box in enumerate(scenario.obstacles):
        dx, dy = offsets[k] if k < len(offsets) else (0.0, 0.0)
        parts.append(
            _box_xml(f"box_{k}", box.x_m + dx, box.y_m + dy, box.yaw_rad, box.size_x_m, box.size_y_m, box.height_m)
        )
    if scenario.target is not None:  # a pursuit's target: moved by the twin's evader, seen and bumped into
        tg = scenario.target
        parts.append(
            f'<body name="target" mocap="true" pos="{tg.start.x_m} {tg.start.y_m} {tg.height_m / 2}">'
            f'<geom name="target" type="cylinder" size="{tg.radius_m} {tg.height_m / 2}" contype="2" conaffinity="2" '
            'rgba="0.55 0.35 0.2 1"/></body>'
        )
    r_nom = max(base.wheel_radius_left_m, base.wheel_radius_right_m)
    m = base.mass_kg
    caster_z = CASTER_RADIUS_M - r_nom
    half = base.wheel_separation_m / 2
    for i, start in enumerate(scenario.starts):
        shape = scenario.shapes[i]  # a mixed fleet's bodies differ; the wheels are the profile's
        radius, height = shape.radius_m, shape.height_m
        ixx = m * (3 * radius**2 + height**2) / 12
        izz = m * radius**2 / 2
        chassis_z = CHASSIS_CLEARANCE_M + height / 2 - r_nom
        caster_x = radius - CASTER_RADIUS_M - 0.01
        parts.append(f'<body name="robot_{i}" pos="{start[0]} {start[1]} {r_nom}" euler="0 0 {start[2]}">')
        parts.append(f'<freejoint name="free_{i}"/>')
        parts.append(
            f'<inertial pos="0 0 {chassis_z}" mass="{m}" diaginertia="{ixx} {ixx} {izz}"/>'
            f'<geom name="chassis_{i}" type="cylinder" pos="0 0 {chassis_z}" size="{radius} {height / 2}" '
            'contype="2" conaffinity="2" mass="0" rgba="0.2 0.3 0.8 1"/>'
        )
        for side, y, r in (("left", half, base.wheel_radius_left_m), ("right", -half, base.wheel_radius_right_m)):
            parts.append(
                f'<body name="wheel_{side}_{i}" pos="0 {y} {r - r_nom}">'
                f'<joint name="{side}_{i}" type="hinge" axis="0 1 0" damping="0.0005" '
                f'armature="{MOTOR_ARMATURE_KGM2}"/>'
                f'<geom type="cylinder" zaxis="0 1 0" size="{r} {WHEEL_WIDTH_M / 2}" mass="{WHEEL_MASS_KG}" '
                'contype="0" conaffinity="0" rgba="0.1 0.1 0.1 1"/>'
                f'<geom type="sphere" size="{r}" mass="0" contype="1" conaffinity="0" condim="3" '
                f'friction="{base.friction} 0 0" rgba="0 0 0 0"/>'
                "</body>"
            )
        for name, x in (("front", caster_x), ("back", -caster_x)):
            parts.append(
                f'<geom name="caster_{name}_{i}" type="sphere" pos="{x} 0 {caster_z}" size="{CASTER_RADIUS_M}" '
                'mass="0.02" contype="1" conaffinity="0" condim="1" friction="0.0 0 0" priority="1"/>'
            )
        parts.append("</body>")
    parts.append("</worldbody><actuator>")
    for i in range(scenario.n_robots):
        for side in ("left", "right"):
            parts.append(
                f'<velocity joint="{side}_{i}" kv="{SERVO_GAIN_NMS}" forcelimited="true" '
                f'forcerange="{-MAX_TORQUE_NM} {MAX_TORQUE_NM}"/>'
            )
    parts.append("</actuator></mujoco>")
    return "".join(parts)


class FleetPhysics:
    """Wheel-level physics of every robot of `scenario`; robots in scenario order."""

    def __init__(
        self,
        scenario: Scenario,
        base: BaseParams,
        box_offsets_m: np.ndarray | None = None,
        wall_offset_m: float = 0.0,
        timestep_s: float = 0.002,
        lidar_height_m: float | None = None,
    ) -> None:
        offsets = np.zeros((0, 2)) if box_offsets_m is None else np.asarray(box_offsets_m, dtype=float)
        problems = base.problems()
        if offsets.ndim != 2 or (len(offsets) and offsets.shape[1] != 2):
            problems.append(ConfigProblem("map.box_offsets_m", offsets.tolist(), "a list of [dx, dy] pairs (m)"))
        elif len(offsets) > len(scenario.obstacles):
            problems.append(
                ConfigProblem(
                    "map.box_offsets_m",
                    offsets.tolist(),
                    f"at most one offset per box of scenario {scenario.name!r} ({len(scenario.obstacles)})",
                )
            )
        if problems:
            raise ConfigError("<twin base>", problems)
        self.scenario = scenario
        self.base = base
        self.n = scenario.n_robots
        self._offsets = np.zeros((len(scenario.obstacles), 2))
        self._offsets[: len(offsets)] = offsets
        self.model = mujoco.MjModel.from_xml_string(_model_xml(scenario, base, offsets, wall_offset_m, timestep_s))
        self.data = mujoco.MjData(self.model)
        self.timestep_s = float(self.model.opt.timestep)
        self.lidar_height_m = LIDAR_HEIGHT_M if lidar_height_m is None else lidar_height_m
        m = self.model
        self._body = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"robot_{i}") for i in range(self.n)])
        free = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"free_{i}")] for i in range(self.n)]
        self._qpos = np.array(free)
        self._qvel = np.array(
            [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"free_{i}")] for i in range(self.n)]
        )
        wheel_joints = [
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"{side}_{i}") for side in ("left", "right")]
            for i in range(self.n)
        ]
        self._wheel_q = np.array([[m.jnt_qposadr[j] for j in pair] for pair in wheel_joints])
        self._wheel_v = np.array([[m.jnt_dofadr[j] for j in pair] for pair in wheel_joints])
        self._chassis = np.array(
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"chassis_{i}") for i in range(self.n)]
        )
        self._pose_index = self._qpos[:, None] + np.array([0, 1, 3, 4, 5, 6])
        self._vel_index = self._qvel[:, None] + np.array([0, 1, 5])
        self._geomid = np.zeros(1, dtype=np.int32)
        self._dist = np.zeros(1)
        self.targets = np.zeros((self.n, 2))
        self.setpoint = np.zeros((self.n, 2))
        self.motor = np.zeros((self.n, 2))
        self._angle0 = np.zeros((self.n, 2))
        self.time_s = 0.0
        self.reset(scenario.starts)

    # -- state -----------------------------------------------------------------------------

    def use_layout(self, layout: Scenario) -> None:
        """Boxes where `layout` puts them (plus the profile's offsets): the episode's layout of this scenario."""
        for k, box in enumerate(layout.obstacles):
            gid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f"box_{k}")
            self.model.geom_pos[gid, :2] = (box.x_m + self._offsets[k, 0], box.y_m + self._offsets[k, 1])
            self.model.geom_quat[gid] = (math.cos(box.yaw_rad / 2), 0.0, 0.0, math.sin(box.yaw_rad / 2))

    def reset(self, poses: np.ndarray) -> None:
        """Bases at `poses` (n, 3) at rest, settled on their wheels; motors stopped; wheel angles count from 0."""
        mujoco.mj_resetData(self.model, self.data)
        r0 = max(self.base.wheel_radius_left_m, self.base.wheel_radius_right_m)
        for i, (x, y, yaw) in enumerate(np.asarray(poses, dtype=float)):
            a = self._qpos[i]
            self.data.qpos[a : a + 3] = (x, y, r0)
            self.data.qpos[a + 3 : a + 7] = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        self.targets[:] = 0.0
        self.setpoint[:] = 0.0
        self.motor[:] = 0.0
        self.data.ctrl[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        for _ in range(int(0.05 / self.timestep_s)):  # let the bases settle on wheels and casters
            mujoco.mj_step(self.model, self.data)
        self.data.time = 0.0
        self.time_s = 0.0
        self._angle0 = self._raw_wheel_angles()

    def set_wheel_targets(self, targets_radps: np.ndarray) -> None:
        """Target angular speeds (n, 2) of the left and right wheels (rad/s)."""
        self.targets = np.array(targets_radps, dtype=float).reshape(self.n, 2)

    def _motors(self) -> None:
        b, dt = self.base, self.timestep_s
        target = np.where(np.abs(self.targets) < b.deadband_radps, 0.0, self.targets)
        if b.max_wheel_accel_radps2 is None:
            self.setpoint = target
        else:
            limit = b.max_wheel_accel_radps2 * dt
            self.setpoint = self.setpoint + np.clip(target - self.setpoint, -limit, limit)
        if b.motor_time_constant_s > 0:
            self.motor += (1.0 - math.exp(-dt / b.motor_time_constant_s)) * (self.setpoint - self.motor)
        else:
            self.motor = self.setpoint.copy()
        self.data.ctrl[:] = self.motor.reshape(-1)

    def step(self, k: int = 1) -> None:
        for _ in range(k):
            self._motors()
            mujoco.mj_step(self.model, self.data)
        self.time_s += k * self.timestep_s

    def poses(self) -> np.ndarray:
        """(n, 3) x, y (m), yaw (rad) of each base (the midpoint of its wheel axle, on the floor plane)."""
        q = self.data.qpos[self._pose_index]  # (n, 6): x, y, qw, qx, qy, qz
        w, x, y, z = q[:, 2], q[:, 3], q[:, 4], q[:, 5]
        return np.stack([q[:, 0], q[:, 1], np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))], axis=1)

    def body_velocity(self) -> np.ndarray:
        """(n, 2) forward speed (m/s) and yaw rate (rad/s) of each base."""
        v = self.data.qvel[self._vel_index]  # (n, 3): vx, vy, wz
        yaw = self.poses()[:, 2]
        return np.stack([np.cos(yaw) * v[:, 0] + np.sin(yaw) * v[:, 1], v[:, 2]], axis=1)

    def _raw_wheel_angles(self) -> np.ndarray:
        return np.array(self.data.qpos[self._wheel_q], dtype=float)

    def wheel_angles(self) -> np.ndarray:
        """(n, 2) rad each wheel turned since the last reset (forward positive)."""
        return self._raw_wheel_angles() - self._angle0

    def wheel_speeds(self) -> np.ndarray:
        return np.array(self.data.qvel[self._wheel_v], dtype=float)

    def in_collision(self) -> np.ndarray:
        """(n,) whether each chassis touches a wall, a box or another robot."""
        hit = np.zeros(self.n, dtype=bool)
        index = {int(g): i for i, g in enumerate(self._chassis)}
        for c in self.data.contact[: self.data.ncon]:
            for g in (int(c.geom1), int(c.geom2)):
                if g in index:
                    hit[index[g]] = True
        return hit

    def set_target(self, xy: np.ndarray) -> None:
        """Move a pursuit's target body to `xy` (2,)."""
        self.data.mocap_pos[0, :2] = np.asarray(xy, dtype=float)[:2]

    # -- lidar -----------------------------------------------------------------------------

    def cast(self, robot: int, origin_xy: np.ndarray, angles_rad: np.ndarray) -> np.ndarray:
        """Ranges (m) of horizontal rays at the lidar's height from `origin_xy` at world `angles_rad`,
        past robot `robot`'s own chassis; inf where nothing is hit. `last_surfaces` keeps what each ray hit (a geom
        id, -1 for nothing)."""
        angles = np.asarray(angles_rad, dtype=float).reshape(-1)
        k = len(angles)
        if k == 0:
            return np.zeros(0)
        vec = np.zeros(3 * k)
        vec[0::3] = np.cos(angles)
        vec[1::3] = np.sin(angles)
        if len(self._dist) < k:
            self._dist = np.zeros(k)
            self._geomid = np.zeros(k, dtype=np.int32)
        dist, geomid = self._dist[:k], self._geomid[:k]
        pnt = np.array([origin_xy[0], origin_xy[1], self.lidar_height_m])
        mujoco.mj_multiRay(
            self.model, self.data, pnt, vec, None, 1, int(self._body[robot]), geomid, dist, None, k, 100.0
        )
        self.last_surfaces = geomid.copy()
        return np.where(geomid >= 0, dist, np.inf)
