"""The calibration drive: held steps of several sizes between the policy's own driving, safe in front of walls."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from pipeline.mappings import from_mapping, to_mapping
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.excitation import ROOM_AHEAD_M, STEP_SIZES, TURN_SHARES, ExcitationDrive
from pipeline.policy.spec import PolicySpec
from tests.policy_helpers import spec_mapping

BEAMS = 15
POLICY_COMMAND = (0.123, 0.0456)


class FixedPolicy:
    """A policy runtime's interface whose every robot always commands `POLICY_COMMAND`."""

    def __init__(self, kind: str = "continuous") -> None:
        mapping = spec_mapping("0" * 64, kind, 3, "rich", BEAMS, "obstacles")
        self.spec = from_mapping(PolicySpec, mapping, "<test>")
        self.layout = self.spec.world.layout()
        self.codec = self.spec.world.codec()
        self.checked: list[tuple[Any, ...]] = []

    @property
    def name(self) -> str:
        return "fixed"

    @property
    def document(self) -> dict[str, Any]:
        return dict(to_mapping(self.spec))

    def commands(self, obs: np.ndarray) -> np.ndarray:
        return np.tile(POLICY_COMMAND, (len(obs), 1))

    def check_fits(self, robots: Any, layout: Any, *args: Any, **kwargs: Any) -> None:
        self.checked.append((tuple(robots), layout))


def observations(policy: FixedPolicy, ahead_m: float) -> np.ndarray:
    """Three robots' observations with every lidar range `ahead_m`."""
    obs = np.zeros((3, policy.layout.size), dtype=np.float32)
    obs[:, policy.layout.slices["ranges"]] = ahead_m
    return obs


def drive(seed: int, ahead_m: float, steps: int = 3000) -> tuple[np.ndarray, FixedPolicy]:
    policy = FixedPolicy()
    excitation = ExcitationDrive(policy, seed=seed)
    obs = observations(policy, ahead_m)
    return np.stack([excitation.commands(obs) for _ in range(steps)]), policy


def held_runs(values: np.ndarray) -> list[tuple[float, int]]:
    """(value, length) of each run of equal consecutive values."""
    runs: list[tuple[float, int]] = []
    for v in values:
        if runs and runs[-1][0] == v:
            runs[-1] = (v, runs[-1][1] + 1)
        else:
            runs.append((float(v), 1))
    return runs


def test_a_robot_holds_forward_steps_of_every_size_and_turns_over_the_whole_range_between_the_policys_driving():
    cmd, policy = drive(seed=3, ahead_m=4.0)
    v_max, w_max = policy.codec.v_max_mps, policy.codec.w_max_radps
    period = policy.spec.world.control_period_s
    for robot in range(3):
        v, w = cmd[:, robot, 0], cmd[:, robot, 1]
        straight = v[(w == 0) & (v > 0)]
        held_v = {round(value / v_max, 6) for value, n in held_runs(straight) if n * period >= 1.0 - 1e-9}
        assert held_v == set(STEP_SIZES), held_v
        turns = w[v == 0]
        held_w = [value / w_max for value, n in held_runs(turns) if value != 0 and n * period >= 1.0 - 1e-9]
        shares = np.sort(np.abs(held_w))
        low, high = TURN_SHARES
        assert len(shares) >= 10 and low - 1e-9 <= shares[0] and shares[-1] <= high + 1e-9, shares
        assert min(held_w) < 0 < max(held_w)  # either way
        # each turn at a level of its own, the levels spread over the whole range: no bracket of fixed levels
        assert len(np.unique(shares.round(6))) == len(shares)
        assert np.max(np.diff(np.r_[low, shares, high])) < 0.25 * (high - low), shares
        stops = [n for value, n in held_runs(np.abs(v) + np.abs(w)) if value == 0]
        assert stops and max(stops) * period >= 1.0
        driven = np.all(cmd[:, robot] == POLICY_COMMAND, axis=1)
        assert 0.1 < driven.mean() < 0.5  # the policy drives a share of the time, not all of it
    # each robot draws its own phases
    assert not np.array_equal(cmd[:, 0], cmd[:, 1])


def test_no_forward_step_starts_without_room_ahead_and_one_in_progress_stops_at_a_wall():
    cmd, _ = drive(seed=5, ahead_m=ROOM_AHEAD_M - 0.1)
    held = cmd[~np.all(cmd == POLICY_COMMAND, axis=2)]
    assert np.all(held[:, 0] == 0.0)  # turns and stops only: the room ahead is shorter than a step needs
    policy = FixedPolicy()
    excitation = ExcitationDrive(policy, seed=5)
    open_room, wall = observations(policy, 4.0), observations(policy, 0.3)
    for _ in range(1000):
        now = excitation.commands(open_room)
        stepping = (now[:, 0] > 0) & (now[:, 1] == 0)
        if stepping.any():
            break
    assert stepping.any()
    assert np.all(excitation.commands(wall)[stepping] == 0.0)


def test_the_drive_is_deterministic_per_seed_and_its_actions_are_the_policys_codec():
    a, _ = drive(seed=11, ahead_m=3.0, steps=400)
    b, _ = drive(seed=11, ahead_m=3.0, steps=400)
    c, _ = drive(seed=12, ahead_m=3.0, steps=400)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    policy = FixedPolicy()
    excitation = ExcitationDrive(policy, seed=0)
    obs = observations(policy, 3.0)
    actions = excitation.actions(obs)
    assert actions.shape == (3, 2) and np.all(np.abs(actions) <= 1.0)
    assert excitation.spec is policy.spec and excitation.document == policy.document
    excitation.check_fits(("robot_1",), policy.layout)
    assert policy.checked == [(("robot_1",), policy.layout)]


def test_a_discrete_policy_is_refused_with_the_reason():
    with pytest.raises(PolicyMismatch, match="holds commands of several sizes"):
        ExcitationDrive(FixedPolicy("discrete"))
