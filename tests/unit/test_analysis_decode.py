"""Column-wise CDR decoding equals the message store's decoder, to the bit, on random and recorded messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from pipeline.analysis.decode import MAX_LAYOUTS_PER_LENGTH, Decoded, Ragged, Strings, concat, decode
from pipeline.analysis.layouts import DECODABLE, LAYOUTS, LEGACY_LAYOUTS, layout_for
from pipeline.core.scan import ScanGeometry
from pipeline.messages import convert as C
from pipeline.messages import message_store
from pipeline.messages import topics as T
from pipeline.messages.errors import MessageError
from pipeline.record import McapLog

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "session.mcap"
GOLDEN_V1 = Path(__file__).resolve().parents[1] / "golden" / "session_v1.mcap"
NS = 1_000_000_000
SPECIAL = np.array([np.nan, np.inf, -np.inf, -0.0, 5e-324, 1e308])


def assert_same(fast: Decoded, slow: Decoded) -> None:
    """Equal columns: numbers bit for bit, strings and sequences element by element."""
    assert fast.n == slow.n and fast.typename == slow.typename
    assert list(fast.columns) == list(slow.columns)
    for name, a in fast.columns.items():
        b = slow.columns[name]
        if isinstance(a, Strings) or isinstance(b, Strings):
            assert isinstance(a, Strings) and isinstance(b, Strings), name
            assert a.tolist() == b.tolist(), name
        elif isinstance(a, Ragged) or isinstance(b, Ragged):
            rows_a = a.tolist() if isinstance(a, Ragged) else list(a)
            rows_b = b.tolist() if isinstance(b, Ragged) else list(b)
            assert len(rows_a) == len(rows_b)
            for x, y in zip(rows_a, rows_b, strict=True):
                assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
        else:
            assert a.dtype == b.dtype and a.shape == b.shape, name
            assert a.tobytes() == b.tobytes(), name


def both(typename: str, datas: list[bytes]) -> tuple[Decoded, Decoded]:
    fast = decode(typename, datas)
    slow = decode(typename, datas, fast=False)
    assert slow.generic == len(datas)
    assert_same(fast, slow)
    return fast, slow


def _value(rng: np.random.Generator) -> float:
    return float(SPECIAL[rng.integers(len(SPECIAL))]) if rng.random() < 0.1 else float(rng.normal(0, 10))


def _name(rng: np.random.Generator, choices: tuple[str, ...]) -> str:
    return choices[rng.integers(len(choices))]


FRAMES = ("map", "robot_1/odom", "", "r", "röbot_2/odom", "a_much_longer_frame_name/with/parts")


def random_messages(typename: str, n: int, seed: int) -> list[bytes]:
    """`n` CDR messages of `typename` with random values, strings and sequence lengths."""
    s = message_store()
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        t = int(rng.integers(-(2**31) * NS, 2**31 * NS))
        frame = _name(rng, FRAMES)
        pose = np.array([_value(rng), _value(rng), float(rng.normal())])
        if typename == T.POSE_STAMPED:
            msg = C.pose_stamped(t, frame, pose, store=s)
            msg.pose.position.z, msg.pose.orientation.x = _value(rng), _value(rng)
        elif typename == T.ODOMETRY:
            msg = C.odometry(t, _name(rng, ("robot_1", "robot_22", "")), pose, (_value(rng), _value(rng)), store=s)
            msg.header.frame_id = frame
            msg.pose.covariance = rng.normal(size=36)
            msg.pose.pose.orientation.w = _value(rng)
        elif typename == T.TWIST:
            msg = C.twist(_value(rng), _value(rng), store=s)
            msg.linear.y, msg.angular.x = _value(rng), _value(rng)
        elif typename == T.LASER_SCAN:
            beams = int(rng.choice([1, 7, 360]))
            geometry = ScanGeometry(beams, -math.pi, 2 * math.pi / beams, 0.05, 12.0)
            ranges = rng.uniform(0, 13, size=beams).astype(np.float32)
            ranges[rng.random(beams) < 0.1] = np.float32(np.inf)
            msg = C.laser_scan(t, frame, ranges, geometry, store=s)
            if rng.random() < 0.3:
                msg.intensities = rng.uniform(0, 100, size=beams).astype(np.float32)
        elif typename == T.TIMING:
            topic = _name(rng, ("/robot_1/scan", "/robot_1/ground_truth", "", "/robot_2/cmd_vel"))
            kind = _name(rng, ("send", "receive", "tick", "control"))
            msg = C.timing(t, kind, _name(rng, ("robot_1", "", "robot_3")), topic, t - 7, 2**63 + 5, 12, store=s)
        elif typename == T.EPISODE_EVENT:
            event = _name(rng, tuple(C.EVENT_CODES))
            msg = C.episode_event(t, 2**32 - 1, 17, event, _name(rng, ("robot_1", "")), _name(rng, FRAMES), store=s)
        elif typename == T.ACTION:
            output = rng.normal(size=int(rng.integers(1, 3))).astype(np.float32)
            msg = C.action(t, 3, 4, _name(rng, ("robot_1", "robot_2")), output, (_value(rng), _value(rng)), store=s)
        elif typename == T.OBSERVATION:
            values = rng.normal(size=int(rng.choice([17, 19, 0]))).astype(np.float32)
            msg = C.observation(t, 3, 4, "robot_1", _name(rng, ("paper", "rich", "")), values, store=s)
        elif typename == T.RESET_REQUEST:
            msg = C.reset_request(t, 9, int(rng.integers(0, 2**63)), bool(rng.random() < 0.5), store=s)
        elif typename == T.CLOCK:
            msg = C.clock(abs(t), store=s)
        else:
            raise AssertionError(typename)
        out.append(s.serialize(msg, typename))
    return out


@pytest.mark.parametrize("typename", sorted(DECODABLE))
def test_random_messages_decode_the_same_both_ways(typename):
    datas = random_messages(typename, 300, seed=len(typename))
    fast, _ = both(typename, datas)
    assert fast.generic == 0  # every one of these layouts is regular


def test_one_layout_reads_every_field_as_numbers():
    s = message_store()
    pose = np.array([1.5, -2.25, 0.3])
    datas = [
        s.serialize(C.odometry(k * NS + 7, "robot_1", pose + k, (0.2, -0.1), store=s), T.ODOMETRY) for k in range(5)
    ]
    fast = decode(T.ODOMETRY, datas)
    assert fast.generic == 0
    np.testing.assert_array_equal(fast.columns["stamp_ns"], np.arange(5) * NS + 7)
    np.testing.assert_array_equal(fast.columns["x"], 1.5 + np.arange(5))
    assert fast.columns["linear_x"].tolist() == [0.2] * 5 and fast.columns["angular_z"].tolist() == [-0.1] * 5
    frame = fast.columns["child_frame_id"]
    assert isinstance(frame, Strings) and frame.values == ("robot_1/base_link",)
    assert "pose_covariance" not in fast.columns


def test_scans_of_one_beam_count_are_a_matrix_and_mixed_counts_ragged():
    s = message_store()
    geometry = ScanGeometry(360, -math.pi, 2 * math.pi / 360, 0.05, 12.0)
    ranges = np.random.default_rng(3).uniform(0, 12, size=(20, 360)).astype(np.float32)
    same = [
        s.serialize(C.laser_scan(k, "robot_1/laser", r, geometry, store=s), T.LASER_SCAN) for k, r in enumerate(ranges)
    ]
    fast = decode(T.LASER_SCAN, same)
    assert fast.generic == 0
    assert isinstance(fast.columns["ranges"], np.ndarray) and fast.columns["ranges"].shape == (20, 360)
    assert fast.columns["ranges"].tobytes() == ranges.tobytes()
    assert fast.columns["intensities"].shape == (20, 0)
    mixed = decode(T.LASER_SCAN, random_messages(T.LASER_SCAN, 50, seed=4))
    assert isinstance(mixed.columns["ranges"], Ragged)


def test_padding_other_byte_orders_and_odd_layouts_fall_back_to_the_generic_decoder():
    s = message_store()
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    datas = random_messages(T.POSE_STAMPED, 100, seed=11)
    padded = [d + b"\x00" * (k % 4) for k, d in enumerate(datas)]  # CDR may pad a message to a multiple of 4
    both(T.POSE_STAMPED, padded)
    msg = C.pose_stamped(5 * NS, "map", np.array([1.0, 2.0, 3.0]), store=s)
    big_endian = bytes(jazzy.serialize_cdr(msg, T.POSE_STAMPED, little_endian=False))
    assert big_endian[:2] == b"\x00\x00"
    mixed = [*datas[:10], big_endian, *datas[10:20], big_endian]
    fast, _ = both(T.POSE_STAMPED, mixed)
    assert fast.generic == 2
    assert fast.columns["x"][10] == 1.0 and fast.columns["stamp_ns"][21] == 5 * NS


def test_more_layouts_than_the_limit_still_decode_the_same():
    s = message_store()
    n = MAX_LAYOUTS_PER_LENGTH + 20
    # one byte length, a different split between the two strings in each message (the robot is the frame id too)
    datas = [
        s.serialize(C.timing(k, "send", "r" * (8 * k + 3), "t" * (16 * (n - k) + 3), k, k, k, store=s), T.TIMING)
        for k in range(n)
    ]
    assert len({len(d) for d in datas}) == 1
    fast, _ = both(T.TIMING, datas)
    assert fast.generic == n - MAX_LAYOUTS_PER_LENGTH


def test_batches_concatenate_to_the_whole():
    datas = random_messages(T.LASER_SCAN, 90, seed=5) + random_messages(T.LASER_SCAN, 40, seed=6)
    whole = decode(T.LASER_SCAN, datas)
    parts = [decode(T.LASER_SCAN, datas[k : k + 32]) for k in range(0, len(datas), 32)]
    assert_same(concat(parts), whole)
    events = random_messages(T.EPISODE_EVENT, 60, seed=8)
    assert_same(
        concat([decode(T.EPISODE_EVENT, events[:25]), decode(T.EPISODE_EVENT, events[25:])]),
        decode(T.EPISODE_EVENT, events),
    )


def test_garbled_message_is_named_by_its_log_time():
    datas = random_messages(T.ODOMETRY, 5, seed=1)
    datas[3] = datas[3][:40]
    with pytest.raises(MessageError, match=r"file\.mcap: topic /robot_1/odom: message logged at 103 ns.*Odometry"):
        decode(T.ODOMETRY, datas, where="file.mcap: topic /robot_1/odom", log_times_ns=[100, 101, 102, 103, 104])


def test_unknown_type_is_refused():
    with pytest.raises(MessageError, match="no column decoder for tf2_msgs/msg/TFMessage"):
        decode(T.TF_MESSAGE, [b"\x00\x01\x00\x00"])


def test_empty_input_gives_empty_columns():
    out = decode(T.LASER_SCAN, [])
    assert out.n == 0 and out.columns["stamp_ns"].shape == (0,)


def test_layouts_are_the_definitions_of_the_schemas():
    s = message_store()
    for typename in DECODABLE:
        assert layout_for(typename, s.msgdef(typename)) is LAYOUTS[typename], typename
    assert "seed" in [f.name for f in LAYOUTS[T.EPISODE_EVENT]]


def test_a_recording_made_before_the_seed_field_decodes_by_its_own_schema():
    log = McapLog(GOLDEN_V1)
    schema = log.schemas()["/mrl/episode"]
    assert layout_for(T.EPISODE_EVENT, schema) is LEGACY_LAYOUTS[T.EPISODE_EVENT][0]
    datas = [m.data for m in log.raw("/mrl/episode")]
    fast = decode(T.EPISODE_EVENT, datas, schema=schema)
    slow = decode(T.EPISODE_EVENT, datas, schema=schema, fast=False)
    assert_same(fast, slow)
    assert fast.generic == 0 and slow.generic == len(datas) == 6
    assert "seed" not in fast.columns
    assert isinstance(fast.columns["detail"], Strings) and "seed=7" in fast.columns["detail"].values
    with pytest.raises(MessageError):  # the old bytes are not today's definition
        decode(T.EPISODE_EVENT, datas, fast=False)


def test_a_definition_no_layout_fits_is_refused():
    other = message_store().msgdef(T.EPISODE_EVENT).replace("int64 seed", "float64 seed")
    with pytest.raises(MessageError, match=r"f\.mcap: no column decoder for the recorded definition.*float64.*seed"):
        decode(T.EPISODE_EVENT, [], schema=other, where="f.mcap")


def test_golden_recording_decodes_the_same_both_ways():
    log = McapLog(GOLDEN)
    checked = 0
    for topic, typename in log.topics().items():
        if typename not in DECODABLE:
            continue
        datas = [m.data for m in log.raw(topic)]
        fast, _ = both(typename, datas)
        assert fast.generic == 0
        checked += 1
    assert checked >= 10
