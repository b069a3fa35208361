"""``doctor`` against live graphs of real rclpy nodes, each broken in one way, and a healthy one.

The graph is a stand-in of the base (node ``m4k_bridge`` with the bridge's topics, types, QoS,
rates and transforms) plus what a Nav2 user adds; the test spins it in this process (the run's
isolated ROS_DOMAIN_ID, localhost discovery) and runs the real ``doctor`` script beside it.
The ground truth is how the graph was built; doctor must name that problem (its exit status 1
and a line saying what and how to fix it), and find nothing in the healthy graph (exit 0).
"""

import subprocess
import sys
import threading

from geometry_msgs.msg import TransformStamped, Twist
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, LaserScan, Range
from tf2_msgs.msg import TFMessage
from wsenv import config_with, stack_env

from m4k_bridge import doctor

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope='module')
def slow_config(tmp_path_factory):
    """Return the configuration doctor judges rates against: config/ with the 100 Hz IMU and
    33 Hz sonar slowed to 20 Hz (a stand-in bridge in this shared, loaded test process keeps
    such rates reliably; the judgement is the same ratio)."""
    d = config_with(tmp_path_factory.mktemp('config'), {'m4k.yaml': {'tasks': {
        'imu': {'period_ms': 50}, 'sonar': {'period_ms': 50}}}})
    RATES.update(doctor.expected_rates(d))
    return d


RATES = {}


def _tf(parent, child, stamp):
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.header.stamp = stamp
    t.transform.rotation.w = 1.0
    return t


class Graph:
    """Nodes in one context, spun by one executor thread until :meth:`close`."""

    def __init__(self):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.nodes = []
        self.keep = []
        self.children = []

    def spawn(self, code):
        # a node in a process of its own (FastDDS refuses a second type for one topic name
        # inside one process, as a second robot or laptop would not)
        self.children.append(subprocess.Popen(
            [sys.executable, '-c', code], env=stack_env('/nonexistent'),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

    def node(self, name, namespace='/', **kw):
        n = Node(name, namespace=namespace, context=self.ctx, **kw)
        self.nodes.append(n)
        self.ex.add_node(n)
        return n

    def every(self, node, hz, fn):
        self.keep.append(node.create_timer(1.0 / hz, fn))

    def bridge(self, odom_hz=None, static=True):
        """Add the base: the bridge's topics at their configured rates, its transforms."""
        b = self.node('m4k_bridge')
        odom = b.create_publisher(Odometry, 'odom', RELIABLE)
        imu = b.create_publisher(Imu, 'imu', qos_profile_sensor_data)
        scan = b.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        sonar = b.create_publisher(Range, 'sonar', qos_profile_sensor_data)
        tf = b.create_publisher(TFMessage, '/tf', QoSProfile(depth=100))
        self.keep.append(b.create_subscription(Twist, 'cmd_vel', lambda m: None,
                                               qos_profile_sensor_data))
        self.every(b, odom_hz or RATES['odom'], lambda: (
            odom.publish(Odometry()),
            tf.publish(TFMessage(transforms=[_tf('odom', 'base_footprint',
                                                 b.get_clock().now().to_msg())]))))
        self.every(b, RATES['imu'], lambda: imu.publish(Imu()))
        self.every(b, RATES['scan'], lambda: scan.publish(LaserScan()))
        self.every(b, RATES['sonar'], lambda: sonar.publish(Range()))
        if static:
            st = b.create_publisher(TFMessage, '/tf_static', LATCHED)
            now = b.get_clock().now().to_msg()
            st.publish(TFMessage(transforms=[_tf('base_footprint', 'base_link', now),
                                             _tf('base_link', 'laser', now)]))
            self.keep.append(st)
        return b

    def run_doctor(self):
        t = threading.Thread(target=self.ex.spin, name='graph')
        t.start()
        try:
            env = stack_env('/nonexistent')
            proc = subprocess.run(
                [sys.executable, '-m', 'm4k_bridge.doctor', '--duration', '2.5',
                 '--discovery', '20',
                 '--config-dir', self.config],
                env=env, capture_output=True, text=True, timeout=120)
        finally:
            for child in self.children:
                child.terminate()
                child.wait(timeout=30)
            self.ex.shutdown()
            t.join()
            for n in self.nodes:
                n.destroy_node()
            rclpy.try_shutdown(context=self.ctx)
        return proc.returncode, proc.stdout.splitlines(), proc.stderr


TELEOP_STAMPED = """
import rclpy
from geometry_msgs.msg import TwistStamped
rclpy.init()
n = rclpy.create_node('teleop')
pub = n.create_publisher(TwistStamped, 'cmd_vel', 10)
n.create_timer(0.1, lambda: pub.publish(TwistStamped()))
try:
    rclpy.spin(n)
except BaseException:
    pass
"""


@pytest.fixture
def graph(slow_config):
    g = Graph()
    g.config = slow_config
    return g


def _one(lines, *words):
    hits = [line for line in lines if all(w in line for w in words)]
    assert len(hits) == 1, lines
    return hits[0]


def test_healthy_graph_exits_zero(graph):
    graph.bridge()
    mux = graph.node('twist_mux', parameter_overrides=[Parameter('use_stamped', value=False)],
                     automatically_declare_parameters_from_overrides=True)
    pub = mux.create_publisher(Twist, 'cmd_vel', RELIABLE)
    graph.every(mux, 10, lambda: pub.publish(Twist()))
    costmap = graph.node('local_costmap', namespace='/local_costmap')
    graph.keep.append(costmap.create_subscription(LaserScan, '/scan', lambda m: None,
                                                  qos_profile_sensor_data))
    rc, lines, err = graph.run_doctor()
    assert (rc, lines) == (0, []), err
    assert 'no problem found' in err


def test_rogue_costmap_subscriber_is_named_with_the_absolute_name(graph):
    graph.bridge()
    costmap = graph.node('local_costmap', namespace='/local_costmap')
    graph.keep.append(costmap.create_subscription(LaserScan, 'scan', lambda m: None,
                                                  qos_profile_sensor_data))
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, '/local_costmap/scan')
    assert line.startswith('/local_costmap/local_costmap subscribes /local_costmap/scan')
    assert 'm4k publishes /scan' in line and 'absolute name /scan' in line


def test_twist_stamped_publisher_on_a_twist_robot_is_named(graph):
    graph.bridge()
    graph.spawn(TELEOP_STAMPED)
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, 'TwistStamped')
    assert line.startswith('/teleop publishes /cmd_vel as geometry_msgs/TwistStamped')
    assert 'enable_stamped_cmd_vel to true' in line


