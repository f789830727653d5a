"""Fleet files: which robots, on which network, and whether they are real or the hardware twin.

A fleet file is YAML (see ``pipeline/ros/fleets/twin.yaml``)::

    target: twin            # twin: start the bundled hardware twin; robots: use the running graph
    transport: dds          # dds (Cyclone DDS from Python) | rclpy (ROS 2 installed) | ros1 (a ROS 1 master)
    scenario: obstacles     # the map the robots drive in: bundled name or scenario YAML path
    network: {domain_id: 0, loopback_only: true, peers: []}   # no domain_id: a twin takes a free one; ros1: master_uri
    robots:                 # in scenario order: the i-th entry drives the scenario's i-th robot
      - {name: robot_1, namespace: robot_1, v_max_mps: 0.4, w_max_radps: 0.2}
    twin: {profile: mild, time_scale: 1.0, seed: 0}
    timing: {tick_period_s: 0.02, command_validity_s: 0.12, ...}

Loading is strict like params.yaml: unknown, missing or out-of-range keys fail with the file and
the dotted key named.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal

from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, read_yaml, setting
from pipeline.messages.topics import TopicSpec, robot_topics
from pipeline.ros.errors import NetworkSettingsError
from pipeline.ros.transport import NetworkSettings

_NAMESPACE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


@dataclass(frozen=True)
class FleetRobot:
    """One robot: its name in the pipeline, its ROS namespace, its velocity limits."""

    name: str = setting()
    namespace: str = setting()
    v_max_mps: float = setting(0.4, gt=0.0, le=5.0)
    w_max_radps: float = setting(0.2, gt=0.0, le=10.0)

    def check(self) -> list[tuple[str, object, str]]:
        if not _NAMESPACE.match(self.namespace):
            return [("namespace", self.namespace, "a ROS namespace without leading slash, e.g. robot_1 or lab/robot_1")]
        return []

    def topics(self) -> dict[str, TopicSpec]:
        return robot_topics(self.namespace)


@dataclass(frozen=True)
class FleetNetwork:
    domain_id: int | None = setting(None, ge=0, le=232, optional=True)
    """The DDS (and ROS 2) domain; absent: a twin takes a free one of its machine for each deployment
    (:mod:`pipeline.ros.domains`), robots ROS's default, 0."""
    loopback_only: bool = setting(True)
    peers: tuple[str, ...] = setting(())
    master_uri: str = setting("", allow_empty=True, optional=True)
    """The ROS 1 master of a ros1 fleet (``http://HOST:PORT``); empty: ``ROS_MASTER_URI``."""
    interface: str = setting("", allow_empty=True, optional=True)
    """The network interface (name or IPv4 address) of this host that reaches the robots, where it has several
    (``loopback_only: false``); empty: the transport's choice."""

    @property
    def domain(self) -> int:
        """The domain the fleet is on: its own, or ROS's default (0) before a deployment leases one."""
        return self.domain_id if self.domain_id is not None else 0


@dataclass(frozen=True)
class TwinSettings:
    """How the deploy stage starts the hardware twin (target: twin)."""

    profile: str = setting("mild")
    """A bundled reality profile (mild, harsh) or the path of a profile YAML file."""
    time_scale: float | Literal["auto"] = setting(1.0, gt=0.0, le=20.0)
    """Simulated seconds per wall-clock second; above 1 the twin publishes /clock. ``auto``: the highest the host
    lets the twin keep, measured before the first episode and lowered when it falls behind
    (:mod:`pipeline.rollout.pace`)."""
    seed: int = setting(0, ge=0)


