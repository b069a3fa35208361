"""m4k_msgs/RtStatus makes a round trip through real rclpy publish/subscribe over DDS."""

import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor

from m4k_msgs.msg import RtStatus, TaskTiming


@pytest.mark.allow_leaks('fds')  # FastDDS keeps its transport sockets for the process lifetime
def test_rt_status_round_trip_over_dds():
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('m4k_msgs_roundtrip', context=context)
        received = []
        pub = node.create_publisher(RtStatus, 'rt_status', 10)
        node.create_subscription(RtStatus, 'rt_status', received.append, 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        sent = RtStatus(policy=RtStatus.POLICY_FIFO, memory_locked=True, schedulable=True,
                        liu_layland_bound=0.743)
        sent.tasks = [TaskTiming(name='actuator', priority=90, period=0.01, cycles=7)]
        deadline = time.monotonic() + 20.0
        while not received and time.monotonic() < deadline:
            pub.publish(sent)
            executor.spin_once(timeout_sec=0.1)
        assert received, 'no RtStatus arrived within 20 s'
        got = received[0]
        assert got.policy == RtStatus.POLICY_FIFO and got.memory_locked
        assert got.tasks[0].name == 'actuator' and got.tasks[0].cycles == 7
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
