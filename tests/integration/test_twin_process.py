"""The hardware twin as a process: ready line, clean shutdown on SIGINT and SIGTERM, clear bad-input errors."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from tests.integration.conftest import write_fleet

pytestmark = pytest.mark.integration


def start_twin(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.twin", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_twin_reports_ready_and_stops_cleanly(tmp_path, sig):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    proc = start_twin("--fleet", str(fleet), "--time-scale", "2")
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("twin: ready, profile mild, 3 robots"), line
    time.sleep(1.0)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "twin: stopped after" in out and "Traceback" not in err


def test_twin_refuses_bad_input_with_a_clear_message(tmp_path):
    fleet = write_fleet(tmp_path / "fleet.yaml")
    (tmp_path / "bad.yaml").write_text("lidar: {beams: 0}\n")
    proc = start_twin("--fleet", str(fleet), "--profile", str(tmp_path / "bad.yaml"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "Traceback" not in err
    assert "bad.yaml" in err and "lidar.beams = 0" in err and "actuation = <missing>" in err
    proc = start_twin("--fleet", str(tmp_path / "nowhere.yaml"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "nowhere.yaml" in err and "Traceback" not in err
    for bad in ("robot_2@soon", "robot_2@1.0+long"):
        proc = start_twin("--fleet", str(fleet), "--silence", bad)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "Traceback" not in err
        assert f"--silence {bad!r}" in err and "NAMESPACE@START[+DURATION]" in err
    proc = start_twin("--fleet", str(fleet), "--link-record", str(tmp_path / "nowhere" / "record.npz"))
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "--link-record" in err and "folder does not exist" in err and "Traceback" not in err
    proc = start_twin("--fleet", str(fleet), "--timing-record", str(tmp_path / "nowhere" / "timing.json"))
    _, err = proc.communicate(timeout=60)
    assert (
        proc.returncode == 2 and "--timing-record" in err and "folder does not exist" in err and "Traceback" not in err
    )
    for bad, allowed in (("two@1", "SECONDS@START"), ("0@1", "SECONDS above 0"), ("1@-2", "START at least 0")):
        proc = start_twin("--fleet", str(fleet), "--stall", bad)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "Traceback" not in err
        assert f"--stall {bad!r}" in err and allowed in err
    proc = start_twin("--fleet", str(fleet), "--silence", "robot_9@1.0")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "no robot 'robot_9' in the fleet" in err and "Traceback" not in err
    proc = start_twin("--fleet", str(fleet), "--domain-id", "999")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "network.domain_id = 999: must be in 0..232" in err and "Traceback" not in err


@pytest.mark.alone  # reads the clock offset through the delivery delay (5 ms at most): a busy host's is longer
def test_the_lab_twin_publishes_each_stream_at_its_own_rate_in_the_robots_clock(tmp_path):
    """40 Hz odometry is 40 Hz and 8 Hz lidar 8 Hz (no common tick); scan and odometry stamps run 35 ms ahead
    of the host and 40 ppm fast; motion capture stays on the host's clock; a sweep takes its beams over 125 ms."""
    import dataclasses
    import threading

    import numpy as np

    from pipeline.core.scenario import load_scenario
    from pipeline.messages import convert as C
    from pipeline.ros.clock import WallClock
    from pipeline.ros.fleet import load_fleet
    from pipeline.ros.transport import open_transport
    from pipeline.twin.profile import load_profile_for
    from pipeline.twin.twin import HardwareTwin

    fleet = load_fleet(write_fleet(tmp_path / "fleet.yaml"))
    scenario = load_scenario(fleet.scenario)
    _, lab = load_profile_for("lab", scenario)
    lab = dataclasses.replace(lab, network=dataclasses.replace(lab.network, loss_prob=0.0, jitter_s=0.0))
    twin_side = open_transport(fleet.transport, fleet.network_settings())
    listener = open_transport(fleet.transport, fleet.network_settings())
    received: dict[str, list[tuple[int, int]]] = {"scan": [], "odom": [], "ground_truth": []}
    increments = []
    lock = threading.Lock()

    def on(kind: str):
        def callback(spec, msg, receive_ns):
            stamp = C.time_ns(msg.header.stamp)
            with lock:
                received[kind].append((stamp, receive_ns))
                if kind == "scan":
                    increments.append(float(msg.time_increment) * len(msg.ranges))

        return callback

    topics = fleet.robots[0].topics()
    subs = [listener.subscribe(topics[k], on(k)) for k in received]
    twin = HardwareTwin(fleet, scenario, lab, twin_side, WallClock(), seed=0)
    stop = threading.Event()
    thread = threading.Thread(target=twin.run, args=(stop,))
    try:
        assert listener.wait_for_match(topics["scan"], 1, 10.0)
        time.sleep(0.5)
        with lock:
            for k in received:
                received[k].clear()
        thread.start()
        time.sleep(4.0)
    finally:
        stop.set()
        thread.join(5.0)
        twin.close()
        for s in subs:
            s.close()
        listener.close()
        twin_side.close()
    rates = {}
    for kind, rows in received.items():
        stamps = np.array([s for s, _ in rows])
        rates[kind] = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    assert rates["odom"] == pytest.approx(40.0, rel=0.01) and rates["scan"] == pytest.approx(8.0, rel=0.01)
    assert rates["ground_truth"] == pytest.approx(50.0, rel=0.01)
    odom_ahead = np.median([s - r for s, r in received["odom"]]) / 1e6
    truth_ahead = np.median([s - r for s, r in received["ground_truth"]]) / 1e6
    assert 30.0 < odom_ahead < 36.0 and -5.0 < truth_ahead <= 0.5  # the robots' clock is 35 ms ahead
    assert increments and all(x == pytest.approx(0.125, rel=1e-6) for x in increments)  # beams spread over a sweep


