"""record: an MCAP recording of the running stack, read back with independent decoders.

Also: a recorder killed with SIGKILL leaves nothing under the name it was given, and a bag
under that name with ``.partial`` appended that the ``mcap`` package and rosbags open as it is
(each with its own parser and CDR decoder) and that ``--recover`` names; an existing ``-o`` is
refused. A finished recording is indexed (chunk indexes in its summary) and names the commit.

The file is read with the ``mcap`` reader and decoded by mcap-ros2-support's decoder (its own
CDR parser driven by the schema text in the file), not by the recorder's code or rclpy: a wrong
or incomplete ``ros2msg`` schema, or bytes that are not the messages, fail the decode.
"""

import os
import signal
import subprocess
import sys

from mcap.reader import make_reader, NonSeekingReader
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
    assert out.is_dir() and not (tmp_path / 'run1.partial').exists()   # renamed when done
    head = subprocess.run(['git', 'rev-parse', 'HEAD'], capture_output=True, text=True,
                          cwd=os.path.dirname(__file__), check=True).stdout.strip()
    counts, decoded, hashes = {}, {}, {}
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        summary = reader.get_summary()
        # Indexed: the summary's chunk indexes cover every message (Lichtblick seeks by them).
        assert summary.chunk_indexes and summary.statistics.chunk_count == len(
            summary.chunk_indexes)
        commits = [m.metadata['m4k.commit'] for m in reader.iter_metadata() if m.name == 'm4k']
        assert len(commits) == 1 and commits[0].split('-')[0] == head
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
    assert meta['custom_data']['m4k.commit'] == commits[0]
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


def test_record_refuses_an_existing_output_directory(tmp_path):
    out = tmp_path / 'earlier'
    out.mkdir()
    (out / 'earlier_0.mcap').write_bytes(b'an earlier recording')
    r = subprocess.run([sys.executable, '-m', 'm4k_bridge.bag.record', '-o', str(out)],
                       env=stack_env(str(tmp_path / 'rt')), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2, r.stderr
    assert 'exists' in r.stderr and 'never overwrites' in r.stderr and str(out) in r.stderr
    assert (out / 'earlier_0.mcap').read_bytes() == b'an earlier recording'
    assert sorted(p.name for p in out.iterdir()) == ['earlier_0.mcap']


def test_record_refuses_a_name_whose_partial_exists(tmp_path):
    crashed = tmp_path / 'run.partial'           # what a crashed recording of 'run' leaves
    crashed.mkdir()
    r = subprocess.run([sys.executable, '-m', 'm4k_bridge.bag.record', '-o',
                        str(tmp_path / 'run')], env=stack_env(str(tmp_path / 'rt')),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert str(crashed) in r.stderr and '--recover' in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir() if p.name != 'rt') == ['run.partial']


def _mcap_counts(path):
    """Messages per topic in the MCAP, read linearly by the mcap package's streaming reader."""
    counts = {}
    with open(path, 'rb') as f:
        for _, channel, _ in NonSeekingReader(f).iter_messages(log_time_order=False):
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_record_killed_with_sigkill_leaves_a_bag_that_independent_readers_open(
        stack, procs, m4k_runtime_dir, tmp_path):  # noqa: F811
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores

    user, _, _ = stack
    out = tmp_path / 'crash'
    err = tmp_path / 'record.err'
    with open(err, 'w') as f:
        rec = procs.start(['python', '-m', 'm4k_bridge.bag.record', '-o', str(out)],
                          env=stack_env(m4k_runtime_dir), stdout=f, stderr=f)
    _wait_text(user, err, ('recording /odom', 'recording /scan'), 30)
    user.spin_for(5.0)
    rec.send_signal(signal.SIGKILL)
    assert rec.wait(20) == -signal.SIGKILL
    # Nothing under the name asked for: the cut-off recording says so in its own name.
    assert not out.exists()
    partial = tmp_path / 'crash.partial'
    path = partial / 'crash_0.mcap'
    meta = yaml.safe_load((partial / 'metadata.yaml').read_text())[
        'rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['relative_file_paths'] == ['crash_0.mcap']
    listed = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert meta['message_count'] == sum(listed.values())
    # 1. The mcap package's reader: the file ends in a footer as it is, without a summary (the
    # last sync writes it), so the reader reads it linearly.
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_summary() is None
        odoms = [m for _, ch, _, m in reader.iter_decoded_messages(topics=['/odom'])]
    in_file = _mcap_counts(path)
    # The odometry recorded before the last sync is there, decoded, in order (how many
    # messages 5 s at 20 Hz leave after the cut is a figure of the machine's load: printed).
    stamps = [o.header.stamp.sec * 10**9 + o.header.stamp.nanosec for o in odoms]
    assert stamps and stamps == sorted(stamps), stamps[:5]
    assert all(o.header.frame_id == 'odom' and len(o.pose.covariance) == 36 for o in odoms)
    print(f'record killed: {len(odoms)} odometry messages in the cut-off bag')
    # The metadata never lists more than the file holds (it is at most one sync behind).
    assert set(listed) == set(in_file)
    assert all(listed[t] <= in_file[t] for t in listed), (listed, in_file)
    # 2. rosbags opens the directory (metadata.yaml + MCAP) and its own CDR decoder reads it.
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(partial) as bag:
        conns = [c for c in bag.connections if c.topic == '/odom']
        assert conns and conns[0].msgtype == 'nav_msgs/msg/Odometry'
        decoded = [store.deserialize_cdr(raw, conns[0].msgtype)
                   for _, _, raw in bag.messages(connections=conns)]
    assert len(decoded) == len(odoms)
    assert decoded[-1].child_frame_id == 'base_footprint'
    # 3. --recover: a bag as the crash left it needs nothing, or only the metadata catching up;
    # either way it gets the name asked for.
    r = subprocess.run([sys.executable, '-m', 'm4k_bridge.bag.record', '--recover', str(out)],
                       env=stack_env(m4k_runtime_dir), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert not partial.exists() and (out / 'crash_0.mcap').is_file()
    with open(out / 'crash_0.mcap', 'rb') as f:          # and indexed now
        assert make_reader(f).get_summary().chunk_indexes
    after = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert {t['topic_metadata']['name']: t['message_count']
            for t in after['topics_with_message_count']} == in_file
