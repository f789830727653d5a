"""The installed ``mrl`` command, run as a process on real files: help, info, calibrate, episodes, bad input.

The calibration bags hold only what ``ros2 bag record`` on the robots would: the robots' scan, odom,
cmd_vel and ground_truth, plus /tf and /clock; no /mrl/* topics, no session metadata, no scenario.
They are copies of one simulated session (known lidar noise, actuation gain and odometry drift) as a
plain MCAP file, a rosbag2 folder with MCAP storage and one with sqlite3 storage.
"""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin

from pipeline.analysis.tables import EPISODES_SCHEMA
from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.record import McapLog, RawMessage
from pipeline.record.results import EPISODES_CSV_COLUMNS, read_episodes_csv
from tests.calibration_helpers import TWIN_EPISODES, simulate_session
from tests.golden.make_golden import GOLDEN_MCAP
from tests.integration.test_calibration_inputs import MILD_WORLD
from tests.unit.test_record_bags import STANDARD, golden_raw, write_plain_mcap, write_ros1, write_rosbag2

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
MRL = Path(sys.executable).parent / "mrl"
VERBS = ("info", "episodes", "compare", "calibrate", "replay", "twin", "deploy")
ROBOT_KINDS = ("scan", "odom", "cmd_vel", "ground_truth")
BAG_KINDS = ("mcap", "rosbag2-mcap", "rosbag2-sqlite3")
EPISODES, STEPS = 3, 60


def mrl(*args: str | Path, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run the installed command; its exit code, stdout and stderr."""
    assert MRL.is_file(), f"{MRL} is missing: pip install -e . installs the mrl script"
    return subprocess.run(
        [str(MRL), *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd, check=False
    )


def refused(proc: subprocess.CompletedProcess[str], verb: str, *names: str) -> str:
    """The one stderr line of a bad-input exit (rc 2); it names every one of `names`."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr
    # progress lines ("calibrate: reading 1 recording (0 s)") may come first; the error is one line
    lines = [line for line in proc.stderr.strip().splitlines() if not line.startswith(f"{verb}: ")]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"mrl {verb}: "), lines[0]
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


