"""The planner node in process: own rclpy Context, fake odom and scan, cmd_vel checked."""

import math
import time

from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String

from m4k_bench.planning.node import ParamError, PlannerNode

pytestmark = [pytest.mark.allow_leaks('fds'),  # FastDDS keeps its sockets for the process
              pytest.mark.e2e]           # ROS nodes: the end-to-end tier


class Harness:
    def __init__(self, overrides=()):
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.planner = None
        self.peer = rclpy.create_node('planner_test_peer', context=self.context)
        self.executor.add_node(self.peer)
        self.cmd, self.states = [], []
        self.peer.create_subscription(Twist, 'cmd_vel', self.cmd.append, 10)
        self.peer.create_subscription(String, 'planner_state',
                                      lambda m: self.states.append(m.data), 10)
        self.odom_pub = self.peer.create_publisher(Odometry, 'odom', 10)
        self.scan_pub = self.peer.create_publisher(LaserScan, 'scan', qos_profile_sensor_data)
        self.planner = PlannerNode(context=self.context, parameter_overrides=list(overrides))
        self.executor.add_node(self.planner)

    def odom(self, x=0.0, v=0.0):
        msg = Odometry()
        msg.header.stamp = self.peer.get_clock().now().to_msg()
        msg.pose.pose.position.x = x
        msg.pose.pose.orientation.w = 1.0
        msg.twist.twist.linear.x = v
        self.odom_pub.publish(msg)

    def scan(self, ranges):
        msg = LaserScan()
        msg.header.stamp = self.peer.get_clock().now().to_msg()
        msg.angle_min = -math.radians(120.0)
        msg.angle_increment = math.radians(240.0) / (len(ranges) - 1)
        msg.range_min, msg.range_max = 0.02, 5.6
        msg.ranges = [float(r) for r in ranges]
        self.scan_pub.publish(msg)

    def run(self, seconds, scan=None):
        end = time.monotonic() + seconds
        next_pub = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_pub:
                self.odom()
                if scan is not None:
                    self.scan(scan)
                next_pub = time.monotonic() + 0.05
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        self.executor.shutdown()
        if self.planner is not None:
            self.planner.destroy_node()
        self.peer.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def harness_factory():
    made = []

    def make(*overrides):
        h = Harness(overrides)
        made.append(h)
        return h
    yield make
    for h in made:
        h.close()


def test_free_scan_and_goal_ahead_drive_forward(harness_factory):
    h = harness_factory(Parameter('goal_x', value=3.0), Parameter('goal_y', value=0.0))
    h.run(2.0, scan=[math.inf] * 61)
    assert 'moving' in h.states
    assert any(m.linear.x > 0.0 for m in h.cmd)
    assert all(0.0 <= m.linear.x <= 0.25 for m in h.cmd)


def test_without_scan_the_planner_holds_still(harness_factory):
    h = harness_factory(Parameter('goal_x', value=3.0), Parameter('goal_y', value=0.0))
    h.run(1.0)
    assert h.states and set(h.states) <= {'waiting_odom', 'waiting_scan'}
    assert 'waiting_scan' in h.states
    assert h.cmd and all(m.linear.x == 0.0 and m.angular.z == 0.0 for m in h.cmd)


def test_without_goal_the_planner_is_idle(harness_factory):
    h = harness_factory()
    h.run(1.0, scan=[math.inf] * 61)
    assert 'idle' in h.states
    assert all(m.linear.x == 0.0 for m in h.cmd)


def test_wall_right_ahead_is_not_driven_into(harness_factory):
    # Every beam sees a surface 0.3 m away: the front of the body (0.225 m) is within reach.
    h = harness_factory(Parameter('goal_x', value=3.0), Parameter('goal_y', value=0.0))
    h.run(1.5, scan=[0.3] * 241)
    assert h.cmd and all(m.linear.x == 0.0 for m in h.cmd)


def test_bad_dwa_parameter_is_named():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(ParamError, match=r'dwa\.max_v: must be > 0, got -1\.0'):
            PlannerNode(context=context,
                        parameter_overrides=[Parameter('dwa.max_v', value=-1.0)])
        with pytest.raises(ParamError, match='laser_mount'):
            PlannerNode(context=context,
                        parameter_overrides=[Parameter('laser_mount', value=[0.0, 0.0])])
    finally:
        rclpy.try_shutdown(context=context)
