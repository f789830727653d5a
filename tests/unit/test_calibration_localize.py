"""Localization against the map: the occupancy grid, scan matching, global localization, whole recordings."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.calibration.calibrate import calibrate
from pipeline.calibration.errors import CalibrationError
from pipeline.calibration.localize import (
    OccupancyMap,
    compose,
    global_localize,
    interpolate_poses,
    inverse,
    localize_robot,
    match_scan,
    scan_points,
    track_episode,
)
from pipeline.calibration.options import CalibrationSettings
from pipeline.calibration.raycast import MapGeometry
from pipeline.calibration.recording import read_session
from pipeline.core.scenario import load_scenario
from tests.calibration_helpers import simulate_session

BEAMS = 360
ANGLES = -math.pi + np.arange(BEAMS) * 2 * math.pi / BEAMS


def synthetic_scan(scenario_name: str, pose: np.ndarray, noise_m: float, rng: np.random.Generator) -> np.ndarray:
    geometry = MapGeometry.from_scenario(load_scenario(scenario_name))
    hits = geometry.cast(pose[:2], pose[2] + ANGLES)
    return hits.range_m + rng.normal(0.0, noise_m, BEAMS)


def test_the_distance_field_is_signed_at_the_walls_and_boxes():
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    room = load_scenario("obstacles").room
    inside = np.array([[room.x_min_m + 0.5, 2.0], [room.x_min_m + 0.05, 2.0], [room.x_min_m - 0.03, 2.0]])
    d = grid.distance_only(inside)
    assert d[0] == pytest.approx(0.5, abs=0.02) and d[1] == pytest.approx(0.05, abs=0.01) and d[2] < 0


def test_a_map_server_map_reads_back_as_written(tmp_path):
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    path = grid.write_map_server(tmp_path / "floor.yaml")
    meta = yaml.safe_load(path.read_text())
    assert meta["image"] == "floor.pgm" and meta["mode"] == "trinary" and len(meta["origin"]) == 3
    back = OccupancyMap.from_map_server(path)
    np.testing.assert_array_equal(back.occupied, grid.occupied)
    assert back.resolution_m == grid.resolution_m and back.origin == grid.origin


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"resolution": None}, "missing key(s) resolution"),
        ({"mode": "fancy"}, "mode 'fancy'"),
        ({"resolution": -0.05}, "resolution must be > 0"),
        ({"image": "nowhere.pgm"}, "cannot read the map image"),
        ({"origin": "left"}, "must be numbers"),
    ],
)
def test_a_bad_map_server_file_is_refused_naming_it(tmp_path, change, message):
    path = OccupancyMap.from_scenario(load_scenario("empty")).write_map_server(tmp_path / "floor.yaml")
    meta = yaml.safe_load(path.read_text())
    for key, value in change.items():
        if value is None:
            del meta[key]
        else:
            meta[key] = value
    path.write_text(yaml.safe_dump(meta))
    with pytest.raises(CalibrationError) as err:
        OccupancyMap.from_map_server(path)
    assert message in str(err.value) and "floor.yaml" in str(err.value)


def test_a_scan_match_recovers_the_pose_and_its_interval_covers_it():
    """From priors 10 cm and 0.1 rad off, 1 cm range noise: the match lands within a centimetre, and the
    reported standard deviations give 95 % intervals that cover the true pose in at least 90 % of trials."""
    rng = np.random.default_rng(4)
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    covered, errors = 0, []
    trials = 30
    for _ in range(trials):
        truth = np.array([rng.uniform(0.6, 3.4), rng.uniform(0.6, 1.6), rng.uniform(-math.pi, math.pi)])
        ranges = synthetic_scan("obstacles", truth, 0.01, rng)
        pts = scan_points(ranges, -math.pi, 2 * math.pi / BEAMS, 180)
        prior = truth + np.array([0.07, -0.07, 0.1])
        m = match_scan(grid, pts, prior)
        err = m.pose - truth
        err[2] = math.remainder(err[2], 2 * math.pi)
        errors.append(math.hypot(err[0], err[1]))
        std = np.sqrt(np.diag(m.covariance))
        covered += bool(np.all(np.abs(err) <= 1.96 * std))
        assert m.score > 0.9
    assert np.median(errors) < 0.01
    assert covered >= 0.9 * trials


def test_global_localization_finds_the_robot_in_the_obstacle_room():
    rng = np.random.default_rng(1)
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    truth = np.array([1.1, 3.3, 0.7])
    pts = scan_points(synthetic_scan("obstacles", truth, 0.01, rng), -math.pi, 2 * math.pi / BEAMS, 180)
    found = global_localize(grid, pts)
    assert not found.ambiguous
    assert math.hypot(*(found.match.pose[:2] - truth[:2])) < 0.03
    assert abs(math.remainder(found.match.pose[2] - truth[2], 2 * math.pi)) < 0.02


def test_a_symmetric_room_is_refused_as_ambiguous_without_an_initial_pose():
    """The empty room looks the same turned by 180 degrees about its centre: global localization refuses,
    an initial pose settles it."""
    rng = np.random.default_rng(2)
    grid = OccupancyMap.from_scenario(load_scenario("empty"))
    truth = np.array([1.0, 1.5, 0.3])
    pts = [scan_points(synthetic_scan("empty", truth, 0.005, rng), -math.pi, 2 * math.pi / BEAMS, 180)]
    odom_t = np.array([0, 10**9])
    odom = np.zeros((2, 3))
    with pytest.raises(CalibrationError, match="ambiguous"):
        track_episode(grid, np.array([0]), pts, odom_t, odom, np.zeros(3), None, "bag")
    near = truth + np.array([0.05, 0.05, 0.05])
    track = track_episode(grid, np.array([0]), pts, odom_t, odom, np.zeros(3), near, "bag")
    assert math.hypot(*(track.pose[0, :2] - truth[:2])) < 0.02 and track.start == "initial pose"


def narrow_scan(pose: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A scan of the obstacle room at `pose` that sees only 60 degrees ahead (the other beams without return)."""
    angles = -math.pi + np.arange(BEAMS) * 2 * math.pi / BEAMS
    return np.where(np.abs(angles) <= math.radians(30), synthetic_scan("obstacles", pose, 0.01, rng), np.nan)


