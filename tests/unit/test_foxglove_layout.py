"""The committed Foxglove layout is the generator's, and shows only topics a session records."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.messages import fleet_topics
from pipeline.record.foxglove import layout, layout_json

COMMITTED = Path(__file__).resolve().parents[2] / "pipeline" / "record" / "foxglove_layout.json"


def test_committed_layout_matches_the_generator():
    assert COMMITTED.read_text() == layout_json(["robot_1", "robot_2", "robot_3"])


def test_layout_refers_to_recorded_topics_and_fields():
    data = json.loads(COMMITTED.read_text())
    recorded = set(fleet_topics(["robot_1", "robot_2", "robot_3"]))
    panels = data["configById"]
    assert set(panels["3D!room"]["topics"]) <= recorded and "/mrl/map" in panels["3D!room"]["topics"]
    paths = [p["value"] for key in ("Plot!speed", "Plot!turn", "StateTransitions!events") for p in panels[key]["paths"]]
    assert {p.split(".")[0] for p in paths} <= recorded
    # every panel in the configuration is placed in the layout tree, and vice versa
    placed, stack = set(), [data["layout"]]
    while stack:
        node = stack.pop()
        if isinstance(node, str):
            placed.add(node)
        else:
            stack += [node["first"], node["second"]]
    assert placed == set(panels)


def test_layout_scales_to_any_number_of_robots():
    six = layout([f"robot_{i}" for i in range(1, 7)])
    assert len([t for t in six["configById"]["3D!room"]["topics"] if t.endswith("/scan")]) == 6
