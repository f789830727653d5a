"""A sweep on a real two-node Ray cluster on this machine (a head and a worker node with a CPU each, started with
``ray.cluster_utils.Cluster``): trials land on both nodes, the table equals a local run's, a scenario given as a
file travels with the trials, and a worker node killed mid-sweep loses no row and doubles none."""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import polars as pl
import pytest

from pipeline.bench.sweep import SweepError, _scenario_here, check_address
from pipeline.bench.trials import Trial
from pipeline.ros.ros1 import free_port
from tests.integration.test_sweep import MRL

pytestmark = pytest.mark.integration

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "pipeline" / "core" / "scenarios"
TIMING = ["train_wall_s", "env_steps_per_s", "wall_to_convergence_s", "node_id"]
"""Columns that differ between runs of the same trial by nature (times) or by design (the node)."""


@pytest.fixture
def cluster() -> Iterator[object]:
    from ray.cluster_utils import Cluster

    made = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        made.add_node(num_cpus=1)
        made.wait_for_nodes()
        yield made
    finally:
        made.shutdown()


def sweep(
    params: Path, out: Path, scenario: Path, seeds: tuple[int, int], address: str = "", steps: int = 300
) -> subprocess.Popen[str]:
    command = [
        str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", str(scenario),
        "--seeds", str(seeds[1]), "--first-seed", str(seeds[0]), "--params", str(params), "--out", str(out),
        "--episodes", "2", "--set", f"train.total_steps={steps}", "--bootstrap", "100",
    ]  # fmt: skip
    command += ["--address", address] if address else ["--workers", "1"]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def finished(proc: subprocess.Popen[str], timeout_s: float = 600) -> str:
    out, _ = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, out
    return out


def test_a_sweep_on_a_two_node_cluster(cluster, tiny_params, tmp_path):
    room = tmp_path / "room.yaml"  # a scenario given as a file, read on the driver
    shutil.copyfile(SCENARIOS_DIR / "empty.yaml", room)
    head = cluster.head_node.node_id
    worker = next(n for n in cluster.list_all_nodes() if n.node_id != head)

    # two trials at once, one CPU each: one on each node
    finished(sweep(tiny_params, tmp_path / "on_cluster", room, (0, 2), cluster.address))
    rows = pl.read_parquet(tmp_path / "on_cluster" / "results.parquet")
    assert rows.height == 2 and set(rows["node_id"]) == {head, worker.node_id}
    # the same trials on a local Ray: the same table but for the times and the node
    finished(sweep(tiny_params, tmp_path / "local", room, (0, 2)))
    local = pl.read_parquet(tmp_path / "local" / "results.parquet")
    assert rows.drop(TIMING).equals(local.drop(TIMING))

    # the worker node dies while both trials train: its trial runs again on the head, no row lost or doubled
    out = tmp_path / "killed"
    proc = sweep(tiny_params, out, room, (2, 2), cluster.address, steps=5000)
    deadline = time.monotonic() + 300
    while len(list((out / "trials").glob("*/run"))) < 2:  # both trials are training
        if proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the trials did not start on both nodes: {proc.communicate()[0]}")
        time.sleep(0.2)
    cluster.remove_node(worker, allow_graceful=False)
    text = finished(proc)
    after = pl.read_parquet(out / "results.parquet")
    names = [Trial("sac", "independent", str(room), s).name for s in (2, 3)]
    assert after["name"].to_list() == names and names[0].startswith("sac-independent-room."), text
    assert set(after["node_id"]) == {head}, text
    assert "0 failed" in text


def test_a_cluster_address_that_does_not_answer_is_refused_before_anything_runs(tiny_params, tmp_path):
    port = free_port()
    with pytest.raises(SweepError, match=f"--address 127.0.0.1:{port}: no Ray head answers there"):
        check_address(f"127.0.0.1:{port}", timeout_s=1.0)
    with pytest.raises(SweepError, match="must be HOST:PORT of a Ray head"):
        check_address("head-node")
    proc = subprocess.run(
        [str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", "empty", "--seeds", "1",
         "--params", str(tiny_params), "--out", str(tmp_path / "s"), "--address", f"127.0.0.1:{port}"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 2 and "no Ray head answers there" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "s" / "trials").exists()


def test_a_scenario_file_travels_to_a_node_that_lacks_it(tmp_path):
    text = (SCENARIOS_DIR / "empty.yaml").read_text()
    missing = tmp_path / "elsewhere" / "room.yaml"
    copy = _scenario_here(str(missing), text)
    assert copy is not None and copy != missing and copy.read_text() == text and copy.name == "room.yaml"
    present = tmp_path / "room.yaml"
    present.write_text(text)
    assert _scenario_here(str(present), text) == present
    present.write_text(text + "\n# changed on this node\n")  # another text than the driver's: the driver's wins
    assert _scenario_here(str(present), text).read_text() == text
    assert _scenario_here("empty", None) is None
