"""``mrl compare`` run as a process on session recordings: the same file twice, worlds from the recordings' session
metadata, labels, metrics keys, axis labels of the trajectories."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from tests.integration.test_mrl_command import mrl, refused
from tests.unit.test_analysis_tables import write_session

pytestmark = pytest.mark.integration

SAME_FILE = "warning: both inputs are the same file"


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A sim session, a real one with deployment timing, and a session whose metadata names neither world."""
    root = tmp_path_factory.mktemp("compare_inputs")
    return {
        "sim": write_session(root / "simrun.mcap", world="sim"),
        "real": write_session(root / "fleet.mcap", ground_truth=False, timing=True, world="real"),
        "lab": write_session(root / "lab.mcap", world="lab"),
    }


def compare(*args: str | Path, cwd: Path | None = None) -> tuple[str, str, str, dict]:
    """``mrl compare ARGS``, which must succeed: its stdout, stderr, report.md and metrics.json (the last of --out)."""
    proc = mrl("compare", *args, cwd=cwd)
    assert proc.returncode == 0, (proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    out = Path(str(args[list(args).index("--out") + 1]))
    out = out if out.is_absolute() or cwd is None else cwd / out
    return proc.stdout, proc.stderr, (out / "report.md").read_text(), json.loads((out / "metrics.json").read_text())


def table_rows(markdown: str, heading: str) -> list[dict[str, str]]:
    """The rows of the first markdown table under `heading`, as {column: cell}."""
    lines = markdown.split(f"## {heading}\n", 1)[1].splitlines()
    table = [line for line in lines[: next(k for k, line in enumerate(lines) if line.startswith("## "))]]
    table = [line for line in table if line.startswith("|")]
    header = [c.strip() for c in table[0].strip("|").split("|")]
    return [dict(zip(header, (c.strip() for c in row.strip("|").split("|")), strict=True)) for row in table[2:]]


def warning_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("mrl compare: warning: ")]


# -- the same file twice ---------------------------------------------------------------------------


def test_the_same_file_twice_is_warned_about_on_stderr_and_in_the_report(recordings, tmp_path):
    sim = recordings["sim"]
    _, err, report, _ = compare(sim, sim, "--out", tmp_path / "same")
    assert any(SAME_FILE in line and str(sim) in line for line in warning_lines(err)), err
    assert "## Warnings" in report and "both inputs are the same file" in report.split("## Sessions")[0]
    # the same file by other spellings of its path: relative to the working folder, through a link
    os.symlink(sim, tmp_path / "alias.mcap")
    _, err, report, _ = compare(sim.name, tmp_path / "alias.mcap", "--out", tmp_path / "spelled", cwd=sim.parent)
    assert any(SAME_FILE in line for line in warning_lines(err)), err
    assert "both inputs are the same file" in report


def test_a_copy_is_the_same_file_by_content(recordings, tmp_path):
    copy = tmp_path / "copy.mcap"
    shutil.copyfile(recordings["real"], copy)
    _, err, report, _ = compare(recordings["real"], copy, "--out", tmp_path / "copy")
    line = next(line for line in warning_lines(err) if SAME_FILE in line)
    assert str(recordings["real"]) in line and str(copy) in line and "SHA-256" in line
    assert "same content (SHA-256" in report


def test_two_recordings_give_no_warning(recordings, tmp_path):
    _, err, report, metrics = compare(recordings["sim"], recordings["real"], "--out", tmp_path / "two")
    assert warning_lines(err) == [], err
    assert "## Warnings" not in report
    assert metrics["gap/simrun vs fleet/robot_success"] is not None


# -- worlds from the session metadata -----------------------------------------------------------


def test_worlds_come_from_the_session_metadata(recordings, tmp_path):
    # the real recording given first (as SIM): it is real in the report, and the sim one is sim
    out, err, report, metrics = compare(recordings["real"], recordings["sim"], "--out", tmp_path / "swapped")
    worlds = {Path(row["file"]).name: row["world"] for row in table_rows(report, "Sessions")}
    assert worlds == {"fleet.mcap": "real", "simrun.mcap": "sim"}
    lines = warning_lines(err)
    assert any(f"{recordings['real']} is given as SIM but its session metadata says world real" in x for x in lines)
    assert any(f"{recordings['sim']} is given as REAL but its session metadata says world sim" in x for x in lines)
    assert "is given as SIM but its session metadata says world real" in report
    # the gap is sim - real whatever the order: the timing figures belong to the real recording
    assert "real/fleet/send_skew_p99_ms" in metrics and not any("simrun/send_skew" in key for key in metrics)
    assert "compare: robot_success sim " in out


def test_two_recordings_of_one_world_are_not_pooled(recordings, tmp_path):
    other = write_session(tmp_path / "other" / "fleet.mcap", ground_truth=False, world="real")
    _, err, report, metrics = compare(recordings["real"], other, "--out", tmp_path / "both_real")
    assert any("both recordings are real (session metadata): no sim-vs-real gap" in x for x in warning_lines(err))
    rows = table_rows(report, "Sessions")
    assert [row["world"] for row in rows] == ["real", "real"]
    labels = [row["label"] for row in rows]
    assert len(set(labels)) == 2 and all(label.endswith("-fleet") for label in labels), labels
    assert not any(key.startswith("gap/") for key in metrics)
    assert {metrics[f"real/{label}/episodes"] for label in labels} == {5}  # each its own five, not ten pooled


