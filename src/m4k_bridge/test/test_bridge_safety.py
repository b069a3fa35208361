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


def _with_safety(tmp_path, fn):
    import rclpy

    from m4k_bridge.safety import SafetyInterface

    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('m4k_bridge', context=context)
        sent = []
        fn(lambda: SafetyInterface(node, sent.append, 'e_stop', 0.3,
                                   state_dir=str(tmp_path)), sent)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_engaged_request_is_persisted_gates_commands_and_leads_every_link(tmp_path):
    from m4k_rt.estop_request import read_request

    def run(make, sent):
        safety = make()
        assert not safety.gating and safety.link_preamble() is None
        safety._request(True)
        assert read_request(str(tmp_path)).engaged is True
        assert safety.gating
        _, msg = p.decode(safety.link_preamble())
        assert msg == p.EStop(1)
        # a restarted bridge finds the request: gated, and E_STOP leads its first link
        again = make()
        assert again.requested is True and again.gating
        assert p.decode(again.link_preamble())[1] == p.EStop(1)
        again._request(False)
        assert read_request(str(tmp_path)).engaged is False and not again.gating
        assert again.link_preamble() is None
        assert make().requested is None                   # released: nothing to re-assert

    _with_safety(tmp_path, run)


def test_open_contact_becomes_an_e_stop_request_that_only_a_release_clears(tmp_path):
    from m4k_rt.estop_request import read_request

    def run(make, sent):
        safety = make()
        safety.on_flags(0)
        assert safety.requested is None
        safety.on_flags(p.ODOM_ESTOP_OPEN | p.ODOM_E_STOP)
        assert safety.requested is True and safety.contact_requests == 1
        assert read_request(str(tmp_path)).engaged is True
        assert p.decode(sent[-1])[1] == p.EStop(1)
        safety.on_flags(p.ODOM_E_STOP)                    # contact closed: still requested
        assert safety.gating
        safety._request(False)
        assert not safety.gating

    _with_safety(tmp_path, run)


def test_port_pump_writes_the_preamble_first_on_every_link(tmp_path):
    # A real RT-side socket: the pump links, writes the preamble before anything queued,
    # and again first after the RT side went away and came back.
    import time

    from m4k_bridge.ports import PortPump
    from m4k_rt.channel import rt_xddp_bind

    d = str(tmp_path)
    pre = p.encode(p.Kind.E_STOP, 0, 0, 1)
    cmd = p.encode(p.Kind.VELOCITY_CMD, 0, 0, 0.0, 0.5)
    pump = PortPump('cmd', 1, lambda *a: None, d, retry_interval=0.05, preamble=lambda: pre)

    def first_two(sock):
        got = []
        end = time.monotonic() + 10
        while len(got) < 2 and time.monotonic() < end:
            pump.send(cmd)
            data = sock.recv()
            if data is not None:
                got.append(bytes(data))
            time.sleep(0.02)
        return got

    sock = rt_xddp_bind(1, 'cmd', runtime_dir=d)
    pump.start()
    try:
        for _ in range(2):
            got = first_two(sock)
            assert got and got[0] == pre, got
            assert all(g == cmd for g in got[1:])
            sock.close()
            time.sleep(0.3)
            sock = rt_xddp_bind(1, 'cmd', runtime_dir=d)
        assert pump.preambles_sent >= 2
    finally:
        pump.close()
        sock.close()
