"""A Fast DDS robot driver stand-in, built from the pipeline's IDL with Debian's fastddsgen and libfastrtps-dev.

:func:`build` generates the IDL of the robot's message types (:func:`pipeline.ros.idl_text.idl_document`),
runs ``fastddsgen`` on it and compiles ``fastdds_robot/robot.cpp`` with CMake, once per source
digest (the binary is kept under the user's cache folder). :class:`FastDdsRobot` runs one driver
per robot with the QoS and type hash of each ROS 2 topic from :mod:`pipeline.messages.topics` and
plays the operator on its stdin (``reset``). :func:`read_log` parses what the driver received and
published.
"""

from __future__ import annotations

import hashlib
import math
import os
import queue
import shutil
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.core.scenario import Scenario
from pipeline.messages import topics as T
from pipeline.messages.store import message_store
from pipeline.messages.topics import TopicSpec
from pipeline.ros.idl_text import idl_document

SOURCE = Path(__file__).resolve().parent / "fastdds_robot"
TYPES = (T.LASER_SCAN, T.ODOMETRY, T.POSE_STAMPED, T.TWIST)
HEADERS = Path("/usr/include/fastdds/dds/domain/DomainParticipant.hpp")
BEAMS = 360


def missing() -> str | None:
    """Why the stand-in cannot be built here (None: it can)."""
    absent = [tool for tool in ("fastddsgen", "cmake", "g++") if shutil.which(tool) is None]
    if not HEADERS.exists():
        absent.append("libfastrtps-dev")
    if absent:
        return (
            f"the Fast DDS peer needs Debian's {', '.join(absent)} "
            "(apt-get install libfastrtps-dev fastddsgen cmake g++)"
        )
    return None


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mrl" / "fastdds_robot"


def build(root: Path | None = None) -> Path:
    """The driver's executable, built on first use for this IDL and these sources."""
    idl = idl_document(TYPES)
    digest = hashlib.sha256(idl.encode())
    for path in sorted(SOURCE.iterdir()):
        digest.update(path.name.encode() + path.read_bytes())
    out = (root or cache_root()) / digest.hexdigest()[:16]
    binary = out / "build" / "mrl_fastdds_robot"
    if binary.exists():
        return binary
    gen = out / "generated"
    gen.mkdir(parents=True, exist_ok=True)
    (gen / "ros2_types.idl").write_text(idl, encoding="utf-8")
    _run(["fastddsgen", "-replace", "-d", str(gen), str(gen / "ros2_types.idl")], out)
    _run(["cmake", "-S", str(SOURCE), "-B", str(out / "build"), f"-DGENERATED_DIR={gen}"], out)
    _run(["cmake", "--build", str(out / "build"), "-j", "2"], out)
    return binary


def _run(cmd: list[str], cwd: Path) -> None:
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stdout[-4000:]}\n{done.stderr[-4000:]}")


def qos_arg(spec: TopicSpec) -> str:
    q = spec.qos
    return f"{q.reliability},{q.durability},{q.depth},{message_store().rihs01(spec.typename)}"


@dataclass
class FastDdsRobot:
    """One driver process for robot `index` of `scenario` on `domain`, logging to `log`."""

    binary: Path
    scenario: Scenario
    index: int
    namespace: str
    domain: int
    log: Path
    proc: subprocess.Popen[str] | None = None
    lines: queue.Queue[str] = field(default_factory=queue.Queue)

    def command(self) -> list[str]:
        s = self.scenario
        start = s.robots[self.index].start
        room = s.room
        topics = T.robot_topics(self.namespace)
        cmd = [
            str(self.binary),
            "--domain", str(self.domain),
            "--ns", self.namespace,
            "--start", f"{start.x_m!r},{start.y_m!r},{start.yaw_rad!r}",
            "--room", f"{room.x_min_m!r},{room.y_min_m!r},{room.x_max_m!r},{room.y_max_m!r}",
            "--beams", str(BEAMS),
            "--qos-scan", qos_arg(topics["scan"]),
            "--qos-odom", qos_arg(topics["odom"]),
            "--qos-truth", qos_arg(topics["ground_truth"]),
            "--qos-cmd", qos_arg(topics["cmd_vel"]),
            "--log", str(self.log),
        ]  # fmt: skip
        for box in s.obstacles:
            cmd += ["--box", f"{box.x_m!r},{box.y_m!r},{box.size_x_m / 2!r},{box.size_y_m / 2!r},{box.yaw_rad!r}"]
        return cmd

    def start(self, timeout_s: float = 20.0) -> None:
        self.proc = subprocess.Popen(
            self.command(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
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


NAMESPACES = ("robot_1", "robot_2", "robot_3")


def deploy_on_drivers(
    binary: Path, policy: Path, folder: Path, episodes: int, domain: int, seed: int = 3
) -> tuple[Path, dict[str, Path], list[Any]]:
    """Deploy `policy` on three Fast DDS drivers (target ``robots``, loopback, `domain`), the test playing the
    operator who puts the robots back; returns the recording, each driver's log and the episodes."""
    from pipeline.core.scenario import load_scenario
    from pipeline.policy.runtime import PolicyRuntime
    from pipeline.rollout.deployment import DeployRequest, deploy_policy
    from pipeline.ros.fleet import load_fleet
    from tests.integration.conftest import write_fleet

    fleet_file = write_fleet(folder / "fleet.yaml", target="robots", network={"domain_id": domain})
    fleet = load_fleet(fleet_file)
    scenario = load_scenario(fleet.scenario, len(fleet.robots))
    logs = {ns: folder / f"{ns}.log" for ns in NAMESPACES}
    drivers = [FastDdsRobot(binary, scenario, i, ns, domain, logs[ns]) for i, ns in enumerate(NAMESPACES)]
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
