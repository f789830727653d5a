"""MuJoCo model of a scenario: walls, boxes and differential-drive robots.

Each robot is a cylinder on a planar base (slide x, slide y, yaw hinge, all in the world frame).
Three velocity servos act through a site at the robot's centre in its own frame: forward speed,
lateral speed (held at zero: wheels do not slide sideways) and yaw rate. Their gains set a
first-order response with the configured time constant; their force limits let walls, boxes and
other robots stop a robot through real contacts. Integration is implicit in velocity, so stiff
servos stay stable at the physics timestep.

A pursuit's target is a mocap body (moved by the evader each control step) in the static group.

Geom groups: 0 static map (walls, boxes, a pursuit's target), 1 robot bodies, 3 the optional enlarged robot volume
that only the lidar sees (no contacts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from pipeline.core.scenario import Scenario
from pipeline.params import WorldConfig

GROUP_STATIC, GROUP_ROBOT, GROUP_LIDAR_ONLY = 0, 1, 3
LATERAL_TIME_CONSTANT_S = 0.01
MAX_FORCE_N = 60.0
MAX_TORQUE_NM = 6.0
ROBOT_RGBA = ("0.85 0.2 0.2 1", "0.2 0.45 0.85 1", "0.2 0.7 0.3 1", "0.85 0.6 0.1 1", "0.6 0.3 0.8 1", "0.1 0.7 0.7 1")


@dataclass(frozen=True)
class ModelIndex:
    """Addresses in the compiled model, per robot (n_robots,)."""

    body: np.ndarray
    qpos: np.ndarray  # (n_robots, 3) addresses of x, y, yaw
    qvel: np.ndarray  # (n_robots, 3)
    ctrl: np.ndarray  # (n_robots, 3) forward, lateral, yaw actuators


def robot_mjcf(i: int, name: str, scenario: Scenario, world: WorldConfig) -> tuple[str, str]:
    """MJCF of one robot: its body and its three actuators."""
    shape = scenario.shapes[i]
    r, h = shape.radius_m, shape.height_m
    tau = world.actuation.time_constant_s
    inertia_z = 0.5 * shape.mass_kg * r * r
    rgba = ROBOT_RGBA[i % len(ROBOT_RGBA)]
    seen = world.lidar.robot_radius_seen_m
    lidar_geom = ""
    if seen > 0:
        lidar_geom = (
            f'<geom name="{name}_seen" type="cylinder" size="{max(seen, r)} {h / 2}" contype="0" '
            f'conaffinity="0" group="{GROUP_LIDAR_ONLY}" rgba="1 1 1 0.1" mass="0"/>'
        )
    return (
        f"""
    <body name="{name}" pos="0 0 {h / 2}">
      <joint name="{name}_x" type="slide" axis="1 0 0"/>
      <joint name="{name}_y" type="slide" axis="0 1 0"/>
      <joint name="{name}_yaw" type="hinge" axis="0 0 1"/>
      <geom name="{name}_body" type="cylinder" size="{r} {h / 2}" mass="{shape.mass_kg}" group="{GROUP_ROBOT}"
            rgba="{rgba}" contype="1" conaffinity="1" friction="0.3 0.005 0.0001"/>
      {lidar_geom}
      <site name="{name}_base" pos="0 0 0"/>
    </body>""",
        f"""
    <velocity name="{name}_v" site="{name}_base" gear="1 0 0 0 0 0" kv="{shape.mass_kg / tau}"
              forcelimited="true" forcerange="{-MAX_FORCE_N} {MAX_FORCE_N}"/>
    <velocity name="{name}_lateral" site="{name}_base" gear="0 1 0 0 0 0"
              kv="{shape.mass_kg / LATERAL_TIME_CONSTANT_S}" forcelimited="true"
              forcerange="{-MAX_FORCE_N} {MAX_FORCE_N}"/>
    <velocity name="{name}_w" site="{name}_base" gear="0 0 0 0 0 1" kv="{inertia_z / tau}"
              forcelimited="true" forcerange="{-MAX_TORQUE_NM} {MAX_TORQUE_NM}"/>""",
    )


def scenario_mjcf(scenario: Scenario, world: WorldConfig) -> str:
    """MJCF text of the scenario's world."""
    room = scenario.room
    t, hh = room.wall_thickness_m, room.wall_height_m / 2
    cx, cy = (room.x_min_m + room.x_max_m) / 2, (room.y_min_m + room.y_max_m) / 2
    lx, ly = (room.x_max_m - room.x_min_m) / 2 + t, (room.y_max_m - room.y_min_m) / 2 + t
    walls = [
        ("wall_south", cx, room.y_min_m - t / 2, lx, t / 2),
        ("wall_north", cx, room.y_max_m + t / 2, lx, t / 2),
        ("wall_west", room.x_min_m - t / 2, cy, t / 2, ly),
        ("wall_east", room.x_max_m + t / 2, cy, t / 2, ly),
    ]
    static = [
        f'<geom name="{n}" type="box" pos="{x} {y} {hh}" size="{sx} {sy} {hh}" group="{GROUP_STATIC}" '
        f'rgba="0.5 0.5 0.5 1"/>'
        for n, x, y, sx, sy in walls
    ]
    for k, box in enumerate(scenario.obstacles):
        static.append(
            f'<geom name="box_{k}" type="box" pos="{box.x_m} {box.y_m} {box.height_m / 2}" '
            f'euler="0 0 {box.yaw_rad}" size="{box.size_x_m / 2} {box.size_y_m / 2} {box.height_m / 2}" '
            f'group="{GROUP_STATIC}" rgba="0.9 0.5 0.1 1"/>'
        )
    if scenario.target is not None:  # a mocap body the evader moves; lidars see it, robots bump into it
        tg = scenario.target
        static.append(
            f'<body name="target" mocap="true" pos="{tg.start.x_m} {tg.start.y_m} {tg.height_m / 2}">'
            f'<geom name="target" type="cylinder" size="{tg.radius_m} {tg.height_m / 2}" group="{GROUP_STATIC}" '
            f'rgba="0.55 0.35 0.2 1"/></body>'
        )
    bodies, actuators = zip(
        *(robot_mjcf(i, n, scenario, world) for i, n in enumerate(scenario.robot_names)), strict=True
    )
    return f"""<mujoco model="{scenario.name}">
  <compiler angle="radian"/>
  <option timestep="{world.physics_timestep_s}" integrator="implicitfast" gravity="0 0 0">
    <flag gravity="disable"/>
  </option>
  <worldbody>
    {"".join(static)}
    {"".join(bodies)}
  </worldbody>
  <actuator>{"".join(actuators)}
  </actuator>
</mujoco>"""


def build_model(scenario: Scenario, world: WorldConfig) -> tuple[mujoco.MjModel, ModelIndex]:
    """Compile the scenario into a MuJoCo model and the per-robot addresses."""
    model = mujoco.MjModel.from_xml_string(scenario_mjcf(scenario, world))
    names = scenario.robot_names
    body = np.array([model.body(n).id for n in names])
    joints = [[model.joint(f"{n}_{j}") for j in ("x", "y", "yaw")] for n in names]
    qpos = np.array([[int(j.qposadr[0]) for j in js] for js in joints])
    qvel = np.array([[int(j.dofadr[0]) for j in js] for js in joints])
    ctrl = np.array([[model.actuator(f"{n}_{a}").id for a in ("v", "lateral", "w")] for n in names])
    return model, ModelIndex(body=body, qpos=qpos, qvel=qvel, ctrl=ctrl)


def lidar_directions(n_beams: int) -> np.ndarray:
    """(n_beams, 2) unit vectors in the robot frame, beam k at 2 pi k / n_beams."""
    a = 2 * math.pi * np.arange(n_beams) / n_beams
    return np.stack([np.cos(a), np.sin(a)], axis=1)
