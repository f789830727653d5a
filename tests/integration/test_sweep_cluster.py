"""A sweep on a real Ray cluster on this machine, started with Ray's own commands as docs/benchmarks.md's recipe
does (``ray start --head``, ``ray start --address``; here with ``--block`` so that the test owns the nodes'
processes): trials land on both nodes, the table equals a local run's, a scenario given as a file travels with the
trials, a worker node killed mid-sweep loses no row and doubles none, and a node that has not this package's
source is refused by name before any trial runs."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import polars as pl
import pytest

import pipeline
from pipeline.bench.hosts import HostsUnavailable, OtherHost, other_host
from pipeline.bench.sweep import SweepError, _scenario_here, check_address
from pipeline.bench.trials import Trial
from pipeline.ros.ros1 import free_port
from tests.integration.test_sweep import MRL

pytestmark = pytest.mark.integration

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "pipeline" / "core" / "scenarios"
RAY = Path(sys.executable).parent / "ray"
TIMING = ["train_wall_s", "env_steps_per_s", "wall_to_convergence_s", "node_id", "finished_utc"]
"""Columns that differ between runs of the same trial by nature (times) or by design (the node)."""
NODES = """
import json, sys, ray
ray.init(address=sys.argv[1], log_to_driver=False, logging_level="ERROR")
print(json.dumps({n["NodeID"]: "node:__internal_head__" in n["Resources"] for n in ray.nodes() if n["Alive"]}))
"""


class RecipeCluster:
    """Nodes started with ``ray start ... --block`` in sessions of their own, on a free port of loopback, with a home
    of their own (the token the recipe makes goes there, not into the user's ``~/.ray``)."""

    def __init__(self, cwd: Path, ip: str = "127.0.0.1") -> None:
        self.port = free_port()
        self.address = f"{ip}:{self.port}"
        self.cwd = cwd
        self.home = cwd / "home"
        self.home.mkdir(exist_ok=True)
        self.env = {**os.environ, "HOME": str(self.home)}
        self.env.pop("RAY_AUTH_MODE", None)
        self.nodes: list[subprocess.Popen[bytes]] = []
        self.started = 0

    def token(self) -> str:
        """The head's token, made where none exists (``ray get-auth-token --generate``, as the recipe says)."""
        done = subprocess.run([str(RAY), "get-auth-token", "--generate"], capture_output=True, text=True, timeout=120,
                              check=True, env=self.env)  # fmt: skip
        return done.stdout.strip().splitlines()[-1]

    def start(
        self, *args: str, env: dict[str, str] | None = None, host: OtherHost | None = None
    ) -> subprocess.Popen[bytes]:
        """A node as the recipe starts it: token authentication on, the head's token handed to the others; on
        `host` (another host's network) where given."""
        token = {} if "--head" in args else {"RAY_AUTH_TOKEN": self.token()}
        log = (self.cwd / f"node{self.started}.log").open("wb")
        self.started += 1
        command = [str(RAY), "start", *args, "--num-cpus", "1", "--disable-usage-stats", "--block"]
        command = host.command(*command) if host is not None else command
        proc = subprocess.Popen(
            command, cwd=self.cwd, stdout=log, stderr=subprocess.STDOUT,
            env={**self.env, "RAY_AUTH_MODE": "token", **token, **(env or {})}, start_new_session=True,
        )  # fmt: skip
        self.nodes.append(proc)
        return proc

    def alive(self) -> dict[str, bool]:
        """{node id: is the head} of the cluster's live nodes."""
        done = subprocess.run(
            [sys.executable, "-c", NODES, self.address], capture_output=True, text=True, timeout=120, check=False,
            env={**self.env, "RAY_AUTH_MODE": "token"},  # as the sweep's driver does where it finds a token
        )  # fmt: skip
        return dict(json.loads(done.stdout.strip().splitlines()[-1])) if done.returncode == 0 else {}

    def wait_for(self, count: int, timeout_s: float = 180) -> dict[str, bool]:
        deadline = time.monotonic() + timeout_s
        while len(nodes := self.alive()) != count:
            if time.monotonic() > deadline or any(proc.poll() is not None for proc in self.nodes):
                logs = {p.name: p.read_text(errors="replace")[-2000:] for p in self.cwd.glob("node*.log")}
                pytest.fail(f"the cluster has {len(nodes)} live nodes, not {count}: {logs}")
            time.sleep(1.0)
        return nodes

    def kill(self, proc: subprocess.Popen[bytes], sig: int = signal.SIGKILL) -> None:
        """End a node: SIGKILL to its whole process group, a machine that dies (nothing of it is left behind)."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        proc.wait(timeout=60)
        self.nodes.remove(proc)


@pytest.fixture
def recipe_cluster(tmp_path: Path) -> Iterator[RecipeCluster]:
    """A head and a worker node with a CPU each, as the recipe starts them."""
    cluster = RecipeCluster(tmp_path)
    cluster.token()
    try:
        cluster.start("--head", "--port", str(cluster.port), "--node-ip-address", "127.0.0.1",
                      "--include-dashboard", "false")  # fmt: skip
        cluster.wait_for(1)
        cluster.start("--address", cluster.address, "--node-ip-address", "127.0.0.1")
        cluster.wait_for(2)
        yield cluster
    finally:
        for proc in reversed(cluster.nodes):
            cluster.kill(proc)


def sweep(
    params: Path, out: Path, scenario: Path, seeds: tuple[int, int], address: str = "", steps: int = 300,
    env: dict[str, str] | None = None,
) -> subprocess.Popen[str]:  # fmt: skip
    command = [
        str(MRL), "sweep", "--algorithms", "sac", "--modes", "independent", "--scenarios", str(scenario),
        "--seeds", str(seeds[1]), "--first-seed", str(seeds[0]), "--params", str(params), "--out", str(out),
        "--episodes", "2", "--set", f"train.total_steps={steps}", "--bootstrap", "100",
    ]  # fmt: skip
    command += ["--address", address] if address else ["--workers", "1"]
    # run from the sweep's folder: Ray puts the driver's working folder on its workers' path, and a checkout there
    # would hand every node this package whatever the node has installed
    out.parent.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=out.parent,
                            env=env)  # fmt: skip


def finished(proc: subprocess.Popen[str], timeout_s: float = 600, returncode: int = 0) -> str:
    out, _ = proc.communicate(timeout=timeout_s)
    assert proc.returncode == returncode, out
    return out


def test_a_sweep_on_a_cluster_started_as_the_recipe_says(recipe_cluster, tiny_params, tmp_path):
    cluster = recipe_cluster
    room = tmp_path / "room.yaml"  # a scenario given as a file, read on the driver
    shutil.copyfile(SCENARIOS_DIR / "empty.yaml", room)
    nodes = cluster.alive()
    head = next(node for node, is_head in nodes.items() if is_head)

    # a driver without the head's token is refused in one line that says where the token comes from
    elsewhere = {**cluster.env, "HOME": str(tmp_path / "elsewhere")}
    text = finished(sweep(tiny_params, tmp_path / "no_token", room, (0, 1), cluster.address, env=elsewhere), 120, 2)
    assert "ray get-auth-token" in text and "Traceback" not in text and not (tmp_path / "no_token" / "trials").exists()

    # two trials at once, one CPU each: one on each node, every node checked first (the driver finds the token)
    text = finished(sweep(tiny_params, tmp_path / "on_cluster", room, (0, 2), cluster.address, env=cluster.env))
    assert f"cluster at {cluster.address}: 2 nodes with this package's source, 2 CPUs" in text
    rows = pl.read_parquet(tmp_path / "on_cluster" / "results.parquet")
    assert rows.height == 2 and set(rows["node_id"]) == set(nodes), text
    runs = json.loads((tmp_path / "on_cluster" / "sweep.json").read_text())
    assert len(runs) == 1 and runs[0]["address"] == cluster.address and sorted(runs[0]["ran"]) == rows["name"].to_list()
    assert set(rows["commit"]) == {runs[0]["commit"]} and runs[0]["commit"] != "unknown"
    # the same trials on a local Ray: the same table but for the times and the node
    finished(sweep(tiny_params, tmp_path / "local", room, (0, 2)))
    local = pl.read_parquet(tmp_path / "local" / "results.parquet")
    assert rows.drop(TIMING).equals(local.drop(TIMING))

    # the worker node dies while both trials train: its trial runs again on the head, no row lost or doubled
    out = tmp_path / "killed"
    proc = sweep(tiny_params, out, room, (2, 2), cluster.address, steps=5000, env=cluster.env)
    deadline = time.monotonic() + 300
    while len(list((out / "trials").glob("*/run"))) < 2:  # both trials are training
        if proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"the trials did not start on both nodes: {proc.communicate()[0]}")
        time.sleep(0.2)
    cluster.kill(cluster.nodes[1])
    text = finished(proc)
    after = pl.read_parquet(out / "results.parquet")
    names = [Trial("sac", "independent", str(room), s).name for s in (2, 3)]
    assert after["name"].to_list() == names and names[0].startswith("sac-independent-room."), text
    assert set(after["node_id"]) == {head}, text
    assert "0 failed" in text

    # two nodes join whose `pipeline` is not the driver's: one with edited source, one where it cannot be imported
    # (a package of that name first on their PYTHONPATH); the sweep names both and moves nothing, not even the rows
    # of other settings it would set aside
    edited = tmp_path / "edited"
    shutil.copytree(Path(pipeline.__file__).parent, edited / "pipeline", ignore=shutil.ignore_patterns("__pycache__"))
    with (edited / "pipeline" / "bench" / "sweep.py").open("a") as f:
        f.write("\n# edited on this node\n")
    broken = tmp_path / "broken" / "pipeline"
    broken.mkdir(parents=True)
    (broken / "__init__.py").write_text("raise ImportError('not installed here')\n")
    for count, shadow in enumerate((edited, broken.parent), start=2):  # one at a time: a raylet starts in seconds
        cluster.start("--address", cluster.address, "--node-ip-address", "127.0.0.1",
                      env={"PYTHONPATH": str(shadow)})  # fmt: skip
        cluster.wait_for(count)
    rows_before = {p: p.read_bytes() for p in (tmp_path / "on_cluster" / "trials").glob("*/row.json")}
    proc = sweep(tiny_params, tmp_path / "on_cluster", room, (0, 2), cluster.address, steps=400, env=cluster.env)
    text = finished(proc, returncode=2)
    assert "has other source of this package" in text and "cannot import this package (ImportError" in text, text
    assert "install this package" in text and "Traceback" not in text, text
    assert len([line for line in text.splitlines() if line.startswith("mrl sweep:")]) == 1, text
    assert {p: p.read_bytes() for p in (tmp_path / "on_cluster" / "trials").glob("*/row.json")} == rows_before
    assert not list((tmp_path / "on_cluster" / "trials").glob("*/row.stale-*.json"))


def test_a_driver_in_token_mode_reaches_a_head_without_authentication(tmp_path):
    cluster = RecipeCluster(tmp_path)
    cluster.token()  # the driver has a token; the head does not ask for one
    try:
        cluster.start("--head", "--port", str(cluster.port), "--node-ip-address", "127.0.0.1",
                      "--include-dashboard", "false", env={"RAY_AUTH_MODE": "disabled"})  # fmt: skip
        deadline = time.monotonic() + 120
        while not check_answers(cluster.address):
            assert time.monotonic() < deadline and cluster.nodes[0].poll() is None, "the head did not start"
            time.sleep(0.5)
        connect = (
            "import ray\nfrom pipeline.bench.sweep import _connect\n"
            f"_connect('{cluster.address}', 1, 1.0, print)\nimport os\nprint(os.environ['RAY_AUTH_MODE'])\n"
            "ray.shutdown()\n"
        )
        done = subprocess.run([sys.executable, "-c", connect], capture_output=True, text=True, timeout=180,
                              env=cluster.env, cwd=tmp_path, check=False)  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        assert f"cluster at {cluster.address}: 1 nodes with this package's source" in done.stdout
        assert done.stdout.strip().splitlines()[-1] == "token"
    finally:
        for proc in list(cluster.nodes):
            cluster.kill(proc)


def check_answers(address: str) -> bool:
    try:
        check_address(address, timeout_s=0.5)
    except SweepError:
        return False
    return True


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


def test_a_worker_node_on_another_host_joins_the_head_here_and_takes_trials(tiny_params, tmp_path):
    """A lab's cluster: the head on this host, bound to the interface that reaches the other host; a worker node
    there (its own network, reached over a veth pair) joins it as the recipe says; the sweep's trials land on both
    (that the table equals a local run's is tested on loopback above)."""
    room = tmp_path / "room.yaml"
    shutil.copyfile(SCENARIOS_DIR / "empty.yaml", room)
    try:
        hosts = other_host("r")
        host = hosts.__enter__()
    except HostsUnavailable as exc:
        pytest.skip(str(exc))
    cluster = RecipeCluster(tmp_path, host.here_addr)
    try:
        cluster.token()
        cluster.start("--head", "--port", str(cluster.port), "--node-ip-address", host.here_addr,
                      "--include-dashboard", "false")  # fmt: skip
        cluster.wait_for(1)
        cluster.start("--address", cluster.address, "--node-ip-address", host.there_addr, host=host)
        nodes = cluster.wait_for(2)
        text = finished(sweep(tiny_params, tmp_path / "across", room, (0, 2), cluster.address, env=cluster.env))
        assert f"cluster at {cluster.address}: 2 nodes with this package's source, 2 CPUs" in text
        rows = pl.read_parquet(tmp_path / "across" / "results.parquet")
        assert rows.height == 2 and set(rows["node_id"]) == set(nodes), text
    finally:
        for proc in reversed(cluster.nodes):
            cluster.kill(proc)
        hosts.__exit__(None, None, None)