def standard_messages(session: Path) -> list[RawMessage]:
    """The robots' standard topics of `session`, with /tf and /clock at 10 Hz added, in log-time order."""
    log = McapLog(session)
    robots = [t for t in log.topics() if not t.startswith("/mrl/") and t.rsplit("/", 1)[-1] in ROBOT_KINDS]
    messages = list(log.raw(robots))
    store = message_store()
    names = sorted({t.split("/")[1] for t in robots})
    start, end = messages[0].log_time_ns, messages[-1].log_time_ns
    for t in range(start, end, 100_000_000):
        clock = store.serialize(C.clock(t, store=store), T.CLOCK)
        tf = C.tf_message(t, [("map", f"{ns}/odom", np.zeros(3)) for ns in names], store=store)
        messages.append(RawMessage("/clock", T.CLOCK, t, t, 0, clock))
        messages.append(RawMessage("/tf", T.TF_MESSAGE, t, t, 0, store.serialize(tf, T.TF_MESSAGE)))
    return sorted(messages, key=lambda m: m.log_time_ns)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated session recording (this project's layout): 3 robots, MILD_WORLD's noise and drift."""
    root = tmp_path_factory.mktemp("mrl_session")
    return simulate_session(root / "session.mcap", MILD_WORLD, episodes=EPISODES, steps=STEPS)


@pytest.fixture(scope="module")
def bags(session: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The session's standard topics as a plain MCAP, a rosbag2 MCAP folder and a rosbag2 sqlite3 folder."""
    root = tmp_path_factory.mktemp("mrl_bags")
    messages = standard_messages(session)
    return {
        "mcap": write_plain_mcap(root / "robots.mcap", messages),
        "rosbag2-mcap": write_rosbag2(root / "robots_mcap", messages, StoragePlugin.MCAP),
        "rosbag2-sqlite3": write_rosbag2(root / "robots_db3", messages, StoragePlugin.SQLITE3),
    }


@pytest.fixture(scope="module")
def calibrations(bags: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    """``mrl calibrate --scenario obstacles`` on each bag: the parsed calibration.yaml per bag kind."""
    root = tmp_path_factory.mktemp("mrl_calibrations")
    out = {}
    for kind, bag in bags.items():
        folder = root / kind
        proc = mrl("calibrate", bag, "--scenario", "obstacles", "--bootstrap", "20", "--out", folder)
        assert proc.returncode == 0, (kind, proc.stderr)
        assert "Traceback" not in proc.stderr
        assert f"{folder / 'calibration.yaml'} from {bag}" in proc.stdout
        assert (folder / "calibration.md").is_file()
        out[kind] = yaml.safe_load((folder / "calibration.yaml").read_text())
    return out


# -- help -----------------------------------------------------------------------------------------


def test_help_lists_every_verb_and_each_verb_has_usage():
    top = mrl("--help")
    assert top.returncode == 0 and top.stdout.startswith("usage: mrl")
    for verb in VERBS:
        assert re.search(rf"^\s+{verb}\b", top.stdout, re.MULTILINE), verb
        proc = mrl(verb, "--help")
        assert proc.returncode == 0, (verb, proc.stderr)
        assert proc.stdout.startswith("usage:") and "--help" in proc.stdout, verb
    assert "--fleet" in mrl("twin", "--help").stdout  # the twin's own options
    for option in ("--robots", "--topic"):
        assert option in mrl("calibrate", "--help").stdout


def test_help_lists_every_exit_code_the_verbs_use_with_its_meaning():
    top = mrl("--help")
    assert top.returncode == 0 and "\nexit codes:\n" in top.stdout
    section = top.stdout.split("\nexit codes:\n", 1)[1]
    listed = {int(m[1]): m[2] for m in re.finditer(r"^  (\d+)\s+(\S.*)$", section, re.MULTILINE)}
    assert listed.keys() == {0, 1, 2, 3, 4, 130}
    assert listed[0] == "done" and listed[1].startswith("no result") and listed[2].startswith("bad input")
    assert listed[3].startswith("runtime fault") and listed[130].startswith("interrupted")
    assert listed[4].startswith("a deployment that finished, but in some episodes it did not keep its")
    # every code the verbs, the twin they start and the stages' plumbing return is among them
    import pipeline.stage

    used = {v for k, v in vars(pipeline.stage).items() if k.startswith("EXIT_") and isinstance(v, int)}
    for path in [*(ROOT / "pipeline" / "mrl").glob("*.py"), ROOT / "pipeline" / "twin" / "__main__.py"]:
        used |= {int(n) for n in re.findall(r"\b(?:return|exit\()\s*(\d+)\b", path.read_text())}
    assert used and used <= listed.keys(), used - listed.keys()


def mistyped(proc: subprocess.CompletedProcess[str], verb: str) -> str:
    """The error line of an argument the verb does not know: exit 2, the verb's own usage first, nothing on stdout."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert proc.stdout == "" and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"usage: mrl {verb} "), proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"mrl {verb}: error: "), last
    return last


def test_a_mistyped_option_gets_the_verbs_usage_and_the_nearest_option(tmp_path):
    assert "did you mean --map?" in mistyped(mrl("calibrate", "--mpa"), "calibrate")
    line = mistyped(mrl("calibrate", GOLDEN_MCAP, "--mpa", tmp_path / "floor.yaml"), "calibrate")
    assert "unrecognized arguments: --mpa" in line and "--mpa: did you mean --map?" in line
    line = mistyped(mrl("episodes", GOLDEN_MCAP, "--outt=table.csv", "--robts", "robot_1"), "episodes")
    assert "--outt: did you mean --out?" in line and "--robts: did you mean --robots?" in line
    assert not (tmp_path / "table.csv").exists()
    line = mistyped(mrl("info", GOLDEN_MCAP, "--xyzzy"), "info")
    assert "--xyzzy: not an option of mrl info" in line
    # the twin's options are its own: refused before a twin starts
    assert "--profle: did you mean --profile?" in mistyped(mrl("twin", "--profle", "harsh", timeout=60), "twin")


# -- info -----------------------------------------------------------------------------------------


def topic_line(text: str, topic: str, typename: str, count: int) -> bool:
    return re.search(rf"^\s+{re.escape(topic)}\s+{re.escape(typename)}\s+{count}\b", text, re.MULTILINE) is not None


def test_info_on_a_session_a_rosbag2_sqlite3_copy_and_a_ros1_copy(tmp_path):
    golden = McapLog(GOLDEN_MCAP)
    counts, types = golden.message_counts(), golden.topics()
    db3 = write_rosbag2(tmp_path / "fleet_db3", golden_raw(), StoragePlugin.SQLITE3)
    ros1 = write_ros1(tmp_path / "fleet.bag", golden_raw(STANDARD))
    proc = mrl("info", GOLDEN_MCAP, db3, ros1)
    assert proc.returncode == 0, proc.stderr
    sections = proc.stdout.split("\n\n")
    assert len(sections) == 3
    for text, topics, fmt in (
        (sections[0], list(types), "mcap (a session recording"),
        (sections[1], list(types), "rosbag2-sqlite3 (imported)"),
        (sections[2], STANDARD, "ros1 (imported)"),
    ):
        assert f"format: {fmt}" in text
        assert "robots: robot_1, robot_2 (2)" in text
        assert f"messages: {sum(counts[t] for t in topics)} on {len(topics)} topics" in text
        for topic in topics:
            assert topic_line(text, topic, types[topic], counts[topic]), (fmt, topic)
        assert "ground truth: yes (every robot)" in text
    assert "session metadata: yes (world sim)" in sections[0]
    assert "episode events: yes" in sections[0] and "episode events: yes" in sections[1]
    assert "session metadata: no" in sections[2] and "episode events: no" in sections[2]
    assert "episodes: needs /mrl/episode (recorded by this project)" in sections[2]


def test_info_on_a_bag_of_standard_topics_says_what_calibrate_needs(bags):
    proc = mrl("info", bags["rosbag2-mcap"])
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "robots: robot_1, robot_2, robot_3 (3)" in text
    assert topic_line(text, "/robot_2/scan", T.LASER_SCAN, EPISODES * STEPS)
    assert topic_line(text, "/robot_2/odom", T.ODOMETRY, EPISODES * STEPS * 5)
    assert "calibrate: lidar, actuation, odometry, network (ground truth present); needs --scenario" in text
    assert "episodes: needs /mrl/episode" in text
    # no observations to re-run a policy on, but commands, scans and odometry: the map's route is named
    assert "replay --policy: needs /mrl/observation, /mrl/action" in text
    assert "replay --map FLOOR.yaml: the commands open loop against the path localized in the map" in text


def test_info_describes_a_bag_without_robot_topics_instead_of_refusing_it(tmp_path):
    """A bag of /tf and /clock alone (a robot's topics under names of its own) is described: its topics, and how
    to map them; beside it a bag with robots is described as usual."""
    tf_only = write_ros1(tmp_path / "tf.bag", golden_raw(["/tf", "/clock"]))
    proc = mrl("info", tf_only, GOLDEN_MCAP)
    assert proc.returncode == 0, proc.stderr
    first, second = proc.stdout.split("\n\n")
    assert f"bag: {tf_only}" in first and "robots: none" in first
    assert "/tf     tf2_msgs/msg/TFMessage" in first and "/clock  rosgraph_msgs/msg/Clock" in first
    assert "--topic scan=/base_scan" in first
    assert "robots: robot_1, robot_2 (2)" in second


# -- calibrate ------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_calibrate_recovers_lidar_noise_and_linear_gain(calibrations, bags, kind):
    data = calibrations[kind]
    assert data["scenario"] == "obstacles"
    assert data["profile"]["lidar"]["beams"] == 360
    assert data["profile"]["lidar"]["noise_sigma_m"] == pytest.approx(MILD_WORLD["lidar"]["noise_sigma_m"], rel=0.10)
    assert data["profile"]["actuation"]["linear_gain"] == pytest.approx(
        MILD_WORLD["actuation"]["linear_gain"], rel=0.05
    )
    assert [r["path"] for r in data["source"]["recordings"]] == [str(bags[kind])]  # the bag as given


@pytest.mark.parametrize("kind", BAG_KINDS)
def test_a_converted_bag_is_named_and_hashed_as_the_user_has_it(calibrations, bags, kind):
    """The recording calibration.yaml names is the user's bag (file or folder) with its own SHA-256, not the
    temporary MCAP it was read through."""
    from pipeline.record.bags import bag_sha256

    (recording,) = calibrations[kind]["source"]["recordings"]
    assert recording["path"] == str(bags[kind])
    assert recording["sha256"] == bag_sha256(bags[kind])
    if bags[kind].is_file():
        assert recording["sha256"] == hashlib.sha256(bags[kind].read_bytes()).hexdigest()


def test_the_three_bag_formats_calibrate_to_the_same_values(calibrations):
    first = calibrations["mcap"]
    for kind in BAG_KINDS[1:]:
        assert calibrations[kind]["profile"] == first["profile"], kind
        assert calibrations[kind]["world"] == first["world"], kind


def test_calibrate_recovers_odometry_drift(calibrations, session, tmp_path):
    """Standard topics only give the drift of the full recording (whose episode events delimit the odometry
    draws), and the simulated drift lies in the stated 95 % interval. With 3 short episodes one standard error
    is about 15 %, so closeness to the simulated value itself is not the bar here (the twin recordings of
    tests/integration/test_calibration_plain_bags.py are long enough for that)."""
    truth = MILD_WORLD["odometry"]["drift_per_m"]
    proc = mrl("calibrate", session, "--bootstrap", "20", "--out", tmp_path)
    assert proc.returncode == 0, proc.stderr
    full = yaml.safe_load((tmp_path / "calibration.yaml").read_text())["uncertainty"]["odometry"]["drift_per_m"]
    for kind in BAG_KINDS:
        estimate = calibrations[kind]["uncertainty"]["odometry"]["drift_per_m"]
        assert estimate["status"] == "ok", (kind, estimate)
        measured = estimate["value"]
        assert measured == pytest.approx(full["value"], rel=0.15), (
            f"{kind}: odometry.drift_per_m {measured:.5f} from standard topics, {full['value']:.5f} from the full "
            "recording"
        )
        low, high = estimate["interval_95"]
        assert low <= truth <= high, (kind, estimate)


def test_bad_input_is_one_line_naming_the_path_or_option(tmp_path, bags):
    missing = tmp_path / "nowhere.mcap"
    refused(mrl("info", missing), "info", str(missing), "no such file")
    notes = tmp_path / "notes.txt"
    notes.write_text("not a bag\n")
    refused(mrl("calibrate", notes, "--scenario", "obstacles"), "calibrate", str(notes), "not a bag")
    refused(mrl("info", bags["mcap"], "--topic", "scan"), "info", "--topic 'scan'", "OURS=BAG")
    line = refused(mrl("calibrate", bags["rosbag2-sqlite3"], "--bootstrap", "20"), "calibrate", "names no scenario")
    assert str(bags["rosbag2-sqlite3"]) in line and "mrl-" not in line  # the bag as given, not the imported copy
    refused(mrl("episodes", bags["mcap"]), "episodes", str(bags["mcap"]), "/mrl/episode")
    refused(mrl("episodes", bags["mcap"], "--out", tmp_path / "table.txt"), "episodes", "--out", ".csv or .parquet")


def test_a_replay_horizon_of_no_seconds_is_refused_before_the_bag_is_read(tmp_path):
    line = refused(
        mrl(
            "replay",
            tmp_path / "floor.bag",
            "--map",
            tmp_path / "floor.yaml",
            "--horizon-s",
            "0",
            "--out",
            tmp_path / "r",
        ),
        "replay",
        "--horizon-s 0",
    )
    assert "above 0" in line and not (tmp_path / "r").exists()


def test_replay_without_policy_or_map_says_that_one_of_them_is_needed(tmp_path):
    line = refused(mrl("replay", GOLDEN_MCAP, "--out", tmp_path / "r"), "replay", "--policy DIR", "--map MAP")
    assert "is needed" in line and "not both" not in line
    both = mrl("replay", GOLDEN_MCAP, "--policy", tmp_path / "p", "--map", tmp_path / "m.yaml")
    assert "not both" in refused(both, "replay", "--policy", "--map")
    assert not (tmp_path / "r").exists()


# -- episodes -------------------------------------------------------------------------------------


def test_episodes_table_printed_and_written_as_csv_and_parquet(session, tmp_path):
    printed = mrl("episodes", session)
    assert printed.returncode == 0, printed.stderr
    assert "time_to_goal_s" in printed.stdout and "path_length_m" in printed.stdout
    assert f"episodes: {EPISODES} episodes (0 aborted)" in printed.stdout
    tables = {}
    for suffix in (".csv", ".parquet"):
        out = tmp_path / "tables" / f"episodes{suffix}"
        proc = mrl("episodes", session, "--out", out)
        assert proc.returncode == 0, proc.stderr
        assert f"-> {out}" in proc.stdout
        tables[suffix] = pl.read_csv(out) if suffix == ".csv" else pl.read_parquet(out)
    # the CSV is a session's episodes.csv layout (one schema under that name), the Parquet file the whole table
    assert tables[".csv"].columns == list(EPISODES_CSV_COLUMNS)
    assert tables[".parquet"].columns == list(EPISODES_SCHEMA)
    rows = read_episodes_csv(tmp_path / "tables" / "episodes.csv")
    assert [r["success"] for r in rows] == [int(v) for v in tables[".parquet"]["success"].to_list()]
    for suffix, table in tables.items():
        assert table.height == EPISODES * 3, suffix
        pairs = set(zip(table["episode"].to_list(), table["robot"].to_list(), strict=True))
        assert pairs == {(e, f"robot_{r}") for e in range(EPISODES) for r in (1, 2, 3)}, suffix
        assert (table["path_length_m"] > 0).all() and table["steps"].to_list() == [STEPS] * table.height
    assert tables[".parquet"].schema == pl.Schema(EPISODES_SCHEMA)
    assert tables[".csv"]["path_length_m"].to_list() == pytest.approx(
        tables[".parquet"]["path_length_m"].to_list(), abs=5e-5
    )


def test_episodes_of_a_twin_deployment_give_the_path_lengths_of_its_own_episodes_csv(twin_session, tmp_path):
    """The harsh twin's ground truth comes at 50 Hz, lost and out of order; a path is measured one way, along the
    poses at the control steps, so the table read back from the recording is the one the deployment wrote."""
    recording = twin_session("harsh")
    out = tmp_path / "episodes.csv"
    proc = mrl("episodes", recording, "--out", out)
    assert proc.returncode == 0, proc.stderr
    written = {(r["episode"], r["robot"]): r for r in read_episodes_csv(recording.parent / "episodes.csv")}
    read_back = {(r["episode"], r["robot"]): r for r in read_episodes_csv(out)}
    assert len(written) == TWIN_EPISODES * 3 and read_back.keys() == written.keys()
    assert sum(r["path_length_m"] for r in written.values()) > TWIN_EPISODES  # the robots drove
    assert {k: r["path_length_m"] for k, r in read_back.items()} == {k: r["path_length_m"] for k, r in written.items()}


# -- calibrate without motion capture -------------------------------------------------------------


def _keyboard(levels: tuple[float, ...]):
    """Commands as a keyboard teleoperation sends them: forward speed from `levels`, held 1 s each in turn, while
    the turn rate steps through five values every 0.7 s."""
    turns = np.array([-0.3, -0.15, 0.0, 0.15, 0.3])

    def commands(truth: np.ndarray, tick: int) -> np.ndarray:
        t = tick * 0.02
        v = levels[int(t) % len(levels)]
        w = turns[int(t / 0.7) % len(turns)]
        return np.tile([v, w], (len(truth), 1))

    return commands


def test_calibrate_names_a_gain_or_limit_ambiguity_and_a_recording_that_separates_them(tmp_path):
    """One forward speed (0.5 m/s or stop) into a base capped at 0.31 m/s: the gain and the limit explain the bag
    alike; mrl calibrate prints both, keeps the limit and says what would separate them. Forward speeds below and
    above the cap separate them: the limit is found, the gain is the base's."""
    world = {"actuation": {"max_linear_mps": 0.31}}
    runs = {}
    for name, levels in (("one", (0.0, 0.5)), ("several", (0.0, 0.1, 0.5, 0.2, 0.5, 0.3))):
        bag = simulate_session(
            tmp_path / f"{name}.mcap", world, episodes=3, steps=60, seed=5, commands=_keyboard(levels)
        )
        proc = mrl("calibrate", bag, "--parts", "actuation", "--bootstrap", "30", "--out", tmp_path / name, timeout=300)
        assert proc.returncode == 0, proc.stderr
        runs[name] = (proc.stdout, yaml.safe_load((tmp_path / name / "calibration.yaml").read_text()))
    printed, data = runs["one"]
    assert "calibrate: ambiguous: a linear gain of" in printed and "the nominal gain up to a limit of" in printed
    assert "several linear speeds" in printed
    (ambiguity,) = [a for a in data["ambiguous"] if a["keys"][0] == "actuation.linear_gain"]
    assert ambiguity["kept"].startswith("the limit")
    assert data["world"]["actuation"]["max_linear_mps"] == pytest.approx(0.31, rel=0.06)
    assert "linear_gain" not in data["world"]["actuation"]
    assert "actuation.linear_gain" in data["unidentified"]
    printed, data = runs["several"]
    assert "ambiguous: a linear gain" not in printed
    assert not [a for a in data["ambiguous"] if a["keys"][0] == "actuation.linear_gain"]
    assert data["world"]["actuation"]["max_linear_mps"] == pytest.approx(0.31, rel=0.06)
    assert data["world"]["actuation"]["linear_gain"] == pytest.approx(1.0, rel=0.05)
    # the drive's delay and lag are the simulator's effective values, not the profile's keys
    assert set(data["effective"]) == {"drive_delay_s", "drive_lag_s", "drive_response_s"}
    assert data["effective"]["drive_lag_s"]["stands_for"][:2] == [
        "actuation.time_constant_s",
        "base.motor_time_constant_s",
    ]
    assert "delay_s" not in data["profile"].get("actuation", {})
    assert data["world"]["actuation"]["delay_s"] == data["effective"]["drive_delay_s"]["value"]


def test_calibrate_a_bag_without_ground_truth_in_a_map_server_map(tmp_path):
    from pipeline.calibration.localize import OccupancyMap
    from pipeline.core.scenario import load_scenario

    bag = simulate_session(tmp_path / "nogt.mcap", {}, episodes=2, steps=60, seed=4, omit=["/ground_truth"])
    floor = OccupancyMap.from_scenario(load_scenario("obstacles")).write_map_server(tmp_path / "floor.yaml")
    proc = mrl("calibrate", bag, "--map", floor, "--parts", "actuation", "--bootstrap", "20", "--out", tmp_path / "c")
    assert proc.returncode == 0, proc.stderr
    assert "poses localized from scans and odometry in the map_server map floor.yaml" in proc.stdout
    poses = yaml.safe_load((tmp_path / "c" / "calibration.yaml").read_text())["source"]["poses"]
    assert (
        poses["kind"] == "localized"
        and poses["match_score"] > 0.9
        and set(poses["robots"])
        == {
            "robot_1",
            "robot_2",
            "robot_3",
        }
    )
    bad = mrl("calibrate", bag, "--initial-pose", "1,2")  # argparse's usage, then its one error line
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    last = bad.stderr.strip().splitlines()[-1]
    assert last.endswith("--initial-pose: '1,2': expected x,y,yaw (metres, metres, radians)")
    refused(mrl("calibrate", bag, "--initial-pose", "1,2,0"), "calibrate", "one robot", "has 3")
    refused(mrl("calibrate", bag, "--map", tmp_path / "none.yaml"), "calibrate", "none.yaml", "cannot read the map")


def bare_robot_bag(session: Path, dest: Path) -> Path:
    """Robot robot_1 of `session` as a single-robot driver records it: ``/scan``, ``/odom``, ``/cmd_vel``, ``/tf``
    (odom -> base_link) and ``/tf_static`` (base_link -> laser), frames without namespace, as a rosbag2 folder."""
    store = message_store()
    out: list[RawMessage] = []
    keep = ["/robot_1/scan", "/robot_1/odom", "/robot_1/cmd_vel", "/tf_static"]
    for raw in McapLog(session).raw(keep):
        msg = store.deserialize(raw.data, raw.typename)
        if raw.typename == T.TF_MESSAGE:
            msg.transforms = [tr for tr in msg.transforms if tr.header.frame_id.startswith("robot_1/")]
            for tr in msg.transforms:
                tr.header.frame_id = tr.header.frame_id.removeprefix("robot_1/")
                tr.child_frame_id = tr.child_frame_id.removeprefix("robot_1/")
        elif hasattr(msg, "header"):
            msg.header.frame_id = msg.header.frame_id.removeprefix("robot_1/")
        if raw.typename == T.ODOMETRY:
            msg.child_frame_id = msg.child_frame_id.removeprefix("robot_1/")
            q = msg.pose.pose
            pose = np.array([q.position.x, q.position.y, 2 * np.arctan2(q.orientation.z, q.orientation.w)])
            tf = C.tf_message(raw.log_time_ns, [("odom", "base_link", pose)], store=store)
            out.append(
                RawMessage("/tf", T.TF_MESSAGE, raw.log_time_ns, raw.log_time_ns, 0, store.serialize(tf, T.TF_MESSAGE))
            )
        topic = raw.topic.removeprefix("/robot_1")
        out.append(raw._replace(topic=topic, data=store.serialize(msg, raw.typename)))
    return write_rosbag2(dest, sorted(out, key=lambda m: m.log_time_ns), StoragePlugin.MCAP)


def test_calibrate_a_single_robot_bag_without_namespace_ground_truth_or_scenario(tmp_path):
    from pipeline.calibration.localize import OccupancyMap
    from pipeline.core.scenario import load_scenario

    room = load_scenario("obstacles", n_robots=1)
    world = {
        "lidar": {"noise_sigma_m": 0.01, "mount_xy_m": [0.05, 0.0], "mount_yaw_rad": 0.03},
        "actuation": {"max_linear_mps": 0.25},  # commands go up to 0.4 m/s
    }
    session = simulate_session(
        tmp_path / "s.mcap", world, episodes=3, steps=100, seed=5, scenario=room, tf_static=True, omit=["/ground_truth"]
    )
    bag = bare_robot_bag(session, tmp_path / "bag")
    floor = OccupancyMap.from_scenario(room).write_map_server(tmp_path / "floor.yaml")
    info = mrl("info", bag)
    assert info.returncode == 0 and "robots: robot_1 (1)" in info.stdout, info.stdout
    assert "/robot_1/scan     sensor_msgs/msg/LaserScan       300  (from /scan)" in info.stdout
    assert "(no ground truth: poses localized from scans and odometry" in info.stdout
    out = tmp_path / "c"
    proc = mrl("calibrate", bag, "--map", floor, "--parts", "lidar,actuation", "--bootstrap", "30", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "poses localized from scans and odometry in the map_server map floor.yaml" in proc.stdout
    assert "calibrate: linear speed limit 0.2" in proc.stdout and "commanded up to 0.4 m/s" in proc.stdout, proc.stdout
    data = yaml.safe_load((out / "calibration.yaml").read_text())
    # no scenario anywhere: the map stands for the room, its faces for the lidar's surfaces
    assert data["scenario"] == "map floor.yaml"
    poses = data["source"]["poses"]
    assert poses["kind"] == "localized" and set(poses["robots"]) == {"robot_1"} and poses["match_score"] > 0.9
    # the laser's mounting from /tf_static (base_link -> laser), used by the localization
    lidar = data["uncertainty"]["lidar"]
    assert (
        lidar["mount_yaw_rad"]["value"] == pytest.approx(0.03) and lidar["mount_yaw_rad"]["method"] == "from /tf_static"
    )
    assert lidar["mount_xy_m[0]"]["value"] == pytest.approx(0.05)
    assert lidar["noise_sigma_m"]["value"] == pytest.approx(0.01, rel=0.15)
    # the base saturates: a top speed of 0.25 m/s, and the gain below it stays about 1 (not 0.25 / 0.4)
    limit = data["speed_limits"]["linear"]
    assert limit["saturated"] and limit["value"] == pytest.approx(0.25, rel=0.03) and limit["commanded_max"] > 0.35
    assert not data["speed_limits"]["angular"]["saturated"]
    assert data["uncertainty"]["actuation"]["linear_gain"]["value"] == pytest.approx(1.0, rel=0.05)
    assert data["world"]["actuation"]["max_linear_mps"] == pytest.approx(0.25, rel=0.03)


def test_a_map_given_with_motion_capture_is_checked_and_a_wrong_one_refused(session, tmp_path):
    """With ground truth the poses come from it; a map given is not ignored: the scans at the captured poses are
    checked against it, and a map of another frame (its origin a metre off) is refused by name."""
    from pipeline.calibration.localize import OccupancyMap
    from pipeline.core.scenario import load_scenario

    floor = OccupancyMap.from_scenario(load_scenario("obstacles")).write_map_server(tmp_path / "floor.yaml")
    proc = mrl("calibrate", session, "--map", floor, "--parts", "lidar", "--bootstrap", "20", "--out", tmp_path / "c")
    assert proc.returncode == 0, proc.stderr
    assert "poses from motion capture; the map floor.yaml checked against them:" in proc.stdout
    poses = yaml.safe_load((tmp_path / "c" / "calibration.yaml").read_text())["source"]["poses"]
    assert poses["kind"] == "ground_truth" and poses["map_checked"]["map"] == "floor.yaml"
    assert poses["map_checked"]["endpoints_on_map"] > 0.9
    assert "the map floor.yaml checked against them" in (tmp_path / "c" / "calibration.md").read_text()
    moved = yaml.safe_load(floor.read_text())
    moved["origin"] = [moved["origin"][0] + 1.0, moved["origin"][1] - 0.7, 0.0]
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(moved))
    assert (tmp_path / moved["image"]).exists()  # the moved map reads the same image
    line = refused(mrl("calibrate", session, "--map", other, "--out", tmp_path / "d"), "calibrate", str(other))
    assert "not the room of" in line and "of the scans' endpoints lie on this map (need 70 %)" in line
    assert not (tmp_path / "d").exists()
