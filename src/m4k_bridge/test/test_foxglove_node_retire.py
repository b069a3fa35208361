"""A dropped teleop client's zero Twist outlives the client: its publisher waits for the ack.

A reliable writer destroyed right after its last sample can take the sample with it (under
load the live-view test once saw the robot drive on to the guard after its client dropped).
The node therefore keeps the publisher until the readers acknowledged the zero Twist.
"""

from __future__ import annotations

import time

from geometry_msgs.msg import Twist, Vector3
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from m4k_bridge.foxglove.node import FoxgloveNode

pytestmark = [pytest.mark.allow_leaks('fds'),  # FastDDS keeps its sockets for the process
              pytest.mark.e2e]           # ROS nodes: the end-to-end tier


def test_the_zero_twist_is_delivered_in_order_and_the_publisher_retired_after_the_ack() -> None:
    rclpy.init(args=['x', '--ros-args', '-p', 'port:=0', '-p', 'graph_period:=0.2'])
    node = FoxgloveNode()
    node.server.client_right = lambda client: 'drive'   # as the server would for client 7
    node.server.client_name = lambda client: 'client {}'.format(client)
    reader = rclpy.create_node('retire_reader')
    got: list[float] = []
    reader.create_subscription(Twist, 'cmd_vel', lambda m: got.append(m.linear.x),
                               QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(reader)

    def spin_until(cond, what: str, timeout: float = 20.0) -> None:
        end = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < end, what
            ex.spin_once(timeout_sec=0.05)

    try:
        problem = node.on_client_advertise(7, {'id': 1, 'topic': '/cmd_vel', 'encoding': 'cdr',
                                                'schemaName': 'geometry_msgs/msg/Twist'})
        assert problem is None
        spin_until(lambda: node.count_publishers('/cmd_vel') == 1, 'no publisher')
        spin_until(lambda: node.count_subscribers('/cmd_vel') == 1
                   and reader.count_publishers('/cmd_vel') == 1, 'not matched')
        forward = serialize_message(Twist(linear=Vector3(x=0.2)))
        for _ in range(3):
            node.on_client_message(7, 1, forward)
        node.on_client_unadvertise(7, 1)          # the client dropped
        spin_until(lambda: not node._actions and node._retiring, 'the drop did not run')
        # The zero Twist is out and its writer still alive: not destroyed with it in flight.
        assert node.count_publishers('/cmd_vel') == 1
        spin_until(lambda: len(got) >= 4, 'the zero Twist did not arrive')
        assert got == [0.2, 0.2, 0.2, 0.0]
        # Retired after the acknowledgement, not with the sample in flight.
        spin_until(lambda: node.count_publishers('/cmd_vel') == 0, 'publisher never retired')
        assert not node._retiring
    finally:
        ex.shutdown()
        reader.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()
