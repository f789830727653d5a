"""Constants and record encoders of the MCAP files the pipeline writes (ROS 2 profile).

Layout of a finished file: magic, Header, then the data section (Chunks, each followed by the
Message Index records of its channels, and Metadata records), DataEnd, the summary section
(Schemas, Channels, Statistics, Chunk Indexes, Metadata Indexes), Summary Offsets, Footer, magic.
Schema and Channel records travel inside the chunk of their first message, so a file cut after
any complete chunk still defines every channel used so far.
"""

from __future__ import annotations

import struct

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import McapRecord

MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes that open and close every MCAP file."""
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
QOS_KEY = "offered_qos_profiles"
"""Channel metadata key the ros2 profile requires: the publisher QoS as rosbag2 YAML."""

RECORD_PREFIX = struct.Struct("<BQ")
"""Every record starts with its opcode (uint8) and the byte length of its body (uint64)."""
MESSAGE_HEAD = struct.Struct("<BQHIQQ")
"""Message record up to its data: opcode, length, channel id, sequence, log time ns, publish time ns."""
MESSAGE_FIXED = MESSAGE_HEAD.size - RECORD_PREFIX.size
"""Body bytes of a Message record before its data (22)."""
MESSAGE_FIELDS = struct.Struct("<HIQQ")
"""Body of a Message record before its data: channel id, sequence, log time ns, publish time ns."""
CHUNK_FIELDS = struct.Struct("<QQQI")
"""Body of a Chunk record before its compression string: start ns, end ns, uncompressed size, CRC-32."""
FOOTER_SIZE = RECORD_PREFIX.size + 20
"""Bytes of a Footer record: prefix, summary start, summary offset start, summary CRC."""


def encode(record: McapRecord) -> bytes:
    """The bytes of one record, prefix included, in mcap's own encoding."""
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


def message_index(channel_id: int, entries: list[int]) -> bytes:
    """A Message Index record; `entries` is flat (log time ns, offset in the chunk's records, ...)."""
    size = 8 * len(entries)
    return struct.pack(f"<BQHI{len(entries)}Q", Opcode.MESSAGE_INDEX, 6 + size, channel_id, size, *entries)


def chunk(start_ns: int, end_ns: int, records: bytes, crc: int, compression: str, data: bytes) -> bytes:
    """A Chunk record holding `records` (uncompressed, CRC-32 `crc`) stored as `data`."""
    name = compression.encode()
    body_size = CHUNK_FIELDS.size + 4 + len(name) + 8 + len(data)
    return b"".join(
        (
            RECORD_PREFIX.pack(Opcode.CHUNK, body_size),
            CHUNK_FIELDS.pack(start_ns, end_ns, len(records), crc),
            struct.pack("<I", len(name)),
            name,
            struct.pack("<Q", len(data)),
            data,
        )
    )