@dataclass(frozen=True)
class FleetTiming:
    """Deploy-side timing (seconds of the fleet's clock)."""

    tick_period_s: float = setting(0.02, gt=0.0, le=1.0)
    command_validity_s: float = setting(0.12, gt=0.0, le=5.0)
    """How long a command stays valid: the control period plus one emitter tick of grace, so a control
    step that runs a little late does not leave a tick without a command."""
    discovery_timeout_s: float = setting(20.0, gt=0.0, le=600.0)
    reset_timeout_s: float = setting(20.0, gt=0.0, le=3600.0)
    scan_stale_s: float = setting(0.5, gt=0.0, le=10.0)
    odom_stale_s: float = setting(0.3, gt=0.0, le=10.0)
    truth_stale_s: float = setting(0.3, gt=0.0, le=10.0)
    """Ground truth staleness; used when use_ground_truth is true."""
    outage_limit_s: float = setting(5.0, gt=0.0, le=600.0)
    """A robot blind (stale) this long without a break aborts the episode; until then it stands still (zero
    commands) and the other robots drive on. 5 s: a Wi-Fi link's loss bursts last tens to hundreds of ms and a
    roaming hand-over 1-3 s; a robot that has missed five seconds of scans is lost to its operator."""
    use_ground_truth: bool = setting(True)
    """Judge goals and collisions on /<ns>/ground_truth (motion capture or twin); else odometry and lidar."""


@dataclass(frozen=True)
class Fleet:
    target: Literal["twin", "robots"] = setting()
    robots: tuple[FleetRobot, ...] = setting(min_len=1)
    transport: Literal["dds", "rclpy", "ros1"] = setting("dds")
    scenario: str = setting("obstacles")
    network: FleetNetwork = setting(FleetNetwork())
    twin: TwinSettings = setting(TwinSettings())
    timing: FleetTiming = setting(FleetTiming())

    def check(self) -> list[tuple[str, object, str]]:
        bad: list[tuple[str, object, str]] = []
        for field_name in ("name", "namespace"):
            seen: set[str] = set()
            for i, robot in enumerate(self.robots):
                value = getattr(robot, field_name)
                if value in seen:
                    bad.append((f"robots[{i}].{field_name}", value, f"a {field_name} not used by another robot"))
                seen.add(value)
        if self.timing.command_validity_s < self.timing.tick_period_s:
            bad.append(("timing.command_validity_s", self.timing.command_validity_s, "at least timing.tick_period_s"))
        limits = {"timing.scan_stale_s": self.timing.scan_stale_s, "timing.odom_stale_s": self.timing.odom_stale_s}
        if self.timing.use_ground_truth:
            limits["timing.truth_stale_s"] = self.timing.truth_stale_s
        key, longest = max(limits.items(), key=lambda kv: kv[1])
        if self.timing.outage_limit_s < longest:
            bad.append(
                (
                    "timing.outage_limit_s",
                    self.timing.outage_limit_s,
                    f"at least the longest staleness limit ({key} = {longest:g} s): a robot is blind only once stale",
                )
            )
        return bad

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.robots)

    def network_settings(self, source: str = "<fleet>", *, on_this_host: bool = False) -> NetworkSettings:
        """The fleet's network settings; `on_this_host`: checked against this host too (its interface exists, its
        peers resolve and have a route: :meth:`NetworkSettings.check_host`), before a transport opens."""
        n = self.network
        try:
            settings = NetworkSettings(n.domain, n.loopback_only, n.peers, n.master_uri, n.interface)
            if on_this_host:
                settings.check_host()
            return settings
        except NetworkSettingsError as exc:
            raise ConfigError(source, [ConfigProblem(f"network.{exc.setting}", exc.value, exc.allowed)]) from exc


def bundled_fleets() -> tuple[str, ...]:
    folder = resources.files("pipeline.ros") / "fleets"
    return tuple(sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml")))


def fleet_path(spec: str | Path) -> Path:
    """The file of a bundled fleet name or a path."""
    text = str(spec)
    if text in bundled_fleets():
        return Path(str(resources.files("pipeline.ros") / "fleets" / f"{text}.yaml"))
    return Path(text)


def load_fleet(spec: str | Path) -> Fleet:
    """A validated fleet from a bundled name or a YAML path; ConfigError names the file and key."""
    path = fleet_path(spec)
    fleet = from_mapping(Fleet, read_yaml(path), str(path))
    fleet.network_settings(str(path))
    return fleet
