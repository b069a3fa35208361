"""record: an MCAP recording of the running stack, read back with independent decoders.

The file is read with the ``mcap`` reader and decoded by mcap-ros2-support's decoder (its own
CDR parser driven by the schema text in the file), not by the recorder's code or rclpy: a wrong
or incomplete ``ros2msg`` schema, or bytes that are not the messages, fail the decode.
"""

import signal

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest
from test_stack_e2e import stack  # noqa: F401 -- the stack fixture
from wsenv import stack_env
import yaml

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process


def _wait_text(user, path, needles, timeout):
    def found():
        try:
            text = path.read_text()
        except OSError:
            return False
        return all(n in text for n in needles)
    user.spin_until(found, timeout, 'the recorder to subscribe {}'.format(needles))


def test_record_writes_mcap_that_an_independent_decoder_reads(stack, procs,  # noqa: F811
                                                             m4k_runtime_dir, tmp_path):
    user, _, _ = stack
    out = tmp_path / 'run1'
    err = tmp_path / 'record.err'
    with open(err, 'w') as f:
        rec = procs.start(['python', '-m', 'm4k_bridge.bag.record', '-o', str(out)],
                          env=stack_env(m4k_runtime_dir), stdout=f, stderr=f)
    _wait_text(user, err, ('recording /odom', 'recording /scan', 'recording /imu'), 30)
    user.spin_for(2.5)
    rec.send_signal(signal.SIGTERM)
    assert rec.wait(20) == 0, err.read_text()[-2000:]
    path = out / 'run1_0.mcap'
    counts, decoded, hashes = {}, {}, {}
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        summary = reader.get_summary()
        for ch in summary.channels.values():
            hashes[ch.topic] = ch.metadata.get('topic_type_hash', '')
            schema = summary.schemas[ch.schema_id]
            assert schema.encoding == 'ros2msg' and ch.message_encoding == 'cdr'
        for schema, channel, _, ros_msg in reader.iter_decoded_messages(
                topics=['/odom', '/scan', '/imu']):
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            decoded[channel.topic] = (schema, ros_msg)
    assert all(counts.get(t, 0) > 0 for t in ('/odom', '/scan', '/imu')), counts
    schema, odom = decoded['/odom']
    assert schema.name == 'nav_msgs/msg/Odometry'
    assert b'MSG: geometry_msgs/PoseWithCovariance' in schema.data
    assert odom.header.frame_id == 'odom' and odom.child_frame_id == 'base_footprint'
    assert len(odom.pose.covariance) == 36
    _, scan = decoded['/scan']
    assert scan.header.frame_id == 'laser' and len(scan.ranges) > 600
    assert scan.angle_max > scan.angle_min
    _, imu = decoded['/imu']
    q = imu.orientation
    assert abs(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w - 1.0) < 1e-3
    # the type hashes are the ones the publishers announce on the ROS graph
    for topic in ('/odom', '/scan', '/imu'):
        infos = user.node.get_publishers_info_by_topic(topic)
        assert hashes[topic] == str(infos[0].topic_type_hash)
        assert hashes[topic].startswith('RIHS01_')
    # The directory is a rosbag2 bag: metadata.yaml (format 9) agrees with the MCAP file.
    meta = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['run1_0.mcap'] == [f['path'] for f in meta['files']]
    by_id = {ch.id: ch.topic for ch in summary.channels.values()}
    in_file = {by_id[i]: n for i, n in summary.statistics.channel_message_counts.items()}
    listed = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert {k: v['message_count'] for k, v in listed.items()} == in_file
    stats = summary.statistics
    assert meta['message_count'] == stats.message_count
    assert meta['starting_time']['nanoseconds_since_epoch'] == stats.message_start_time
    assert meta['duration']['nanoseconds'] == (stats.message_end_time
                                               - stats.message_start_time)
    odom_meta = listed['/odom']['topic_metadata']
    assert odom_meta['type'] == 'nav_msgs/msg/Odometry'
    assert odom_meta['type_description_hash'] == hashes['/odom']
    assert odom_meta['offered_qos_profiles'][0]['reliability'] == 'reliable'
    assert listed['/scan']['topic_metadata']['offered_qos_profiles'][0]['reliability'] == \
        'best_effort'
