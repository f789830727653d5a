"""MCAP session recordings: the recorder, the reader, and their errors.

One file per evaluation or deployment session, in the ROS 2 profile (``ros2msg`` schemas from
``schemas/``, ``cdr`` messages, zstd chunks, ``offered_qos_profiles`` on every channel), so
Foxglove, ``ros2 bag play`` and rosbags read it. A file whose recorder was killed is read back
up to its last complete chunk.
"""

from pipeline.record.errors import (
    LogDecodeError,
    LogFormatError,
    LogReadError,
    RecordError,
    TruncatedLogWarning,
    UndecodableMessageWarning,
)
from pipeline.record.reader import LogMessage, McapLog, RawMessage
from pipeline.record.writer import DEFAULT_CHUNK_SIZE, LIBRARY, McapRecorder, versions_metadata

__all__ = [
    "DEFAULT_CHUNK_SIZE",
    "LIBRARY",
    "LogDecodeError",
    "LogFormatError",
    "LogMessage",
    "LogReadError",
    "McapLog",
    "McapRecorder",
    "RawMessage",
    "RecordError",
    "TruncatedLogWarning",
    "UndecodableMessageWarning",
    "versions_metadata",
]
