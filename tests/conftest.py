from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]

UNIT_NICENESS = 10
"""Scheduling priority of the unit tier in a parallel run: the integration tier's twins, runners and peers keep real
time against deadlines (a reset's 10 s, a command's validity), so they take the CPU first."""
OFFLINE = frozenset(
    f"tests/integration/{name}.py"
    for name in (
        "test_analysis_sim",
        "test_calibration_inputs",
        "test_eval_sim_session",
        "test_export_agreement",
        "test_imitation",
        "test_layout_failures_run",
        "test_map_replay",
        "test_memory_dropout",
        "test_path_teacher",
        "test_replay",
        "test_scripted_eval_stage",
        "test_selection",
        "test_teachers_script",
        "test_world_workers",
    )
)
"""Integration modules without deadlines (simulation, files, training; no twin, fleet, peer or Ray cluster): in a
parallel run they go with the unit tier."""


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """A parallel run (pytest -n N) sends the integration tier (but its `OFFLINE` modules) to one worker as a whole,
    in order, so that its module and session fixtures are made once and no two of its deployments run at once; the
    other modules go to the other workers (and to that one when it is done)."""
    from xdist.scheduler import LoadScopeScheduling

    class IntegrationInOne(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return "tests/integration" if _real_time(module) else module

    return IntegrationInOne(config, log)


def pytest_runtest_setup(item: pytest.Item) -> None:
    """In a parallel run, the unit tier and the `OFFLINE` modules at `UNIT_NICENESS`, the rest of the integration tier
    at the default priority (a worker runs both kinds in turn; lowering the niceness again needs the right to, which
    root has: without it the worker stays at the lower priority)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return
    module = Path(str(item.path)).relative_to(ROOT).as_posix()
    with contextlib.suppress(PermissionError):
        os.setpriority(os.PRIO_PROCESS, 0, 0 if _real_time(module) else UNIT_NICENESS)


def _real_time(module: str) -> bool:
    """Whether a test module (its path from the repository's root) runs against deadlines: the integration tier but
    its `OFFLINE` modules."""
    return module.startswith("tests/integration/") and module not in OFFLINE


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
