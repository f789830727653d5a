"""Episodes table, topic frames and pose frames of small hand-written recordings; errors on bad files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from pipeline.analysis.errors import AnalysisError
from pipeline.analysis.tables import (
    EPISODES_SCHEMA,
    Recording,
    episodes_table,
    events_frame,
    poses_frame,
    topic_frame,
)
from pipeline.core.scan import ScanGeometry
from pipeline.core.scenario import load_scenario
from pipeline.errors import MrlError
from pipeline.mappings import to_mapping
from pipeline.messages import QOS_SENSOR, TopicSpec
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.record import McapLog, McapRecorder, TruncatedLogWarning
from pipeline.record.errors import MissingTopicError, TopicTypeError
from pipeline.record.session import SessionLog, dumps, session_metadata

NS = 1_000_000_000
PERIOD_NS = 100_000_000
ROBOTS = ("robot_1", "robot_2")
GEOMETRY = ScanGeometry(8, -math.pi, math.pi / 4, 0.05, 5.0)

# (seed, steps written, robot events (step, event, robot), team events (step, event, detail), closed by end)
EPISODES = [
    (5, 10, [(4, "collision", "robot_2"), (6, "goal", "robot_1")], [(10, "end", "incomplete")]),
    (6, 5, [(3, "goal", "robot_1"), (5, "goal", "robot_2")], [(5, "success", ""), (5, "end", "team_success")]),
    (7, 8, [(2, "abort", "robot_2"), (8, "timeout", "robot_1")], [(8, "end", "aborted")]),
    (8, 4, [(2, "goal", "robot_1")], [(4, "abort", "interrupted")]),
    (9, 7, [], []),  # the recorder stops inside this episode
]


def start_ns(k: int, episodes: list = EPISODES) -> int:
    return sum(steps * PERIOD_NS + NS for _, steps, _, _ in episodes[:k])


def write_session(
    path: Path,
    ground_truth: bool = True,
    odom: bool = True,
    chunk_size: int = 1 << 20,
    gap_pose: bool = True,
    episodes: list = EPISODES,
    timing: bool = False,
    scenario_name: str = "empty",
    legacy_seeds: bool = False,
    world: str = "real",
) -> Path:
    """Two robots moving +0.1 m in x per control step; the events of `episodes` (EPISODES by default), recorded
    as a session of `world` (its session metadata's ``world``).

    With `legacy_seeds`, start events carry their seed as recordings made before the seed field
    did: the text ``seed=<n>`` of their detail, the seed field left at -1.

    With `timing`, the deploy buffers' records too: five 20 ms emitter ticks per step, each sending
    both robots' commands 50 us apart, and a control step 5 ms after each robot's odometry and scan
    arrived.
    """
    scenario = load_scenario(scenario_name, n_robots=2)
    session = session_metadata(world, scenario_name, ROBOTS, 0.1, profile="mild")  # type: ignore[arg-type]
    docs = {"scenario": dumps(to_mapping(scenario))}
    with SessionLog(path, ROBOTS, session, docs, chunk_size=chunk_size) as log:
        for k, (seed, steps, robot_events, team_events) in enumerate(episodes):
            t0 = start_ns(k, episodes)
            if legacy_seeds:
                log.event(t0, k, 0, "start", detail=f"seed={seed}")
            else:
                log.start_episode(t0, k, seed)
            for step in range(steps + 1):
                t = t0 + step * PERIOD_NS
                for i, ns in enumerate(ROBOTS):
                    pose = np.array([1.0 + 0.1 * step, 1.0 + i, 0.25 * i])
                    if ground_truth:
                        log.ground_truth(t, ns, pose)
                    if odom:
                        log.odom(t, ns, pose + np.array([0.01, 0.0, 0.0]), (0.1, 0.0))
                    log.scan(t, ns, np.full(8, 2.0 + step, dtype=np.float32), GEOMETRY)
                    log.cmd_vel(t, ns, 0.1, 0.05 * i)
                    if timing:
                        for channel in ("odom", "scan"):
                            log.timing(t, "receive", ns, f"/{ns}/{channel}", 0, step, 0)
                if timing:
                    log.timing(t + 5_000_000, "control", "", "", 0, step, 0)
                    for k_tick in range(5):
                        t_tick = t + 10_000_000 + k_tick * 20_000_000
                        tick = t_tick // 20_000_000  # one counter over the session, as the emitter keeps
                        log.timing(t_tick, "tick", "", "", 0, 0, tick)
                        for i, ns in enumerate(ROBOTS):
                            log.timing(t_tick + 50_000 * i, "send", ns, f"/{ns}/cmd_vel", 0, tick, tick)
                for when, event, robot in robot_events:
                    if when == step:
                        log.event(t, k, step, event, robot, detail="stale odom" if event == "abort" else "")
                for when, event, detail in team_events:
                    if when == step:
                        log.event(t, k, step, event, detail=detail)
            if gap_pose and ground_truth and k + 1 < len(episodes):  # a pose between two episodes
                log.ground_truth(t0 + steps * PERIOD_NS + NS // 2, "robot_1", np.array([9.0, 9.0, 0.0]))
            log.flush()
    return path


@pytest.fixture(scope="module")
def recording_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_session(tmp_path_factory.mktemp("tables") / "deploy_round.mcap")


def test_episodes_table_reads_every_outcome(recording_path):
    table = episodes_table(recording_path)
    assert table.schema == pl.Schema(EPISODES_SCHEMA)
    assert table.height == len(EPISODES) * len(ROBOTS)
    rows = {(r["episode"], r["robot"]): r for r in table.iter_rows(named=True)}
    assert set(table["session"]) == {"deploy_round"} and set(table["world"]) == {"real"}
    assert set(table["profile"]) == {"mild"} and set(table["scenario"]) == {"empty"}

    a, b = rows[(0, "robot_1")], rows[(0, "robot_2")]
    assert (a["reached"], a["collided"], a["success"], a["timeout"], a["aborted"]) == (True, False, True, False, False)
    assert (b["reached"], b["collided"], b["success"]) == (False, True, False)
    assert a["time_to_goal_s"] == 6 * 0.1 and a["time_to_goal_clock_s"] == pytest.approx(0.6)
    assert b["time_to_goal_s"] is None
    assert a["steps"] == 10 and a["seed"] == 5 and a["end"] == "incomplete" and not a["team_success"]
    assert a["path_length_m"] == pytest.approx(1.0) and a["path_source"] == "ground_truth"
    assert a["start_ns"] == 0 and a["end_ns"] == 10 * PERIOD_NS

    for robot in ROBOTS:
        r = rows[(1, robot)]
        assert r["success"] and r["team_success"] and r["end"] == "team_success" and r["steps"] == 5
    assert rows[(1, "robot_2")]["time_to_goal_s"] == 5 * 0.1

    for robot in ROBOTS:  # a robot-level abort and an end 'aborted': the whole episode is aborted
        r = rows[(2, robot)]
        assert r["aborted"] and "robot_2: stale odom" in r["abort_reason"] and r["steps"] == 8
    assert rows[(2, "robot_1")]["timeout"]

    r = rows[(3, "robot_1")]  # a team abort ends the episode without an end event
    assert (
        r["aborted"]
        and r["reached"]
        and r["steps"] == 4
        and r["end"] == "aborted"
        and r["end_ns"] == start_ns(3) + 4 * PERIOD_NS
    )
    assert "interrupted" in r["abort_reason"]

    r = rows[(4, "robot_2")]  # no end at all: aborted, steps from the last pose, window open to the end of the file
    assert r["aborted"] and r["steps"] == 7 and r["end_ns"] is None and not r["salvaged"]
    assert "no end event" in r["abort_reason"]
    assert r["path_length_m"] == pytest.approx(0.7)


def test_episodes_and_events_frames(recording_path):
    rec = Recording(recording_path)
    episodes = rec.episodes()
    assert episodes["episode"].to_list() == [0, 1, 2, 3, 4]
    assert episodes["seed"].to_list() == [5, 6, 7, 8, 9]
    assert episodes["aborted"].to_list() == [False, False, True, True, True]
    assert episodes["team_success"].to_list() == [False, True, False, False, False]
    events = events_frame(rec)
    assert events.columns == ["t_ns", "episode", "step", "robot", "event", "detail"]
    assert events.filter(pl.col("event") == "start").height == 5
    assert events.filter(pl.col("event") == "collision")["robot"].to_list() == ["robot_2"]


def test_seeds_in_the_legacy_detail_text_are_read_the_same(recording_path, tmp_path):
    legacy = write_session(tmp_path / "legacy.mcap", legacy_seeds=True)
    events = McapLog(legacy).messages(["/mrl/episode"])
    assert {(m.msg.seed, m.msg.detail) for m in events if m.msg.event == C.EVENT_CODES["start"]} == {
        (-1, f"seed={seed}") for seed, *_ in EPISODES
    }
    assert Recording(legacy).episodes()["seed"].to_list() == [5, 6, 7, 8, 9]
    columns = [c for c in EPISODES_SCHEMA if c not in ("session", "path")]
    assert episodes_table(legacy).select(columns).equals(episodes_table(recording_path).select(columns))


def test_pose_frames_carry_robot_and_episode(recording_path):
    rec = Recording(recording_path)
    truth = poses_frame(rec, "ground_truth")
    assert truth.columns == ["robot", "episode", "t_ns", "stamp_ns", "x_m", "y_m", "yaw_rad"]
    total_poses = sum(steps + 1 for _, steps, _, _ in EPISODES)
    assert truth.filter(pl.col("robot") == "robot_2").height == total_poses
    between = truth.filter(pl.col("episode").is_null())
    assert between.height == len(EPISODES) - 1
    assert between["x_m"].to_list() == [9.0] * (len(EPISODES) - 1)
    assert truth.filter(pl.col("robot") == "robot_2")["yaw_rad"].to_list() == pytest.approx([0.25] * total_poses)
    first = truth.filter((pl.col("robot") == "robot_1") & (pl.col("episode") == 1))
    assert first["t_ns"].min() == start_ns(1) and first.height == 6
    odom = poses_frame(rec, "odom")
    assert odom.columns == ["robot", "episode", "t_ns", "stamp_ns", "x_m", "y_m", "yaw_rad", "v_mps", "w_radps"]
    assert odom["v_mps"].to_list() == [0.1] * odom.height


def test_topic_frames(recording_path):
    scans = topic_frame(recording_path, "/robot_1/scan")
    assert scans["ranges_m"].dtype == pl.Array(pl.Float32, 8)
    assert scans["frame_id"].unique().to_list() == ["robot_1/laser"]
    assert scans["range_max_m"].to_list() == [5.0] * scans.height
    assert "intensities" not in scans.columns
    assert scans["ranges_m"][0].to_list() == [2.0] * 8
    cmd = topic_frame(recording_path, "/robot_2/cmd_vel")
    assert {"t_ns", "v_mps", "w_radps"} <= set(cmd.columns)
    assert cmd["w_radps"].to_list() == [0.05] * cmd.height
    odom = topic_frame(recording_path, "/robot_1/odom")
    assert odom["child_frame_id"].unique().to_list() == ["robot_1/base_link"]
    assert (odom["stamp_ns"] == odom["t_ns"]).all()


def test_recorded_scenario_is_loaded(recording_path):
    scenario = Recording(recording_path).scenario()
    assert scenario.name == "empty" and scenario.n_robots == 2


def test_odometry_stands_in_for_missing_ground_truth(tmp_path):
    path = write_session(tmp_path / "no_truth.mcap", ground_truth=False)
    table = episodes_table(path)
    assert set(table["path_source"]) == {"odom"}
    assert table.filter(pl.col("episode") == 0)["path_length_m"].to_list() == pytest.approx([1.0, 1.0])
    with pytest.raises(MissingTopicError, match=r"no_truth\.mcap.*/robot_1/ground_truth"):
        poses_frame(path, "ground_truth")


def test_missing_topics_are_named_with_the_file(tmp_path):
    path = write_session(tmp_path / "blind.mcap", ground_truth=False, odom=False)
    with pytest.raises(MissingTopicError, match=r"blind\.mcap: .*/robot_1/ground_truth or /robot_1/odom"):
        episodes_table(path)
    with pytest.raises(MissingTopicError, match=r"blind\.mcap: .*/robot_1/nothing"):
        topic_frame(path, "/robot_1/nothing")
    with pytest.raises(AnalysisError, match=r"/tf carries tf2_msgs/msg/TFMessage, which has no column decoder"):
        with SessionLog(tmp_path / "tf.mcap", ROBOTS, session_metadata("sim", "empty", ROBOTS, 0.1)) as log:
            log.tf(0, np.zeros((2, 3)))
        topic_frame(tmp_path / "tf.mcap", "/tf")
    no_events = tmp_path / "no_events.mcap"
    with SessionLog(no_events, ROBOTS, session_metadata("sim", "empty", ROBOTS, 0.1)) as log:
        log.ground_truth(0, "robot_1", np.zeros(3))
    with pytest.raises(MissingTopicError, match=r"no_events\.mcap: the recording has no topic /mrl/episode"):
        episodes_table(no_events)


def test_a_topic_of_the_wrong_type_is_refused(tmp_path):
    path = tmp_path / "odd.mcap"
    with McapRecorder(path, {}) as rec:
        rec.write(TopicSpec("/mrl/episode", T.EPISODE_EVENT, QOS_SENSOR), C.episode_event(0, 0, 0, "start"), 0)
        rec.write(TopicSpec("/robot_1/ground_truth", T.TWIST, QOS_SENSOR, "robot_1"), C.twist(0.1, 0.0), 0)
    with pytest.raises(TopicTypeError, match=r"/robot_1/ground_truth carries geometry_msgs/msg/Twist, expected"):
        episodes_table(path)


def test_files_that_are_not_recordings_are_refused(tmp_path):
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording")
    with pytest.raises(MrlError, match=r"notes\.mcap: not an MCAP file"):
        episodes_table(text)
    with pytest.raises(MrlError, match=r"missing\.mcap: no such file"):
        episodes_table(tmp_path / "missing.mcap")


def test_truncated_recording_is_salvaged_and_its_open_episode_aborted(tmp_path):
    full = write_session(tmp_path / "full.mcap", chunk_size=2048, gap_pose=False)
    cut = tmp_path / "cut.mcap"
    data = full.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.warns(TruncatedLogWarning, match=r"cut\.mcap"):
        rec = Recording(cut)
    assert rec.salvaged
    table = rec.episodes_table()
    assert table["salvaged"].all()
    last = table["episode"].max()
    assert last is not None and last < len(EPISODES) - 1
    tail = table.filter(pl.col("episode") == last)
    assert tail["aborted"].all() and tail["end_ns"].is_null().all()
    assert "no end event" in tail["abort_reason"][0]
    complete = episodes_table(full).filter(pl.col("episode") < last)
    assert (
        table.filter(pl.col("episode") < last)
        .drop("salvaged", "session", "path")
        .equals(complete.drop("salvaged", "session", "path"))
    )


def test_an_open_log_and_a_recording_are_accepted(recording_path):
    from_log = episodes_table(McapLog(recording_path))
    rec = Recording(recording_path, session="round_1")
    assert from_log.drop("session").equals(episodes_table(rec).drop("session"))
    assert set(episodes_table(rec)["session"]) == {"round_1"}


def test_paths_are_read_at_the_control_steps_not_at_the_rate_or_order_ground_truth_arrived_in(tmp_path):
    """Motion capture at 50 Hz, two of its messages delivered out of order: the path goes through the newest pose
    received at each control step (0.5 m at 0.5 m/s for 1 s), not to and fro between the swapped ones. Where a
    robot's first poses of an episode are lost, its path starts at its first pose after the start, not at the
    previous episode's last (a jump back to the start across the reset)."""
    path = tmp_path / "mocap.mcap"
    tick_ns = 20_000_000
    with SessionLog(path, ROBOTS, session_metadata("real", "empty", ROBOTS, 0.1, profile="mild")) as log:
        for k, t0 in enumerate((0, 2 * NS)):
            log.start_episode(t0, k, k)
            for j in range(51):
                arrives = t0 + {22: 23, 23: 22}.get(j, j) * tick_ns if k == 0 else t0 + j * tick_ns
                if k == 0 or j >= 10:  # the second episode's first 0.2 s of robot_1 are lost
                    log.ground_truth(arrives, "robot_1", np.array([1.0 + 0.5 * j * tick_ns / NS, 1.0, 0.0]))
                log.ground_truth(t0 + j * tick_ns, "robot_2", np.array([2.0, 2.0, 0.0]))
            log.event(t0 + 10 * PERIOD_NS, k, 10, "end", detail="incomplete")
    table = episodes_table(path)
    lengths = {(r["episode"], r["robot"]): r["path_length_m"] for r in table.iter_rows(named=True)}
    assert lengths[(0, "robot_1")] == pytest.approx(0.5, abs=1e-12)
    assert lengths[(1, "robot_1")] == pytest.approx(0.4, abs=1e-12)
    assert lengths[(0, "robot_2")] == lengths[(1, "robot_2")] == 0.0
