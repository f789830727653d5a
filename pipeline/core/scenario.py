"""Scenarios as data: the room, the robots' starts and goals, and the obstacles.

A scenario is a YAML file (bundled ones live in ``pipeline/core/scenarios/``); users add rooms,
robots or obstacles by writing a new file, no code. Both worlds read the same map: the
simulator builds its MuJoCo model from it, the episode judge checks goals and collisions
against it, on the twin and on robots alike.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np

from pipeline.core.errors import ScenarioError
from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, read_yaml, setting


@dataclass(frozen=True)
class Room:
    """Axis-aligned room; walls stand on its edges (metres)."""

    x_min_m: float = setting()
    x_max_m: float = setting()
    y_min_m: float = setting()
    y_max_m: float = setting()
    wall_thickness_m: float = setting(0.1, gt=0.0)
    wall_height_m: float = setting(0.5, gt=0.0)

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        if not self.x_max_m > self.x_min_m:
            bad.append(("x_max_m", self.x_max_m, f"a value > x_min_m ({self.x_min_m})"))
        if not self.y_max_m > self.y_min_m:
            bad.append(("y_max_m", self.y_max_m, f"a value > y_min_m ({self.y_min_m})"))
        return bad


SPARK_WHEEL_RADIUS_M = 0.034
SPARK_WHEEL_SEPARATION_M = 0.281
"""The SPARK's wheel geometry (wheel diameter 0.068 m), the one place it is written: the simulator's wheel model, the
twin's ideal base, the robots' drivers (odometry integrates encoder ticks with it) and calibration take it from here."""


@dataclass(frozen=True)
class RobotShape:
    """The robot body, shared by every robot of a scenario (SPARK by default)."""

    radius_m: float = setting(0.165, gt=0.0)
    height_m: float = setting(0.2, gt=0.0)
    mass_kg: float = setting(5.0, gt=0.0)
    wheel_separation_m: float = setting(SPARK_WHEEL_SEPARATION_M, gt=0.0)
    wheel_diameter_m: float = setting(2 * SPARK_WHEEL_RADIUS_M, gt=0.0)


@dataclass(frozen=True)
class Pose2D:
    x_m: float = setting()
    y_m: float = setting()
    yaw_rad: float = setting(0.0)


@dataclass(frozen=True)
class Point2D:
    x_m: float = setting()
    y_m: float = setting()


@dataclass(frozen=True)
class RobotSpec:
    """Where a robot starts and the centre of its goal square (none in a pursuit: the target is the goal)."""

    start: Pose2D = setting()
    goal: Point2D | None = setting(None, optional=True)
    shape: RobotShape | None = setting(None, optional=True)
    """This robot's body when it differs from the scenario's `robot` (a mixed fleet)."""
    v_max_mps: float | None = setting(None, gt=0.0, le=10.0, optional=True)
    """This robot's speed limit when it differs from params.yaml's world.actions (a mixed fleet)."""
    w_max_radps: float | None = setting(None, gt=0.0, le=50.0, optional=True)


@dataclass(frozen=True)
class Target:
    """The pursuit task's moving target (a quadruped in the reference paper), driven by the scripted evader of
    :mod:`pipeline.core.evader`: it flees the nearest pursuer closer than `flee_distance_m` at up to
    `speed_mps`, stays `radius_m` plus `clearance_m` off walls and boxes, and is caught when any robot's centre
    comes within `capture_distance_m` of its own."""

    start: Point2D = setting()
    radius_m: float = setting(0.25, gt=0.0, le=2.0, optional=True)
    height_m: float = setting(0.4, gt=0.0, optional=True)
    speed_mps: float = setting(0.2, ge=0.0, le=5.0, optional=True)
    flee_distance_m: float = setting(2.0, gt=0.0, optional=True)
    capture_distance_m: float = setting(0.6, gt=0.0, optional=True)
    clearance_m: float = setting(0.1, ge=0.0, optional=True)


def _unplaced(target: Target | None) -> Target | None:
    """`target` without its start (its body, speed and evasion alone)."""
    return None if target is None else dataclasses.replace(target, start=Point2D(0.0, 0.0))


@dataclass(frozen=True)
class Box:
    """An obstacle: a box centred at (x, y) with full sizes along its own axes."""

    kind: Literal["box"] = setting()
    x_m: float = setting()
    y_m: float = setting()
    size_x_m: float = setting(gt=0.0)
    size_y_m: float = setting(gt=0.0)
    height_m: float = setting(0.4, gt=0.0)
    yaw_rad: float = setting(0.0)


Range = tuple[float, ...]
"""[low, high] of a uniform draw."""


@dataclass(frozen=True)
class LayoutRanges:
    """Per-episode layouts (:mod:`pipeline.core.layouts`): each episode draws every robot's start pose and goal
    and every box's centre (and yaw) uniformly from these ranges (metres, radians), seeded by the episode's
    seed; boxes keep their sizes. A draw keeps `clearance_m` of free space between bodies, walls and goal
    squares and each goal at least `min_goal_distance_m` from its robot's start; a scenario whose ranges give
    no such layout in `tries` draws is refused with the reason. In a pursuit the goal ranges draw the target's
    start, which each robot's start keeps `min_goal_distance_m` from."""

    start_x_m: Range = setting(min_len=2, max_len=2)
    start_y_m: Range = setting(min_len=2, max_len=2)
    goal_x_m: Range = setting(min_len=2, max_len=2)
    goal_y_m: Range = setting(min_len=2, max_len=2)
    start_yaw_rad: Range = setting((-math.pi, math.pi), min_len=2, max_len=2, optional=True)
    box_x_m: Range = setting((0.0, 0.0), min_len=2, max_len=2, optional=True)
    box_y_m: Range = setting((0.0, 0.0), min_len=2, max_len=2, optional=True)
    box_yaw_rad: Range = setting((0.0, 0.0), min_len=2, max_len=2, optional=True)
    move_boxes: bool = setting(True, optional=True)
    """False: the boxes stay where `obstacles` puts them (box ranges unused)."""
    min_goal_distance_m: float = setting(1.0, ge=0.0, optional=True)
    box_in_way_share: float = setting(0.0, ge=0.0, le=1.0, optional=True)
    """Each box lands on a robot's straight way from its start to its goal with this probability (0: boxes
    anywhere in their ranges)."""
    box_in_way_offset_m: float = setting(0.15, ge=0.0, le=2.0, optional=True)
    """How far to either side of that straight way such a box may stand."""
    clearance_m: float = setting(0.1, ge=0.0, optional=True)
    tries: int = setting(1000, ge=1, le=1_000_000, optional=True)

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, tuple) and len(value) == 2 and not value[0] <= value[1]:
                bad.append((f.name, list(value), "[low, high] with low <= high"))
        return bad


