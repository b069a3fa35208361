"""The bridge's e-stop helpers: the stamp gate, the latch state, the reset service's answers."""

import pytest

from m4k_bridge.safety import CommandStampGate, latch_state
from m4k_rt import protocol as p

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier


def test_stamped_command_from_before_the_release_is_dropped():
    gate = CommandStampGate()
    assert gate.accept(100) and gate.accept(200)
    gate.released()
    assert not gate.accept(200)          # the last one before the release, re-sent
    assert not gate.accept(150)
    assert gate.accept(201)              # anything newer than every earlier stamp
    assert gate.accept(0)                # unstamped: nothing to judge by
    assert gate.rejected == 2


def test_release_without_earlier_commands_lets_everything_stamped_through():
    gate = CommandStampGate()
    gate.released()
    assert gate.accept(1)


def test_latch_state_reads_the_odometry_flags():
    assert latch_state(None) == (False, False)
    assert latch_state(p.ODOM_E_STOP | p.ODOM_BRAKING) == (True, False)
    assert latch_state(p.ODOM_HOLD) == (False, True)


def _call_reset(ack):
    """Call ~/reset_odometry on a SafetyInterface whose RT side acks (or not); return reply."""
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger

    from m4k_bridge.safety import SafetyInterface

    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('m4k_bridge', context=context)
        user = rclpy.create_node('user', context=context)
        sent = []
        safety = SafetyInterface(node, sent.append, 'e_stop', 0.3)
        client = user.create_client(Trigger, '/m4k_bridge/reset_odometry')
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        executor.add_node(user)
        assert client.wait_for_service(10)
        future = client.call_async(Trigger.Request())
        end = time.monotonic() + 10
        while not future.done() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
            if ack and sent:
                _, req = p.decode(sent[0])
                safety.on_reset_ack(req.request_id)
        assert [p.decode(d)[0].kind for d in sent] == [p.Kind.ODOM_RESET]
        executor.shutdown()
        user.destroy_node()
        node.destroy_node()
        return future.result()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process
def test_reset_odometry_succeeds_only_on_the_rt_acknowledgement():
    reply = _call_reset(ack=True)
    assert reply.success and 'zeroed' in reply.message


@pytest.mark.allow_leaks('fds')
def test_reset_odometry_without_acknowledgement_fails_with_the_reason():
    reply = _call_reset(ack=False)
    assert not reply.success
    assert 'no acknowledgement from the RT actuator within 0.3 s' in reply.message
