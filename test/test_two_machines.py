"""Robot and laptop on two machines: two network namespaces joined by a veth pair.

The robot stack (bringup) runs in one namespace, a plain rclpy client publishing cmd_vel
(``netns_driver.py``) in the other; the only link between them is a veth pair with a /30 of
10.231.x.0 (nothing else gets an address, no default route). DDS discovers across the link by
multicast (``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``, the multicast flag and a 224.0.0.0/4 route
on the veth) and Fast DDS is told to use UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``): its
shared-memory transport would otherwise carry the data between two processes of one kernel
and a cut link would cut nothing.

Cut the link while driving at 0.25 m/s: the ground truth must stop within ``cmd_vel_timeout +
v / max_deceleration + 2 periods`` (read from config) plus a slack for the motor's lag and the
link. The laptop keeps publishing for a while into the dead link, then stops; restoring the
link must not move the robot (no command from before or during the outage may arrive late);
a fresh command does. Needs root (namespaces); every namespace and link is removed at the end.
"""

import math
import shutil
import time

import pytest
from test_bringup import write_overlay
from test_estop_e2e import (
    _actuator_period_s,
    _dist,
    _motor_tau_s,
    AT_REST,
    rest_after,
    SETTLE_S,
    STILL_M,
    Truth,
)
from test_stack_e2e import _control, START
from twomachines import ip, laptop_status, Link, net_env, say, start_pair, stop

from m4k_rt.control.params import control_params

pytestmark = [
    pytest.mark.allow_leaks('fds'),
    pytest.mark.needs_root('network namespaces (ip netns, veth pairs)'),
    pytest.mark.skipif(shutil.which('ip') is None, reason='iproute2 (ip) is not installed'),
]

V = 0.25
LINK_SLACK_S = 0.1   # last command up to one 50 ms publishing period before the cut, + margin


@pytest.fixture
def link():
    lk = Link()
    try:
        yield lk
    finally:
        lk.close()
        left = ip('netns', 'list').stdout
        assert lk.robot not in left and lk.laptop not in left


def _wait(predicate, timeout, what, truth):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        truth.poll()
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError('timed out after {} s waiting for {}'.format(timeout, what))


def _collect(truth, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        truth.poll()
        time.sleep(0.05)


def test_cut_link_stops_the_robot_and_restoring_it_does_not_restart_it(
        link, procs, tmp_path, m4k_runtime_dir):
    from wsenv import stack_env
    params = control_params(_control())
    period = _actuator_period_s()
    tau = _motor_tau_s()
    a = params.linear.max_deceleration or params.linear.max_acceleration
    slack = LINK_SLACK_S + tau * math.log(max(a * tau / AT_REST, 1.0))
    bound_s = params.cmd_vel_timeout + V / a + 2 * period + slack
    truth = Truth(m4k_runtime_dir)
    control = tmp_path / 'control'
    status = tmp_path / 'status'
    say(control, 'off')
    env = net_env(stack_env(m4k_runtime_dir))
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    robot, laptop = start_pair(procs, link, tmp_path, overlay, control, status, env, env)
    try:
        _wait(lambda: truth.latest() is not None and laptop_status(status)[0] > 0
              or robot.poll() is not None or laptop.poll() is not None, 60,
              'the stack up and the laptop matched across the link', truth)
        assert robot.poll() is None, (tmp_path / 'bringup.err').read_text()[-3000:]
        assert laptop.poll() is None, (tmp_path / 'laptop.err').read_text()[-3000:]
        # drive
        say(control, str(V))
        _wait(lambda: truth.reports[-1]['v'] > V - 0.01, 30, 'the true speed 0.25 m/s', truth)
        before = truth.latest()
        t_cut = time.monotonic_ns()
        link.down()
        # the laptop keeps publishing into the dead link: the robot comes to rest, stays there
        after = rest_after(truth, t_cut, lambda sec: _collect(truth, sec), bound_s + SETTLE_S)
        assert len(after) >= 2, 'the robot did not come to rest after the cut'
        assert after[-1]['t_ns'] - after[0]['t_ns'] >= 1.5e9, 'at rest for too short a time'
        assert all(abs(r['v']) < AT_REST and _dist(r, after[0]) < STILL_M for r in after)
        travelled = _dist(after[-1], before)
        allowed = (V * (t_cut - before['t_ns']) * 1e-9 + V * params.cmd_vel_timeout
                   + V * V / (2 * a) + V * (2 * period + slack))
        print('stopped: travelled {:.3f} m of {:.3f} m allowed; at rest by the first report '
              '{:.2f} s after the event (bound {:.2f} s)'.format(
                  travelled, allowed, (after[0]['t_ns'] - t_cut) * 1e-9, bound_s))
        # the laptop stops commanding, then the link comes back: nothing may move the robot
        say(control, 'off')
        # the laptop reads its control file every 50 ms: wait until it says it acted on 'off'
        _wait(lambda: laptop_status(status)[2] == 'off', 10, 'the laptop to stop publishing',
              truth)
        sent = laptop_status(status)[1]
        _collect(truth, 0.3)
        assert laptop_status(status)[1] == sent, 'the laptop published after acting on off'
        link.up()
        rest = truth.latest()
        _collect(truth, 3.0)
        assert _dist(truth.latest(), rest) < STILL_M
        assert all(abs(r['v']) < AT_REST for r in truth.reports if r['t_ns'] > rest['t_ns'])
        # a fresh command from the laptop drives again (discovery recovered across the link)
        say(control, str(V))
        _wait(lambda: truth.reports[-1]['v'] > 0.1, 30, 'a fresh command to drive', truth)
        say(control, '0.0')
        assert robot.poll() is None
    finally:
        stop(laptop, robot)
