from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.core.actions import ActionCodec
from pipeline.core.errors import ActionError
from pipeline.core.observation import ObservationLayout


def test_paper_layout_is_17_values_for_15_beams():
    layout = ObservationLayout("paper", 15)
    assert layout.size == 17
    assert layout.slices == {"position": slice(0, 2), "ranges": slice(2, 17)}
    assert len(layout.names) == 17 and layout.names[:3] == ("x_m", "y_m", "range_0_m")


def test_rich_layout_slices_and_goal_in_robot_frame():
    layout = ObservationLayout("rich", 15)
    assert layout.size == 21
    pose = np.array([[1.0, 1.0, math.pi / 2]])  # facing +y
    goals = np.array([[1.0, 3.0]])  # 2 m straight ahead
    obs = layout.build(pose, np.full((1, 15), 2.5), goals)
    s = layout.slices
    np.testing.assert_allclose(obs[0, s["position"]], [1.0, 1.0])
    np.testing.assert_allclose(obs[0, s["heading"]], [0.0, 1.0], atol=1e-7)
    np.testing.assert_allclose(obs[0, s["goal_in_robot"]], [2.0, 0.0], atol=1e-6)
    assert obs.dtype == np.float32
    goals_left = np.array([[0.0, 1.0]])  # 1 m to the robot's left when facing +y
    obs = layout.build(pose, np.full((1, 15), 2.5), goals_left)
    np.testing.assert_allclose(obs[0, s["goal_in_robot"]], [0.0, 1.0], atol=1e-6)


def test_layout_rejects_wrong_beam_count_and_unknown_names():
    with pytest.raises(ValueError, match="ranges have shape"):
        ObservationLayout("paper", 15).build(np.zeros((2, 3)), np.zeros((2, 14)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="unknown observation layout"):
        ObservationLayout("fancy", 15)  # type: ignore[arg-type]


def test_bounds_contain_room_and_ranges():
    low, high = ObservationLayout("paper", 15).bounds((0, 6), (0, 4), 0.055, 5.0)
    assert low[0] == -1 and high[0] == 7 and low[2] == np.float32(0.055) and high[-1] == 5.0


def test_continuous_scaling_and_clamping():
    codec = ActionCodec("continuous", 0.4, 0.2)
    cmd = codec.decode(np.array([[1.0, -1.0], [0.5, 0.25], [3.0, -7.0]]))
    np.testing.assert_allclose(cmd, [[0.4, -0.2], [0.2, 0.05], [0.4, -0.2]])
    np.testing.assert_allclose(codec.encode(cmd[:2]), [[1.0, -1.0], [0.5, 0.25]])


def test_forward_only_speed_commands():
    codec = ActionCodec("continuous", 0.4, 0.2, reverse=False)
    cmd = codec.decode(np.array([[-1.0, 0.0], [0.0, 1.0], [1.0, -1.0], [-5.0, 0.5]]))
    np.testing.assert_allclose(cmd, [[0.0, 0.0], [0.2, 0.2], [0.4, -0.2], [0.0, 0.1]])
    np.testing.assert_allclose(codec.encode(cmd[:3]), [[-1.0, 0.0], [0.0, 1.0], [1.0, -1.0]])
    np.testing.assert_allclose(codec.encode(np.array([[-0.3, 0.0]])), [[-1.0, 0.0]])  # no reverse: stop
    mixed = ActionCodec("continuous", 0.4, 0.2, robot_limits=((0.4, 0.2), (0.8, 0.5)), reverse=False)
    np.testing.assert_allclose(mixed.decode(np.array([[0.0, 1.0], [1.0, 1.0]])), [[0.2, 0.2], [0.8, 0.5]])
    assert codec.differences(ActionCodec("continuous", 0.4, 0.2)) == ["actions.reverse False vs True"]


def test_discrete_set_and_limits():
    codec = ActionCodec("discrete", 0.4, 0.2, ("forward", "left", "right", "backward", "stop"))
    np.testing.assert_allclose(
        codec.decode(np.array([0, 1, 2, 3, 4])), [[0.15, 0.0], [0.1, 0.2], [0.1, -0.2], [-0.15, 0.0], [0.0, 0.0]]
    )
    slow = ActionCodec("discrete", 0.12, 0.1, ("forward", "left"))
    np.testing.assert_allclose(slow.table, [[0.12, 0.0], [0.1, 0.1]])


@pytest.mark.parametrize(
    ("codec", "actions", "match"),
    [
        (ActionCodec("discrete", 0.4, 0.2), np.array([0, 3]), r"\[0, 2\]"),
        (ActionCodec("discrete", 0.4, 0.2), np.array([0.5]), "integers"),
        (ActionCodec("continuous", 0.4, 0.2), np.array([[np.nan, 0.0]]), "finite"),
        (ActionCodec("continuous", 0.4, 0.2), np.array([0.1, 0.2]), "shape"),
    ],
)
def test_bad_actions_raise(codec, actions, match):
    with pytest.raises(ActionError, match=match):
        codec.decode(actions)


def test_unknown_discrete_name():
    with pytest.raises(ActionError, match="unknown discrete"):
        ActionCodec("discrete", 0.4, 0.2, ("forward", "jump"))
