"""A Foxglove layout for session recordings: the room in 3D beside per-robot plots.

``python -m pipeline.record.foxglove robot_1 robot_2 robot_3 > layout.json`` writes it for any
robots; ``pipeline/record/foxglove_layout.json`` is the one for the three reference robots.
In Foxglove: open the MCAP (Open local file), then Layouts -> Import from file.

The 3D panel follows ``map`` and shows ``/mrl/map`` (walls, boxes, goal squares, robot bodies on
their ground-truth frames), every robot's scan in its colour and its ground-truth pose. Beside it:
commanded vs measured forward speed and yaw rate per robot, and the episode events.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

from pipeline.messages.convert import ROBOT_RGBA


def _hex(rgba: tuple[float, float, float, float]) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgba[:3])


def layout(robots: Sequence[str], room_centre: tuple[float, float] = (3.0, 2.0)) -> dict[str, Any]:
    """The layout (Foxglove's JSON layout format) for robots with these namespaces."""
    topics: dict[str, Any] = {"/mrl/map": {"visible": True}}
    speed_paths: list[dict[str, Any]] = []
    turn_paths: list[dict[str, Any]] = []
    for i, ns in enumerate(robots):
        colour = _hex(ROBOT_RGBA[i % len(ROBOT_RGBA)])
        topics[f"/{ns}/scan"] = {"visible": True, "colorMode": "flat", "flatColor": colour, "pointSize": 4}
        topics[f"/{ns}/ground_truth"] = {
            "visible": True,
            "type": "arrow",
            "color": colour,
            "arrowScale": [0.3, 0.06, 0.06],
        }
        speed_paths += [
            {
                "value": f"/{ns}/cmd_vel.linear.x",
                "enabled": True,
                "timestampMethod": "receiveTime",
                "label": f"{ns} commanded",
            },
            {
                "value": f"/{ns}/odom.twist.twist.linear.x",
                "enabled": True,
                "timestampMethod": "receiveTime",
                "label": f"{ns} measured",
            },
        ]
        turn_paths += [
            {
                "value": f"/{ns}/cmd_vel.angular.z",
                "enabled": True,
                "timestampMethod": "receiveTime",
                "label": f"{ns} commanded",
            },
            {
                "value": f"/{ns}/odom.twist.twist.angular.z",
                "enabled": True,
                "timestampMethod": "receiveTime",
                "label": f"{ns} measured",
            },
        ]
    return {
        "configById": {
            "3D!room": {
                "followMode": "follow-none",
                "followTf": "map",
                "cameraState": {
                    "distance": 9.0,
                    "perspective": False,
                    "phi": 0.0,
                    "thetaOffset": 0.0,
                    "target": [0, 0, 0],
                    "targetOffset": [room_centre[0], room_centre[1], 0.0],
                    "targetOrientation": [0, 0, 0, 1],
                    "fovy": 45,
                    "near": 0.01,
                    "far": 5000,
                },
                "scene": {"transforms": {"showLabel": False, "axisScale": 0.3}},
                "topics": topics,
                "layers": {
                    "grid": {
                        "layerId": "foxglove.Grid",
                        "instanceId": "grid",
                        "label": "Grid",
                        "visible": True,
                        "frameId": "map",
                        "size": 10,
                        "divisions": 10,
                        "lineWidth": 1,
                        "color": "#248eff40",
                        "position": [room_centre[0], room_centre[1], 0],
                        "rotation": [0, 0, 0],
                    }
                },
            },
            "Plot!speed": {
                "title": "forward speed (m/s)",
                "paths": speed_paths,
                "showLegend": True,
                "xAxisVal": "timestamp",
            },
            "Plot!turn": {
                "title": "yaw rate (rad/s)",
                "paths": turn_paths,
                "showLegend": True,
                "xAxisVal": "timestamp",
            },
            "StateTransitions!events": {
                "paths": [{"value": "/mrl/episode.event", "timestampMethod": "receiveTime", "label": "episode event"}],
            },
        },
        "globalVariables": {},
        "userNodes": {},
        "layout": {
            "direction": "row",
            "first": "3D!room",
            "second": {
                "direction": "column",
                "first": "Plot!speed",
                "second": {
                    "direction": "column",
                    "first": "Plot!turn",
                    "second": "StateTransitions!events",
                    "splitPercentage": 70,
                },
                "splitPercentage": 40,
            },
            "splitPercentage": 60,
        },
    }


def layout_json(robots: Sequence[str]) -> str:
    return json.dumps(layout(robots), indent=2) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    robots = list(argv if argv is not None else sys.argv[1:]) or ["robot_1", "robot_2", "robot_3"]
    sys.stdout.write(layout_json(robots))
    return 0


if __name__ == "__main__":
    sys.exit(main())
