"""``doctor`` against a live 3-robot fleet of real rclpy nodes, clean and with one planted mistake.

Each robot is laid out as the documented commands run it (docs/nav2.md, "Several robots"):
its nodes in ``/rK``, its tree on ``/rK/tf`` and ``/rK/tf_static``, frames unprefixed. Per
robot: a stand-in of the base (``m4k_bridge`` with the bridge's topics, QoS, rates, static
transforms and parameters; ``publish_tf: false`` since the EKF owns odom -> base_footprint),
an EKF and slam_toolbox broadcasting their edges with the parameters that say so, and the
lifecycle nodes of Nav2's cmd_vel chain (collision monitor into the bridge, docking server into
``cmd_vel_nav``), activated. The graph spins in this process (the run's isolated
ROS_DOMAIN_ID, localhost discovery) and the real ``doctor`` script runs beside it.
Ground truth is how the graph was built: the clean fleet exits 0, each mistake exits 1 with
a line naming it.
"""

import subprocess
import sys
import threading

from geometry_msgs.msg import TransformStamped, Twist
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, LaserScan, Range
from tf2_msgs.msg import TFMessage
from wsenv import config_with, stack_env

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
ROBOTS = ('r1', 'r2', 'r3')
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


def _tf(parent, child, stamp):
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.header.stamp = stamp
    t.transform.rotation.w = 1.0
    return t


def _params(**kw):
    return [Parameter(k, value=v) for k, v in kw.items()]


class Fleet:
    """Three robots' nodes in one context, spun by one executor thread; each robot's parts
    can be swapped for a planted mistake through ``plant``."""

    def __init__(self, config_dir, plant=None):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.nodes, self.keep = [], []
        self.config = config_dir
        self.plant = plant or {}
        from m4k_bridge import doctor
        self.rates = doctor.expected_rates(config_dir)
        for r in ROBOTS:
            self.robot('/' + r)

    def node(self, name, ns, params=(), lifecycle=False):
        cls = LifecycleNode if lifecycle else Node
        n = cls(name, namespace=ns, context=self.ctx, parameter_overrides=list(params),
                automatically_declare_parameters_from_overrides=True)
        self.nodes.append(n)
        self.ex.add_node(n)
        return n

    def every(self, node, hz, fn):
        self.keep.append(node.create_timer(1.0 / hz, fn))

    def listens_tf(self, node, tf='tf'):
        # a tf2_ros TransformListener: /tf (reliable) and /tf_static (transient local),
        # remapped into the namespace
        self.keep.append(node.create_subscription(TFMessage, tf, lambda m: None, TF_QOS))
        self.keep.append(node.create_subscription(TFMessage, tf + '_static', lambda m: None,
                                                  LATCHED))

    def robot(self, ns):
        p = self.plant.get(ns, {})
        bridge_tf = p.get('bridge_publish_tf', False)
        b = self.node('m4k_bridge', ns, _params(
            publish_tf=bridge_tf, odom_frame='odom', footprint_frame='base_footprint',
            base_frame='base_link', sonar_no_echo='positive_infinity',
            sonar_field_of_view=0.2618, tf_namespaced=True))
        odom = b.create_publisher(Odometry, 'odom', RELIABLE)
        pubs = [(b.create_publisher(Imu, 'imu', qos_profile_sensor_data), Imu, 'imu'),
                (b.create_publisher(LaserScan, 'scan', qos_profile_sensor_data), LaserScan,
                 'scan'),
                (b.create_publisher(Range, 'sonar', qos_profile_sensor_data), Range, 'sonar')]
        tf = b.create_publisher(TFMessage, 'tf', TF_QOS)
        self.keep.append(b.create_subscription(Twist, 'cmd_vel', lambda m: None,
                                               qos_profile_sensor_data))
        now = b.get_clock().now
        self.every(b, self.rates['odom'], lambda: (
            odom.publish(Odometry()),
            bridge_tf and tf.publish(TFMessage(transforms=[
                _tf('odom', 'base_footprint', now().to_msg())]))))
        for pub, cls, key in pubs:
            self.every(b, self.rates[key], lambda pub=pub, cls=cls: pub.publish(cls()))
        st = b.create_publisher(TFMessage, 'tf_static', LATCHED)
        st.publish(TFMessage(transforms=[_tf('base_footprint', 'base_link', now().to_msg()),
                                         _tf('base_link', 'laser', now().to_msg()),
                                         _tf('base_link', 'sonar_link', now().to_msg())]))
        self.keep.append(st)
        # robot_localization's EKF: publish_tf broadcasts world_frame -> base_link_frame
        ekf = self.node('ekf_filter_node', ns, _params(
            publish_tf=True, world_frame='odom', odom_frame='odom',
            base_link_frame='base_footprint', map_frame='map'))
        ekf_tf = ekf.create_publisher(TFMessage, p.get('ekf_tf', 'tf'), TF_QOS)
        self.listens_tf(ekf)
        self.every(ekf, 20, lambda: ekf_tf.publish(TFMessage(transforms=[
            _tf('odom', 'base_footprint', ekf.get_clock().now().to_msg())])))
        # slam_toolbox: map -> odom
        slam = self.node('slam_toolbox', ns, _params(
            map_frame='map', odom_frame='odom', base_frame='base_footprint'))
        slam_tf = slam.create_publisher(TFMessage, 'tf', TF_QOS)
        self.listens_tf(slam)
        self.every(slam, 10, lambda: slam_tf.publish(TFMessage(transforms=[
            _tf('map', 'odom', slam.get_clock().now().to_msg())])))
        # Nav2's collision monitor (the final output into the bridge) and docking server
        sources = p.get('monitor_sources', {'scan': {'type': 'scan', 'topic': ns + '/scan'}})
        flat = {'{}.{}'.format(s, k): v for s, d in sources.items() for k, v in d.items()}
        cm = self.node('collision_monitor', ns, _params(
            base_frame_id=p.get('monitor_base', 'base_footprint'), odom_frame_id='odom',
            polygons=['FootprintApproach'], observation_sources=list(sources),
            **{'FootprintApproach.min_points': 6}, **flat), lifecycle=True)
        self.listens_tf(cm)
        out = cm.create_publisher(Twist, 'cmd_vel', RELIABLE)
        self.every(cm, 10, lambda: out.publish(Twist()))
        dock = self.node('docking_server', ns, _params(base_frame='base_link',
                                                       fixed_frame='odom'), lifecycle=True)
        self.listens_tf(dock)
        dock_out = dock.create_publisher(Twist, p.get('dock_cmd_vel', 'cmd_vel_nav'), RELIABLE)
        self.every(dock, 10, lambda: dock_out.publish(Twist()))
        smoother = self.node('velocity_smoother', ns)
        self.keep.append(smoother.create_subscription(Twist, 'cmd_vel_nav', lambda m: None,
                                                      RELIABLE))
        if p.get('sim_time'):
            self.node('sim_clock_user', ns, _params(use_sim_time=True))
        for n, skip in ((cm, False), (dock, p.get('dock_inactive', False))):
            if not skip:
                n.trigger_configure()
                n.trigger_activate()

    def run_doctor(self):
        t = threading.Thread(target=self.ex.spin, name='fleet')
        t.start()
        try:
            proc = subprocess.run(
                [sys.executable, '-m', 'm4k_bridge.doctor', '--duration', '2.5',
                 '--discovery', '20',
                 '--config-dir', self.config], env=stack_env('/nonexistent'),
                capture_output=True, text=True, timeout=180)
        finally:
            self.ex.shutdown()
            t.join()
            for n in self.nodes:
                if isinstance(n, LifecycleNode):
                    # the state machine holds the node handle: the node (and its graph
                    # entry) lives on until the machine goes, misleading the next test
                    n._state_machine.destroy_when_not_in_use()
                n.destroy_node()
            rclpy.try_shutdown(context=self.ctx)
        return proc.returncode, proc.stdout.splitlines(), proc.stderr


