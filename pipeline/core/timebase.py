"""Time units: every time inside the pipeline is an int of nanoseconds, as in ROS 2 stamps."""

from __future__ import annotations

NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000
NS_PER_US = 1_000
