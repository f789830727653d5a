from __future__ import annotations

import numpy as np
import pytest
import yaml

from pipeline.core.errors import ScenarioError
from pipeline.core.scenario import bundled_scenarios, load_scenario
from pipeline.errors import ConfigError
from pipeline.mappings import to_mapping


def test_reference_scenarios_match_the_paper():
    empty, obstacles = load_scenario("empty"), load_scenario("obstacles")
    assert {"empty", "obstacles", "six"} <= set(bundled_scenarios())
    for s in (empty, obstacles):
        assert (s.room.x_max_m, s.room.y_max_m) == (6.0, 4.0)
        np.testing.assert_allclose(s.starts, [[1, 1, 0], [4, 2, np.pi], [1, 3, 0]])
        np.testing.assert_allclose(s.goals, [[4.5, 0.5], [1.0, 2.0], [4.5, 3.5]])
        assert s.goal_size_m == 0.4 and s.robot.radius_m == 0.165
        assert s.robot_names == ("robot_1", "robot_2", "robot_3")
    assert empty.obstacles == ()
    assert [(b.x_m, b.y_m, b.size_x_m, b.size_y_m) for b in obstacles.obstacles] == [
        (2.5, 1.0, 0.3, 0.3),
        (2.5, 2.9, 0.3, 0.3),
    ]


def test_user_scenario_file_and_robot_subset(tmp_path):
    data = to_mapping(load_scenario("obstacles"))
    data["name"] = "wide"
    data["room"]["x_max_m"] = 8.0
    data["robots"].append({"start": {"x_m": 7.0, "y_m": 2.0, "yaw_rad": 0.0}, "goal": {"x_m": 7.5, "y_m": 3.5}})
    path = tmp_path / "wide.yaml"
    path.write_text(yaml.safe_dump(data))
    wide = load_scenario(path)
    assert wide.n_robots == 4 and wide.robot_names[-1] == "robot_4"
    assert load_scenario(path, n_robots=1).n_robots == 1
    with pytest.raises(ScenarioError, match="1 to 4 robots"):
        load_scenario(path, n_robots=5)


def _broken(mutate) -> dict:
    data = to_mapping(load_scenario("obstacles"))
    mutate(data)
    return data


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda d: d["robots"][1]["start"].update(x_m=1.2, y_m=1.1), "robot_1 and robot_2 start .* overlap"),
        (lambda d: d["robots"][0]["goal"].update(x_m=5.9), "goal of robot_1 .* does not lie inside the room"),
        (
            lambda d: d["robots"][0]["start"].update(x_m=2.5, y_m=1.1),
            "robot_1 starts at .* inside or touching obstacle 0",
        ),
        (lambda d: d["robots"][2]["start"].update(x_m=6.5), "robot_3 starts at .* outside the room"),
        (lambda d: d["obstacles"][0].update(x_m=5.95), "obstacle 0 .* reaches outside the room"),
        (
            lambda d: d["robots"][2]["goal"].update(x_m=4.3, y_m=0.7),
            r"the goal squares of robot_1 at \(4.5, 0.5\) and robot_3 at \(4.3, 0.7\) overlap",
        ),
        (
            lambda d: d.update(goal_size_m=0.05) or d["robots"][1]["goal"].update(x_m=4.56, y_m=0.5),
            r"robot_1 at \(4.5, 0.5\) and robot_2 at \(4.56, 0.5\) are too close for both robots to stand in them",
        ),
    ],
)
def test_impossible_geometry_fails_before_simulation(mutate, match):
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_broken(mutate))


def test_bad_scenario_data_names_the_key(tmp_path):
    path = tmp_path / "bad.yaml"
    data = to_mapping(load_scenario("empty"))
    data["robots"][0]["goal"]["x_m"] = "far"
    data["obstacles"] = [
        {"kind": "cylinder", "x_m": 1, "y_m": 1, "size_x_m": 1, "size_y_m": 1, "height_m": 1, "yaw_rad": 0}
    ]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    text = str(info.value)
    assert str(path) in text and "robots[0].goal.x_m = 'far'" in text and "obstacles[0].kind" in text


def test_unknown_scenario_name_lists_bundled_ones():
    with pytest.raises(ConfigError, match=r"bundled scenario .*obstacles"):
        load_scenario("warehouse")


def test_overlapping_goal_squares_name_the_file_and_both_goals(tmp_path):
    data = to_mapping(load_scenario("six"))
    data["robots"][4]["goal"] = {"x_m": 0.75, "y_m": 0.4}  # robot_5 onto robot_4's square at (0.6, 0.5)
    path = tmp_path / "crowded.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    assert "robot_4 at (0.6, 0.5) and robot_5 at (0.75, 0.4) overlap" in text
    assert "goal_size_m 0.4" in text and f"(scenario file {path})" in text and "\n" not in text


@pytest.mark.parametrize("apart", [0.4, 0.41])
def test_goal_squares_that_touch_or_stand_apart_are_accepted(apart):
    data = to_mapping(load_scenario("empty"))
    data["robots"][2]["goal"] = {"x_m": 4.5 - apart, "y_m": 0.5}
    assert load_scenario(data).goals[2][0] == pytest.approx(4.5 - apart)


def test_bundled_scenarios_keep_their_goals_apart():
    for name in bundled_scenarios():
        assert load_scenario(name).n_robots >= 3


def test_another_layout_of_the_same_room_and_robots_is_nothing_beyond_a_layout():
    drawn = load_scenario("obstacles_random")
    assert drawn.beyond_layout(load_scenario("obstacles_random_in_way")) == []
    assert drawn.beyond_layout(load_scenario("obstacles")) == []  # the paper's fixed layout of the room
    assert drawn.beyond_layout(load_scenario("empty")) == ["other obstacles (2 vs 0, or other sizes)"]
    assert drawn.beyond_layout(load_scenario("six")) == ["3 robots vs 6"]
    assert drawn.beyond_layout(load_scenario("mixed")) == ["robot_3's body or speed limits differ"]
    assert drawn.beyond_layout(load_scenario("pursuit")) == ["target differs"]
    bigger = to_mapping(drawn)
    bigger["obstacles"][1]["size_x_m"] = 0.5
    assert drawn.beyond_layout(load_scenario(bigger)) == ["other obstacles (2 vs 2, or other sizes)"]