def test_the_twin_records_what_it_realized_when_asked(tmp_path):
    """--link-record: on exit, each stamped message as the lossy link handed it on and each command as the driver
    took it (what the coverage benchmark scores jitter and the drive's replay against)."""
    import numpy as np

    from pipeline.messages import convert as C
    from pipeline.ros.fleet import load_fleet
    from pipeline.ros.transport import open_transport

    fleet_file = write_fleet(tmp_path / "fleet.yaml")
    fleet = load_fleet(fleet_file)
    record = tmp_path / "realized.npz"
    proc = start_twin(
        "--fleet", str(fleet_file), "--profile", "harsh", "--time-scale", "2", "--link-record", str(record)
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().startswith("twin: ready")
    sent = [(0.1, 0.0), (0.2, 0.3), (0.0, -0.4)]
    with open_transport(fleet.transport, fleet.network_settings()) as driver:
        topic = fleet.robots[1].topics()["cmd_vel"]
        pub = driver.publisher(topic)
        assert driver.wait_for_match(topic, 1, 10.0)
        for v, w in sent:
            pub.publish(C.twist(v, w))
            time.sleep(0.3)
        time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0 and "Traceback" not in err, err
    with np.load(record) as data:
        robot, t = data["cmd_robot"], data["cmd_ns"]
        assert list(robot) == [fleet.robots[1].namespace] * 3
        assert [(float(v), float(w)) for v, w in zip(data["cmd_v"], data["cmd_w"], strict=True)] == sent
        assert np.all(np.diff(t) > 0)  # in the order they took effect, on the twin's clock
        topics = set(data["topic"].tolist())
        ns = fleet.robots[0].namespace
        assert {f"/{ns}/odom", f"/{ns}/scan", f"/{ns}/ground_truth"} <= topics
        assert np.all(data["handed_ns"] >= 0) and len(data["stamp_ns"]) == len(data["topic"])
        assert float(data["jitter_s"]) > 0  # the harsh profile's link jitters


class StallingClock:
    """Twin time that passes only as the twin sleeps, except where the host stalls: the wake after `stall_at_ns`
    comes `stall_ns` late. Stops the twin at `end_ns`."""

    scale = 1.0

    def __init__(self, stall_at_ns: int, stall_ns: int, end_ns: int, stop) -> None:
        self.now = 10**12
        self.start = self.now
        self.stall_at, self.stall_ns, self.end, self.stop = stall_at_ns, stall_ns, end_ns, stop
        self.stalled = False

    def now_ns(self) -> int:
        return self.now

    def sleep_until(self, t_ns: int, stop=None) -> bool:
        self.now = max(self.now, t_ns)
        if not self.stalled and self.now - self.start >= self.stall_at:
            self.stalled = True
            self.now += self.stall_ns
        if self.now - self.start >= self.end:
            self.stop.set()
            return False
        return True


@pytest.mark.parametrize(("stall_s", "jumped"), [(0.3, False), (1.5, True)])
def test_the_twin_catches_up_a_host_stall_and_jumps_only_a_long_one(tmp_path, stall_s, jumped):
    """A busy host wakes the twin late: its physics steps through the missed time (the world does not freeze, or
    the recorded motion would run slow by the frozen share); a stall beyond STALL_JUMP_NS is jumped, recorded and
    reported."""
    import dataclasses
    import threading

    import numpy as np

    from pipeline.core.scenario import load_scenario
    from pipeline.messages import convert as C
    from pipeline.ros.fleet import load_fleet
    from pipeline.ros.transport import open_transport
    from pipeline.twin.profile import load_profile_for
    from pipeline.twin.twin import HardwareTwin

    fleet = load_fleet(write_fleet(tmp_path / "fleet.yaml"))
    scenario = load_scenario(fleet.scenario)
    _, lab = load_profile_for("lab", scenario)
    lab = dataclasses.replace(lab, network=dataclasses.replace(lab.network, loss_prob=0.0, jitter_s=0.0))
    stop = threading.Event()
    stall_ns = round(stall_s * 1e9)
    clock = StallingClock(500_000_000, stall_ns, 3_000_000_000, stop)
    with open_transport(fleet.transport, fleet.network_settings()) as transport:
        twin = HardwareTwin(fleet, scenario, lab, transport, clock, seed=0)
        twin.link.deliveries = []
        twin._on_reset(None, C.reset_request(clock.now, 7, 0, False), clock.now)  # an episode begins, as asked
        twin.run(stop)
        twin.write_record(str(tmp_path / "record.npz"))
        twin.close()
        twin.close_timing()
    # the episode's timing: a stall caught up keeps the clock; one jumped over does not (the episode is marked)
    (timing,) = twin.timing
    assert timing.episode == 7 and timing.kept == (not jumped)
    assert timing.lag_max_ns >= stall_ns - twin.step_ns
    assert timing.jumped_ns == sum(j[1] for j in twin.jumps)
    simulated_ns = round(twin.physics.data.time * 1e9)
    elapsed_ns = twin.physics_ns - clock.start
    assert elapsed_ns >= 2_900_000_000
    truth = np.array(
        sorted(
            stamp for topic, stamp, _ in twin.link.deliveries if topic == f"/{fleet.robots[0].namespace}/ground_truth"
        )
    )
    gaps = np.diff(truth)
    if not jumped:
        assert twin.jumps == []
        assert abs(simulated_ns - elapsed_ns) <= twin.step_ns  # every step of the stall simulated
        # motion capture sampled through the stall at its own rate (published late), no gap
        assert len(truth) > 100 and gaps.max() <= 2 * twin.truth_period_ns
    else:
        assert len(twin.jumps) == 1
        at, skipped = twin.jumps[0]
        assert stall_ns - twin.step_ns - 50_000_000 <= skipped <= stall_ns
        assert 400_000_000 <= at - clock.start <= 600_000_000  # where the stall was
        assert gaps.max() >= skipped - twin.truth_period_ns  # nothing sampled in the frozen world
        assert abs(simulated_ns - (elapsed_ns - skipped)) <= twin.step_ns
    with np.load(tmp_path / "record.npz") as data:
        assert list(data["jump_skipped_ns"]) == [j[1] for j in twin.jumps]
