"""The deploy runner (Cyclone DDS) driving three robot drivers built on Fast DDS, over real discovery on loopback.

The drivers are C++ programs compiled here from the pipeline's IDL with Debian's fastddsgen and
libfastrtps-dev (``tests/peers``); the tier skips where those packages are absent (``.ci/run``
installs them).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.record import McapLog
from tests.integration.conftest import free_domain_id
from tests.peers import drivers, fastdds

pytestmark = [
    pytest.mark.integration,
    pytest.mark.skipif(fastdds.missing() is not None, reason=str(fastdds.missing())),
]


@pytest.fixture(scope="module")
def driver_binary() -> Path:
    return fastdds.build()


def test_the_runner_drives_fast_dds_robots_through_whole_episodes(driver_binary, tiny_policy, tmp_path):
    recording, logs, results = fastdds.deploy_on_drivers(
        driver_binary, tiny_policy, tmp_path, episodes=2, domain=free_domain_id()
    )
    assert McapLog(recording).metadata()["session"]["transport"] == "dds"
    drivers.check_whole_episodes(recording, logs, results, episodes=2)
