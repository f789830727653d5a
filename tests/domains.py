"""DDS domain ids for tests: never the default one, and in a parallel run (pytest -n N) each worker draws from a
share of its own of every band, so that two tests running at once on one host never share a domain."""

from __future__ import annotations

import os

BANDS = {"hosts": (20, 40), "loopback": (40, 100), "contract": (100, 130), "fleet": (130, 160)}
"""Per use, the domain ids [first, end) its tests draw from; clear of the domains deployments lease for themselves
(`pipeline.ros.domains.FREE_DOMAINS`)."""


def domain_id(band: str, salt: int) -> int:
    """A domain id of `band` for this worker; `salt` (a counter, a process id, a random draw) picks within its
    share."""
    first, end = BANDS[band]
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    index = int(worker) if worker.isdigit() else 0
    workers = max(int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")), 1)
    width = max((end - first) // workers, 1)
    return first + (index % workers) * width + salt % width
