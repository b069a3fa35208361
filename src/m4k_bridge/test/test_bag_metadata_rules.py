"""metadata.yaml against rosbag2 Jazzy's reader rules, written from its source, not from ours.

rosbag2 (jazzy branch, rosbag2_storage yaml.hpp, qos.cpp, metadata_io.cpp) reads
``rosbag2_bagfile_information`` and, for format 9: takes a QoS entry's ``history`` as a string
(an int would make it read the entry as format 8), turns each policy name back with rmw's
``*_from_str`` (so only rmw's names are valid), reads durations as ``sec`` / ``nsec`` and the
key sets of every level by version (``files`` from 5, ``custom_data`` from 6,
``type_description_hash`` from 7, ``ros_distro`` from 8). This reader applies those rules to
what the recorder writes for real rclpy QoS profiles.
"""

from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    qos_profile_sensor_data,
    QoSProfile,
    ReliabilityPolicy,
)
import yaml

from m4k_bridge.bag import metadata

# rmw's qos_string_conversions: the names its *_from_str functions accept.
RMW_NAMES = {
    'history': {'system_default', 'keep_last', 'keep_all'},
    'reliability': {'system_default', 'reliable', 'best_effort', 'best_available'},
    'durability': {'system_default', 'transient_local', 'volatile', 'best_available'},
    'liveliness': {'system_default', 'automatic', 'manual_by_topic', 'best_available'},
}
TOP_KEYS = {'version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
            'topics_with_message_count', 'compression_format', 'compression_mode',
            'relative_file_paths', 'files', 'custom_data', 'ros_distro'}
QOS_KEYS = {'history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions'}


def _time(node: dict) -> int:
    assert set(node) == {'sec', 'nsec'}
    assert isinstance(node['sec'], int) and node['sec'] >= 0
    assert isinstance(node['nsec'], int) and 0 <= node['nsec'] < 1_000_000_000
    return node['sec'] * 1_000_000_000 + node['nsec']


def read_qos(node: dict) -> dict:
    """Read one offered QoS entry as rosbag2 Jazzy does for format 9."""
    assert set(node) == QOS_KEYS
    assert isinstance(node['history'], str), 'an int history is read as format 8'
    for policy, names in RMW_NAMES.items():
        assert node[policy] in names, '{}: {!r} is not an rmw name'.format(policy,
                                                                           node[policy])
    assert isinstance(node['depth'], int) and node['depth'] >= 0
    assert isinstance(node['avoid_ros_namespace_conventions'], bool)
    return {k: (_time(node[k]) if k in ('deadline', 'lifespan', 'liveliness_lease_duration')
                else node[k]) for k in node}


def read_bag(text: str) -> dict:
    """Read metadata.yaml as rosbag2 Jazzy's MetadataIo does (format 9)."""
    info = yaml.safe_load(text)['rosbag2_bagfile_information']
    assert set(info) == TOP_KEYS and info['version'] == 9
    assert set(info['duration']) == {'nanoseconds'}
    assert set(info['starting_time']) == {'nanoseconds_since_epoch'}
    for f in info['files']:
        assert set(f) == {'path', 'starting_time', 'duration', 'message_count'}
    topics = {}
    for t in info['topics_with_message_count']:
        assert set(t) == {'topic_metadata', 'message_count'}
        meta = t['topic_metadata']
        assert set(meta) == {'name', 'type', 'serialization_format', 'offered_qos_profiles',
                             'type_description_hash'}
        topics[meta['name']] = [read_qos(q) for q in meta['offered_qos_profiles']]
    assert isinstance(info['custom_data'], dict) and isinstance(info['ros_distro'], str)
    return topics


def test_real_rclpy_profiles_read_back_as_rosbag2_jazzy_reads_them() -> None:
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    deadline = QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST,
                          deadline=Duration(seconds=0, nanoseconds=250_000_000),
                          liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
                          liveliness_lease_duration=Duration(seconds=2))
    profiles = {'/tf_static': [latched], '/scan': [qos_profile_sensor_data],
                '/odom': [QoSProfile(depth=10)], '/cmd_vel': [deadline],
                '/all': [QoSProfile(history=HistoryPolicy.KEEP_ALL)]}
    topics = [metadata.TopicRecord(name, 'std_msgs/msg/Empty', 'RIHS01_' + '0' * 64,
                                   metadata.qos_entries(q), count=1)
              for name, q in profiles.items()]
    got = read_bag(metadata.metadata_yaml('b_0.mcap', topics, 10, 20))
    assert got['/tf_static'][0]['durability'] == 'transient_local'
    assert got['/tf_static'][0]['reliability'] == 'reliable'
    assert got['/scan'][0]['reliability'] == 'best_effort'
    assert got['/scan'][0]['depth'] == qos_profile_sensor_data.depth
    assert got['/cmd_vel'][0]['deadline'] == 250_000_000
    assert got['/cmd_vel'][0]['liveliness'] == 'manual_by_topic'
    assert got['/cmd_vel'][0]['liveliness_lease_duration'] == 2_000_000_000
    assert got['/all'][0]['history'] == 'keep_all'


def test_the_reader_refuses_a_format_8_style_entry() -> None:
    """The rules above can fail: an int policy (format 8) is refused."""
    entry = metadata.qos_entries([QoSProfile(depth=1)])[0]
    entry['history'] = 1
    try:
        read_qos(entry)
    except AssertionError as exc:
        assert 'format 8' in str(exc)
    else:
        raise AssertionError('an int history was accepted')
