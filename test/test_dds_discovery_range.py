"""The discovery range the robot ships with (LOCALHOST + ROS_STATIC_PEERS), on two machines.

Two network namespaces joined by a veth pair (``twomachines.Link``), the robot stack
(bringup) in one, a plain rclpy ``cmd_vel`` publisher (``netns_driver.py``) in the other,
Fast DDS on UDP only. The veth has **no multicast flag and no multicast route**: what
discovers here is the static peer list alone. Judged on the simulator's ground truth.

* robot LOCALHOST naming the laptop, laptop LOCALHOST naming the robot: the laptop drives
  (the documented robot/laptop setup works without multicast);
* robot LOCALHOST naming nobody, laptop SUBNET, and here the link **does** carry multicast
  (flag and route on both ends, as on a normal LAN): no match, no motion;
* robot LOCALHOST naming nobody, laptop naming the robot: the laptop **does** drive --
  rmw_fastrtps listens for unicast on every interface under LOCALHOST, so the range is not
  access control; docs/live-view.md ("The DDS graph") says to firewall the RTPS ports.
"""

import time

import pytest
from test_bringup import write_overlay
from test_estop_e2e import Truth
from test_stack_e2e import START
from twomachines import ip, laptop_status, Link, net_env, say, start_pair, stop
from wsenv import stack_env

pytestmark = [
    pytest.mark.allow_leaks('fds'),
    pytest.mark.needs_root('network namespaces (ip netns, veth pairs)'),
]

QUIET_S = 12.0      # a discovery that does not happen: watched this long (announcements ~1 s)


@pytest.fixture
def unicast_link():
    lk = Link()
    try:
        for ns in (lk.robot, lk.laptop):       # no multicast anywhere on the link
            ip('-n', ns, 'route', 'del', '224.0.0.0/4', 'dev', lk.veth[ns], check=False)
            ip('-n', ns, 'link', 'set', lk.veth[ns], 'multicast', 'off')
        yield lk
    finally:
        lk.close()


@pytest.mark.parametrize('robot_peer, laptop_range, laptop_peer, drives', [
    (True, 'LOCALHOST', True, True),
    (False, 'SUBNET', False, False),
    (False, 'LOCALHOST', True, True),
], ids=['both-name-each-other', 'stranger-by-multicast', 'stranger-naming-the-robot'])
def test_localhost_with_static_peers(unicast_link, procs, tmp_path, m4k_runtime_dir,
                                     robot_peer, laptop_range, laptop_peer, drives):
    lk = unicast_link
    if laptop_range == 'SUBNET':
        lk.up()                                # a LAN where multicast passes
    truth = Truth(m4k_runtime_dir)
    control, status = tmp_path / 'control', tmp_path / 'status'
    say(control, 'off')
    base = stack_env(m4k_runtime_dir)
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    robot, laptop = start_pair(
        procs, lk, tmp_path, overlay, control, status,
        net_env(base, 'LOCALHOST', lk.addr[lk.laptop] if robot_peer else ''),
        net_env(base, laptop_range, lk.addr[lk.robot] if laptop_peer else ''))
    try:
        deadline = time.monotonic() + 60
        while truth.latest() is None:
            assert time.monotonic() < deadline and robot.poll() is None, \
                (tmp_path / 'bringup.err').read_text()[-3000:]
            time.sleep(0.1)
        start = truth.latest()
        say(control, '0.2')
        end = time.monotonic() + (60 if drives else QUIET_S)

        def moved():
            # any report since the start: the newest alone may be a dip under load (the loop
            # once broke on v > 0.1 and a fresh read a moment later said 0.09)
            return next((r for r in truth.reports if r['t_ns'] > start['t_ns']
                         and r['v'] > 0.1), None)
        while time.monotonic() < end and moved() is None:
            truth.poll()
            time.sleep(0.1)
        assert (moved() is not None) == drives, (laptop_status(status), moved(), start)
        assert (laptop_status(status)[0] > 0) == drives, laptop_status(status)
        assert laptop.poll() is None and robot.poll() is None
    finally:
        say(control, 'off')
        stop(laptop, robot)
