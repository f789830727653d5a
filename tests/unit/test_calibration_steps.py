"""Calibration's steps: the registry runs the estimators of the parts asked for, in order, each reading streams that
the gathering knows; a step of two parts runs only with both."""

from __future__ import annotations

import pytest

from pipeline.calibration.options import PARTS
from pipeline.calibration.steps import STEPS, wanted
from pipeline.calibration.streams import STREAM_NAMES, Gathered, gather


def test_every_step_reads_streams_the_gathering_makes_and_belongs_to_known_parts() -> None:
    assert len({step.label for step in STEPS}) == len(STEPS)
    for step in STEPS:
        assert set(step.reads) <= set(STREAM_NAMES), step.label
        assert set(step.parts) <= set(PARTS), step.label
    fields = set(Gathered.__dataclass_fields__)
    assert set(STREAM_NAMES) - {"scans"} <= fields and {"beams", "scan_stamps"} <= fields


def test_the_parts_asked_for_choose_the_steps_in_the_registry_s_order() -> None:
    labels = lambda parts: [s.label for s in wanted(parts)]  # noqa: E731
    assert labels(PARTS) == [s.label for s in STEPS]
    assert labels(("lidar",)) == ["lidar"]
    assert labels(("odometry",)) == ["odometry and wheels"]
    assert labels(("actuation",)) == ["actuation", "randomization ranges"]
    assert labels(("network", "odometry", "actuation")) == [
        "actuation",
        "odometry and wheels",
        "motors",
        "randomization ranges",
        "network and clock",
    ]


def test_gathering_a_stream_no_step_reads_is_refused() -> None:
    with pytest.raises(ValueError, match="streams wheels: not among"):
        gather([], [], ("wheels",), None, None)  # type: ignore[arg-type]
