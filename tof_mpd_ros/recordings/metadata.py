"""rosbag2 ``metadata.yaml`` (version 9, as ROS 2 Jazzy writes it): build, write, parse."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from ..atomic_file import write_atomically
from ..errors import RecordingError
from . import msgdefs

METADATA_FILE = "metadata.yaml"
# rosbag2 Jazzy writes version 9 (QoS profiles as a YAML list with string enums).
ROSBAG2_VERSION = 9
ROS_DISTRO = "jazzy"
_INFINITE = {"sec": 9223372036, "nsec": 854775807}
# What the recorder offered: reliable, volatile (the profile of the collector's publishers).
RECORDING_QOS = [{
    "history": "unknown", "depth": 0, "reliability": "reliable", "durability": "volatile",
    "deadline": dict(_INFINITE), "lifespan": dict(_INFINITE), "liveliness": "automatic",
    "liveliness_lease_duration": dict(_INFINITE), "avoid_ros_namespace_conventions": False,
}]


@dataclass(frozen=True)
class TopicStats:
    """One topic of a recording.

    Attributes:
        name: topic name.
        msgtype: ROS type, ``pkg/msg/Type``.
        count: number of messages.
    """

    name: str
    msgtype: str
    count: int


def build(mcap_name: str, topics: list[TopicStats], start_ns: int, end_ns: int,
          custom_data: Mapping[str, str]) -> dict[str, Any]:
    """The ``metadata.yaml`` document of a single-file MCAP recording.

    Args:
        mcap_name: file name of the ``.mcap`` next to metadata.yaml.
        topics: topics with their message counts.
        start_ns, end_ns: first and last message log time, integer ns (0, 0 when empty).
        custom_data: string key/value pairs.
    """
    count = sum(t.count for t in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    return {"rosbag2_bagfile_information": {
        "version": ROSBAG2_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msgtype,
                                "serialization_format": "cdr",
                                "offered_qos_profiles": copy.deepcopy(RECORDING_QOS),
                                "type_description_hash": msgdefs.TYPE_HASHES.get(t.msgtype, "")},
             "message_count": t.count}
            for t in topics],
        # Compression is inside the MCAP (chunk compression), so rosbag2 records none here.
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [mcap_name],
        "files": [{"path": mcap_name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": count}],
        "custom_data": {str(k): str(v) for k, v in custom_data.items()},
        "ros_distro": ROS_DISTRO,
    }}


def write(directory: Path, document: dict[str, Any]) -> None:
    """Write ``metadata.yaml`` atomically (a crash leaves the old or the new file, never half)."""
    path = directory / METADATA_FILE
    text = yaml.safe_dump(document, sort_keys=False).encode("utf-8")
    try:
        write_atomically(path, lambda stream: stream.write(text))
    except OSError as err:
        raise RecordingError(f"{path}: cannot write metadata: {err}") from err


@dataclass(frozen=True)
class BagMetadata:
    """What the reader uses from a ``metadata.yaml``.

    Attributes:
        path: the metadata.yaml.
        files: relative paths of the storage files.
        topics: topics with their recorded counts (may be stale after a crash).
        custom_data: the ``custom_data`` map ({} when absent).
        version: rosbag2 metadata version.
    """

    path: Path
    files: tuple[str, ...]
    topics: tuple[TopicStats, ...]
    custom_data: dict[str, str]
    version: int


def read(path: Path) -> BagMetadata:
    """Parse a rosbag2 ``metadata.yaml``.

    Raises:
        RecordingError: unreadable YAML, not rosbag2 metadata, or not MCAP storage.
    """
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise RecordingError(f"{path}: cannot read rosbag2 metadata: {err}") from err
    try:
        info = doc["rosbag2_bagfile_information"]
        storage = info.get("storage_identifier", "")
        if storage != "mcap":
            raise RecordingError(f"{path}: storage {storage!r} is not supported (only mcap)")
        topics = tuple(
            TopicStats(t["topic_metadata"]["name"], t["topic_metadata"]["type"],
                       int(t.get("message_count", 0)))
            for t in info.get("topics_with_message_count") or [])
        files = tuple(str(f) for f in info.get("relative_file_paths") or [])
        custom = {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}
        return BagMetadata(path, files, topics, custom, int(info.get("version", 0)))
    except (KeyError, TypeError, AttributeError, ValueError) as err:
        raise RecordingError(f"{path}: not rosbag2 metadata ({type(err).__name__}: {err})"
                             ) from err
