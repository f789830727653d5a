"""Two users on one machine: each deployment holds its DDS domain, a twin fleet without one takes a free one, and a
pinned domain another process holds is refused by name before a training."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.errors import RuntimeFault
from pipeline.ros.domains import FREE_DOMAINS, lease_free_domain, lock_path, pinned_domain_is_free, try_lease
from pipeline.ros.fleet import load_fleet
from tests.domains import BANDS

ROOT = Path(__file__).resolve().parents[2]

HOLD = (
    "import sys, time\n"
    "from pipeline.ros.domains import try_lease\n"
    "lease = try_lease(int(sys.argv[1]))\n"
    "print('held' if lease is not None else 'busy', flush=True)\n"
    "time.sleep(60)\n"
)


def hold(domain_id: int) -> subprocess.Popen[str]:
    """Another process (another user's deployment) holding `domain_id`'s lease until it is killed."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(domain_id)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_a_held_domain_is_not_leased_again_until_its_holder_ends():
    domain = FREE_DOMAINS.stop - 1
    holder = hold(domain)
    try:
        assert try_lease(domain) is None and not pinned_domain_is_free(domain)
        lease = lease_free_domain()
        assert lease.domain_id != domain and lease.domain_id in FREE_DOMAINS
        lease.release()
    finally:
        holder.kill()
        holder.wait()
    time.sleep(0.05)
    again = try_lease(domain)  # the kernel let the lock go with the process, however it ended
    assert again is not None
    again.release()
    assert lock_path(domain).stat().st_mode & 0o666 == 0o666  # any user can open it to take it


def test_deployments_started_together_take_different_domains():
    first = lease_free_domain()
    second = lease_free_domain()
    try:
        assert first.domain_id != second.domain_id
    finally:
        first.release()
        second.release()


def test_the_tests_own_domains_and_the_free_ones_do_not_meet():
    for first, end in BANDS.values():
        assert end <= FREE_DOMAINS.start or first >= FREE_DOMAINS.stop


def test_the_bundled_twin_fleets_pin_no_domain():
    for name in ("twin", "twin_rclpy", "twin_ros1"):
        fleet = load_fleet(name)
        assert fleet.network.domain_id is None
        assert fleet.network_settings().domain_id == 0  # before a deployment leases one


def test_a_pinned_domain_another_deployment_holds_is_refused_before_the_training(tmp_path: Path):
    """The dvc stage fleet_check runs before the trainings: a clash is found then, not after them."""
    import yaml

    from pipeline.ros.domains import check_pinned_domain
    from tests.integration.conftest import write_fleet

    domain = FREE_DOMAINS.stop - 2
    fleet_file = write_fleet(tmp_path / "fleet.yaml", network={"domain_id": domain, "loopback_only": True, "peers": []})
    check_pinned_domain(domain, str(fleet_file))  # nobody holds it: nothing to say
    check_pinned_domain(None, "twin")  # nothing pinned: a twin takes a free one
    params = tmp_path / "params.yaml"
    defaults = yaml.safe_load((ROOT / "params.yaml").read_text())
    defaults["deploy"]["fleet"] = str(fleet_file)
    params.write_text(yaml.safe_dump(defaults))
    holder = hold(domain)
    try:
        with pytest.raises(RuntimeFault, match=rf"DDS domain {domain} already has another deployment on this machine"):
            check_pinned_domain(domain, str(fleet_file))
        done = subprocess.run(
            [sys.executable, str(ROOT / "stages" / "fleet_check.py"), "--params", str(params)],
            capture_output=True, text=True, cwd=tmp_path, timeout=120, check=False,
        )  # fmt: skip
        assert done.returncode == 3, done.stderr
        assert f"fleet_check: DDS domain {domain} already has another deployment" in done.stderr
        assert not (tmp_path / "logs" / "fleet_check.json").exists()
    finally:
        holder.kill()
        holder.wait()
    done = subprocess.run(
        [sys.executable, str(ROOT / "stages" / "fleet_check.py"), "--params", str(params)],
        capture_output=True, text=True, cwd=tmp_path, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert yaml.safe_load((tmp_path / "logs" / "fleet_check.json").read_text())["pinned_domain"] == domain
