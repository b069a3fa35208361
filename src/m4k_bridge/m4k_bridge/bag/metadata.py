"""rosbag2's ``metadata.yaml`` (format version 9, ROS 2 Jazzy) for a one-file MCAP bag (pure).

With it the recorder's directory is a bag: ``ros2 bag info DIR``, ``ros2 bag play DIR`` and
the rosbag2 directory readers open it without ``ros2 bag reindex``. Version 9 writes
``offered_qos_profiles`` as a YAML sequence with the policies by name (``keep_last``,
``reliable``, ``transient_local``, ...), durations as ``sec`` / ``nsec``, and each topic's
``type_description_hash`` (RIHS01).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import yaml

__all__ = ['TopicRecord', 'VERSION', 'metadata_yaml', 'qos_entries', 'qos_entries_from_yaml']

VERSION = 9
_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 3: 'manual_by_topic', 4: 'unknown',
               5: 'best_available'}


@dataclasses.dataclass
class TopicRecord:
    """What the bag knows of one recorded topic."""

    name: str
    type: str
    type_hash: str
    qos: list[dict[str, Any]]
    count: int = 0


def _duration(ns: int) -> dict[str, int]:
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def qos_entries(profiles: Sequence[Any]) -> list[dict[str, Any]]:
    """Return the offered QoS profiles (rclpy QoSProfile) as version-9 metadata entries."""
    return [{'history': _HISTORY.get(int(q.history), 'unknown'), 'depth': int(q.depth),
             'reliability': _RELIABILITY.get(int(q.reliability), 'unknown'),
             'durability': _DURABILITY.get(int(q.durability), 'unknown'),
             'deadline': _duration(int(q.deadline.nanoseconds)),
             'lifespan': _duration(int(q.lifespan.nanoseconds)),
             'liveliness': _LIVELINESS.get(int(q.liveliness), 'unknown'),
             'liveliness_lease_duration': _duration(int(q.liveliness_lease_duration.nanoseconds)),
             'avoid_ros_namespace_conventions': bool(q.avoid_ros_namespace_conventions)}
            for q in profiles]


def _named(table: dict[int, str], value: Any) -> Any:
    return table.get(value, 'unknown') if isinstance(value, int) else value


def qos_entries_from_yaml(text: str) -> list[dict[str, Any]]:
    """Return version-9 entries from an MCAP channel's ``offered_qos_profiles`` text.

    That text (what :func:`m4k_bridge.bag.record.qos_yaml` writes) gives the policies as
    numbers; the metadata names them. Unreadable text gives no entries (rosbag2 then uses
    its defaults).
    """
    try:
        doc = yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []
    if not isinstance(doc, list):
        return []
    out = []
    for q in doc:
        if not isinstance(q, dict):
            continue
        e = dict(q)
        for key, table in (('history', _HISTORY), ('reliability', _RELIABILITY),
                           ('durability', _DURABILITY), ('liveliness', _LIVELINESS)):
            if key in e:
                e[key] = _named(table, e[key])
        out.append(e)
    return out


def metadata_yaml(file_name: str, topics: Sequence[TopicRecord], start_ns: int,
                  end_ns: int, compression: str = '',
                  custom_data: dict[str, str] | None = None) -> str:
    """Return the metadata.yaml text of a bag of one MCAP file ``file_name`` (relative).

    ``start_ns`` / ``end_ns``: receive times (ns since the epoch) of the first and last
    message (both 0 for an empty bag). ``compression``: '' -- the MCAP chunks are compressed
    inside the file, not the file by rosbag2. ``custom_data``: rosbag2's free string map
    (``ros2 bag record --custom-data``), e.g. a flight recorder's trigger.
    """
    total = sum(t.count for t in topics)
    duration = max(0, end_ns - start_ns)
    info = {
        'version': VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start_ns},
        'message_count': total,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.type, 'serialization_format': 'cdr',
                                'offered_qos_profiles': t.qos,
                                'type_description_hash': t.type_hash},
             'message_count': t.count} for t in topics],
        'compression_format': compression,
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start_ns},
                   'duration': {'nanoseconds': duration}, 'message_count': total}],
        'custom_data': {str(k): str(v) for k, v in (custom_data or {}).items()},
        'ros_distro': 'jazzy',
    }
    return yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False)
