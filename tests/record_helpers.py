"""Shared pieces of the recorder tests: one message of every recorded type, and a plain-data view of messages."""

from __future__ import annotations

import array
import dataclasses
import math
from typing import Any

import numpy as np

from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import load_scenario
from pipeline.messages import convert as C
from pipeline.messages import fleet_topics, message_store

NS = 1_000_000_000
ROBOTS = ("robot_1", "robot_2")


def topic_table() -> dict:
    return fleet_topics(ROBOTS)


def contract_messages(t0_ns: int = 1_700_000_000 * NS) -> list[tuple[str, Any, int]]:
    """(topic, message, log time ns) covering every topic type of the contract; increasing log times."""
    s = message_store()
    geometry = ScanGeometry(
        n_beams=8, angle_min_rad=-math.pi, angle_increment_rad=math.pi / 4, range_min_m=0.055, range_max_m=5.0
    )
    ranges = np.array([0.5, 1.25, np.inf, 4.999, 0.055, -np.inf, np.nan, 2.0], dtype=np.float32)
    pose = np.array([1.0, 2.5, 0.3])
    t = t0_ns
    out: list[tuple[str, Any]] = []
    for k, ns in enumerate(ROBOTS):
        out.append((f"/{ns}/scan", C.laser_scan(t, f"{ns}/laser", ranges + k, geometry, store=s)))
        out.append((f"/{ns}/odom", C.odometry(t, ns, pose + k, (0.15, -0.2), store=s)))
        out.append((f"/{ns}/ground_truth", C.pose_stamped(t, "map", pose * (k + 1), store=s)))
        out.append((f"/{ns}/cmd_vel", C.twist(0.1 * (k + 1), -0.2, store=s)))
    tf = [("map", f"{ns}/odom", np.array([0.01 * k, -0.02, 0.001])) for k, ns in enumerate(ROBOTS)]
    out.append(("/tf", C.tf_message(t, tf, store=s)))
    out.append(("/clock", C.clock(t, store=s)))
    obs = np.arange(17, dtype=np.float32) / 7
    out.append(("/mrl/observation", C.observation(t, 3, 12, "robot_1", "paper", obs, store=s)))
    out.append(("/mrl/action", C.action(t, 3, 12, "robot_1", np.array([0.25, -1.0]), (0.1, -0.2), store=s)))
    out.append(("/mrl/episode", C.episode_event(t, 3, 0, "start", store=s, seed=7)))
    out.append(("/mrl/episode", C.episode_event(t, 3, 40, "collision", robot="robot_2", store=s)))
    out.append(("/mrl/timing", C.timing(t, "receive", "robot_1", "/robot_1/scan", t - 5, 99, 4, store=s)))
    out.append(("/mrl/reset", C.reset_request(t, 4, 2**40 + 3, False, store=s)))
    out.append(("/mrl/reset_done", C.reset_request(t, 4, 2**40 + 3, True, store=s)))
    frames = [f"{ns}/ground_truth" for ns in ROBOTS]
    out.append(("/mrl/map", C.map_markers(t, load_scenario("obstacles"), frames, store=s)))
    return [(topic, msg, t + 1000 * (i + 1)) for i, (topic, msg) in enumerate(out)]


def _float(x: float) -> Any:
    return x if math.isfinite(x) else repr(x)  # 'nan', 'inf', '-inf': JSON has no such numbers


def plain(value: Any) -> Any:
    """Nested dicts, lists, ints, floats and strings of a decoded message (any decoder), bit-exact for floats.

    NaN and infinities become the strings 'nan', 'inf', '-inf'; float32 values become the exact
    float64 of the same number, so equal plain data means equal bits.
    """
    if isinstance(value, np.ndarray):
        return [plain(v) for v in value.tolist()]
    if isinstance(value, (array.array, list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return list(bytes(value))
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _float(float(value))
    if isinstance(value, str):
        return value
    if dataclasses.is_dataclass(value):
        # rosbags declares constants as fields annotated 'ClassVar[...]': they are not message data
        names = [f.name for f in dataclasses.fields(value) if not str(f.type).startswith("ClassVar")]
    else:
        names = getattr(value, "__slots__", None)
        if names is None:
            raise TypeError(f"no plain form for {type(value).__name__}")
    return {name: plain(getattr(value, name)) for name in names if not name.startswith("__")}
