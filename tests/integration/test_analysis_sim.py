"""Analysis of a real simulated session: the episodes table equals the evaluation's own results.

The scripted go-to-goal controller drives the obstacles scenario; in every other episode robot_3
drives straight ahead at full speed into the box in front of it, and a short step limit makes
robot_1 time out now and then, so the recording holds goals, collisions and timeouts.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from pipeline.analysis.decode import decode
from pipeline.analysis.gap_report import write_report
from pipeline.analysis.layouts import DECODABLE
from pipeline.analysis.tables import Recording, episodes_table
from pipeline.core.episode import EpisodeResult
from pipeline.mappings import to_mapping
from pipeline.policy.scripted import GoToGoalController
from pipeline.record import McapLog, TruncatedLogWarning
from pipeline.record.session import SessionLog, dumps, session_metadata
from pipeline.rollout.sim import evaluate
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

pytestmark = pytest.mark.integration

EPISODES = 6
MAX_STEPS = 190


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[EpisodeResult]]:
    scenario, world = make_world("obstacles", observation="rich", max_steps=MAX_STEPS)
    sim = MultiRobotSim(scenario, world)
    controller = GoToGoalController(world.layout(), world.codec())
    codec = world.codec()
    crash = {"on": True}

    def policy(obs: np.ndarray) -> np.ndarray:
        if sim.judge.steps == 0:
            crash["on"] = not crash["on"]
        cmd = controller.commands(obs)
        if crash["on"]:
            cmd[2] = (codec.v_max_mps, 0.0)
        return codec.encode(cmd)

    path = tmp_path_factory.mktemp("sim_analysis") / "scripted.mcap"
    meta = session_metadata("sim", scenario.name, scenario.robot_names, world.control_period_s, profile="sim")
    documents = {"scenario": dumps(to_mapping(scenario)), "world": dumps(to_mapping(world))}
    with SessionLog(path, scenario.robot_names, meta, documents, chunk_size=64 * 1024) as log:
        results = evaluate(sim, policy, EPISODES, seed=0, progress=False, log=log, layout_name="rich")
    return path, results


def test_the_recording_has_goals_collisions_and_timeouts(session):
    path, results = session
    table = episodes_table(path)
    assert table["reached"].any() and table["collided"].any() and table["timeout"].any()
    assert not any(r.aborted for r in results)


def test_episodes_table_equals_the_evaluation(session):
    path, results = session
    table = episodes_table(path)
    assert table.height == EPISODES * 3
    rows = {(r["episode"], r["robot"]): r for r in table.iter_rows(named=True)}
    for result in results:
        for i in range(len(result.reached)):
            row = rows[(result.episode, f"robot_{i + 1}")]
            assert row["seed"] == result.seed
            assert row["steps"] == result.steps
            assert row["reached"] == bool(result.reached[i])
            assert row["collided"] == bool(result.collided[i])
            assert row["success"] == bool(result.success[i])
            assert row["team_success"] == result.team_success
            assert not row["aborted"]
            expected = float(result.time_to_goal_s[i])
            assert (row["time_to_goal_s"] is None) if math.isnan(expected) else (row["time_to_goal_s"] == expected)
            timed_out = result.steps == MAX_STEPS and not (result.reached[i] or result.collided[i])
            assert row["timeout"] == timed_out
            assert row["path_source"] == "ground_truth"
            assert row["path_length_m"] == pytest.approx(float(result.path_length_m[i]), rel=1e-12, abs=1e-12)


def test_pose_frames_follow_the_trajectories(session):
    path, results = session
    poses = Recording(path).poses("ground_truth")
    for result in results[:2]:
        for i in range(3):
            track = poses.filter((pl.col("robot") == f"robot_{i + 1}") & (pl.col("episode") == result.episode))
            np.testing.assert_array_equal(track.select("x_m", "y_m").to_numpy(), result.trajectory[:, i, :2])


def test_fast_decoding_equals_the_message_store_on_the_recording(session):
    path, _ = session
    log = McapLog(path)
    for topic, typename in log.topics().items():
        if typename not in DECODABLE:
            continue
        datas = [m.data for m in log.raw(topic)]
        fast = decode(typename, datas)
        slow = decode(typename, datas, fast=False)
        assert fast.generic == 0
        for name, column in fast.columns.items():
            other = slow.columns[name]
            if isinstance(column, np.ndarray) and isinstance(other, np.ndarray):
                assert column.dtype == other.dtype and column.tobytes() == other.tobytes(), (topic, name)
            else:
                assert column.tolist() == other.tolist(), (topic, name)


def test_a_recording_cut_in_half_is_salvaged(session, tmp_path):
    path, _ = session
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.warns(TruncatedLogWarning):
        recording = Recording(cut)
    table = recording.episodes_table()
    assert recording.salvaged and table["salvaged"].all()
    last = int(table["episode"].max())
    assert 0 < last < EPISODES - 1
    assert table.filter(pl.col("episode") == last)["aborted"].all()
    full = episodes_table(path).filter(pl.col("episode") < last)
    kept = table.filter(pl.col("episode") < last)
    assert kept.drop("salvaged", "session", "path").equals(full.drop("salvaged", "session", "path"))


def test_report_on_recordings(session, tmp_path):
    path, _ = session
    real = tmp_path / "deployed.mcap"
    shutil.copy(path, real)
    report = write_report(tmp_path / "report", [("nominal", "sim", path), ("nominal", "real", real)])
    metrics = report.comparison.metrics
    assert metrics["gap/nominal/robot_success"] == 0.0 and metrics["gap/nominal/robot_success_p_value"] == 1.0
    assert (tmp_path / "report" / "trajectories.png").stat().st_size > 20_000
