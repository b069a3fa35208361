"""The discovery range the robot ships with (LOCALHOST + ROS_STATIC_PEERS), on two machines.

Two network namespaces joined by a veth pair (``test_two_machines.Link``), the robot stack
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

import os
import signal
import subprocess
import time

import pytest
from test_bringup import write_overlay
from test_estop_e2e import Truth
from test_stack_e2e import START
from test_two_machines import _ip, _say, _status, Link
from wsenv import ROOT, stack_env

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
            _ip('-n', ns, 'route', 'del', '224.0.0.0/4', 'dev', lk.veth[ns], check=False)
            _ip('-n', ns, 'link', 'set', lk.veth[ns], 'multicast', 'off')
        yield lk
    finally:
        lk.close()


def _env(base, rng, peer):
    env = dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE=rng, FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    env.pop('ROS_STATIC_PEERS', None)
    if peer:
        env['ROS_STATIC_PEERS'] = peer
    return env


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
    _say(control, 'off')
    base = stack_env(m4k_runtime_dir)
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    robot = procs.start(lk.argv(lk.robot, [
        'python', '-m', 'm4k_bringup.bringup', '--python-m', '--config', overlay,
        '--no-status']), env=_env(base, 'LOCALHOST', lk.addr[lk.laptop] if robot_peer else ''),
        stdout=open(tmp_path / 'bringup.out', 'w'), stderr=open(tmp_path / 'bringup.err', 'w'))
    laptop = procs.start(lk.argv(lk.laptop, [
        'python', os.path.join(ROOT, 'test', 'netns_driver.py'), str(control), str(status)]),
        env=_env(base, laptop_range, lk.addr[lk.robot] if laptop_peer else ''),
        stdout=open(tmp_path / 'laptop.out', 'w'), stderr=open(tmp_path / 'laptop.err', 'w'))
    try:
        deadline = time.monotonic() + 60
        while truth.latest() is None:
            assert time.monotonic() < deadline and robot.poll() is None, \
                (tmp_path / 'bringup.err').read_text()[-3000:]
            time.sleep(0.1)
        start = truth.latest()
        _say(control, '0.2')
        end = time.monotonic() + (60 if drives else QUIET_S)
        while time.monotonic() < end:
            truth.poll()
            if truth.latest()['v'] > 0.1:
                break
            time.sleep(0.1)
        moved = truth.latest()['v'] > 0.1
        assert moved == drives, (_status(status), truth.latest(), start)
        assert (_status(status)[0] > 0) == drives, _status(status)
        assert laptop.poll() is None and robot.poll() is None
    finally:
        _say(control, 'off')
        for proc in (laptop, robot):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(40)
                except subprocess.TimeoutExpired:
                    proc.kill()
