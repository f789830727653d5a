"""What the robot driver stand-ins (Fast DDS, roscpp) share: their process, the operator on their stdin, their logs.

A driver is a C++ program (``tests/peers/<kind>_robot``, with ``common/robot_world.hpp``) that publishes one
robot's scan, odometry and ground truth and takes its ``cmd_vel``. :class:`DriverProcess` runs one with the
room of a scenario and plays the operator (``reset``); :func:`read_log` parses what it received and published;
:func:`deploy_on_drivers` runs whole episodes of a policy on three of them through the deploy runner.
"""

from __future__ import annotations

import hashlib
import math
import queue
import subprocess
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.core.scenario import Scenario

PEERS = Path(__file__).resolve().parent
COMMON = PEERS / "common"
BEAMS = 360
NAMESPACES = ("robot_1", "robot_2", "robot_3")


def source_digest(*folders: Path, extra: bytes = b"") -> str:
    """A digest of the files in `folders` (and `extra`): a driver is built once per digest."""
    digest = hashlib.sha256(extra)
    for folder in folders:
        for path in sorted(folder.iterdir()):
            digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


def run(cmd: list[str], cwd: Path) -> None:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stdout[-4000:]}\n{done.stderr[-4000:]}")


def world_args(scenario: Scenario, index: int, namespace: str, log: Path) -> list[str]:
    """The shared command-line flags of robot `index` of `scenario` (robot_world.hpp's ``world_flag``)."""
    start = scenario.robots[index].start
    room = scenario.room
    args = [
        "--ns", namespace,
        "--start", f"{start.x_m!r},{start.y_m!r},{start.yaw_rad!r}",
        "--room", f"{room.x_min_m!r},{room.y_min_m!r},{room.x_max_m!r},{room.y_max_m!r}",
        "--beams", str(BEAMS),
        "--log", str(log),
    ]  # fmt: skip
    for box in scenario.obstacles:
        args += ["--box", f"{box.x_m!r},{box.y_m!r},{box.size_x_m / 2!r},{box.size_y_m / 2!r},{box.yaw_rad!r}"]
    return args