def test_a_world_other_than_sim_or_real_is_refused(recordings, tmp_path):
    line = refused(mrl("compare", recordings["lab"], recordings["real"], "--out", tmp_path / "lab"), "compare")
    assert str(recordings["lab"]) in line and "world 'lab'" in line and "neither sim nor real" in line
    assert not (tmp_path / "lab" / "report.md").exists()


# -- labels and keys ----------------------------------------------------------------------------


def test_every_table_names_each_input_by_its_label(recordings, tmp_path):
    _, _, report, metrics = compare(recordings["sim"], recordings["real"], "--out", tmp_path / "labels")
    assert {row["label"]: row["world"] for row in table_rows(report, "Sessions")} == {"simrun": "sim", "fleet": "real"}
    assert {row["label"]: row["world"] for row in table_rows(report, "Success")} == {"simrun": "sim", "fleet": "real"}
    assert {(row["world"], row["label"]) for row in table_rows(report, "Per robot")} == {
        ("sim", "simrun"),
        ("real", "fleet"),
    }
    assert {row["label"] for row in table_rows(report, "Sim vs real")} == {"simrun vs fleet"}
    assert metrics["sim/simrun/robot_trials"] == 10 and metrics["real/fleet/robot_trials"] == 10


def test_recordings_of_one_name_share_their_label(tmp_path):
    sim = write_session(tmp_path / "logs" / "sim" / "nominal" / "session.mcap", world="sim")
    real = write_session(tmp_path / "logs" / "real" / "nominal" / "session.mcap", world="real", timing=True)
    out, _, report, metrics = compare(sim, real, "--out", tmp_path / "report")
    assert {row["label"] for row in table_rows(report, "Sessions")} == {"session"}
    assert metrics["gap/session/robot_success"] == 0.0
    assert "compare: robot_success sim 0.400 real 0.400 gap 0.000" in out


def test_metrics_keys_have_one_separator(recordings, tmp_path):
    _, _, _, metrics = compare(recordings["sim"], recordings["real"], "--out", tmp_path / "keys")
    assert not [key for key in metrics if "//" in key or key.startswith("/") or key.endswith("/")]
    assert metrics["real/fleet/send_skew_p99_ms"] == pytest.approx(0.05)


# -- a bag of the robots' own topics; progress ------------------------------------------------------


def test_a_bag_without_episodes_is_refused_naming_it_and_what_reads_it(recordings, tmp_path):
    """A user's rosbag2 of the robots' topics has no episodes: refused before any report folder exists, naming the
    bag as the user has it and the verbs that read such a bag."""
    from rosbags.rosbag2 import StoragePlugin

    from tests.unit.test_record_bags import golden_raw, write_rosbag2

    robots_only = [m for m in golden_raw() if not m.topic.startswith("/mrl/")]
    bag = write_rosbag2(tmp_path / "floor_db3", robots_only, StoragePlugin.SQLITE3)
    out = tmp_path / "report"
    line = refused(mrl("compare", recordings["sim"], bag, "--out", out), "compare", str(bag), "no episodes")
    assert "rosbag2-sqlite3" in line and "mrl calibrate" in line and "mrl replay" in line
    assert not out.exists()
    refused(mrl("episodes", bag), "episodes", str(bag), "no episodes")


def test_compare_says_each_stage_on_stderr_and_keeps_stdout_for_results(recordings, tmp_path):
    stdout, stderr, _, _ = compare(recordings["sim"], recordings["real"], "--out", tmp_path / "out")
    stages = [line for line in stderr.splitlines() if line.startswith("compare: ")]
    assert [s.split(" (")[0] for s in stages] == [
        "compare: reading sim 'simrun'",
        "compare: reading real 'fleet'",
        "compare: comparing the episodes",
        "compare: drawing the figures",
    ], stderr
    assert str(recordings["sim"]) in stages[0] and "MB" in stages[0]
    assert all(line.endswith(" s)") for line in stages)
    assert not [line for line in stdout.splitlines() if "reading" in line]


def on_a_terminal(*args: str | Path) -> str:
    """What ``mrl ARGS`` writes to stderr when it is a terminal 120 columns wide (stdout discarded)."""
    import fcntl
    import pty
    import struct
    import subprocess
    import termios

    from tests.integration.test_mrl_command import MRL

    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))  # a terminal has a width
    with subprocess.Popen([str(MRL), *map(str, args)], stdout=subprocess.DEVNULL, stderr=follower) as proc:
        os.close(follower)
        seen = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the terminal closes with the process
                break
            if not chunk:
                break
            seen += chunk
        assert proc.wait(timeout=300) == 0, seen
    os.close(leader)
    return seen.decode("utf-8", "replace")


def test_on_a_terminal_reading_a_recording_shows_a_bar_of_its_messages(recordings, tmp_path):
    """Under a pseudo-terminal (as a user runs it) reading shows a tqdm bar counting messages (episodes, compare and
    calibrate); piped, none."""
    text = on_a_terminal("episodes", recordings["sim"])
    assert "reading simrun:" in text and "msg" in text, text
    text = on_a_terminal("calibrate", recordings["sim"], "--parts", "lidar", "--bootstrap", "20", "--out", tmp_path)
    assert "reading simrun:" in text and "msg" in text and "calibrate: lidar (" in text, text
    piped = mrl("episodes", recordings["sim"])
    assert piped.returncode == 0 and "msg/s" not in piped.stderr and "reading simrun:" not in piped.stderr
