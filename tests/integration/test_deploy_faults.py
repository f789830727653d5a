"""Faults a first user meets when deploying: a killed runner, a stray twin, two clocks, limits that do not
match, bad input after a good session, a deployment that stops partway. Real processes, DDS on loopback."""

from __future__ import annotations

import csv
import hashlib
import json
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import polars as pl
import psutil
import pytest
import yaml

from pipeline.analysis.tables import episodes_table
from pipeline.core.timebase import CONTROL_LATE_LIMIT, NS_PER_S
from pipeline.messages.convert import EVENT_NAMES
from pipeline.mrl import main as mrl_main
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record import McapLog
from pipeline.record.results import STAGING, read_episodes_csv
from pipeline.rollout.deployment import DeployRequest, deploy_session
from pipeline.rollout.errors import DeployAborted, FleetConflict, FleetNotReady
from pipeline.ros.fleet import load_fleet
from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


def stage_params(tmp_path: Path, policy: Path, fleet: Path, **deploy: object) -> Path:
    """A params.yaml for stages/deploy.py that deploys `policy` (as the nominal round) on `fleet`."""
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    shutil.copytree(policy, tmp_path / "models" / "nominal" / "policy", dirs_exist_ok=True)
    params["export"]["out_dir"] = str(tmp_path / "models")
    params["deploy"].update(
        {"fleet": str(fleet), "episodes": 1, "time_scale": 0.0, "out_dir": str(tmp_path / "real"), **deploy}
    )
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    return path


