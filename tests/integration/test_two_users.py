"""Two users on one machine: two deployments on the bundled twin fleet at once (no domain given, as two ``dvc
repro`` loops in two clones run them) each take a DDS domain of their own and record clean sessions; a third that
pins the domain one of them holds is refused by name before its twin starts."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

from pipeline.messages.convert import EVENT_NAMES
from pipeline.record import McapLog
from tests.integration.conftest import write_fleet
from tests.integration.test_mrl_command import MRL

pytestmark = pytest.mark.integration


def deploy(policy: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    """`mrl deploy` of `policy` for one episode at 1x (the robots' own pace: two twins and two runners on a 2-core host
    fell behind at 2x, and the deployments rightly refused their sessions as the host's)."""
    return subprocess.Popen(
        [str(MRL), "deploy", "--policy", str(policy), "--episodes", "1", "--time-scale", "1", "--out", str(out),
         *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


@pytest.mark.alone  # two twins and two runners at 1x: a second worker's test beside them takes the host they keep
def test_two_deployments_on_the_bundled_twin_fleet_at_once_record_clean_sessions(tiny_policy, tmp_path):
    runs = [deploy(tiny_policy, tmp_path / f"user_{k}", "--fleet", "twin") for k in (1, 2)]
    outputs = [run.communicate(timeout=300) for run in runs]
    domains = []
    for k, (run, (_, stderr)) in enumerate(zip(runs, outputs, strict=True), start=1):
        assert run.returncode == 0, stderr
        log = McapLog(tmp_path / f"user_{k}" / "session.mcap")
        session = log.metadata()["session"]
        domains.append(int(session["domain_id"]))
        names = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
        assert names.count("start") == 1 and names.count("end") == 1
        # one twin per session: every scan came from its own deployment's twin (the runner refuses a second writer)
        assert log.message_counts().get("/robot_1/scan", 0) > 0
    assert domains[0] != domains[1]


def test_a_pinned_domain_held_by_a_running_deployment_is_refused_before_its_twin_starts(tiny_policy, tmp_path):
    first = deploy(tiny_policy, tmp_path / "first", "--fleet", "twin", "--episodes", "3")
    try:
        domain = None
        for line in first.stderr:  # its progress names the domain once its twin is ready
            if "DDS domain" in line:
                domain = int(line.split("DDS domain", 1)[1].split()[0].strip(",;:"))
                break
        assert domain is not None, "the first deployment never said its domain"
        pinned = write_fleet(tmp_path / "fleet.yaml", network={"domain_id": domain, "loopback_only": True, "peers": []})
        done = subprocess.run(
            [str(MRL), "deploy", "--policy", str(tiny_policy), "--fleet", str(pinned), "--episodes", "1",
             "--out", str(tmp_path / "second")],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        assert done.returncode == 3, done.stderr
        assert f"DDS domain {domain} already has another deployment on this machine" in done.stderr
        assert not (tmp_path / "second").exists()
        assert yaml.safe_load(pinned.read_text())["network"]["domain_id"] == domain
    finally:
        first.kill()
        first.wait()
