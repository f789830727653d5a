"""MCAP session recordings: the recorder, the reader, and their errors.

One file per evaluation or deployment session, in the ROS 2 profile (``ros2msg`` schemas from
``schemas/``, ``cdr`` messages, zstd chunks, ``offered_qos_profiles`` on every channel), so
Foxglove, ``ros2 bag play`` and rosbags read it. A file whose recorder was killed is read back
up to its last complete chunk.

Bags recorded elsewhere (any MCAP, rosbag2 folders with mcap or sqlite3 storage, ROS 1 bags) are
imported into that layout by :func:`import_bag`; :func:`write_rosbag2_metadata` makes a session's
folder a rosbag2 bag.
"""

from pipeline.record.bags import BagFormat, BagTopic, ImportedBag, import_bag, parse_topic_map
from pipeline.record.errors import (
    BagError,
    BagImportWarning,
    BagReadError,
    DamagedLogWarning,
    EmptyBagError,
    LogDecodeError,
    LogFormatError,
    LogReadError,
    MissingTopicError,
    NoRobotsError,
    NotABagError,
    RecordError,
    RemapError,
    RemapTopicMissingError,
    TopicMapError,
    TopicTypeError,
    TruncatedLogWarning,
    UndecodableMessageWarning,
    UnknownMessageTypeError,
)
from pipeline.record.reader import LogMessage, LostRange, McapLog, RawMessage
from pipeline.record.rosbag2 import write_rosbag2_metadata
from pipeline.record.writer import DEFAULT_CHUNK_SIZE, LIBRARY, McapRecorder, versions_metadata

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "LIBRARY",
    "BagError",
    "BagFormat",
    "BagImportWarning",
    "BagReadError",
    "BagTopic",
    "DamagedLogWarning",
    "EmptyBagError",
    "ImportedBag",
    "LogDecodeError",
    "LogFormatError",
    "LogMessage",
    "LogReadError",
    "LostRange",
    "McapLog",
    "McapRecorder",
    "MissingTopicError",
    "NoRobotsError",
    "NotABagError",
    "RawMessage",
    "RecordError",
    "RemapError",
    "RemapTopicMissingError",
    "TopicMapError",
    "TopicTypeError",
    "TruncatedLogWarning",
    "UndecodableMessageWarning",
    "UnknownMessageTypeError",
    "import_bag",
    "parse_topic_map",
    "versions_metadata",
    "write_rosbag2_metadata",
]
