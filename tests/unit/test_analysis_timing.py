"""Deployment timing figures from a hand-written /mrl/timing whose jitter, skew and ages are known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.analysis.errors import AnalysisError
from pipeline.analysis.timing import timing_figures, timing_markdown
from pipeline.messages.convert import TIMING_CODES
from pipeline.record import McapLog
from pipeline.record.errors import MissingTopicError
from pipeline.record.session import SessionLog, dumps, session_metadata

ROBOTS = ("robot_1", "robot_2", "robot_3")
MS = 1_000_000
T0 = 1_000_000_000_000


def write_session(path: Path, tick_ms: float = 20.0, with_fleet: bool = True) -> dict[str, np.ndarray]:
    """Two episodes of 50 ticks separated by a 2 s reset pause, each ended by an abort's zero commands sent off
    the grid (tick 0); returns the planted quantities."""
    rng = np.random.default_rng(3)
    period = round(tick_ms * MS)
    docs = {"fleet": dumps({"timing": {"tick_period_s": tick_ms / 1000.0}})} if with_fleet else {}
    planted: dict[str, list[float]] = {"jitter": [], "skew": [], "age": []}
    with SessionLog(path, ROBOTS, session_metadata("real", "empty", ROBOTS, 0.1), docs) as log:
        tick = 1  # the emitter counts its ticks from 1
        for episode in range(2):
            t = T0 + episode * 3_000 * MS
            for k in range(50):
                offset = int(rng.integers(-300_000, 300_000))  # +-0.3 ms around the grid
                stamp = t + k * period + offset
                log.timing(stamp, "tick", "", "", 0, 0, tick)
                gaps = rng.integers(10_000, 60_000, size=len(ROBOTS))  # 10-60 us between sends
                send = stamp
                for i, robot in enumerate(ROBOTS):
                    send += int(gaps[i])
                    log.timing(send, "send", robot, f"/{robot}/cmd_vel", 0, tick, tick)
                planted["skew"].append(float(send - stamp - gaps[0]))
                if k % 5 == 2:  # a control step every 100 ms, midway between ticks
                    control = stamp + period // 2
                    for j, robot in enumerate(ROBOTS):
                        for channel, age_ms in (("odom", 7 + j), ("scan", 30 + j)):
                            log.timing(control - age_ms * MS, "receive", robot, f"/{robot}/{channel}", 0, k, 0)
                            planted["age"].append(float(age_ms * MS))
                    log.timing(control, "control", "", "", 0, k, tick)
                tick += 1
            if episode == 1:
                log.timing(t + 10 * period, "stale", "robot_2", "odom: 0.4 s old", 0, 0, 0)
            halt = t + 50 * period + 7 * MS
            for i, robot in enumerate(ROBOTS):
                log.timing(halt + i * 20_000, "send", robot, f"/{robot}/cmd_vel", 0, 0, 0)
    periods = np.diff(np.array(_ticks(path), dtype=np.float64))
    planted["jitter"] = list(np.abs(periods[periods < 5 * period] - period))
    return {k: np.array(v) for k, v in planted.items()}


def _ticks(path: Path) -> list[int]:
    return [m.msg.local_ns for m in McapLog(path).messages(["/mrl/timing"]) if m.msg.kind == TIMING_CODES["tick"]]


def test_figures_match_the_planted_timing(tmp_path: Path) -> None:
    planted = write_session(tmp_path / "s.mcap")
    f = timing_figures(tmp_path / "s.mcap")
    assert f.ticks == 100
    assert f.tick_period_ms == pytest.approx(20.0)
    # 98 tick periods: the reset pause between the episodes is not one of them
    assert planted["jitter"].size == 98
    assert f.tick_jitter_p99_ms == pytest.approx(np.percentile(planted["jitter"], 99) / MS)
    assert f.tick_jitter_p99_ms < 0.6
    assert f.tick_p50_ms == pytest.approx(20.0, abs=0.3)
    # the two halts, 3 s apart, share tick 0: taken for one tick they would put 3 s into the skew
    assert f.skew_p99_ms == pytest.approx(np.percentile(planted["skew"], 99) / MS)
    assert f.sends == 306
    assert f.controls == 20
    assert f.receives == 20 * 6
    assert f.age_p99_ms == pytest.approx(np.percentile(planted["age"], 99) / MS)
    assert f.stale == 1 and f.stale_robots == ("robot_2",)
    assert f.stale_examples == ("robot_2 odom: 0.4 s old",)
    assert f.as_metrics("real/nominal")["real/nominal/stale_records"] == 1.0
    names = ("tick_jitter_p99_ms", "send_skew_p99_ms", "state_age_p99_ms", "stale_records")
    assert set(f.as_metrics("real")) == set(f.as_metrics("real/")) == {f"real/{name}" for name in names}
    table = timing_markdown([("real nominal", f)])
    assert "| real nominal | 100 |" in table and "(robot_2)" in table


def test_nominal_period_comes_from_the_recorded_fleet(tmp_path: Path) -> None:
    write_session(tmp_path / "s10.mcap", tick_ms=10.0)
    assert timing_figures(tmp_path / "s10.mcap").tick_period_ms == pytest.approx(10.0)
    assert timing_figures(tmp_path / "s10.mcap").tick_jitter_p99_ms < 0.6
    # without a fleet document the default 20 ms grid is assumed and the 10 ms ticks show as jitter
    write_session(tmp_path / "nofleet.mcap", tick_ms=10.0, with_fleet=False)
    assert timing_figures(tmp_path / "nofleet.mcap").tick_jitter_p50_ms > 9.0


def test_recordings_without_timing_are_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "sim.mcap"
    with SessionLog(path, ROBOTS, session_metadata("sim", "empty", ROBOTS, 0.1)) as log:
        log.ground_truth(0, "robot_1", np.zeros(3))
    with pytest.raises(MissingTopicError, match=r"sim\.mcap.*/mrl/timing"):
        timing_figures(path)
    only_sends = tmp_path / "sends.mcap"
    with SessionLog(only_sends, ROBOTS, session_metadata("real", "empty", ROBOTS, 0.1)) as log:
        log.timing(T0, "send", "robot_1", "/robot_1/cmd_vel", 0, 0, 0)
    with pytest.raises(AnalysisError, match="no emitter ticks"):
        timing_figures(only_sends)