@dataclass(frozen=True)
class Scenario:
    """A room, its robots (named robot_1..N in order) and obstacles (and, optionally, ranges that draw another
    layout of them per episode)."""

    name: str = setting()
    room: Room = setting()
    robot: RobotShape = setting()
    robots: tuple[RobotSpec, ...] = setting(min_len=1)
    goal_size_m: float = setting(0.4, gt=0.0)
    obstacles: tuple[Box, ...] = setting(())
    layouts: LayoutRanges | None = setting(None, optional=True)
    """Ranges for a layout per episode; None: every episode uses the layout above."""
    target: Target | None = setting(None, optional=True)
    """The pursuit task: the robots chase this target instead of driving to goals."""

    @property
    def pursuit(self) -> bool:
        return self.target is not None

    @property
    def n_robots(self) -> int:
        return len(self.robots)

    @cached_property
    def shapes(self) -> tuple[RobotShape, ...]:
        """Each robot's body (its own `shape`, else the scenario's `robot`)."""
        return tuple(r.shape if r.shape is not None else self.robot for r in self.robots)

    @cached_property
    def radii(self) -> np.ndarray:
        """(n_robots,) body radii (m)."""
        return np.array([s.radius_m for s in self.shapes])

    @property
    def mixed(self) -> bool:
        """Robots with bodies or speed limits of their own."""
        return any(r.shape is not None or r.v_max_mps is not None or r.w_max_radps is not None for r in self.robots)

    def speed_limits(self, v_max_mps: float, w_max_radps: float) -> np.ndarray:
        """(n_robots, 2) each robot's (v_max m/s, w_max rad/s): its own, else the given ones."""
        return np.array(
            [
                [
                    r.v_max_mps if r.v_max_mps is not None else v_max_mps,
                    r.w_max_radps if r.w_max_radps is not None else w_max_radps,
                ]
                for r in self.robots
            ]
        )

    @property
    def robot_names(self) -> tuple[str, ...]:
        return tuple(f"robot_{i + 1}" for i in range(self.n_robots))

    @cached_property
    def starts(self) -> np.ndarray:
        """(n_robots, 3) start poses x, y (m), yaw (rad)."""
        return np.array([[r.start.x_m, r.start.y_m, r.start.yaw_rad] for r in self.robots])

    @cached_property
    def goals(self) -> np.ndarray:
        """(n_robots, 2) goal square centres (m); in a pursuit, the target's start for every robot."""
        if self.target is not None:
            return np.tile([self.target.start.x_m, self.target.start.y_m], (self.n_robots, 1))
        return np.array([[r.goal.x_m, r.goal.y_m] for r in self.robots])  # type: ignore[union-attr]

    @property
    def diagonal_m(self) -> float:
        return math.hypot(self.room.x_max_m - self.room.x_min_m, self.room.y_max_m - self.room.y_min_m)

    def beyond_layout(self, other: Scenario) -> list[str]:
        """What in `other` is more than another layout of this room and robots, one line each; [] when the two
        differ at most in their name, starts, goals, box poses and layouts ranges (a policy that learned to
        drive in any layout of this room meets nothing new there)."""
        out = []
        for key in ("room", "robot", "goal_size_m"):
            if getattr(self, key) != getattr(other, key):
                out.append(f"{key} differs")
        if _unplaced(self.target) != _unplaced(other.target):  # where the target starts is part of the layout
            out.append("target differs")
        if self.n_robots != other.n_robots:
            out.append(f"{self.n_robots} robots vs {other.n_robots}")
        else:
            for name, mine, theirs in zip(self.robot_names, self.robots, other.robots, strict=True):
                limits = (mine.shape, mine.v_max_mps, mine.w_max_radps)
                if limits != (theirs.shape, theirs.v_max_mps, theirs.w_max_radps):
                    out.append(f"{name}'s body or speed limits differ")
        sizes = [(b.kind, b.size_x_m, b.size_y_m, b.height_m) for b in self.obstacles]
        if sizes != [(b.kind, b.size_x_m, b.size_y_m, b.height_m) for b in other.obstacles]:
            out.append(f"other obstacles ({len(self.obstacles)} vs {len(other.obstacles)}, or other sizes)")
        return out

    def with_robots(self, n: int) -> Scenario:
        """The same scenario with only its first `n` robots."""
        if not 1 <= n <= self.n_robots:
            raise ScenarioError(self.name, f"n_robots = {n}: this scenario defines 1 to {self.n_robots} robots")
        return dataclasses.replace(self, robots=self.robots[:n])

    def validate(self, source: str = "") -> None:
        """Raise ScenarioError for geometry that cannot be simulated or in which the team cannot succeed.

        `source` (the scenario file) is named in the message.
        """
        try:
            self._check_geometry()
        except ScenarioError as exc:
            if source:
                raise ScenarioError(exc.scenario, f"{exc.problem} (scenario file {source})") from None
            raise

    def _check_geometry(self) -> None:
        room = self.room
        half = self.goal_size_m / 2
        missing = [n for n, spec in zip(self.robot_names, self.robots, strict=True) if spec.goal is None]
        if self.target is None and missing:
            raise ScenarioError(
                self.name, f"{', '.join(missing)} has no goal (only a pursuit scenario, with a target, leaves them out)"
            )
        if self.target is not None:
            if self.layouts is not None and self.layouts.box_in_way_share > 0:
                raise ScenarioError(
                    self.name,
                    f"layouts.box_in_way_share is {self.layouts.box_in_way_share:g}: a pursuit scenario must leave "
                    "it at 0 (boxes go on the way to goals, and a pursuit has none)",
                )
            self._check_target()
        for name, spec, r in zip(self.robot_names, self.robots, self.radii, strict=True):
            s, g = spec.start, spec.goal if spec.goal is not None else Point2D(*self.goals[0])
            if not (room.x_min_m + r <= s.x_m <= room.x_max_m - r and room.y_min_m + r <= s.y_m <= room.y_max_m - r):
                raise ScenarioError(
                    self.name,
                    f"{name} starts at ({s.x_m}, {s.y_m}), outside the room or inside a wall "
                    f"(allowed: x in [{room.x_min_m + r}, {room.x_max_m - r}], "
                    f"y in [{room.y_min_m + r}, {room.y_max_m - r}])",
                )
            if not (
                room.x_min_m <= g.x_m - half
                and g.x_m + half <= room.x_max_m
                and room.y_min_m <= g.y_m - half
                and g.y_m + half <= room.y_max_m
            ):
                raise ScenarioError(
                    self.name,
                    f"the goal of {name} at ({g.x_m}, {g.y_m}) does not lie inside the room "
                    f"x in [{room.x_min_m}, {room.x_max_m}], y in [{room.y_min_m}, {room.y_max_m}]",
                )
            for k, box in enumerate(self.obstacles):
                if box_clearance(box, np.array([[s.x_m, s.y_m]]))[0] < r:
                    raise ScenarioError(
                        self.name,
                        f"{name} starts at ({s.x_m}, {s.y_m}), inside or touching obstacle {k} "
                        f"(box at ({box.x_m}, {box.y_m}))",
                    )
        starts = self.starts[:, :2]
        for i in range(self.n_robots):
            for j in range(i + 1, self.n_robots):
                d = float(np.hypot(*(starts[i] - starts[j])))
                reach = float(self.radii[i] + self.radii[j])
                if d < reach:
                    raise ScenarioError(
                        self.name,
                        f"robot_{i + 1} and robot_{j + 1} start {d:.3f} m apart, "
                        f"closer than their two radii ({reach:.3f} m): their bodies overlap",
                    )
        if self.target is None:
            self._check_goals_apart()
        for k, box in enumerate(self.obstacles):
            corners = box_corners(box)
            if (
                corners[:, 0].min() < room.x_min_m
                or corners[:, 0].max() > room.x_max_m
                or corners[:, 1].min() < room.y_min_m
                or corners[:, 1].max() > room.y_max_m
            ):
                raise ScenarioError(self.name, f"obstacle {k} at ({box.x_m}, {box.y_m}) reaches outside the room")

    def _check_target(self) -> None:
        t = self.target
        if t is None:
            return
        room, p = self.room, np.array([[t.start.x_m, t.start.y_m]])
        keep = t.radius_m + t.clearance_m
        if not (
            room.x_min_m + keep <= p[0, 0] <= room.x_max_m - keep
            and room.y_min_m + keep <= p[0, 1] <= room.y_max_m - keep
        ):
            raise ScenarioError(self.name, f"the target starts at ({p[0, 0]}, {p[0, 1]}), within {keep:g} m of a wall")
        for k, box in enumerate(self.obstacles):
            if box_clearance(box, p)[0] < keep:
                raise ScenarioError(self.name, f"the target starts within {keep:g} m of obstacle {k}")
        d = np.hypot(*(self.starts[:, :2] - p).T)
        if d.min() <= t.capture_distance_m:
            raise ScenarioError(
                self.name,
                f"robot_{int(d.argmin()) + 1} starts {d.min():.2f} m from the target: caught before it moves "
                f"(capture_distance_m {t.capture_distance_m:g})",
            )

    def _check_goals_apart(self) -> None:
        """Refuse goal squares that overlap, or that are too close for two robots to stand one in each.

        A robot is in its goal when its centre is inside its square, and it stops there; the team
        succeeds when every robot has arrived. A robot in a shared part of two squares would be in
        another's goal too, and two squares whose farthest points are closer than two robot radii
        cannot hold both robots at once.
        """
        size = self.goal_size_m
        goals = self.goals
        for i in range(self.n_robots):
            for j in range(i + 1, self.n_robots):
                reach = float(self.radii[i] + self.radii[j])
                dx, dy = (float(v) for v in np.abs(goals[i] - goals[j]))
                both = (
                    f"the goal squares of robot_{i + 1} at ({goals[i][0]:g}, {goals[i][1]:g}) and "
                    f"robot_{j + 1} at ({goals[j][0]:g}, {goals[j][1]:g})"
                )
                if dx < size - 1e-9 and dy < size - 1e-9:
                    raise ScenarioError(
                        self.name,
                        f"{both} overlap: with goal_size_m {size:g} their centres must be at least {size:g} m "
                        f"apart in x or in y (they are {dx:.3g} m and {dy:.3g} m apart)",
                    )
                farthest = math.hypot(dx + size, dy + size)
                if farthest < reach:
                    raise ScenarioError(
                        self.name,
                        f"{both} are too close for both robots to stand in them at once: their farthest points "
                        f"are {farthest:.3f} m apart, less than two robot radii ({reach:.3f} m)",
                    )


