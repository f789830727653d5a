from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]

SHARED_SCOPES = {
    "tests/integration/test_calibration_twin.py": "twin_session",
    "tests/integration/test_calibration_plain_bags.py": "twin_session",
}
"""Modules whose session fixtures (integration/conftest.py::twin_session's recordings) one worker of a parallel run
makes once for all of them."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """A parallel run (pytest -n N) sends whole modules to a worker, so that module and session fixtures are made
    once (the modules of `SHARED_SCOPES` together)."""
    from xdist.scheduler import LoadScopeScheduling

    class ByModule(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return SHARED_SCOPES.get(module, module)

    return ByModule(config, log)


@pytest.fixture
def params_data() -> dict:
    """The repository's params.yaml as a fresh mapping."""
    return yaml.safe_load((ROOT / "params.yaml").read_text())


@pytest.fixture
def write_params(tmp_path: Path):
    def write(data: dict, name: str = "params.yaml") -> Path:
        path = tmp_path / name
        path.write_text(yaml.safe_dump(data))
        return path

    return write


@pytest.fixture(scope="session")
def ros1_master(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A private ROS 1 master (Debian's rosmaster on a free loopback port) for the whole session: rospy binds a
    process to one master. Skips where Debian's ROS 1 is absent."""
    from tests.peers import ros1

    why = ros1.missing()
    if why is not None:
        pytest.skip(why)
    with ros1.master(tmp_path_factory.mktemp("ros1")) as uri:
        yield uri
