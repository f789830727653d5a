"""One reader of episodes for every tool: the rule on event sequences, one recording read by the analysis
tables, calibration and replay, the seed as a typed field, and recordings made before that field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.analysis.replay import finished_episodes
from pipeline.analysis.tables import Recording, episodes_table
from pipeline.calibration.recording import read_session
from pipeline.core.scenario import load_scenario
from pipeline.mappings import to_mapping
from pipeline.messages import convert as C
from pipeline.messages import topics as T
from pipeline.messages.errors import MessageError
from pipeline.record import McapLog
from pipeline.record.episodes import (
    EPISODE_TOPIC,
    EpisodeWindow,
    EventRow,
    episode_windows,
    legacy_seed,
    read_episode_windows,
)
from pipeline.record.errors import MissingTopicError
from pipeline.record.session import SessionLog, dumps, session_metadata
from tests.golden.make_golden import GOLDEN_V1_MCAP

NS = 1_000_000_000
PERIOD_NS = 100_000_000
ROBOTS = ("robot_1", "robot_2")


def row(t_ns: int, episode: int, event: str, robot: str = "", detail: str = "", seed: int = -1, step: int = 0):
    return EventRow(t_ns, episode, step, robot, event, detail, seed)


# -- the rule, on event sequences ----------------------------------------------------------------


def test_end_finishes_a_team_abort_aborts_and_a_robot_abort_only_adds_its_reason():
    events = [
        row(10, 0, "start", seed=4),
        row(12, 0, "goal", "robot_1", step=2),
        row(15, 0, "end", detail="incomplete", step=5),
        row(20, 1, "start", seed=5),
        row(22, 1, "abort", "robot_2", "stale odom", step=2),
        row(24, 1, "abort", detail="interrupted", step=4),
    ]
    first, second = episode_windows(events)
    assert first == EpisodeWindow(0, 4, 10, 15, "finished", (), "incomplete", 5, tuple(events[:3]))
    assert second == EpisodeWindow(
        1, 5, 20, 24, "aborted", ("robot_2: stale odom", "interrupted"), "", 4, tuple(events[3:])
    )


def test_a_start_cuts_the_open_episode_short_and_the_file_can_stop_inside_one():
    events = [row(10, 0, "start", seed=1), row(20, 1, "start", seed=2), row(25, 1, "goal", "robot_1")]
    cut, tail = episode_windows(events)
    assert (cut.outcome, cut.end_ns, cut.end_step, cut.events) == ("unfinished", 19, None, (events[0],))
    assert (tail.outcome, tail.end_ns, tail.seed, len(tail.events)) == ("unfinished", None, 2, 2)


def test_events_of_an_episode_that_is_not_open_are_ignored():
    events = [
        row(5, 7, "end", detail="incomplete"),  # its start is not in the file
        row(10, 0, "start", seed=1),
        row(11, 3, "goal", "robot_1"),  # another episode's
        row(20, 1, "start", seed=2),
        row(21, 0, "end", detail="incomplete"),  # of the episode cut short already
        row(30, 1, "end", detail="team_success"),
        row(31, 1, "collision", "robot_2"),  # after its end
    ]
    windows = episode_windows(events)
    assert [(w.episode, w.outcome, w.end_ns) for w in windows] == [(0, "unfinished", 19), (1, "finished", 30)]
    assert windows[0].events == (events[1],) and windows[1].events == (events[3], events[5])
    assert episode_windows([]) == []


def test_seeds_come_from_the_field_then_from_the_legacy_detail():
    events = [
        row(1, 0, "start", seed=7, detail="seed=9"),
        row(2, 1, "start", detail="seed=9"),
        row(3, 2, "start", detail="mode=x, seed=12"),
        row(4, 3, "start"),
        row(5, 4, "start", seed=0),
    ]
    assert [w.seed for w in episode_windows(events)] == [7, 9, 12, None, 0]
    assert legacy_seed("seed=3") == 3 and legacy_seed("reseed=3") is None and legacy_seed("") is None


# -- one recording, three readers ----------------------------------------------------------------

# (episode, seed, poses written (steps + 1), events (step, event, robot, detail))
PLAN = [
    (0, 11, 6, [(3, "goal", "robot_1", ""), (5, "end", "", "incomplete")]),
    (1, 12, 5, [(2, "abort", "robot_2", "stale odom"), (4, "abort", "", "robot_2 lost")]),
    (2, 13, 4, []),  # the next start cuts it short...
    (3, 14, 6, [(0, "late_end_of_2", "", ""), (4, "goal", "robot_1", ""), (5, "goal", "robot_2", "")]),
    (4, 15, 4, []),  # ...and the file stops inside this one
]
SPACING_NS = 2 * NS


def start_ns(k: int) -> int:
    return NS + k * SPACING_NS


def write_recording(path: Path) -> Path:
    """The episodes of PLAN: finished, aborted by the team, cut short by a start, and open at the end of the file."""
    scenario = load_scenario("empty", n_robots=2)
    session = session_metadata("real", "empty", ROBOTS, PERIOD_NS / NS, profile="mild")
    with SessionLog(path, ROBOTS, session, {"scenario": dumps(to_mapping(scenario))}) as log:
        log.event(NS // 2, 99, 7, "end", detail="incomplete")  # an episode whose start is not in the file
        for episode, seed, poses, events in PLAN:
            t0 = start_ns(episode)
            log.start_episode(t0, episode, seed)
            for step in range(poses):
                t = t0 + step * PERIOD_NS
                for i, ns in enumerate(ROBOTS):
                    pose = np.array([1.0 + 0.1 * step, 1.0 + i, 0.0])
                    log.ground_truth(t, ns, pose)
                    log.odom(t, ns, pose, (1.0, 0.0))
                for when, event, robot, detail in events:
                    if when != step:
                        continue
                    if event == "late_end_of_2":  # an end of episode 2 after episode 3 started: ignored
                        log.event(t + 1, 2, 4, "end", detail="incomplete")
                    else:
                        log.event(t, episode, step, event, robot, detail)
            if episode == 3:
                log.event(t0 + 5 * PERIOD_NS, 3, 5, "success")
                log.event(t0 + 5 * PERIOD_NS, 3, 5, "end", detail="team_success")
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_recording(tmp_path_factory.mktemp("episodes") / "session.mcap")


EXPECTED = [  # (episode, seed, start_ns, end_ns, outcome)
    (0, 11, start_ns(0), start_ns(0) + 5 * PERIOD_NS, "finished"),
    (1, 12, start_ns(1), start_ns(1) + 4 * PERIOD_NS, "aborted"),
    (2, 13, start_ns(2), start_ns(3) - 1, "unfinished"),
    (3, 14, start_ns(3), start_ns(3) + 5 * PERIOD_NS, "finished"),
    (4, 15, start_ns(4), None, "unfinished"),
]


def test_the_recording_reads_as_planned(recording):
    windows = read_episode_windows(McapLog(recording))
    assert [(w.episode, w.seed, w.start_ns, w.end_ns, w.outcome) for w in windows] == EXPECTED
    assert windows[1].abort_reasons == ("robot_2: stale odom", "robot_2 lost")
    assert [w.end_detail for w in windows] == ["incomplete", "", "", "team_success", ""]
    assert [w.end_step for w in windows] == [5, 4, None, 5, None]


def test_the_three_readers_agree_on_the_episodes(recording):
    windows = {e[0]: e for e in EXPECTED}

    # analysis: every window; aborted unless finished cleanly
    episodes = Recording(recording).episodes()
    got = list(zip(*(episodes[c].to_list() for c in ("episode", "seed", "start_ns", "end_ns")), strict=True))
    assert got == [e[:4] for e in EXPECTED]
    assert episodes["aborted"].to_list() == [e[4] != "finished" for e in EXPECTED]
    assert episodes["end"].to_list() == ["incomplete", "aborted", "", "team_success", ""]
    assert episodes["team_success"].to_list() == [False, False, False, True, False]
    reasons = episodes["abort_reason"].to_list()
    assert reasons[1] == "robot_2: stale odom; robot_2 lost"
    assert "the next episode started" in reasons[2] and "stops inside the episode" in reasons[4]
    table = episodes_table(recording)
    assert sorted(set(zip(table["episode"], table["seed"], strict=True))) == [e[:2] for e in EXPECTED]

    # calibration: the windows that ended, and the one the file stops inside cut at the last message read;
    # not the one a new start cut short
    data = read_session(recording, ["odometry"])
    assert data.has_episode_topic
    last_pose_ns = start_ns(4) + 3 * PERIOD_NS
    expected = [(e[0], e[1], e[2], last_pose_ns if e[3] is None else e[3]) for e in EXPECTED if e[0] != 2]
    assert [(w.episode, w.seed, w.start_ns, w.end_ns) for w in data.episodes] == expected

    # replay: the finished windows
    finished = [(windows[k][2], windows[k][3]) for k in (0, 3)]
    assert finished_episodes(McapLog(recording)) == finished


def test_start_events_carry_the_seed_in_their_typed_field(recording):
    starts = []
    with open(recording, "rb") as f:
        for schema, _, message in make_reader(f).iter_messages(topics=[EPISODE_TOPIC]):
            assert schema is not None and "int64 seed" in schema.data.decode()
            types = get_typestore(Stores.EMPTY)
            types.register(get_types_from_msg(schema.data.decode(), schema.name))
            msg = types.deserialize_cdr(message.data, schema.name)
            starts += [(msg.episode, msg.seed, msg.detail)] if msg.event == C.EVENT_CODES["start"] else []
            if msg.event != C.EVENT_CODES["start"]:
                assert msg.seed == -1
    assert starts == [(e[0], e[1], "") for e in EXPECTED]
    with open(recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        decoded = [m.decoded_message for m in reader.iter_decoded_messages(topics=[EPISODE_TOPIC])]
    assert [(m.episode, m.seed) for m in decoded if m.event == C.EVENT_CODES["start"]] == [e[:2] for e in EXPECTED]


def test_a_seed_the_field_cannot_hold_is_refused():
    with pytest.raises(MessageError, match=r"EpisodeEvent: seed -2 is out of range"):
        C.episode_event(0, 0, 0, "start", seed=-2)
    assert C.episode_event(0, 0, 0, "start", seed=2**63 - 1).seed == 2**63 - 1


def test_a_recording_without_episode_events_is_named(tmp_path):
    path = tmp_path / "bare.mcap"
    with SessionLog(path, ROBOTS, session_metadata("real", "empty", ROBOTS, 0.1)) as log:
        log.ground_truth(0, "robot_1", np.zeros(3))
    with pytest.raises(MissingTopicError, match=r"bare\.mcap: .*/mrl/episode"):
        read_episode_windows(McapLog(path))
    assert finished_episodes(McapLog(path)) == []


# -- recordings made before the seed field -------------------------------------------------------


def test_the_old_format_fixture_reads_its_seeds_from_the_detail_text():
    log = McapLog(GOLDEN_V1_MCAP)
    assert "seed" not in log.schemas()[EPISODE_TOPIC]
    assert log.topics()[EPISODE_TOPIC] == T.EPISODE_EVENT
    windows = read_episode_windows(log)
    # three control steps, each with a start of episode 3 (seed=7): each start cuts the one before short
    assert [(w.episode, w.seed, w.outcome) for w in windows] == [(3, 7, "unfinished")] * 3
    assert windows[0].end_ns == windows[1].start_ns - 1 and windows[2].end_ns is None
    episodes = Recording(GOLDEN_V1_MCAP).episodes()
    assert episodes["seed"].to_list() == [7, 7, 7]
    assert episodes["start_ns"].to_list() == [w.start_ns for w in windows]