@dataclass
class DriverProcess:
    """One driver process (`command`, with `env`), its stdout read line by line, the operator on its stdin."""

    command: list[str]
    namespace: str
    env: Mapping[str, str] | None = None
    proc: subprocess.Popen[str] | None = None
    lines: queue.Queue[str] = field(default_factory=queue.Queue)

    def start(self, timeout_s: float = 20.0) -> None:
        self.proc = subprocess.Popen(
            self.command,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=None if self.env is None else dict(self.env),
        )
        threading.Thread(target=self._pump, daemon=True).start()
        self.expect(f"ready {self.namespace}", timeout_s)

    def _pump(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def expect(self, text: str, timeout_s: float) -> None:
        seen = []
        try:
            while True:
                line = self.lines.get(timeout=timeout_s)
                if line == text:
                    return
                seen.append(line)
        except queue.Empty:
            raise RuntimeError(f"{self.namespace}: no {text!r} within {timeout_s} s; output: {seen[-20:]}") from None

    def reset(self, number: int, timeout_s: float = 10.0) -> None:
        """The operator puts the robot back at its start (the driver's `number`-th reset)."""
        assert self.proc is not None and self.proc.stdin is not None
        self.proc.stdin.write("reset\n")
        self.proc.stdin.flush()
        self.expect(f"reset {number}", timeout_s)

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        try:
            assert self.proc.stdin is not None
            self.proc.stdin.write("quit\n")
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()


@dataclass(frozen=True)
class DriverLog:
    """What one driver received and published."""

    commands: list[tuple[int, float, float]]
    """(receive unix ns, linear.x, angular.z) per command taken."""
    scans: dict[tuple[int, int], list[float]]
    """(stamp sec, nanosec) -> ranges published."""


def read_log(path: Path) -> DriverLog:
    commands: list[tuple[int, float, float]] = []
    scans: dict[tuple[int, int], list[float]] = {}
    for line in path.read_text().splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "cmd" and len(parts) == 4:
            commands.append((int(parts[1]), float.fromhex(parts[2]), float.fromhex(parts[3])))
        elif parts[0] == "scan" and len(parts) > 3:
            scans[(int(parts[1]), int(parts[2]))] = [_hex(p) for p in parts[3:]]
    return DriverLog(commands, scans)


def _hex(text: str) -> float:
    return math.inf if text == "inf" else float.fromhex(text)


@dataclass(frozen=True)
class Delivery:
    """Commands of one robot: sent (recorded), received by the driver, and their matching."""

    sent: list[tuple[int, float, float]]
    """(send log time ns, v, w) as recorded."""
    received: list[tuple[int, float, float]]
    """(receive unix ns, v, w) as the driver logged them."""
    first_matched: int
    """Index in `sent` of the first command the driver received (earlier ones went out before the match)."""

    @property
    def matched(self) -> bool:
        """From `first_matched` on, the driver received exactly the sent values in order."""
        return self.first_matched >= 0 and [(v, w) for _, v, w in self.sent[self.first_matched :]] == [
            (v, w) for _, v, w in self.received
        ]

    def delays_s(self) -> list[float]:
        """One-way delay of each received command (driver receive time - recorded send time, one host clock)."""
        pairs = zip(self.sent[self.first_matched :], self.received, strict=False)
        return [(got[0] - s[0]) / 1e9 for s, got in pairs]


def delivery(sent: list[tuple[int, float, float]], driver: DriverLog) -> Delivery:
    first = len(sent) - len(driver.commands)
    return Delivery(sent, driver.commands, first if first >= 0 else -1)


def deploy_on_drivers(
    make_driver: Callable[[Scenario, int, str, Path], DriverProcess],
    fleet_file: Path,
    policy: Path,
    folder: Path,
    episodes: int,
    seed: int = 3,
) -> tuple[Path, dict[str, Path], list[Any]]:
    """Deploy `policy` on three drivers (``make_driver(scenario, index, namespace, log)``) of a fleet file with
    target ``robots``, the test playing the operator who puts the robots back; returns the recording, each
    driver's log and the episodes."""
    from pipeline.core.scenario import load_scenario
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.rollout.deployment import DeployRequest, deploy_policy
    from pipeline.ros.fleet import load_fleet

    fleet = load_fleet(fleet_file)
    scenario = load_scenario(fleet.scenario, len(fleet.robots))
    logs = {ns: folder / f"{ns}.log" for ns in NAMESPACES}
    drivers = [make_driver(scenario, i, ns, logs[ns]) for i, ns in enumerate(NAMESPACES)]
    resets = [0]

    def operator(episode: int) -> None:
        resets[0] += 1
        for d in drivers:
            d.reset(resets[0])

    try:
        for d in drivers:
            d.start()
        request = DeployRequest(episodes=episodes, seed=seed, recording=folder / "session.mcap", progress=False)
        results, profile = deploy_policy(PolicyRuntime(policy), fleet, str(fleet_file), request, operator)
    finally:
        for d in drivers:
            d.stop()
    if profile != "robots":
        raise RuntimeError(f"deployed on {profile!r}, not on the drivers")
    return folder / "session.mcap", logs, results


def ticks_of(recording: Path) -> dict[str, dict[int, int]]:
    """Per robot, each recorded send time (ns) of its commands to the start time of the emitter tick that wrote it
    (``/mrl/timing``: a tick's event, then its sends with the tick's number)."""
    import polars as pl

    from pipeline.analysis.tables import Recording
    from pipeline.messages.convert import TIMING_CODES

    frame = Recording(recording).topic_frame("/mrl/timing").select("kind", "robot", "local_ns", "tick")
    ticks = frame.filter(pl.col("kind") == TIMING_CODES["tick"]).select("tick", pl.col("local_ns").alias("start"))
    sends = frame.filter((pl.col("kind") == TIMING_CODES["send"]) & (pl.col("tick") > 0))
    out: dict[str, dict[int, int]] = {}
    joined = sends.join(ticks, on="tick", how="inner").select("robot", "local_ns", "start")
    for robot, sent, start in joined.iter_rows():
        out.setdefault(robot, {})[sent] = start
    return out


def check_whole_episodes(recording: Path, logs: dict[str, Path], results: list[Any], episodes: int) -> None:
    """What a deployment on three drivers must show: every episode run through, the reliable commands from the
    driver's first on received bit for bit and in order, after their tick began and within their validity, every
    recorded scan what the driver published (float32, bit for bit), and the robots moved (their ground truth)."""
    import numpy as np

    from pipeline.record import McapLog

    assert len(results) == episodes and not any(r.aborted for r in results)
    assert all(r.steps >= 1 for r in results)
    log = McapLog(recording)
    episode_times = [m.log_time_ns for m in log.messages(["/mrl/episode"])]
    first, last = min(episode_times), max(episode_times)
    tick_starts = ticks_of(recording)
    for ns in NAMESPACES:
        driver = read_log(logs[ns])
        sent = [(m.log_time_ns, m.msg.linear.x, m.msg.angular.z) for m in log.messages([f"/{ns}/cmd_vel"])]
        got = delivery(sent, driver)
        # commands sent before the driver's reader matched the runner's writer never reach it; from the first one
        # received on, the reliable topic delivers every command, values bit for bit
        assert got.matched, ns
        in_episodes = [s for s in sent if first <= s[0] <= last]
        assert sent.index(in_episodes[0]) >= got.first_matched, f"{ns}: a command sent during an episode was lost"
        assert any(v != 0.0 for _, v, _ in in_episodes), f"{ns}: the policy never moved the robot"
        # arrival follows the start of the emitter's tick that wrote the command (the recorded send time is stamped
        # after the write returns, and a busy host may run the driver before the runner's stamp) and comes within
        # the command's validity
        starts = tick_starts.get(ns, {})
        taken = got.sent[got.first_matched :][: len(got.received)]
        assert all(s[0] in starts for s in taken), f"{ns}: a command sent off the emitter's ticks"
        began = np.array([got.received[k][0] - starts[s[0]] for k, s in enumerate(taken)]) / 1e9
        assert began.min() >= 0.0, (ns, began.min())
        delays = np.array(got.delays_s())
        assert np.quantile(delays, 0.99) < 0.12, ns
        recorded = list(log.messages([f"/{ns}/scan"]))
        assert len(recorded) >= 0.8 * len([k for k in driver.scans if first <= k[0] * 10**9 + k[1] <= last])
        for m in recorded:
            key = (m.msg.header.stamp.sec, m.msg.header.stamp.nanosec)
            assert key in driver.scans, f"{ns}: a scan the driver never published"
            np.testing.assert_array_equal(m.msg.ranges, np.array(driver.scans[key], dtype=np.float32))
            assert m.msg.header.frame_id == f"{ns}/laser" and len(m.msg.ranges) == BEAMS
    truth = [m.msg.pose.position for m in log.messages(["/robot_1/ground_truth"])]
    assert len({(round(p.x, 3), round(p.y, 3)) for p in truth}) > 10
