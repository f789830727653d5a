"""Deployment against the hardware twin in a separate process, over DDS on loopback, recorded to MCAP."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import polars as pl
import psutil
import pytest
import yaml

from pipeline.analysis.tables import episodes_table
from pipeline.core.scenario import load_scenario
from pipeline.errors import ConfigError
from pipeline.messages.convert import EVENT_NAMES
from pipeline.policy.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.rollout.errors import DeployAborted, FleetNotReady
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration

SIM_LAYOUT = {"/tf", "/mrl/observation", "/mrl/action", "/mrl/episode"} | {
    f"/robot_{i}/{t}" for i in (1, 2, 3) for t in ("scan", "odom", "ground_truth", "cmd_vel")
}


def deploy(policy: Path, fleet_file: Path, out: Path, episodes: int = 1, **kwargs):
    request = DeployRequest(episodes=episodes, seed=5, recording=out / "session.mcap", progress=False)
    return deploy_policy(PolicyRuntime(policy), load_fleet(fleet_file), str(fleet_file), request, **kwargs)


def events(path: Path) -> list[tuple[str, str, str]]:
    return [(EVENT_NAMES[m.msg.event], m.msg.robot, m.msg.detail) for m in McapLog(path).messages(["/mrl/episode"])]


def test_episodes_on_the_twin_are_recorded_in_the_sim_layout(tiny_policy, tmp_path):
    results, profile = deploy(tiny_policy, write_fleet(tmp_path / "fleet.yaml"), tmp_path, episodes=2)
    assert profile == "mild" and len(results) == 2
    assert all(r.steps >= 1 and not r.aborted for r in results)
    log = McapLog(tmp_path / "session.mcap")
    assert not log.salvaged
    counts = log.message_counts()
    assert set(counts) >= SIM_LAYOUT
    assert counts["/mrl/timing"] > 0 and counts["/clock"] > 0 and counts["/mrl/reset"] == 2
    session = log.metadata()["session"]
    assert session["world"] == "real" and session["profile"] == "mild" and session["target"] == "twin"
    names = [e for e, _, _ in events(tmp_path / "session.mcap")]
    assert names.count("start") == 2 and names.count("end") == 2
    # every control step logged one observation and one action per robot
    assert counts["/mrl/observation"] == counts["/mrl/action"] == 3 * sum(r.steps for r in results)
    # the twin's 360-beam scans arrive as received
    scan = next(iter(log.messages(["/robot_1/scan"]))).msg
    assert len(scan.ranges) == 360


def test_a_robot_that_never_appears_is_named(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml", target="robots", timing={"discovery_timeout_s": 1.5})
    with pytest.raises(FleetNotReady, match=r"robot_1 \(/robot_1/scan\)"):
        deploy(tiny_policy, fleet, tmp_path)
    # the recording made until then is a valid, finished file
    assert not McapLog(tmp_path / "session.mcap").salvaged


def test_a_robot_blind_past_the_outage_limit_aborts_the_episode_with_zero_commands(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml", timing={"outage_limit_s": 1.0})
    results, _ = deploy(tiny_policy, fleet, tmp_path, twin_extra_args=["--silence", "robot_2@0.3"])
    assert results[0].aborted and results[0].abort_kind == "outage" and "robot_2" in results[0].abort_reason
    assert not results[0].team and results[0].stale_s[1] >= 1.0 and results[0].stale_s[0] == 0.0
    recorded = events(tmp_path / "session.mcap")
    aborts = [(robot, detail) for e, robot, detail in recorded if e == "abort"]
    assert aborts and aborts[0][0] == "robot_2" and "blind for 1 s" in aborts[0][1] and "old" in aborts[0][1]
    assert [robot for e, robot, _ in recorded if e == "stale"] == ["robot_2"]
    assert recorded[-1][0] == "end" and recorded[-1][2] == "aborted"
    # after the abort every robot was commanded zero velocity
    # (in the order written: the twin's clock may stand still under load, so sends can share the abort's time)
    log = McapLog(tmp_path / "session.mcap")
    written = list(log.messages(["/mrl/episode", "/robot_1/cmd_vel", "/robot_3/cmd_vel"]))
    at = next(i for i, m in enumerate(written) if m.topic == "/mrl/episode" and EVENT_NAMES[m.msg.event] == "abort")
    later = [m.msg for m in written[at + 1 :] if m.topic != "/mrl/episode"]
    earlier = [m.msg for m in written[:at] if m.topic != "/mrl/episode"]
    assert len(later) >= 2 and all(m.linear.x == 0.0 and m.angular.z == 0.0 for m in later)
    assert any(m.linear.x != 0.0 or m.angular.z != 0.0 for m in earlier)
    # the aborted episode counts: its robots that had not arrived fail
    table = episodes_table(tmp_path / "session.mcap")
    assert table["aborted"].all() and set(table["abort_kind"]) == {"outage"}
    assert table.filter(pl.col("robot") == "robot_2")["stale_s"][0] >= 1.0


def test_a_silence_shorter_than_the_outage_limit_stops_that_robot_and_the_others_drive_on(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    # 1.5 s blind: longer than the staleness limit, shorter than the 5 s outage limit
    results, _ = deploy(tiny_policy, fleet, tmp_path, twin_extra_args=["--silence", "robot_2@0.4+1.5"])
    assert not results[0].aborted
    assert results[0].stale_s[1] > 0.8 and results[0].stale_s[0] == 0.0 and results[0].stale_s[2] == 0.0
    log = McapLog(tmp_path / "session.mcap")
    stale = [m for m in log.messages(["/mrl/timing"]) if m.msg.kind == 4]
    assert stale and {m.msg.robot for m in stale} == {"robot_2"} and "old" in stale[0].msg.topic
    first, last = stale[0].log_time_ns, stale[-1].log_time_ns
    # while robot_2 was stale its commands were zero; the others kept driving
    during = [m.msg for m in log.messages(["/robot_2/cmd_vel"], start_ns=first + 150_000_000, end_ns=last)]
    assert during and all(m.linear.x == 0.0 and m.angular.z == 0.0 for m in during)
    others = [m.msg for m in log.messages(["/robot_1/cmd_vel", "/robot_3/cmd_vel"], start_ns=first, end_ns=last)]
    assert any(m.linear.x != 0.0 or m.angular.z != 0.0 for m in others)
    # the interval is bounded by a stale and a fresh event of robot_2, and the table counts its seconds
    recorded = events(tmp_path / "session.mcap")
    marks = [(e, robot) for e, robot, _ in recorded if e in ("stale", "fresh")]
    assert marks == [("stale", "robot_2"), ("fresh", "robot_2")]
    table = episodes_table(tmp_path / "session.mcap")
    seconds = table.filter(pl.col("robot") == "robot_2")["stale_s"][0]
    assert seconds == pytest.approx(results[0].stale_s[1], abs=0.11)
    assert not table["aborted"].any()


def test_ten_percent_loss_completes_and_shows_in_the_log(tiny_policy, tmp_path):
    profile = yaml.safe_load(Path("pipeline/twin/profiles/mild.yaml").read_text())
    profile["network"]["loss_prob"] = 0.1
    (tmp_path / "lossy.yaml").write_text(yaml.safe_dump(profile))
    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"profile": str(tmp_path / "lossy.yaml")})
    results, profile_name = deploy(tiny_policy, fleet, tmp_path)
    assert profile_name == "lossy" and not results[0].aborted
    log = McapLog(tmp_path / "session.mcap")
    stamps = np.array(
        [m.msg.header.stamp.sec * 10**9 + m.msg.header.stamp.nanosec for m in log.messages(["/robot_1/ground_truth"])]
    )
    # the twin sends ground truth every 20 ms: gaps of 40 ms or more are lost messages
    gaps = np.diff(np.sort(stamps)) / 1e6
    lost = np.round(gaps / 20.0).astype(int) - 1
    loss = lost[lost >= 0].sum() / (len(stamps) + lost[lost >= 0].sum())
    assert 0.04 < loss < 0.2


def test_a_dying_twin_stops_the_robots_and_finalizes_the_recording(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")

    def kill_twin_later() -> None:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            kids = [p for p in psutil.Process().children(recursive=True) if "pipeline.twin" in " ".join(p.cmdline())]
            if kids and (Path(tmp_path) / "session.mcap").exists():
                time.sleep(3.0)
                for kid in kids:
                    kid.kill()
                return
            time.sleep(0.1)

    killer = threading.Thread(target=kill_twin_later, daemon=True)
    killer.start()
    with pytest.raises(DeployAborted, match="hardware twin exited") as err:
        deploy(tiny_policy, fleet, tmp_path, episodes=20)
    killer.join()
    # the episode under way counts, as aborted on a fault: its robots that had not arrived fail
    cut = err.value.results[-1]
    assert cut.aborted and cut.abort_kind == "fault" and not cut.team
    log = McapLog(tmp_path / "session.mcap")
    assert not log.salvaged
    assert any(e == "abort" for e, _, _ in events(tmp_path / "session.mcap"))
    # the last command each robot was sent is zero velocity
    for ns in ("robot_1", "robot_2", "robot_3"):
        last = list(log.messages([f"/{ns}/cmd_vel"]))[-1].msg
        assert last.linear.x == 0.0 and last.angular.z == 0.0


def test_a_lidar_that_leaves_policy_beams_blind_is_refused(tiny_policy, tmp_path):
    profile = yaml.safe_load(Path("pipeline/twin/profiles/mild.yaml").read_text())
    profile["lidar"]["beams"] = 10  # 36 deg apart: some of the policy's 15 sectors (24 deg) get no beam
    (tmp_path / "sparse.yaml").write_text(yaml.safe_dump(profile))
    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"profile": str(tmp_path / "sparse.yaml")})
    with pytest.raises(PolicyMismatch, match=r"reads 15 lidar beams.*/robot_1/scan has 10 beams") as err:
        deploy(tiny_policy, fleet, tmp_path)
    assert "without a return" in str(err.value)
    log = McapLog(tmp_path / "session.mcap")
    assert not log.salvaged and "/mrl/episode" not in log.message_counts()  # refused before any episode


def test_a_policy_for_another_fleet_is_refused_before_anything_starts(tiny_policy, tmp_path):
    two = write_fleet(
        tmp_path / "fleet.yaml",
        robots=[
            {"name": f"robot_{i}", "namespace": f"robot_{i}", "v_max_mps": 0.4, "w_max_radps": 0.2} for i in (1, 2)
        ],
    )
    with pytest.raises(PolicyMismatch, match="trained for 3 robot"):
        deploy(tiny_policy, two, tmp_path)
    assert not (tmp_path / "session.mcap").exists()


def test_malformed_fleet_and_profile_files_name_the_key(tmp_path):
    bad = write_fleet(tmp_path / "fleet.yaml", network={"domain_id": 999}, target="drone")
    with pytest.raises(ConfigError) as err:
        load_fleet(bad)
    text = str(err.value)
    assert str(bad) in text and "network.domain_id = 999" in text and "target = 'drone'" in text
    from pipeline.twin.profile import load_profile

    profile = yaml.safe_load(Path("pipeline/twin/profiles/mild.yaml").read_text())
    profile["lidar"]["noise_sigma_m"] = -0.1
    del profile["network"]["jitter_s"]
    profile["odometry"]["slip"] = 0.1
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(profile))
    with pytest.raises(ConfigError) as err:
        load_profile(tmp_path / "bad.yaml")
    text = str(err.value)
    assert "lidar.noise_sigma_m = -0.1" in text and "network.jitter_s = <missing>" in text and "odometry.slip" in text
    assert load_scenario("obstacles").n_robots == 3