def test_reliable_subscriber_of_a_best_effort_sensor_is_named(graph):
    graph.bridge()
    rviz = graph.node('rviz')
    graph.keep.append(rviz.create_subscription(LaserScan, '/scan', lambda m: None, RELIABLE))
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, 'QoS incompatible')
    assert line.startswith('/m4k_bridge -> /rviz on /scan') and 'best effort' in line


def test_split_tf_tree_and_stale_stamps_are_named(graph):
    graph.bridge()
    other = graph.node('other_robot')
    tf = other.create_publisher(TFMessage, '/tf', QoSProfile(depth=100))
    old = rclpy.time.Time(seconds=1.0).to_msg()       # far behind the clock
    graph.every(other, 10, lambda: tf.publish(TFMessage(
        transforms=[_tf('r1/odom', 'r1/base_footprint', old)])))
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    assert 'roots odom, r1/odom' in _one(lines, 'split into 2 trees')
    assert _one(lines, 'behind this clock').startswith('transform to r1/base_footprint')


def test_two_publishers_of_one_static_frame_are_named(graph):
    graph.bridge()
    rsp = graph.node('robot_state_publisher')
    st = rsp.create_publisher(TFMessage, '/tf_static', LATCHED)
    st.publish(TFMessage(transforms=[_tf('base_link', 'laser',
                                         rsp.get_clock().now().to_msg())]))
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, 'frame laser')
    assert '/m4k_bridge' in line and '/robot_state_publisher' in line


def test_a_frame_with_two_parents_is_named(graph):
    graph.bridge()
    ekf = graph.node('ekf_filter_node')
    tf = ekf.create_publisher(TFMessage, '/tf', QoSProfile(depth=100))
    graph.every(ekf, 20, lambda: tf.publish(TFMessage(transforms=[
        _tf('odom_ekf', 'base_footprint', ekf.get_clock().now().to_msg())])))
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    assert 'odom, odom_ekf' in _one(lines, 'frame base_footprint has 2 parents')


def test_odometry_far_below_its_configured_rate_is_named(graph):
    graph.bridge(odom_hz=RATES['odom'] / 10.0)
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, '/odom arrives at')
    assert 'configured {:.1f} Hz'.format(RATES['odom']) in line


def test_use_sim_time_mismatch_is_named(graph):
    graph.bridge()
    graph.node('slam_toolbox', parameter_overrides=[Parameter('use_sim_time', value=True)])
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    line = _one(lines, 'use_sim_time', 'one clock')
    assert line.startswith('use_sim_time is true on /slam_toolbox but false on /m4k_bridge')
    # and nothing publishes /clock for it
    assert _one(lines, 'nothing publishes /clock').startswith(
        'use_sim_time is true on /slam_toolbox')


def test_twist_mux_without_use_stamped_is_named(graph):
    graph.bridge()
    graph.node('twist_mux')
    rc, lines, _ = graph.run_doctor()
    assert rc == 1
    assert _one(lines, 'use_stamped').startswith('/twist_mux has no use_stamped parameter')