def test_a_first_scan_that_fits_two_poses_is_told_apart_by_the_next_scans():
    """A first scan that sees only 60 degrees ahead fits the obstacle room at the truth and turned about the room's
    centre; the next scans, full ones taken as the robot drives ahead, fit only the truth, which wins."""
    rng = np.random.default_rng(5)
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    truth = np.array([1.5, 2.0, 0.0])
    first = narrow_scan(truth, rng)
    assert global_localize(grid, scan_points(first, -math.pi, 2 * math.pi / BEAMS, 180)).ambiguous
    n = 41
    poses = np.stack([truth[0] + 0.01 * np.arange(n), np.full(n, truth[1]), np.zeros(n)], axis=1)
    ranges = [first] + [synthetic_scan("obstacles", poses[k], 0.01, rng) for k in range(1, n)]
    pts = [scan_points(r, -math.pi, 2 * math.pi / BEAMS, 180) for r in ranges]
    t = np.arange(n, dtype=np.int64) * 10**8
    odom = poses - poses[0]
    track = track_episode(grid, t, pts, t, odom, np.zeros(3), None, "bag")
    assert math.hypot(*(track.pose[0, :2] - truth[:2])) < 0.03
    assert track.start.startswith("global over")


def test_a_first_scan_that_fits_two_poses_of_a_map_the_rest_do_not_fit_is_a_wrong_map_not_an_ambiguity():
    """A narrow first scan fits the obstacle room at two poses (inliers over 70 %), but the scans after it fit it
    nowhere (another place): the map is named as not matching, not an ambiguity to settle with --initial-pose."""
    rng = np.random.default_rng(5)
    grid = OccupancyMap.from_scenario(load_scenario("obstacles"))
    truth = np.array([1.5, 2.0, 0.0])
    first = narrow_scan(truth, rng)
    n = 41
    elsewhere = [rng.uniform(0.5, 5.0, BEAMS) for _ in range(1, n)]  # ranges of a place the map does not hold
    pts = [scan_points(r, -math.pi, 2 * math.pi / BEAMS, 180) for r in [first, *elsewhere]]
    t = np.arange(n, dtype=np.int64) * 10**8
    odom = np.stack([0.01 * np.arange(n), np.zeros(n), np.zeros(n)], axis=1)
    with pytest.raises(CalibrationError, match=r"do not match the map: the first scan fits it at .* is this the map"):
        track_episode(grid, t, pts, t, odom, np.zeros(3), None, "bag")