def box_corners(box: Box) -> np.ndarray:
    """(4, 2) corners of a box in the world frame (m)."""
    c, s = math.cos(box.yaw_rad), math.sin(box.yaw_rad)
    hx, hy = box.size_x_m / 2, box.size_y_m / 2
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return np.asarray(local @ np.array([[c, s], [-s, c]]) + np.array([box.x_m, box.y_m]))


def box_table(boxes: Sequence[Box]) -> np.ndarray:
    """(k, 6) per box: centre x, y (m), cos and sin of its yaw, half sizes (m); what :func:`boxes_clearance` takes."""
    rows = [[b.x_m, b.y_m, math.cos(b.yaw_rad), math.sin(b.yaw_rad), b.size_x_m / 2, b.size_y_m / 2] for b in boxes]
    return np.array(rows, dtype=np.float64).reshape(-1, 6)


def boxes_clearance(table: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, k) distance (m) from each of `points` (n, 2) to each box surface of `table` (:func:`box_table`); 0 inside."""
    d0 = points[:, 0, None] - table[None, :, 0]
    d1 = points[:, 1, None] - table[None, :, 1]
    c, s = table[None, :, 2], table[None, :, 3]
    ex = np.maximum(np.abs(c * d0 + s * d1) - table[None, :, 4], 0.0)
    ey = np.maximum(np.abs(-s * d0 + c * d1) - table[None, :, 5], 0.0)
    return np.asarray(np.hypot(ex, ey))


def box_clearance(box: Box, points: np.ndarray) -> np.ndarray:
    """Distance (m) from each of `points` (n, 2) to the box surface; 0 inside."""
    return boxes_clearance(box_table((box,)), np.asarray(points, dtype=np.float64))[:, 0]


def bundled_scenarios() -> tuple[str, ...]:
    """Names of the scenarios shipped with the package."""
    folder = resources.files("pipeline.core") / "scenarios"
    return tuple(sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml")))


def load_scenario(spec: str | Path | Scenario | dict[str, Any], n_robots: int | None = None) -> Scenario:
    """A validated scenario from a bundled name, a YAML path, a mapping or a Scenario.

    `n_robots` keeps the first n robots of the scenario.
    """
    source = ""
    if isinstance(spec, Scenario):
        scenario = spec
    elif isinstance(spec, dict):
        scenario = from_mapping(Scenario, spec, "<scenario mapping>")
    else:
        text = str(spec)
        if text in bundled_scenarios():
            ref = resources.files("pipeline.core") / "scenarios" / f"{text}.yaml"
            with resources.as_file(ref) as path:
                scenario = from_mapping(Scenario, read_yaml(path), str(path))
                source = str(path)
        elif text.endswith((".yaml", ".yml")) or Path(text).exists():
            scenario = from_mapping(Scenario, read_yaml(text), text)
            source = text
        else:
            raise ConfigError(
                "<scenario>",
                [
                    ConfigProblem(
                        "scenario",
                        text,
                        "a bundled scenario ("
                        + ", ".join(bundled_scenarios())
                        + ") or the path of a scenario YAML file",
                    )
                ],
            )
    if n_robots is not None:
        scenario = scenario.with_robots(n_robots)
    scenario.validate(source)
    if scenario.layouts is not None:
        from pipeline.core.layouts import draw_layout  # (it builds on this module)

        try:
            draw_layout(scenario, 0)  # a scenario whose ranges hold no valid layout is refused now
        except ScenarioError as exc:
            raise ScenarioError(
                exc.scenario, f"{exc.problem}" + (f" (scenario file {source})" if source else "")
            ) from None
    return scenario


def perturbed_starts(
    scenario: Scenario,
    rng: np.random.Generator,
    xy_m: float,
    yaw_rad: float,
    clearance_m: float = 0.05,
    tries: int = 50,
) -> np.ndarray:
    """(n_robots, 3) start poses moved by up to `xy_m` and turned by up to `yaw_rad`, uniformly.

    Each robot keeps `clearance_m` from walls, boxes, other robots and its own goal square; a
    draw that cannot be placed after `tries` attempts keeps the scenario's start.
    """
    starts = scenario.starts.copy()
    if xy_m <= 0 and yaw_rad <= 0:
        return starts
    room = scenario.room
    half = scenario.goal_size_m / 2
    radii = scenario.radii
    for i in range(scenario.n_robots):
        r = float(radii[i])
        for _ in range(tries):
            cand = scenario.starts[i] + rng.uniform([-xy_m, -xy_m, -yaw_rad], [xy_m, xy_m, yaw_rad])
            x, y = cand[0], cand[1]
            gap = min(x - room.x_min_m, room.x_max_m - x, y - room.y_min_m, room.y_max_m - y) - r
            for box in scenario.obstacles:
                gap = min(gap, float(box_clearance(box, cand[None, :2])[0]) - r)
            others = np.delete(starts[:, :2], i, axis=0)
            if len(others):
                reach = r + np.delete(radii, i)
                gap = min(gap, float((np.hypot(*(others - cand[:2]).T) - reach).min()))
            gx, gy = scenario.goals[i]
            in_goal = abs(x - gx) <= half + r and abs(y - gy) <= half + r
            if gap >= clearance_m and not in_goal:
                starts[i] = cand
                break
    starts[:, 2] = np.angle(np.exp(1j * starts[:, 2]))
    return starts
