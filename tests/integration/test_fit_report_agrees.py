"""One definition per figure: calibration.md and its plots show the values calibration.yaml holds.

A recording of the simulator with a known lidar bias, noise, mounting yaw and odometry drift is calibrated; the
report is rendered from that calibration, and every estimate, interval and plotted line is checked against the YAML
(the curve drawn over the lidar residuals peaks at the tabled bias, the mounting yaw's line stands at the tabled yaw,
the odometry's dashed line rises at the tabled drift)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import yaml

from pipeline.calibration import CalibrationSettings, calibrate, write_calibration
from pipeline.calibration.fit_report import _fmt, lidar_figure, mount_yaw_figure, odometry_figure
from tests.calibration_helpers import simulate_session

pytestmark = pytest.mark.integration

WORLD = {
    "lidar": {"noise_sigma_m": 0.01, "noise_per_m": 0.004, "dropout_prob": 0.01, "bias_m": 0.02, "mount_yaw_rad": 0.05},
    "odometry": {"drift_per_m": 0.04},
}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory):
    folder = tmp_path_factory.mktemp("report")
    recording = simulate_session(folder / "session.mcap", WORLD, episodes=3, steps=80, seed=2)
    cal = calibrate(recording, CalibrationSettings(parts=("lidar", "odometry"), bootstrap=40))
    write_calibration(cal, folder / "out")
    data = yaml.safe_load((folder / "out" / "calibration.yaml").read_text())
    text = (folder / "out" / "calibration.md").read_text()
    return cal, data, text


def test_every_row_of_the_report_shows_the_yaml_s_value_and_interval(report):
    _, data, text = report
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `([^`]+)` \| (.+)$", text, flags=re.MULTILINE)}
    shown = 0
    for group, keys in data["uncertainty"].items():
        for name, entry in keys.items():
            key = f"{group}.{name}"
            if key not in rows or entry["status"] == "unidentifiable":
                continue
            cells = [c.strip() for c in rows[key].split("|")]
            assert cells[0].split()[0] == _fmt(entry["value"]), (key, cells[0], entry["value"])
            interval = entry.get("interval_95")
            expected = "-" if interval is None else f"[{_fmt(interval[0])}, {_fmt(interval[1])}]"
            assert cells[2] == expected, (key, cells[2], interval)
            assert ("(weak)" in cells[0]) == (entry["status"] == "weak"), key
            shown += 1
    assert shown >= 8  # the lidar's and the odometry's identified keys


def test_the_lines_drawn_are_the_values_tabled(report):
    cal, data, _ = report
    lidar = data["profile"]["lidar"]
    fig = lidar_figure(cal)
    assert fig is not None
    (curve,) = [line for line in fig.axes[0].get_lines() if len(line.get_xdata()) > 2]
    x, y = np.asarray(curve.get_xdata()), np.asarray(curve.get_ydata())
    step = float(x[1] - x[0])
    assert x[np.argmax(y)] == pytest.approx(lidar["bias_m"], abs=step)  # the noise drawn sits at the tabled bias
    heights = np.array([p.get_height() for p in fig.axes[0].patches])
    assert heights.max() > 0.3 * y.max()  # the residuals are visible beside it, not a flat row of bars
    mode = np.array([p.get_x() + p.get_width() / 2 for p in fig.axes[0].patches])[np.argmax(heights)]
    assert abs(mode - lidar["bias_m"]) < 3 * lidar["noise_sigma_m"]  # and they peak where the bias says
    fig = mount_yaw_figure(cal)
    assert fig is not None
    (marker,) = [line for line in fig.axes[0].get_lines() if line.get_color() == "C3"]
    drawn = float(np.asarray(marker.get_xdata())[0])
    assert math.radians(drawn) == pytest.approx(lidar["mount_yaw_rad"], rel=1e-5)  # the YAML keeps 6 digits
    fig = odometry_figure(cal)
    assert fig is not None
    (dashed,) = [line for line in fig.axes[0].get_lines() if line.get_linestyle() == "--"]
    dx, dy = np.asarray(dashed.get_xdata()), np.asarray(dashed.get_ydata())
    assert (dy[-1] - dy[0]) / (dx[-1] - dx[0]) == pytest.approx(data["profile"]["odometry"]["drift_per_m"], rel=1e-5)
    for line in fig.axes[0].get_lines():  # a reset inside a stretch breaks its curve instead of drawing across it
        err = np.asarray(line.get_ydata(), dtype=np.float64)
        finite = np.isfinite(err)
        assert not np.any(np.abs(np.diff(err[finite])) > 0.5) or not finite.all()


def test_the_report_names_the_recording_by_what_it_has(report):
    _, data, text = report
    (recording,) = data["source"]["recordings"]
    line = next(line for line in text.splitlines() if line.startswith(f"- `{recording['path']}`"))
    assert f"SHA-256 {recording['sha256'][:16]}" in line
    assert "episode(s)" not in line and "world ?" not in line and "profile ``" not in line
    assert re.search(r"\b3 episodes\b", line)