def corridor() -> OccupancyMap:
    """A 10 x 1.6 m corridor with pillars every 2 m: another building than the reference room."""
    occupied = np.ones((100, 520), dtype=bool)
    occupied[10:90, 10:510] = False
    for x in range(60, 500, 100):
        occupied[10:20, x : x + 10] = True
    return OccupancyMap(occupied, 0.02, (0.0, 0.0, 0.0), "corridor")


def test_scans_of_another_building_are_refused_with_the_match_score():
    rng = np.random.default_rng(3)
    grid = corridor()
    pts = [scan_points(synthetic_scan("obstacles", np.array([1.0, 1.0, 0.2]), 0.01, rng), -math.pi, 0.01745, 180)]
    with pytest.raises(CalibrationError, match=r"do not match the map: at best \d+% of the endpoints"):
        track_episode(grid, np.array([0]), pts, np.array([0, 10**9]), np.zeros((2, 3)), np.zeros(3), None, "bag")


def test_compose_and_inverse_undo_each_other():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    back = compose(inverse(a), compose(a, b))
    back[:, 2] = np.remainder(back[:, 2] - b[:, 2] + np.pi, 2 * np.pi) - np.pi + b[:, 2]
    np.testing.assert_allclose(back, b, atol=1e-12)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> Path:
    return simulate_session(tmp_path_factory.mktemp("loc") / "session.mcap", {}, episodes=2, steps=80, seed=1)


def test_localized_poses_follow_the_ground_truth(simulated):
    full = read_session(simulated, ["odometry"], pose_source="ground_truth")
    data = read_session(simulated, ["odometry"], pose_source="scans")
    grid = OccupancyMap.from_scenario(data.scenario)
    for robot, reference in zip(data.robots, full.robots, strict=True):
        series, info = localize_robot(grid, robot, data.windows, np.zeros(3), None, "sim")
        truth = interpolate_poses(series.time.t_ns, reference.truth.time.t_ns, reference.truth.pose)
        err = np.hypot(*(series.pose[:, :2] - truth[:, :2]).T)
        assert np.median(err) < 0.01 and err.max() < 0.03, robot.name
        assert info.starts[0].startswith("global") and info.median_score > 0.9


def test_calibration_without_ground_truth_says_where_its_poses_came_from(simulated, tmp_path):
    nogt = simulate_session(tmp_path / "nogt.mcap", {}, episodes=2, steps=80, seed=1, omit=["/ground_truth"])
    with_gt = calibrate(simulated, CalibrationSettings(bootstrap=30))
    without = calibrate(nogt, CalibrationSettings(bootstrap=30))
    assert with_gt.pose_source.kind == "ground_truth" and without.pose_source.kind == "localized"
    assert without.pose_source.median_score > 0.9 and "obstacles" in without.pose_source.map
    assert "localized from the same scans" in without.values["lidar.mount_yaw_rad"].reason
    for key in ("actuation.linear_gain", "actuation.angular_gain", "lidar.noise_sigma_m", "base.wheel_separation_m"):
        a, b = with_gt.values[key], without.values[key]
        assert a.ok and b.ok and b.value == pytest.approx(a.value, rel=0.15), key


