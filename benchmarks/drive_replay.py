"""A recording's commands replayed through a reality profile's drive, without sensors or network: what the robots'
bodies would have done, noise-free.

Each episode of the recording starts the twin's own physics (:class:`~pipeline.twin.physics.FleetPhysics` with the
profile's base, map offsets and floor) with every robot at rest at its first recorded pose, and steps it at the
twin's physics step through the episode, each robot's driver (:class:`~pipeline.twin.twin.BaseDriver`: the
profile's delay, lag and gains) taking that robot's commands at the times the recording gives them (zero after the
twin's driver timeout without one). Per robot it returns the body velocity at every step and whether the chassis
touched anything. A benchmark fits the simulator's drive model to these velocities on the stretches calibration
uses, which gives the value an effective drive parameter stands for on that recording: the model's best fit to the
reality's own drive under the same commands (benchmarks/calibration_coverage.py). It lives beside the benchmarks,
not in the package: the twin stands apart from calibration, and the package's benchmark part trains in the
simulator only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.calibration.actuation import CommandTimeline, VelocityTrack
from pipeline.calibration.recording import SessionData
from pipeline.core.timebase import NS_PER_S
from pipeline.errors import MrlError
from pipeline.twin.profile import RealityProfile
from pipeline.twin.twin import DRIVER_TIMEOUT_NS, BaseDriver, fleet_physics


class DriveReplayError(MrlError):
    """A recording that cannot be replayed through a profile's drive (it is named, with the reason)."""


@dataclass(frozen=True)
class ReplayedDrive:
    """One robot's replayed body: step times `t_ns` (m,), body velocity (m, 2) (v m/s, w rad/s) and whether its
    chassis touched a wall, a box or another robot (m,)."""

    t_ns: np.ndarray
    velocity: np.ndarray
    contact: np.ndarray

    def at(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity (k, 2) at times `t_ns` (k,) (linear between steps) and contact at the step before each."""
        t = np.asarray(t_ns, dtype=np.int64)
        v = np.stack([np.interp(t, self.t_ns, self.velocity[:, c]) for c in range(2)], axis=1)
        k = np.clip(np.searchsorted(self.t_ns, t, side="right") - 1, 0, len(self.t_ns) - 1)
        return v, self.contact[k]


def replay_drive(
    session: SessionData,
    profile: RealityProfile,
    commands: dict[str, CommandTimeline] | None = None,
    jumps: Sequence[tuple[int, int]] = (),
) -> dict[str, ReplayedDrive]:
    """Every robot's body under the profile's drive, replaying `session`'s commands episode by episode: the recorded
    ones, or per robot name in `commands` those the robot's driver really took (the twin's record). `jumps` ((start
    ns, ns skipped) on the twin's clock, from its record) are host stalls the twin jumped over: its world stood still
    through them, and so does the replay's."""
    scenario = session.scenario
    if scenario.layouts is not None:
        raise DriveReplayError(
            f"{session.path}: scenario {scenario.name!r} draws its layouts; the replay needs a fixed one"
        )
    physics = fleet_physics(scenario, profile)
    step_ns = round(physics.timestep_s * NS_PER_S)
    robots = session.robots
    n = len(robots)
    driver = BaseDriver(n, profile.actuation)
    timelines = [
        (commands or {}).get(r.name)
        or (
            CommandTimeline(r.commands.t_ns, np.stack([r.commands.v, r.commands.w], axis=1))
            if r.commands is not None and len(r.commands.t_ns)
            else None
        )
        for r in robots
    ]
    times: list[np.ndarray] = []
    velocities: list[np.ndarray] = []
    contacts: list[np.ndarray] = []
    for episode in session.episodes:
        starts = _start_poses(session, episode.start_ns, episode.end_ns)
        if starts is None:
            continue
        physics.reset(starts)
        driver.reset()
        t = np.arange(episode.start_ns, episode.end_ns, step_ns, dtype=np.int64)
        acting = np.zeros((len(t), n, 2))
        for i, timeline in enumerate(timelines):
            if timeline is not None:
                acting[:, i] = timeline.at(t, DRIVER_TIMEOUT_NS / NS_PER_S)
        vel = np.empty((len(t), n, 2))
        touch = np.empty((len(t), n), dtype=bool)
        frozen = np.zeros(len(t), dtype=bool)
        for at, skipped in jumps:
            frozen |= (t >= at) & (t < at + skipped)
        for k, now in enumerate(t):
            if not frozen[k]:
                physics.set_wheel_targets(driver.wheel_targets(int(now), acting[k], physics.timestep_s))
                physics.step(1)
            vel[k] = physics.body_velocity()
            touch[k] = physics.in_collision()
        times.append(t + step_ns)  # the state after the step
        velocities.append(vel)
        contacts.append(touch)
    if not times:
        raise DriveReplayError(f"{session.path}: no episode with every robot's pose at its start to replay from")
    t_all = np.concatenate(times)
    v_all = np.concatenate(velocities)
    c_all = np.concatenate(contacts)
    return {r.name: ReplayedDrive(t_all, v_all[:, i], c_all[:, i]) for i, r in enumerate(robots)}


def _start_poses(session: SessionData, start_ns: int, end_ns: int) -> np.ndarray | None:
    """(n, 3) each robot's first recorded pose in the episode; None where a robot has none."""
    poses = []
    for robot in session.robots:
        truth = robot.truth
        if truth is None or len(truth.pose) == 0:
            return None
        inside = np.flatnonzero((truth.time.t_ns >= start_ns) & (truth.time.t_ns <= end_ns))
        if not len(inside):
            return None
        poses.append(truth.pose[inside[0]])
    return np.asarray(poses, dtype=float)


def replayed_tracks(tracks: Sequence[VelocityTrack], replayed: Mapping[str, ReplayedDrive]) -> list[VelocityTrack]:
    """`tracks` (calibration's contact-free stretches) with the replayed body velocities at their times instead of
    the recorded ones, cut where a replayed robot touches something (pieces of at least 3 samples)."""
    out = []
    for track in tracks:
        velocity, contact = replayed[track.robot].at(track.t_ns)
        edges = np.diff(np.r_[0, (~contact).astype(np.int8), 0])
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            if b - a >= 3:
                out.append(VelocityTrack(track.robot, track.cluster, track.t_ns[a:b], velocity[a:b], track.commands))
    return out