@pytest.fixture(scope='module')
def config_dir(tmp_path_factory):
    """config/ with the IMU, sonar and odometry at 10 Hz (three stand-in bridges in one
    loaded test process keep such rates; the judgement is the same ratio)."""
    return config_with(tmp_path_factory.mktemp('config'), {
        'm4k.yaml': {'tasks': {'imu': {'period_ms': 100}, 'sonar': {'period_ms': 100}}},
        'control.yaml': {'control': {'odom_every_n': 10}}})


def _one(lines, *words):
    hits = [line for line in lines if all(w in line for w in words)]
    assert len(hits) == 1, lines
    return hits[0]


def test_a_clean_three_robot_fleet_exits_zero(config_dir):
    rc, lines, err = Fleet(config_dir).run_doctor()
    assert (rc, lines) == (0, []), err


def test_the_bridge_and_the_ekf_both_broadcasting_odom_to_base_footprint_is_named(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r2': {'bridge_publish_tf': True}}).run_doctor()
    assert rc == 1
    line = _one(lines, 'odom -> base_footprint on /r2/tf is broadcast by 2 nodes')
    assert '/r2/ekf_filter_node' in line and '/r2/m4k_bridge' in line
    assert 'publish_tf: false' in line


def test_an_unremapped_docking_server_is_a_second_writer_on_cmd_vel(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r2': {'dock_cmd_vel': 'cmd_vel'}}).run_doctor()
    assert rc == 1
    line = _one(lines, '/r2/cmd_vel has 2 writers')
    assert '/r2/collision_monitor' in line and '/r2/docking_server' in line
    assert 'cmd_vel:=cmd_vel_nav' in line


def test_the_sonar_in_the_collision_monitor_with_inf_no_echo_is_named(config_dir):
    sources = {'scan': {'type': 'scan', 'topic': '/r3/scan'},
               'sonar': {'type': 'range', 'topic': 'sonar', 'obstacles_angle': 0.1}}
    rc, lines, _ = Fleet(config_dir, {'/r3': {'monitor_sources': sources}}).run_doctor()
    assert rc == 1
    assert _one(lines, 'as +inf').startswith('/r3/collision_monitor takes the sonar')
    assert 'makes 4 points' in _one(lines, 'min_points 6')


def test_an_ekf_publishing_outside_its_robot_s_tree_is_named(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r1': {'ekf_tf': '/tf'}}).run_doctor()
    assert rc == 1
    line = _one(lines, '/r1/ekf_filter_node publishes /tf')
    assert "robot's tree is /r1/tf" in line and '-r /tf:=tf' in line


def test_an_inactive_lifecycle_node_is_named(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r3': {'dock_inactive': True}}).run_doctor()
    assert rc == 1
    assert _one(lines, 'not active').startswith('/r3/docking_server is unconfigured')


def test_a_prefixed_frame_in_an_unprefixed_tree_is_named(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r2': {'monitor_base': 'r2/base_footprint'}}
                         ).run_doctor()
    assert rc == 1
    line = _one(lines, "'r2/base_footprint' is not a frame")
    assert line.startswith('/r2/collision_monitor base_frame_id') and '/r2/tf' in line


def test_sim_time_with_no_clock_is_named(config_dir):
    rc, lines, _ = Fleet(config_dir, {'/r1': {'sim_time': True}}).run_doctor()
    assert rc == 1
    assert _one(lines, 'nothing publishes /clock').startswith(
        'use_sim_time is true on /r1/sim_clock_user')