def test_the_lidar_mounting_comes_from_tf_static_when_the_recording_has_it(tmp_path):
    """A lidar 6 cm ahead of the base and turned 0.05 rad: with /tf_static the localized base follows the
    ground truth and the calibration reports the description's mounting; without it the mounting is
    unidentifiable."""
    mount = {"lidar": {"mount_xy_m": [0.06, 0.0], "mount_yaw_rad": 0.05}}
    common = {"episodes": 1, "steps": 60, "seed": 2, "omit": ["/ground_truth"]}
    with_tf = simulate_session(tmp_path / "tf.mcap", mount, tf_static=True, **common)
    without_tf = simulate_session(tmp_path / "notf.mcap", mount, **common)
    reference = simulate_session(tmp_path / "gt.mcap", mount, episodes=1, steps=60, seed=2)
    truth = read_session(reference, ["odometry"], pose_source="ground_truth")
    errors = {}
    for name, path in (("tf", with_tf), ("no tf", without_tf)):
        data = read_session(path, ["odometry"])
        robot = data.robots[0]
        assert (robot.lidar_mount is not None) == (name == "tf")
        m = np.asarray(robot.lidar_mount if robot.lidar_mount is not None else (0.0, 0.0, 0.0))
        series, _ = localize_robot(OccupancyMap.from_scenario(data.scenario), robot, data.windows, m, None, name)
        ref = truth.robots[0].truth
        expected = interpolate_poses(series.time.t_ns, ref.time.t_ns, ref.pose)
        errors[name] = float(np.median(np.hypot(*(series.pose[:, :2] - expected[:, :2]).T)))
    assert errors["tf"] < 0.01 < errors["no tf"]
    cal = calibrate(with_tf, CalibrationSettings(parts=("lidar",), bootstrap=20))
    assert cal.values["lidar.mount_xy_m[0]"].value == pytest.approx(0.06)
    assert cal.values["lidar.mount_yaw_rad"].value == pytest.approx(0.05)
    assert cal.values["lidar.mount_yaw_rad"].method == "from /tf_static"
    bare = calibrate(without_tf, CalibrationSettings(parts=("lidar",), bootstrap=20))
    assert "no /tf_static" in bare.values["lidar.mount_yaw_rad"].reason


def test_a_map_without_a_scenario_gives_the_lidar_its_faces_and_a_stand_in_room():
    scenario = load_scenario("obstacles")
    grid = OccupancyMap.from_scenario(scenario)
    faces = grid.geometry(0.165)
    walls = MapGeometry.from_scenario(scenario)
    rng = np.random.default_rng(3)
    angles = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    errors = []
    for _ in range(30):
        origin = np.array([rng.uniform(0.2, 5.8), rng.uniform(0.2, 3.8)])
        if walls.clearance(origin[None])[0] < 0.2:
            continue
        a = faces.cast(origin[None, None, :], angles[None, :]).range_m
        b = walls.cast(origin[None, None, :], angles[None, :]).range_m
        assert np.isfinite(a).all()  # a closed room: every ray ends on a face
        errors.append(np.abs(a - b).ravel())
    err = np.concatenate(errors)
    # the same room to within the grid's 2 cm, but for rays grazing a box's rasterized corner (1.5 % of rays here)
    assert np.mean(err <= 0.021) >= 0.98 and np.median(err) == 0.0
    # each face's normal points into free space; merged runs: a few dozen faces, not a face per cell
    mid = (faces.a + faces.b) / 2
    assert (grid.distance_only(mid + 0.05 * faces.normal) > 0.04).all()
    assert (grid.distance_only(mid - 0.05 * faces.normal) < -0.04).all()
    assert len(faces.names) < 40 and all(n.startswith("wall_") for n in faces.names)
    room = grid.scenario("map floor.yaml", 1)
    assert room.name == "map floor.yaml" and room.n_robots == 1 and room.obstacles == ()
    assert room.room.x_min_m < 0 < 6 < room.room.x_max_m and room.robot == scenario.robot
    with pytest.raises(CalibrationError, match="no obstacle next to free space"):
        OccupancyMap(np.zeros((10, 10), dtype=bool), 0.05, (0.0, 0.0, 0.0), "blank").geometry(0.165)


def test_a_map_too_large_is_refused_from_its_header_before_it_is_read(tmp_path, monkeypatch):
    from PIL import Image

    from pipeline.calibration import localize

    Image.new("L", (40, 30), 254).save(tmp_path / "floor.pgm")
    (tmp_path / "floor.yaml").write_text("image: floor.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    monkeypatch.setattr(localize, "MAX_MAP_CELLS", 1000)
    with pytest.raises(CalibrationError) as err:
        localize.OccupancyMap.from_map_server(tmp_path / "floor.yaml")
    text = str(err.value)
    assert str(tmp_path / "floor.yaml") in text and "40 x 30 cells" in text and "crop it" in text
    monkeypatch.setattr(localize, "MAX_MAP_CELLS", 1200)
    assert localize.OccupancyMap.from_map_server(tmp_path / "floor.yaml").occupied.shape == (30, 40)
