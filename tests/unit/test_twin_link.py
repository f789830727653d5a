"""The twin's lossy link records the deliveries it realizes, and the pair rule reads their jitter."""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from calibration_coverage import realized_jitter

from pipeline.messages import convert as C
from pipeline.messages.store import message_store
from pipeline.ros.clock import ScaledClock
from pipeline.twin.twin import LossyLink

NS = 1_000_000_000


class Taker:
    """A publisher that notes what it is handed and when (the link under test decides both)."""

    def __init__(self, name: str, clock: ScaledClock) -> None:
        self.spec = SimpleNamespace(name=name)
        self.closed = False
        self.clock = clock
        self.taken: list[tuple[int, int]] = []

    def publish(self, msg: Any) -> None:
        stamp = int(msg.header.stamp.sec) * NS + int(msg.header.stamp.nanosec)
        self.taken.append((stamp, self.clock.now_ns()))


def test_the_link_records_every_stamped_delivery_it_hands_on(tmp_path):
    clock = ScaledClock(5.0, 10 * NS)
    store = message_store()
    link = LossyLink(clock, 0.1, 0.02, np.random.default_rng(4), burst_len=2.0)
    link.deliveries = []
    pubs = [Taker(f"/robot_{i}/odom", clock) for i in (1, 2, 3)]
    sent: dict[str, list[tuple[int, int]]] = {p.spec.name: [] for p in pubs}
    for _ in range(60):
        now = clock.now_ns()
        for pub in pubs:
            lost = link.lost
            link.send(pub, C.odometry(now, pub.spec.name, np.zeros(3), store=store))
            if link.lost == lost:
                sent[pub.spec.name].append((now, now))
        time.sleep(0.004)
    time.sleep(0.05)
    link.close()
    assert link.lost > 0
    rows = link.deliveries
    assert rows is not None and len(rows) == link.sent == sum(len(p.taken) for p in pubs)
    for pub in pubs:
        mine = [(stamp, handed) for topic, stamp, handed in rows if topic == pub.spec.name]
        # every message that was not lost is recorded once, with its own stamp, handed on no earlier than it was sent
        assert sorted(s for s, _ in mine) == [s for s, _ in sent[pub.spec.name]]
        assert all(handed >= stamp for stamp, handed in mine)
        assert sorted(mine) == sorted(pub.taken) or all(
            abs(a[1] - b[1]) < 0.05 * NS for a, b in zip(sorted(mine), sorted(pub.taken), strict=True)
        )
    out = tmp_path / "link.npz"
    link.write_deliveries(str(out))
    with np.load(out) as data:
        assert list(data["topic"]) == [r[0] for r in rows]
        assert data["stamp_ns"].tolist() == [r[1] for r in rows]
        assert data["handed_ns"].tolist() == [r[2] for r in rows]
        assert float(data["jitter_s"]) == pytest.approx(0.02)


def test_a_link_that_records_nothing_keeps_no_deliveries():
    clock = ScaledClock(5.0, 0)
    link = LossyLink(clock, 0.0, 0.0, np.random.default_rng(0))
    pub = Taker("/robot_1/odom", clock)
    link.send(pub, C.odometry(clock.now_ns(), "robot_1", np.zeros(3), store=message_store()))
    link.close()
    assert link.deliveries is None and len(pub.taken) == 1


@pytest.mark.parametrize("jitter_s", [0.004, 0.015])
def test_the_pair_rule_reads_the_jitter_of_known_deliveries(tmp_path, jitter_s):
    # three odometry topics sharing 2000 stamps, each message handed on after its own uniform delay on [0, J]
    # plus a base delay: the pair rule reads J; a topic that is not a sensor's is left out
    rng = np.random.default_rng(7)
    stamps = np.arange(2000, dtype=np.int64) * 20_000_000
    topics, stamp_ns, handed_ns = [], [], []
    for name in ("/robot_1/odom", "/robot_2/odom", "/robot_3/odom", "/clock_like"):
        delay = 3_000_000 + rng.uniform(0, jitter_s * NS, len(stamps)) * (10 if name == "/clock_like" else 1)
        topics += [name] * len(stamps)
        stamp_ns.append(stamps)
        handed_ns.append(stamps + delay.astype(np.int64))
    path = tmp_path / "known.npz"
    np.savez(path, topic=np.array(topics), stamp_ns=np.concatenate(stamp_ns), handed_ns=np.concatenate(handed_ns))
    assert realized_jitter(path) == pytest.approx(jitter_s, rel=0.08)


def test_no_pair_of_sensor_topics_reads_no_jitter(tmp_path):
    path = tmp_path / "one.npz"
    stamps = np.arange(100, dtype=np.int64) * 20_000_000
    np.savez(path, topic=np.array(["/robot_1/scan"] * 100), stamp_ns=stamps, handed_ns=stamps + 1000)
    assert realized_jitter(path) is None
