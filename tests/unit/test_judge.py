from __future__ import annotations

import numpy as np
import pytest

from pipeline.core import judge as judge_module
from pipeline.core import scenario as scenario_module
from pipeline.core.judge import REWARD_TERMS, EpisodeJudge, JudgeStep, RewardWeights
from pipeline.core.scenario import load_scenario

WEIGHTS = RewardWeights(progress_per_m=1.5, goal=1.0, team=10.0, collision=-1.0, step=-0.01)


@pytest.fixture
def judge() -> EpisodeJudge:
    j = EpisodeJudge(load_scenario("obstacles"), WEIGHTS, max_steps=350, collision_margin_m=0.02)
    j.reset(j.scenario.starts)
    return j


def test_goal_square_membership(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = (4.5 + 0.199, 0.5 - 0.199)
    pose[1, :2] = (1.0 + 0.201, 2.0)
    assert judge.in_goal(pose).tolist() == [True, False, False]


def test_progress_term_and_exact_sum(judge):
    pose = judge.scenario.starts.copy()
    before = judge.goal_distance(pose)
    pose[0, 0] += 0.1
    step = judge.step(pose, truth_pose=pose)
    after = judge.goal_distance(pose)
    np.testing.assert_allclose(step.terms["progress"], 1.5 * (before - after))
    assert set(step.terms) == set(REWARD_TERMS)
    for i in range(3):
        terms = step.robot_terms(i)
        assert sum(terms.values()) == float(step.reward[i])


def test_collisions_with_wall_box_and_robot(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = (2.5 - 0.15 - 0.165 + 0.01, 1.0)  # touching box 0
    pose[1, :2] = (5.9, 2.0)  # 0.1 m from the east wall: body through it
    step = judge.step(pose, truth_pose=pose)
    assert step.collided.tolist() == [True, True, False]
    assert step.terms["collision"].tolist() == [-1.0, -1.0, 0.0]
    assert step.done.tolist() == [True, True, False]
    assert (0, "collision") in step.events and (1, "collision") in step.events
    # robots that are done earn nothing more and do not collide again
    again = judge.step(pose, truth_pose=pose)
    assert again.reward[:2].tolist() == [0.0, 0.0]
    assert again.terms["collision"][:2].tolist() == [0.0, 0.0]


def test_robot_robot_collision():
    scenario = load_scenario("empty")
    j = EpisodeJudge(scenario, WEIGHTS, 350)
    pose = scenario.starts.copy()
    j.reset(pose)
    pose[0, :2] = (3.0, 2.0)
    pose[1, :2] = (3.0 + 0.32, 2.0)
    assert j.step(pose, truth_pose=pose).collided.tolist() == [True, True, False]


def test_lidar_fallback_without_ground_truth(judge):
    pose = judge.scenario.starts.copy()
    ranges = np.full((3, 15), 2.0)
    ranges[2, 7] = 0.17  # closer than radius + margin
    step = judge.step(pose, truth_pose=None, ranges=ranges)
    assert step.collided.tolist() == [False, False, True]


def test_team_bonus_when_all_reach_and_success(judge):
    pose = judge.scenario.starts.copy()
    pose[:, :2] = judge.scenario.goals
    step = judge.step(pose, truth_pose=pose)
    assert step.reached.all() and step.team_success
    assert step.terms["team"].tolist() == [10.0] * 3
    assert step.terms["goal"].tolist() == [1.0] * 3
    assert (-1, "success") in step.events
    assert not step.truncated


def test_timeout_truncates_at_max_steps():
    scenario = load_scenario("empty")
    j = EpisodeJudge(scenario, WEIGHTS, max_steps=3)
    pose = scenario.starts.copy()
    j.reset(pose)
    flags = [j.step(pose, truth_pose=pose).truncated for _ in range(3)]
    assert flags == [False, False, True]


def test_collision_beats_goal_in_the_same_step(judge):
    pose = judge.scenario.starts.copy()
    pose[0, :2] = judge.scenario.goals[0]  # inside its goal square ...
    pose[1, :2] = judge.scenario.goals[0] + (0.0, 0.32)  # ... with robot_2 touching it
    step = judge.step(pose, truth_pose=pose)
    assert judge.in_goal(pose)[0]
    assert step.collided[0] and not step.reached[0]


def test_proximity_term_grows_linearly_to_contact():
    weights = RewardWeights(proximity=-1.0, proximity_m=0.3)
    judge = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    pose = judge.scenario.starts.copy()
    judge.reset(pose)
    radius = judge.scenario.robot.radius_m
    pose[0, :2] = (1.0, radius + 0.15)  # robot_1 0.15 m from the bottom wall: half way in
    pose[1, :2] = (4.0, 2.0)  # robot_2 in the open (the nearest box is 0.85 m off)
    pose[2, :2] = (1.0, 4.0 - radius - 0.3)  # robot_3 just at the edge
    step = judge.step(pose, truth_pose=pose)
    np.testing.assert_allclose(step.terms["proximity"], [-0.5, 0.0, 0.0], atol=1e-9)
    assert not step.collided.any()
    # without ground truth the gap comes from the closest lidar return, as for collisions
    lidar = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    lidar.reset(judge.scenario.starts)
    ranges = np.full((3, 15), 4.0)
    ranges[1, 3] = radius + 0.06
    step = lidar.step(judge.scenario.starts, ranges=ranges)
    np.testing.assert_allclose(step.terms["proximity"], [0.0, -0.8, 0.0], atol=1e-9)
    # a robot whose scan has no valid return is not penalized (nor is its reward nan)
    blank = EpisodeJudge(load_scenario("obstacles"), weights, max_steps=350, collision_margin_m=0.02)
    blank.reset(judge.scenario.starts)
    unknown = np.full((3, 15), 4.0)
    unknown[0] = np.nan
    quiet = blank.step(judge.scenario.starts, ranges=unknown)
    assert np.isfinite(quiet.reward).all() and quiet.terms["proximity"][0] == 0.0
    # off by default; the terms still sum to the reward
    assert RewardWeights().proximity == 0.0
    assert float(step.reward[1]) == pytest.approx(sum(step.robot_terms(1).values()))


@pytest.mark.parametrize("name", ["obstacles", "ten"])
def test_the_clearance_to_every_box_at_once_is_each_box_s_distance_bit_for_bit(name):
    """The judge takes the clearance to all boxes in one pass; it equals the walls', each box's (box_clearance) and
    the other robots' distances taken one at a time, to the last bit, at 2000 random poses in and around the room."""
    from pipeline.core.scenario import box_clearance

    scenario = load_scenario(name)
    judge = EpisodeJudge(scenario, RewardWeights(), max_steps=10)
    rng = np.random.default_rng(0)
    room, radius = scenario.room, judge.radius_m
    for _ in range(2000):
        n = scenario.n_robots
        xy = np.column_stack(
            [
                rng.uniform(room.x_min_m - 0.5, room.x_max_m + 0.5, n),
                rng.uniform(room.y_min_m - 0.5, room.y_max_m + 0.5, n),
            ]
        )
        gap = np.minimum.reduce([xy[:, 0] - room.x_min_m, room.x_max_m - xy[:, 0], xy[:, 1] - room.y_min_m,
                                 room.y_max_m - xy[:, 1]]) - radius  # fmt: skip
        for box in scenario.obstacles:
            gap = np.minimum(gap, box_clearance(box, xy) - radius)
        dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) - (radius[:, None] + radius[None, :])
        np.fill_diagonal(dist, np.inf)
        gap = np.minimum(gap, dist.min(axis=1))
        pose = np.column_stack([xy, rng.uniform(-3, 3, n)])
        assert np.array_equal(judge.clearance(pose), gap)


class ArrayJudge(EpisodeJudge):
    """The judge as it reads on arrays (numpy on every robot at once): the reference the judge's float reading must
    equal to the bit."""

    def clearance(self, pose: np.ndarray) -> np.ndarray:  # the arrays' reading
        """(n_robots,) free distance (m) between each robot's body and the nearest wall, box or robot."""
        xy = np.asarray(pose)[:, :2]
        room = self.scenario.room
        walls = np.minimum(
            np.minimum(xy[:, 0] - room.x_min_m, room.x_max_m - xy[:, 0]),
            np.minimum(xy[:, 1] - room.y_min_m, room.y_max_m - xy[:, 1]),
        )
        gap = walls - self.radius_m
        if len(self._boxes):
            gap = np.minimum(gap, scenario_module.boxes_clearance(self._boxes, xy).min(axis=1) - self.radius_m)
        if len(xy) > 1:
            diff = xy[:, None, :] - xy[None, :, :]
            dist = np.hypot(diff[..., 0], diff[..., 1]) - (self.radius_m[:, None] + self.radius_m[None, :])
            np.fill_diagonal(dist, np.inf)
            gap = np.minimum(gap, dist.min(axis=1))
        return np.asarray(gap)

    def step(
        self, odom_pose: np.ndarray, truth_pose: np.ndarray | None = None, ranges: np.ndarray | None = None
    ) -> JudgeStep:
        """Judge the step that just ended.

        odom_pose, truth_pose: (n_robots, 3) x, y (m), yaw (rad); ranges: (n_robots, n_beams) m,
        used for collisions only when no truth pose is given.
        """
        active = ~self.done
        pose = truth_pose if truth_pose is not None else odom_pose
        self.steps += 1
        if truth_pose is not None:
            gap = self.clearance(truth_pose)
        elif ranges is not None:
            gap = np.asarray(ranges).min(axis=1) - self.radius_m
        else:
            gap = np.full(len(active), np.inf)
        hit = gap < self.margin_m
        arrived = self.in_goal(pose)
        new_collided = active & hit
        new_reached = active & arrived & ~hit
        if self.capture_m is not None and new_reached.any():  # one robot's capture is the whole team's
            new_reached = active & ~hit
        dist = self.goal_distance(pose)
        w = self.weights
        zeros = np.zeros(len(active))
        heading_err = self.heading_error(pose) if w.heading_per_rad else zeros
        terms = {
            "progress": np.where(active, w.progress_per_m * (self._prev_dist - dist), 0.0),
            "heading": np.where(active, w.heading_per_rad * (self._prev_heading_err - heading_err), 0.0),
            "goal": np.where(new_reached, w.goal, 0.0),
            "team": zeros.copy(),
            "collision": np.where(new_collided, w.collision, 0.0),
            "step": np.where(active, w.step, 0.0),
            "proximity": np.where(active, w.proximity * judge_module._closeness(gap, w.proximity_m), 0.0)
            if w.proximity
            else zeros.copy(),
        }
        self._prev_dist = np.where(active, dist, self._prev_dist)
        self._prev_heading_err = np.where(active, heading_err, self._prev_heading_err)
        self.reached |= new_reached
        self.collided |= new_collided
        events = [(int(i), "collision") for i in np.flatnonzero(new_collided)]
        events += [(int(i), "goal") for i in np.flatnonzero(new_reached)]
        if not self.team_success and self.reached.all():
            self.team_success = True
            terms["team"] = np.full(len(active), w.team)
            events.append((-1, "success"))
        truncated = bool(self.steps >= self.max_steps and not self.done.all())
        if truncated:
            events += [(int(i), "timeout") for i in np.flatnonzero(~self.done)]
        reward = zeros.copy()
        for name in REWARD_TERMS:
            reward = reward + terms[name]
        return judge_module.JudgeStep(
            reward=reward,
            terms=terms,
            reached=self.reached.copy(),
            collided=self.collided.copy(),
            done=self.done,
            active=active,
            truncated=truncated,
            team_success=self.team_success,
            events=events,
        )


def _same(a, b) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize(
    ("name", "distance", "weights", "truth"),
    [
        ("obstacles", "geodesic", RewardWeights(), True),
        ("obstacles", "euclidean", RewardWeights(heading_per_rad=0.5, proximity=-1.0, step=-0.01), True),
        ("obstacles", "geodesic", RewardWeights(heading_per_rad=0.3, proximity=-0.5, path_clearance_m=0.1), False),
        ("ten", "geodesic", RewardWeights(proximity=-1.0), True),
        ("pursuit", "geodesic", RewardWeights(proximity=-1.0), True),
        ("empty", "euclidean", WEIGHTS, True),
    ],
)
def test_the_judges_float_reading_is_the_arrays_reading_to_the_bit(name, distance, weights, truth):
    """Two judges in step over 60 random episodes (random walks, jumps into goals, walls, boxes and other robots,
    scans with gaps): every reward, term, flag and event of the judge is the arrays' reading's to the last bit."""
    scenario = load_scenario(name)
    rng = np.random.default_rng(7)
    judges = [cls(scenario, weights, max_steps=25, distance=distance) for cls in (EpisodeJudge, ArrayJudge)]
    seen: set[str] = set()
    room, n = scenario.room, scenario.n_robots
    for _ in range(60):
        pose = scenario.starts.astype(np.float64).copy()
        for judge in judges:
            judge.reset(pose)
        if scenario.pursuit:
            target = rng.uniform([room.x_min_m, room.y_min_m], [room.x_max_m, room.y_max_m])
            for judge in judges:
                judge.track(target)
        for _ in range(25):
            pose = pose + np.column_stack([rng.normal(0, 0.08, (n, 2)), rng.normal(0, 0.3, n)])
            jump = rng.random(n)
            pose[jump < 0.04, :2] = scenario.goals[jump < 0.04] + rng.uniform(
                -0.25, 0.25, (int((jump < 0.04).sum()), 2)
            )
            pose[jump > 0.97, 0] = room.x_max_m - rng.uniform(0, 0.3)
            ranges = rng.uniform(0.1, 4.0, (n, 12))
            ranges[rng.random(n) < 0.2] = np.nan
            got, want = (
                j.step(pose, truth_pose=pose if truth else None, ranges=None if truth else ranges) for j in judges
            )
            assert _same(got.reward, want.reward)
            assert got.terms.keys() == want.terms.keys()
            assert all(_same(got.terms[k], want.terms[k]) for k in want.terms)
            for field in ("reached", "collided", "done", "active"):
                assert _same(getattr(got, field), getattr(want, field)), field
            assert (got.truncated, got.team_success, got.events) == (want.truncated, want.team_success, want.events)
            seen |= {kind for _, kind in got.events}
            if got.done.all() or got.truncated:
                break
    assert _same(judges[0].clearance(pose), judges[1].clearance(pose))
    assert {"collision", "goal"} <= seen  # the sequences reach the judgements that branch