def run_stage(params: Path, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "stages/deploy.py", "--params", str(params)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def twins_of(proc: psutil.Process) -> list[psutil.Process]:
    return [p for p in proc.children(recursive=True) if "pipeline.twin" in " ".join(p.cmdline())]


def recording_with_twin(stage: subprocess.Popen, staged: Path, timeout_s: float = 120) -> list[psutil.Process]:
    """Wait until the deploy `stage` runs its twin and records into `staged`; the twin processes."""
    runner = psutil.Process(stage.pid)
    deadline = time.monotonic() + timeout_s
    twins: list[psutil.Process] = []
    while time.monotonic() < deadline and not (twins and staged.exists() and staged.stat().st_size > 0):
        twins = twins or twins_of(runner)
        assert stage.poll() is None, "the deploy stage ended before it recorded"
        time.sleep(0.1)
    assert twins, "the deploy stage never started its twin"
    return twins


def deploy_into(policy: Path, fleet_file: Path, out: Path, episodes: int = 1, **kwargs):
    request = DeployRequest(episodes=episodes, seed=5, recording=out / "session.mcap", progress=False)
    fleet = load_fleet(fleet_file)
    return deploy_session(PolicyRuntime(policy), fleet, str(fleet_file), request, out, **kwargs)


def summary_span(path: Path) -> tuple[int, int]:
    """(message_start_time, message_end_time) of the MCAP's statistics record, as other tools read them."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    return summary.statistics.message_start_time, summary.statistics.message_end_time


def check_paths_read_back(out: Path) -> None:
    """The path lengths of the deployment's episodes.csv are those its recording gives back, the episode cut short
    included (one definition: pipeline.core.episode.path_lengths_m at the control steps)."""
    written = {(r["episode"], r["robot"]): r["path_length_m"] for r in read_episodes_csv(out / "episodes.csv")}
    table = episodes_table(out / "session.mcap")
    read_back = {(r["episode"], r["robot"]): round(r["path_length_m"], 4) for r in table.iter_rows(named=True)}
    assert written and {k: read_back.get(k) for k in written} == written


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def test_a_killed_runner_takes_its_twin_along_and_the_next_deploy_runs(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    params = stage_params(tmp_path, tiny_policy, fleet, episodes=50)
    stage = subprocess.Popen(
        [sys.executable, "stages/deploy.py", "--params", str(params)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    twins = recording_with_twin(stage, tmp_path / "real" / "nominal" / STAGING / "session.mcap")
    time.sleep(2.0)  # mid-episode
    stage.kill()
    stage.wait()
    _, alive = psutil.wait_procs(twins, timeout=15)
    assert not alive, f"twin process(es) {[p.pid for p in alive]} outlived their runner"
    # the next deploy on the same domain runs (two episodes are enough), and keeps the killed run's recording aside
    done = run_stage(stage_params(tmp_path, tiny_policy, fleet, episodes=2))
    assert done.returncode == 0, done.stderr
    out = tmp_path / "real" / "nominal"
    assert {"session.mcap", "episodes.csv", "metrics.json", "metadata.yaml"} <= {p.name for p in out.iterdir()}
    (kept,) = out.glob("interrupted-*")
    assert (kept / "session.mcap").stat().st_size > 0
    assert not (out / STAGING).exists()


def test_robots_that_this_deploy_did_not_start_are_refused(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    domain = load_fleet(fleet).network.domain_id
    stray = subprocess.Popen(
        [sys.executable, "-m", "pipeline.twin", "--fleet", str(fleet)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert stray.stdout is not None and stray.stdout.readline().startswith("twin: ready")
        with pytest.raises(FleetConflict) as err:
            deploy_into(tiny_policy, fleet, tmp_path / "out")
        text = str(err.value)
        assert f"DDS domain {domain}" in text and "/robot_1/scan" in text and "did not start" in text
        assert not (tmp_path / "out" / "session.mcap").exists() and not (tmp_path / "out" / STAGING).exists()
        # the stage says the same in one line, without a traceback
        done = run_stage(stage_params(tmp_path, tiny_policy, fleet))
        # a clash on the domain is a runtime fault (exit 3), not bad input
        assert done.returncode == 3 and f"DDS domain {domain}" in done.stderr and "Traceback" not in done.stderr
    finally:
        stray.send_signal(signal.SIGINT)
        stray.communicate(timeout=20)


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_a_deployment_recording_has_one_clock_and_spans_the_session(tiny_policy, tmp_path, scale):
    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"time_scale": scale})
    out = tmp_path / "out"
    wall0 = time.time_ns()
    outcome = deploy_into(tiny_policy, fleet, out, episodes=2)
    wall = time.time_ns() - wall0
    log = McapLog(out / "session.mcap")
    session = log.metadata()["session"]
    assert session["clock_epoch"] == "unix" and session["clock"] == ("wall" if scale == 1.0 else "ros_clock")
    times = sorted(m.log_time_ns for m in log.raw())
    start, end = times[0], times[-1]
    # every message on the Unix-epoch clock: nothing logged on a clock that starts near zero
    assert start > 1_600_000_000 * NS_PER_S
    # the span is the session's length: at least its control steps, at most its wall time on the twin's clock
    steps = sum(r.steps for r in outcome.results)
    assert steps * 0.1 * NS_PER_S <= end - start <= wall * scale * 1.05
    assert summary_span(out / "session.mcap") == (start, end)


def test_a_policy_beyond_the_fleet_limits_is_refused(tiny_policy, tmp_path):
    edited = tmp_path / "policy"
    shutil.copytree(tiny_policy, edited)
    meta = json.loads((edited / "policy.json").read_text())
    meta["world"]["actions"]["v_max_mps"] = 4.0
    (edited / "policy.json").write_text(json.dumps(meta))
    fleet = write_fleet(tmp_path / "fleet.yaml")
    with pytest.raises(Exception) as err:
        deploy_into(edited, fleet, tmp_path / "out")
    text = str(err.value)
    assert "up to 4 m/s" in text and "robot_1 to 0.4 m/s" in text and "clamped" in text
    assert not (tmp_path / "out" / "session.mcap").exists()


def test_a_bad_profile_after_a_good_session_leaves_that_session_in_place(tiny_policy, tmp_path):
    out = tmp_path / "out"
    good = write_fleet(tmp_path / "fleet.yaml")
    deploy_into(tiny_policy, good, out)
    before = digests(out)
    assert {"session.mcap", "episodes.csv", "metrics.json", "metadata.yaml"} <= set(before)
    (tmp_path / "bad.yaml").write_text("lidar: {beams: 0}\n")
    bad = write_fleet(tmp_path / "bad_fleet.yaml", twin={"profile": str(tmp_path / "bad.yaml")})
    with pytest.raises(FleetNotReady, match=r"lidar.beams = 0"):
        deploy_into(tiny_policy, bad, out)
    assert digests(out) == before
    assert not (out / STAGING).exists() and not list(out.glob("interrupted-*"))


def test_a_deployment_that_stops_partway_publishes_its_finished_episodes(tiny_policy, tmp_path, monkeypatch):
    out = tmp_path / "out"
    scratch = tmp_path / "scratch"  # this deployment's temporary folders: none left once it has stopped
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    # robot_2 falls silent for good: episode 0 aborts on the outage, the reset of episode 1 never gets its data
    fleet = write_fleet(tmp_path / "fleet.yaml", timing={"reset_timeout_s": 2.0, "outage_limit_s": 1.0})
    with pytest.raises(DeployAborted, match=r"after 1 episode.*robot_2.*episode\(s\) run") as err:
        deploy_into(tiny_policy, fleet, out, episodes=3, twin_extra_args=["--silence", "robot_2@0.3"])
    assert not list(scratch.glob("mrl-twin-timing-*"))
    assert len(err.value.results) == 1 and err.value.results[0].aborted
    assert err.value.results[0].abort_kind == "outage"
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["episode"] for r in rows} == {"0"} and len(rows) == 3
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["real/aborted_episodes"] == 1 and metrics["real/aborted_outage"] == 1
    assert metrics["real/episodes"] == 1 and metrics["real/requested_episodes"] == 3
    assert metrics["real/team_success"] == 0.0 and metrics["real/robot_2_stale_s"] >= 1.0
    assert {r["aborted"] for r in rows} == {"1"} and {r["abort_kind"] for r in rows} == {"outage"}
    log = McapLog(out / "session.mcap")
    assert not log.salvaged
    events = [(EVENT_NAMES[m.msg.event], m.msg.episode, m.msg.step) for m in log.messages(["/mrl/episode"])]
    assert ("start", 0, 0) in events and ("end", 0) in {(e, ep) for e, ep, _ in events}
    check_paths_read_back(out)


def test_an_interrupted_deploy_records_the_step_it_stopped_at(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    params = stage_params(tmp_path, tiny_policy, fleet, episodes=50)
    stage = subprocess.Popen(
        [sys.executable, "stages/deploy.py", "--params", str(params)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    staged = tmp_path / "real" / "nominal" / STAGING / "session.mcap"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (staged.exists() and staged.stat().st_size > 0):
        time.sleep(0.1)
    time.sleep(6.0)  # a few episodes of 30 steps at 2x, and part of the next
    stage.send_signal(signal.SIGINT)
    _, err = stage.communicate(timeout=60)
    assert stage.returncode == 130, err
    out = tmp_path / "real" / "nominal"
    log = McapLog(out / "session.mcap")
    events = [(EVENT_NAMES[m.msg.event], m.msg.episode, m.msg.step) for m in log.messages(["/mrl/episode"])]
    starts = [ep for e, ep, _ in events if e == "start"]
    aborts = [(ep, step) for e, ep, step in events if e == "abort"]
    assert aborts and aborts[-1][0] == starts[-1]
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    run = {int(r["episode"]) for r in rows}
    assert run == set(range(len(run))) and len(run) >= 1
    # the interrupted episode counts, as aborted
    assert {r["abort_kind"] for r in rows if int(r["episode"]) == starts[-1]} == {"interrupted"}
    # the abort names the step the interrupted episode was at: its last recorded control step or the next
    steps = [m.msg.step for m in log.messages(["/mrl/action"]) if m.msg.episode == starts[-1]]
    assert aborts[-1][1] in ({max(steps), max(steps) + 1} if steps else {0})
    check_paths_read_back(out)


def test_a_world_scenario_other_than_the_fleets_is_refused_not_ignored(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    params = stage_params(tmp_path, tiny_policy, fleet)
    data = yaml.safe_load(params.read_text())
    data["world"]["scenario"] = "empty"
    params.write_text(yaml.safe_dump(data))
    done = run_stage(params)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "world.scenario is 'empty'" in done.stderr and "drives in 'obstacles'" in done.stderr
    assert not (tmp_path / "real").exists()


def test_a_fixed_layout_policy_in_another_scenario_is_refused_before_anything_moves(tiny_policy, tmp_path):
    from pipeline.policy.errors import PolicyMismatch

    fleet = write_fleet(tmp_path / "fleet.yaml", scenario="obstacles_random")
    request = DeployRequest(episodes=1, seed=0, recording=tmp_path / "session.mcap", progress=False)
    with pytest.raises(PolicyMismatch, match=r"trained in scenario 'obstacles'.*'obstacles_random'.*one fixed layout"):
        deploy_session(PolicyRuntime(tiny_policy), load_fleet(fleet), str(fleet), request, tmp_path / "real")
    assert not (tmp_path / "session.mcap").exists()


def test_a_twin_that_dies_mid_episode_is_a_runtime_fault_and_its_episode_counts_as_failed(tiny_policy, tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    params = stage_params(tmp_path, tiny_policy, fleet, episodes=50)
    stage = subprocess.Popen(
        [sys.executable, "stages/deploy.py", "--params", str(params)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    twins = recording_with_twin(stage, tmp_path / "real" / "nominal" / STAGING / "session.mcap")
    # killed inside an episode, not in the reset between two: a fixed wait from the recording's start landed in a
    # reset on a slow host; the first episode's progress line, then part of the next (an episode takes 1.6 s here)
    assert stage.stderr is not None
    said = []
    for line in stage.stderr:
        said.append(line)
        if re.search(r"\b1/50\b", line):
            break
    time.sleep(0.8)
    for twin in twins:
        twin.kill()
    _, rest = stage.communicate(timeout=60)
    err = "".join(said) + rest
    # a runtime fault, not bad input: exit 3, one line, no traceback
    assert stage.returncode == 3, err
    assert "hardware twin exited" in err and "Traceback" not in err
    out = tmp_path / "real" / "nominal"
    assert not McapLog(out / "session.mcap").salvaged
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    last = max(int(r["episode"]) for r in rows)
    cut = [r for r in rows if int(r["episode"]) == last]
    assert {r["aborted"] for r in cut} == {"1"} and {r["abort_kind"] for r in cut} == {"fault"}
    assert {r["team_success"] for r in cut} == {"0"}
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["real/episodes"] == last + 1 and metrics["real/aborted_fault"] == 1


def test_a_run_that_stops_partway_keeps_the_finished_session_it_follows(tiny_policy, tmp_path):
    out = tmp_path / "out"
    good = write_fleet(tmp_path / "fleet.yaml")
    deploy_into(tiny_policy, good, out, episodes=2)
    before = digests(out)
    # the next run into the same folder loses robot_2 for good in its first episode and stops partway
    bad = write_fleet(tmp_path / "bad.yaml", timing={"reset_timeout_s": 2.0, "outage_limit_s": 1.0})
    with pytest.raises(DeployAborted, match="the previous session is kept in") as err:
        deploy_into(tiny_policy, bad, out, episodes=3, twin_extra_args=["--silence", "robot_2@0.3"])
    (kept,) = out.glob("previous-*")
    assert digests(kept) == before  # the finished session, byte for byte
    assert str(kept) in str(err.value)
    # the folder holds the new (partial) session, all of its files from it
    assert len(err.value.results) == 1
    with (out / "episodes.csv").open() as f:
        assert {r["aborted"] for r in csv.DictReader(f)} == {"1"}


def test_a_refused_run_leaves_no_folder_behind(tiny_policy, tmp_path):
    # the twin refuses its profile after the session's folder was opened: the folder goes again
    (tmp_path / "bad.yaml").write_text("lidar: {beams: 0}\n")
    bad = write_fleet(tmp_path / "bad_fleet.yaml", twin={"profile": str(tmp_path / "bad.yaml")})
    out = tmp_path / "never"
    with pytest.raises(FleetNotReady, match=r"lidar.beams = 0"):
        deploy_into(tiny_policy, bad, out)
    assert not out.exists()


@pytest.mark.alone  # its second episode must keep its clock: the stall it makes must be the only one
def test_episodes_in_which_the_twin_fell_behind_its_clock_are_marked_not_taken_for_the_policy_s(
    tiny_policy, tmp_path, capsys
):
    """A host too busy for the time scale: the twin stalls 2 s (host) in the first episode and jumps over it. The
    session is published whole; the deployment ends with its own exit code (InvalidMeasurement); metrics.json counts
    the episode and gives the rates over the others; a deployment that kept its clock says so."""
    from pipeline.errors import InvalidMeasurement
    from pipeline.rollout.deployment import check_clock_kept
    from pipeline.stage import EXIT_INVALID_MEASUREMENT, run_stage

    fleet = write_fleet(tmp_path / "fleet.yaml")
    out = tmp_path / "busy"
    busy = deploy_into(tiny_policy, fleet, out, episodes=2, twin_extra_args=["--stall", "2.0@0.5"])
    with pytest.raises(
        InvalidMeasurement,
        match=r"in 1 of 2 episode\(s\) the deployment did not keep its clock \(least time scale the twin realized",
    ) as err:
        check_clock_kept(busy, out)
    assert [r.clock_kept for r in busy.results] == [False, True]
    # episodes.csv marks the episode, and the recording carries the mark: mrl episodes reads it back the same
    rows = read_episodes_csv(out / "episodes.csv")
    assert {r["clock_kept"] for r in rows if r["episode"] == 0} == {0}
    assert {r["clock_kept"] for r in rows if r["episode"] == 1} == {1}
    scale = load_fleet(fleet).twin.time_scale
    assert {r["time_scale_asked"] for r in rows} == {scale}
    assert all(r["time_scale_realized"] < 0.95 * scale for r in rows if r["episode"] == 0)
    table = episodes_table(out / "session.mcap").sort("episode", "robot")
    assert table["clock_kept"].to_list() == [
        r["clock_kept"] == 1 for r in sorted(rows, key=lambda r: (r["episode"], r["robot"]))
    ]
    assert table["time_scale_realized"].to_list() == pytest.approx(
        [r["time_scale_realized"] for r in sorted(rows, key=lambda r: (r["episode"], r["robot"]))], abs=1e-4
    )
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["real/episodes"] == 2 and metrics["real/clock_not_kept_episodes"] == 1
    assert metrics["real/time_scale_realized_min"] < 0.95  # the jumped-over seconds were never simulated
    assert metrics["real/clock_kept_episodes"] == 1  # the rates over the other episode beside the whole session's
    assert 0.0 <= metrics["real/robot_success_clock_kept"] <= 1.0
    assert (out / "episodes.csv").is_file() and (out / "session.mcap").is_file()
    capsys.readouterr()
    assert mrl_main(["episodes", str(out / "session.mcap")]) == 0
    assert "the deployment did not keep its clock in 1 of 2 episode(s) (0)" in capsys.readouterr().out
    assert run_stage("deploy", lambda: (_ for _ in ()).throw(err.value)) == EXIT_INVALID_MEASUREMENT
    quiet = deploy_into(tiny_policy, fleet, tmp_path / "quiet", episodes=1)
    assert quiet.metrics["real/time_scale_realized_min"] == pytest.approx(scale, rel=0.05)
    assert quiet.results[0].time_scale_realized == pytest.approx(scale, rel=0.05)
    # the runner's control steps were timed too (on a loaded test host they may wake late: then the episode is
    # marked, by the same rule), and the recording carries it as episodes.csv does
    late = quiet.results[0].control_late_p95
    assert late >= 0.0 and quiet.results[0].clock_kept == (late <= CONTROL_LATE_LIMIT)
    assert quiet.metrics["real/clock_not_kept_episodes"] == (0 if quiet.results[0].clock_kept else 1)
    (row, *_) = read_episodes_csv(tmp_path / "quiet" / "episodes.csv")
    assert row["control_late_p95"] == pytest.approx(late, abs=1e-4)
    assert episodes_table(tmp_path / "quiet" / "session.mcap")["control_late_p95"][0] == pytest.approx(late)


@pytest.mark.alone  # the stall it makes must be the only one: beside a second worker the host made its own first
def test_time_scale_auto_picks_what_the_host_keeps_and_lowers_it_when_the_twin_falls_behind(
    tiny_policy, tmp_path, capfd
):
    """``auto``: the twin's pace is watched before the first episode and the scale it keeps is used (said on stderr,
    recorded); a host stall in the first episode lowers the scale from the next one on, and every episode keeps the
    scale it ran at in episodes.csv and the recording; the stalled episode, marked, is run again in its place, so the
    deployment is no invalid measurement."""
    from pipeline.errors import InvalidMeasurement
    from pipeline.rollout.deployment import check_clock_kept

    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"time_scale": "auto"})
    out = tmp_path / "auto"
    outcome = deploy_into(tiny_policy, fleet, out, episodes=3, twin_extra_args=["--stall", "2.0@0.5"])
    err = capfd.readouterr().err
    chosen = re.search(r"time scale auto: .*; the episodes start at ([0-9.]+)x", err)
    assert chosen, err
    start = float(chosen.group(1))
    assert 1.0 <= start <= 6.0
    first, *rest = outcome.results
    assert first.time_scale_asked == start and not first.clock_kept  # the stall: marked, not the policy's
    assert "the twin fell behind in episode 0" in err or start == 1.0  # at 1x nothing lower to ask for, nor said
    assert all(r.time_scale_asked < start for r in rest) or start == 1.0
    rows = read_episodes_csv(out / "episodes.csv")
    assert {(r["episode"], r["time_scale_asked"]) for r in rows} == {
        (r.episode, r.time_scale_asked) for r in outcome.results
    }
    log = McapLog(out / "session.mcap")
    assert log.metadata()["session"]["time_scale"] == "auto"
    table = episodes_table(out / "session.mcap")
    assert set(zip(table["episode"], table["time_scale_asked"], strict=True)) == {
        (r.episode, r.time_scale_asked) for r in outcome.results
    }
    # the marked episode was run again in its place: the policy is measured in as many episodes as were asked
    assert "episode 0 did not keep its clock (marked, not the policy's): one more episode in its place" in err
    assert 4 <= len(outcome.results) <= 3 + 2
    assert outcome.metrics["real/episodes"] == len(outcome.results)
    assert outcome.metrics["real/requested_episodes"] == 3
    if sum(r.clock_kept for r in outcome.results) >= 3:
        check_clock_kept(outcome, out)  # no InvalidMeasurement: as many kept their clock as were asked
    else:  # a loaded test host: the other episodes fell behind as well, past what auto may run again
        with pytest.raises(InvalidMeasurement):
            check_clock_kept(outcome, out)


def test_a_runner_that_wakes_late_for_the_first_step_drives_on_from_the_reset_s_data(
    tiny_policy, tmp_path, monkeypatch
):
    """A busy host holds the runner up between the reset and the episode's first control step: by the time it reads
    the fleet's state at that step, every sample it keeps (32 per robot and stream) arrived later than the step, so
    none is the step's. The data the reset found are the episode's first samples: the robots stand still as at any
    stale step and the episode runs, instead of the deployment stopping with 'no message since the episode's reset'."""
    from pipeline.analysis.tables import events_frame
    from pipeline.rollout.runner import DeployRunner

    held = []
    original = DeployRunner.next_control_time

    def held_up(self: DeployRunner, now_ns: int) -> int:
        t = original(self, now_ns)
        if not held:  # the episode's first control time: the host gives the runner no time for a second
            held.append(t)
            time.sleep(1.0)  # at 2x, 2 s of the twin's odometry and ground truth (50 Hz) arrive meanwhile
        return t

    monkeypatch.setattr(DeployRunner, "next_control_time", held_up)
    fleet = write_fleet(tmp_path / "fleet.yaml", twin={"profile": "mild", "time_scale": 2.0, "seed": 0})
    out = tmp_path / "late"
    outcome = deploy_into(tiny_policy, fleet, out, episodes=1)
    assert held and len(outcome.results) == 1 and not outcome.results[0].aborted
    events = events_frame(out / "session.mcap")
    # the episode started at the control time taken before the hold-up, judged from the poses the reset found, and
    # ran to its end: its first step's state was read at that step's own (late) time, as every later step's
    start = events.filter(pl.col("event") == "start")
    assert start["t_ns"].to_list() == held and start["step"].to_list() == [0]
    assert events.filter(pl.col("event") == "end").height == 1 and "abort" not in events["event"].to_list()
    assert outcome.results[0].steps > 1
    # what the hold-up had to do: more than a ring's worth (32) of a robot's odometry arrived after the episode's
    # start and before its first step read the state, so no sample of the rings was the start's
    log = McapLog(out / "session.mcap")
    first_step = min(m.log_time_ns for m in log.messages(["/mrl/observation"]))
    after = [
        sum(held[0] < m.log_time_ns <= first_step for m in log.messages([f"/{ns}/odom"]))
        for ns in ("robot_1", "robot_2", "robot_3")
    ]
    assert min(after) > 32, after
