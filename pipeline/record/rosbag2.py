"""rosbag2 metadata beside a session MCAP, so that its folder opens as a ROS 2 bag.

``ros2 bag info``/``play`` and the ``rosbags`` library open a *folder* with a ``metadata.yaml``
that lists its storage files. :func:`write_rosbag2_metadata` writes one (rosbag2 metadata version 9,
as ROS 2 Jazzy writes it: storage ``mcap``, per-topic message counts, the offered QoS profiles
taken from the channels' ``offered_qos_profiles``, RIHS01 type hashes computed from the schemas
stored in the file) from what the MCAP itself holds, read through :class:`McapLog`. Only the MCAP
is listed in ``relative_file_paths`` and ``files``, so bag readers ignore the other files of a
session folder (episodes.csv, metrics.json).

Times are the MCAP's log times (integer nanoseconds on the recording's clock): ``starting_time``
is the first, ``duration`` the last minus the first, as rosbag2 writes them.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml
from mcap.reader import SeekingReader
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.record import format as fmt
from pipeline.record.errors import LogReadError, RecordError
from pipeline.record.reader import McapLog

METADATA_FILE = "metadata.yaml"
"""The file name rosbag2 looks for in a bag folder."""
VERSION = 9
"""rosbag2 metadata version written (ROS 2 Jazzy; QoS profiles as YAML lists with enum names)."""
ROS_DISTRO = "jazzy"
"""The distribution whose message definitions the pipeline records."""

_QOS_ENUMS: dict[str, Any] = {
    "history": QosHistory,
    "reliability": QosReliability,
    "durability": QosDurability,
    "liveliness": QosLiveliness,
}


def _qos_profiles(text: str | None) -> list[dict[str, Any]]:
    """A channel's ``offered_qos_profiles`` as version 9 lists them (enum names, not numbers); [] if absent."""
    if not text:
        return []
    try:
        loaded = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    if not isinstance(loaded, list):
        return []
    out: list[dict[str, Any]] = []
    for item in loaded:
        if not isinstance(item, dict):
            return []
        profile = dict(item)
        for key, enum in _QOS_ENUMS.items():
            value = profile.get(key)
            if isinstance(value, int) and not isinstance(value, bool):  # metadata version <= 8 stores numbers
                try:
                    profile[key] = enum(value).name.lower()
                except ValueError:
                    profile[key] = "unknown"
        out.append(profile)
    return out


def _type_hashes(path: Path) -> dict[str, str]:
    """RIHS01 hash of every ``ros2msg`` schema stored in the MCAP at `path` (types that fail to parse are left out)."""
    try:
        with open(path, "rb") as f:
            summary = SeekingReader(f, validate_crcs=False).get_summary()
    except Exception:  # the summary was already read by McapLog; anything odd here only costs the hashes
        return {}
    if summary is None:
        return {}
    out: dict[str, str] = {}
    for schema in summary.schemas.values():
        if schema.encoding != fmt.SCHEMA_ENCODING or schema.name in out:
            continue
        try:
            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(bytes(schema.data).decode("utf-8"), schema.name))
            out[schema.name] = str(store.hash_rihs01(schema.name))
        except Exception:  # rosbags raises assorted parser/typesys errors; the hash is optional in rosbag2
            continue
    return out


def rosbag2_metadata(mcap_path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping (version 9) of one complete MCAP, read through McapLog.

    Raises:
        LogReadError: the file cannot be read (missing, not MCAP, damaged).
        RecordError: the file has no summary (its recorder was killed): rosbag2 readers cannot open it.
    """
    path = Path(mcap_path)
    log = McapLog(path)
    if log.salvaged:
        raise RecordError(
            str(path),
            "the recording has no summary and footer (its recorder was killed), so rosbag2 readers cannot "
            "open it; no metadata.yaml written",
        )
    types = log.topics()
    counts = log.message_counts()
    channel_metadata = log.channel_metadata()
    hashes = _type_hashes(path)
    start_ns = end_ns = 0
    first = True
    for message in log.raw():  # log-time order: the first is the earliest, the last the latest
        if first:
            start_ns = message.log_time_ns
            first = False
        end_ns = message.log_time_ns
    duration_ns = end_ns - start_ns
    total = sum(counts.values())
    custom = {"mrl.library": log.library}
    custom.update({f"mrl.session.{key}": value for key, value in log.metadata().get("session", {}).items()})
    return {
        "version": VERSION,
        "storage_identifier": "mcap",
        "relative_file_paths": [path.name],
        "duration": {"nanoseconds": duration_ns},
        "starting_time": {"nanoseconds_since_epoch": start_ns},
        "message_count": total,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": topic,
                    "type": typename,
                    "serialization_format": fmt.MESSAGE_ENCODING,
                    "offered_qos_profiles": _qos_profiles(channel_metadata.get(topic, {}).get(fmt.QOS_KEY)),
                    "type_description_hash": hashes.get(typename, ""),
                },
                "message_count": counts.get(topic, 0),
            }
            for topic, typename in types.items()
        ],
        "compression_format": "",
        "compression_mode": "",
        "files": [
            {
                "path": path.name,
                "starting_time": {"nanoseconds_since_epoch": start_ns},
                "duration": {"nanoseconds": duration_ns},
                "message_count": total,
            }
        ],
        "custom_data": custom,
        "ros_distro": ROS_DISTRO,
    }


def _listed_files(metadata_path: Path) -> list[str] | None:
    """The storage files an existing metadata.yaml lists; None when it is not rosbag2 metadata."""
    try:
        data = yaml.safe_load(metadata_path.read_text(encoding="utf-8"))
        files = data["rosbag2_bagfile_information"]["relative_file_paths"]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return None
    return [Path(str(f)).name for f in files] if isinstance(files, list) else None


def write_rosbag2_metadata(mcap_path: str | os.PathLike[str]) -> Path:
    """Write ``metadata.yaml`` beside the session MCAP `mcap_path` (atomically) and return its path.

    The folder then opens with ``rosbags.rosbag2.Reader(folder)``, ``ros2 bag info`` and ``ros2 bag
    play``; only `mcap_path` is listed, whatever else the folder holds. A metadata.yaml already
    there is replaced when it lists this MCAP alone (or is not rosbag2 metadata) and refused when it
    lists other storage files (another bag lives in that folder).

    Raises:
        LogReadError: the MCAP cannot be read.
        RecordError: the MCAP is incomplete, another bag's metadata.yaml is in the way, or writing fails.
    """
    path = Path(mcap_path)
    target = path.parent / METADATA_FILE
    if not path.is_file():
        raise LogReadError(str(path), "no such file" if not path.exists() else "is not a file")
    if target.exists():
        listed = _listed_files(target)
        if listed is not None and listed != [path.name]:
            raise RecordError(
                str(target),
                f"already describes another bag (storage files {', '.join(listed) or 'none'}); "
                f"not replacing it with one for {path.name}",
            )
    text = yaml.safe_dump({"rosbag2_bagfile_information": rosbag2_metadata(path)}, sort_keys=False)
    tmp = target.with_name(f".{METADATA_FILE}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise RecordError(str(target), f"cannot write the rosbag2 metadata: {exc.strerror}") from exc
    return target
