"""What ``record`` stored is what was published, as rosbags reads it: clean stop and --recover.

rosbags (PyPI, pinned in requirements.txt) reads the rosbag2 directory with its own
metadata.yaml parser, MCAP parser and CDR decoder, written from rosbag2's format, not from the
recorder's code. The test publishes known messages itself (no robot stack): a
``std_msgs/String`` and a ``nav_msgs/Odometry`` topic, each message different. Checked:
topics, types, counts, log times (within the publishing window, in order) and every decoded
field the test set, for a recording stopped with SIGTERM and for one killed with SIGKILL and
finished by ``record --recover``.
"""

import signal
import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
from wsenv import stack_env
import yaml

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process

N = 30                  # messages per topic
CHATTER, ODOM = '/m4k_bag_test/chatter', '/m4k_bag_test/odom'
STORE = get_typestore(Stores.ROS2_JAZZY)


@pytest.fixture
def node():
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(context=ctx)
    n = rclpy.create_node('m4k_bag_publisher', context=ctx)
    try:
        yield n
    finally:
        n.destroy_node()
        rclpy.shutdown(context=ctx)


def _spin_for(node, seconds):
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.02)
    ex.remove_node(node)


def _record(procs, m4k_runtime_dir, out, err):
    with open(err, 'w') as f:
        return procs.start([sys.executable, '-m', 'm4k_bridge.bag.record', CHATTER, ODOM,
                            '-o', str(out)], env=stack_env(m4k_runtime_dir), stdout=f,
                           stderr=f)


def _publish(node, rec, err):
    """Publish N messages on each topic once the recorder subscribes; return the time window."""
    from nav_msgs.msg import Odometry
    from std_msgs.msg import String
    qos = QoSProfile(depth=N, reliability=ReliabilityPolicy.RELIABLE)
    pubs = (node.create_publisher(String, CHATTER, qos),
            node.create_publisher(Odometry, ODOM, qos))
    deadline = time.monotonic() + 40
    while not all(p.get_subscription_count() for p in pubs):
        assert time.monotonic() < deadline and rec.poll() is None, err.read_text()[-2000:]
        _spin_for(node, 0.1)
    t0 = time.time_ns()
    for i in range(N):
        pubs[0].publish(String(data='m4k bag message {}'.format(i)))
        o = Odometry()
        o.header.stamp.sec, o.header.stamp.nanosec = 1000 + i, 250_000_000
        o.header.frame_id, o.child_frame_id = 'odom', 'base_footprint'
        o.pose.pose.position.x = 0.5 * i
        o.twist.twist.angular.z = -0.01 * i
        o.pose.covariance[0] = float(i)
        pubs[1].publish(o)
        _spin_for(node, 0.05)
    t1 = time.time_ns()
    _spin_for(node, 2.5)          # every message received, then at least two syncs (1 s each)
    return t0, t1


def _check(directory, t0, t1):
    """Read the bag with rosbags; everything published is there, as published."""
    with Reader(directory) as bag:
        types = {c.topic: c.msgtype for c in bag.connections}
        assert types == {CHATTER: 'std_msgs/msg/String', ODOM: 'nav_msgs/msg/Odometry'}
        assert {c.topic: c.msgcount for c in bag.connections} == {CHATTER: N, ODOM: N}
        got = {CHATTER: [], ODOM: []}
        for c, t, raw in bag.messages():
            got[c.topic].append((t, STORE.deserialize_cdr(raw, c.msgtype)))
        assert bag.message_count == 2 * N
    for topic, msgs in got.items():
        times = [t for t, _ in msgs]
        assert times == sorted(times) and t0 <= times[0] and times[-1] <= t1 + 2 * 10**9, topic
    assert [m.data for _, m in got[CHATTER]] == ['m4k bag message {}'.format(i) for i in range(N)]
    for i, (_, o) in enumerate(got[ODOM]):
        assert (o.header.stamp.sec, o.header.stamp.nanosec) == (1000 + i, 250_000_000)
        assert (o.header.frame_id, o.child_frame_id) == ('odom', 'base_footprint')
        assert o.pose.pose.position.x == 0.5 * i and o.twist.twist.angular.z == -0.01 * i
        assert o.pose.covariance[0] == float(i) and len(o.pose.covariance) == 36
    meta = yaml.safe_load((directory / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == 2 * N


def test_a_clean_recording_holds_what_was_published(node, procs, m4k_runtime_dir, tmp_path):
    out, err = tmp_path / 'clean', tmp_path / 'record.err'
    rec = _record(procs, m4k_runtime_dir, out, err)
    t0, t1 = _publish(node, rec, err)
    rec.send_signal(signal.SIGTERM)
    assert rec.wait(20) == 0, err.read_text()[-2000:]
    assert not (tmp_path / 'clean.partial').exists()
    _check(out, t0, t1)


def test_a_killed_recording_recovered_holds_what_was_published(node, procs, m4k_runtime_dir,
                                                              tmp_path):
    out, err = tmp_path / 'killed', tmp_path / 'record.err'
    rec = _record(procs, m4k_runtime_dir, out, err)
    t0, t1 = _publish(node, rec, err)
    rec.send_signal(signal.SIGKILL)
    assert rec.wait(20) == -signal.SIGKILL
    partial = tmp_path / 'killed.partial'
    assert partial.is_dir() and not out.exists()
    r = subprocess.run([sys.executable, '-m', 'm4k_bridge.bag.record', '--recover', str(out)],
                       env=stack_env(m4k_runtime_dir), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert out.is_dir() and not partial.exists()
    _check(out, t0, t1)
