"""``mrl replay BAG --map``: a bag without motion capture (a building's map_server map, a 720-beam lidar, a drive of
its own) replayed open loop against its path localized in the map, in the nominal and in the calibrated simulator."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from calibration_scale import DRIVE, building, drive, write_bag

from pipeline.calibration.map_replay import REST_S, TICK_S, rest_starts
from pipeline.sim.open_loop import Track
from tests.integration.test_mrl_command import mrl, refused

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def building_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, str]:
    """A 20 x 20 m building and a 3-minute bag of one robot driving its corridors (stops every 20 s)."""
    folder = tmp_path_factory.mktemp("building")
    floor, corners = building(20.0, 0.05, 0)
    map_yaml = floor.write_map_server(folder / "building.yaml")
    run = drive(corners, 180.0)
    write_bag(folder / "building.mcap", floor, run, 0)
    return folder / "building.mcap", map_yaml, ",".join(f"{v:.3f}" for v in run["pose"][0])


def test_the_calibrated_simulator_stays_on_the_localized_path_where_the_nominal_one_drifts(building_bag, tmp_path):
    bag, map_yaml, start = building_bag
    calibrated = mrl(
        "calibrate", bag, "--map", map_yaml, f"--initial-pose={start}", "--pose-source", "scans",
        "--parts", "lidar,actuation", "--out", tmp_path / "cal", timeout=300,
    )  # fmt: skip
    assert calibrated.returncode == 0, calibrated.stderr
    # the bag's drive is of the simulator's model class: the effective values' intervals hold what it was made with
    effective = yaml.safe_load((tmp_path / "cal" / "calibration.yaml").read_text())["effective"]
    for name, made_with in (("drive_delay_s", DRIVE["delay_s"]), ("drive_lag_s", DRIVE["time_constant_s"])):
        low, high = effective[name]["interval_95"]
        assert low <= made_with <= high, (name, effective[name])
    done = mrl(
        "replay", bag, "--map", map_yaml, f"--initial-pose={start}", "--calibration",
        tmp_path / "cal" / "calibration.yaml", "--out", tmp_path / "replay", timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    figures = json.loads((tmp_path / "replay" / "replay_map.json").read_text())
    assert figures["windows"] >= 4
    # the bag's drive has a delay, a lag and gains of its own: the nominal simulator drifts, more with time
    assert figures["nominal/drift_30s_mean_m"] > figures["nominal/drift_5s_mean_m"] > 0.05
    # the calibrated one carries those values and stays within a few centimetres of the localized path
    assert figures["calibrated/drift_30s_mean_m"] < 0.1
    assert figures["calibrated/drift_30s_mean_m"] < figures["nominal/drift_30s_mean_m"] / 4
    report = (tmp_path / "replay" / "replay_map.md").read_text()
    assert "| 30 s |" in report and "localized in building.yaml" in report


def test_replay_needs_a_policy_or_a_map_not_both(building_bag, tmp_path):
    bag, map_yaml, _ = building_bag
    refused(mrl("replay", bag, "--out", tmp_path / "r"), "replay", "--policy", "--map")
    refused(mrl("replay", bag, "--map", map_yaml, "--policy", tmp_path, "--out", tmp_path / "r"), "replay", "--map")


def test_the_command_s_map_horizons_are_the_replay_s():
    from pipeline.calibration.map_replay import HORIZONS_S
    from pipeline.mrl.replay import MAP_HORIZONS_S

    assert MAP_HORIZONS_S == HORIZONS_S


def test_windows_start_where_every_robot_has_stood_still_for_a_second():
    ns = 1_000_000_000
    t = np.arange(0, 10 * ns, ns // 10)
    moving = np.tile([0.2, 0.0], (len(t), 1))
    moving[(t >= 2 * ns) & (t < 4 * ns)] = 0.0  # stands still 2 s from t = 2 s
    other = moving.copy()
    other[(t >= 3 * ns) & (t < 4 * ns)] = [0.0, 0.1]  # but the second robot turns from t = 3 s
    one = Track(t, moving)
    assert rest_starts([one]).tolist() == [4 * ns - round(TICK_S * 1e9)]  # and none after 5 s
    assert rest_starts([one, Track(t, other)]).tolist() == []  # never both still for REST_S
    assert REST_S == 1.0


def test_a_simulated_robot_that_reaches_a_wall_of_the_map_stays_where_it_was_free():
    from pipeline.core.scenario import load_scenario
    from pipeline.params import world_config
    from pipeline.sim.open_loop import open_loop_errors
    from pipeline.sim.world import SimWorld

    scenario = load_scenario("empty", 1)
    sim = SimWorld(scenario, world_config({"control_period_s": TICK_S}))
    start = np.array([[1.0, 3.0, 0.0]])
    ns = 1_000_000_000
    commands = [Track(np.array([0], dtype=np.int64), np.array([[0.3, 0.0]]))]  # forward, held
    recorded = [Track(np.arange(0, 3 * ns, ns // 50), np.tile([1.0, 3.0, 0.0], (150, 1)))]  # the robot stayed put
    ticks = 100
    free_err, free_hit = open_loop_errors(sim, start, commands, recorded, 0, 3 * ns, ticks, TICK_S)
    wall_err, wall_hit = open_loop_errors(
        sim, start, commands, recorded, 0, 3 * ns, ticks, TICK_S, blocked=lambda xy: xy[:, 0] > 1.2
    )
    assert not free_hit.any() and wall_hit.all()
    assert free_err[-1, 0] > 0.4  # it drove on, 2 s at up to 0.3 m/s
    assert 0.15 < wall_err[-1, 0] <= 0.2 + 1e-9  # it stopped at its last free place, short of x = 1.2
    assert np.all(np.diff(wall_err[-40:, 0]) == 0)  # and stayed there


def test_a_bag_without_a_window_to_replay_is_one_line_naming_it(tmp_path):
    """15 s of driving never holds a 30 s window that starts at rest: refused with the bag and the reason."""
    floor, corners = building(20.0, 0.05, 0)
    map_yaml = floor.write_map_server(tmp_path / "building.yaml")
    run = drive(corners, 15.0)
    bag = tmp_path / "short.mcap"
    write_bag(bag, floor, run, 0)
    start = ",".join(f"{v:.3f}" for v in run["pose"][0])
    done = mrl("replay", bag, "--map", map_yaml, f"--initial-pose={start}", "--out", tmp_path / "r", timeout=300)
    line = refused(done, "replay", str(bag))
    assert "no 30 s stretch of path with commands" in line and "standing still" in line
    assert not (tmp_path / "r" / "replay_map.md").exists()
    # --horizon-s is the window: 5 s windows fit in the 15 s drive, and the drift is read at 5 s alone
    done = mrl(
        "replay", bag, "--map", map_yaml, f"--initial-pose={start}", "--horizon-s", "5", "--out", tmp_path / "r5",
        timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    figures = json.loads((tmp_path / "r5" / "replay_map.json").read_text())
    assert figures["window_s"] == 5 and "nominal/drift_5s_mean_m" in figures
    assert not [k for k in figures if "30s" in k or "10s" in k]
    assert "replay: localizing 1 robot(s)" in done.stderr  # long work says where it is


def test_a_teleoperated_robot_that_stood_still_before_its_first_command_has_a_window():
    """Teleoperation sends commands only while the robot moves (the first at 10.3 s, then silence when released):
    the 10 s before it and each silence past the driver's timeout are standing still, so windows start there."""
    from pipeline.calibration.map_replay import COMMAND_TIMEOUT_S, command_tracks
    from pipeline.calibration.recording import CommandSeries, MessageTimes, PoseSeries, RobotData

    ns = 1_000_000_000
    sent = np.r_[np.arange(10.3, 20.0, 0.1), np.arange(25.0, 40.0, 0.1)]  # released from 20 s to 25 s
    t = (sent * ns).round().astype(np.int64)
    commands = CommandSeries(t, np.full(len(t), 0.2), np.zeros(len(t)))
    truth_t = np.arange(0, 40 * ns, ns // 8)
    truth = PoseSeries(MessageTimes(truth_t, truth_t, truth_t, 0), np.zeros((len(truth_t), 3)))
    (track,) = command_tracks([RobotData("robot_1", truth, None, None, commands)])
    assert track.last_at(5 * ns).tolist() == [0.0, 0.0]  # before the first command: standing still
    assert track.last_at(int(20.0 * ns + COMMAND_TIMEOUT_S * ns) + 1).tolist() == [0.0, 0.0]  # the driver stopped
    assert track.last_at(int(15 * ns)).tolist() == [0.2, 0.0]
    starts = rest_starts([track]) / ns
    assert len(starts) == 2
    assert starts[0] == pytest.approx(10.3 - TICK_S, abs=1e-6)  # the 10 s of standing before teleoperation
    assert starts[1] == pytest.approx(25.0 - TICK_S, abs=1e-6)  # the silence after release


def test_a_bag_without_a_window_is_refused_before_the_localization(tmp_path, monkeypatch):
    """The windows' starts are looked for in the commands first: a bag with none is refused without localizing."""
    import importlib

    from pipeline.calibration.errors import CalibrationError
    from pipeline.calibration.map_replay import map_replay
    from pipeline.params import world_config

    floor, corners = building(20.0, 0.05, 0)
    map_yaml = floor.write_map_server(tmp_path / "building.yaml")
    run = drive(corners, 15.0)
    bag = tmp_path / "short.mcap"
    write_bag(bag, floor, run, 0)

    def localized(*args, **kwargs):
        raise AssertionError("localized before the windows were checked")

    calibrate_module = importlib.import_module("pipeline.calibration.calibrate")  # the module, not its function
    monkeypatch.setattr(calibrate_module, "localize_robot", localized)
    start = tuple(float(v) for v in run["pose"][0])
    with pytest.raises(CalibrationError, match="no 30 s stretch of path with commands"):
        map_replay([bag], map_yaml, {"nominal": world_config({})}, initial_pose=start)
    with pytest.raises(AssertionError, match="localized before"):  # a shorter window exists: localization runs
        map_replay([bag], map_yaml, {"nominal": world_config({})}, horizons_s=(5.0,), initial_pose=start)
