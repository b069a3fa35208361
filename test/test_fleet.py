"""Three robots and a laptop on one DDS domain, each in a network namespace, one argument each.

Each robot is ``bringup --robot rN`` (its own simulated world, runtime directory and RT core)
in a namespace of its own; the laptop (``netns_fleet.py``) in a fourth. The four are joined by
veth pairs to a Linux bridge in a fifth namespace, on 10.232.x.0/24 (nothing else gets an
address), discovery by multicast over UDP only (as test_two_machines: shared memory would
carry the data past a cut link). Ground truth is each simulator's.

* each robot is driven by its own namespaced cmd_vel: a command on /r1/cmd_vel moves r1 and
  nothing else;
* each TF tree is whole and separate: on /rN/tf and /rN/tf_static only rN/ frames, one tree
  from rN/odom to the laser;
* a link drop stops only that robot: cut r2's link while all three drive; r2 is at rest after
  its command timeout and braking, r1 and r3 drive on.
Needs root (namespaces); every namespace and link is removed at the end.
"""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import pytest
from test_bringup import write_overlay
from test_estop_e2e import AT_REST, Truth
from test_stack_e2e import _control, START
from wsenv import ROOT, stack_env

from m4k_rt.control.params import control_params

pytestmark = [
    pytest.mark.allow_leaks('fds'),
    pytest.mark.needs_root('network namespaces (ip netns, veth pairs, a bridge)'),
    pytest.mark.skipif(shutil.which('ip') is None, reason='iproute2 (ip) is not installed'),
]

ROBOTS = ('r1', 'r2', 'r3')
V = 0.2


def _ip(*args, check=True):
    return subprocess.run(['ip', *args], check=check, capture_output=True, text=True,
                          timeout=10)


class Fleet:
    """A hub namespace with a bridge, and one namespace per machine linked to it."""

    def __init__(self, machines):
        tag = '{:x}'.format(random.getrandbits(16))
        net = random.randrange(256)
        self.hub = 'm4kh' + tag
        self.ns = {m: 'm4k{}{}'.format(m, tag) for m in machines}
        self.veth = {m: ('f{}{}'.format(m, tag), 'h{}{}'.format(m, tag)) for m in machines}
        self.created = []
        try:
            _ip('netns', 'add', self.hub)
            self.created.append(self.hub)
            _ip('-n', self.hub, 'link', 'add', 'br0', 'type', 'bridge')
            _ip('-n', self.hub, 'link', 'set', 'br0', 'up')
            for i, m in enumerate(machines):
                ns, (inner, outer) = self.ns[m], self.veth[m]
                _ip('netns', 'add', ns)
                self.created.append(ns)
                _ip('link', 'add', inner, 'type', 'veth', 'peer', 'name', outer)
                _ip('link', 'set', inner, 'netns', ns)
                _ip('link', 'set', outer, 'netns', self.hub)
                _ip('-n', self.hub, 'link', 'set', outer, 'master', 'br0')
                _ip('-n', self.hub, 'link', 'set', outer, 'up')
                _ip('-n', ns, 'addr', 'add', '10.232.{}.{}/24'.format(net, i + 1), 'dev', inner)
                _ip('-n', ns, 'link', 'set', 'lo', 'up')
                self.up(m)
        except BaseException:
            self.close()
            raise

    def up(self, m):
        ns, inner = self.ns[m], self.veth[m][0]
        _ip('-n', ns, 'link', 'set', inner, 'multicast', 'on', 'up')
        _ip('-n', ns, 'route', 'replace', '224.0.0.0/4', 'dev', inner)

    def down(self, m):
        _ip('-n', self.ns[m], 'link', 'set', self.veth[m][0], 'down')

    def argv(self, m, argv):
        return ['ip', 'netns', 'exec', self.ns[m], *argv]

    def close(self):
        for ns in reversed(self.created):
            _ip('netns', 'del', ns, check=False)
        self.created = []


@pytest.fixture
def fleet():
    f = Fleet(ROBOTS + ('laptop',))
    try:
        yield f
    finally:
        f.close()
        left = _ip('netns', 'list').stdout
        assert not any(ns in left for ns in list(f.ns.values()) + [f.hub])


def _env(runtime_dir):
    env = stack_env(runtime_dir)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
    env.pop('ROS_STATIC_PEERS', None)
    return env


def _say(path, doc):
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(json.dumps(doc))
    os.replace(tmp, path)


def _status(path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _wait(predicate, timeout, what, truths):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for t in truths.values():
            t.poll()
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError('timed out after {} s waiting for {}'.format(timeout, what))


def _tree_is_whole_and_own(edges, robot):
    frames = {f for e in edges for f in e}
    assert frames and all(f.startswith(robot + '/') for f in frames), (robot, sorted(frames))
    parent = {c: p for p, c in edges}
    roots = {f for f in frames if f not in parent}
    assert roots == {robot + '/odom'}, (robot, roots, sorted(edges))
    for f in ('base_footprint', 'base_link', 'laser'):
        assert robot + '/' + f in frames, (robot, f)


def test_three_robots_one_argument_each_driven_apart_trees_apart_stopped_apart(
        fleet, procs, tmp_path):
    params = control_params(_control())
    a = params.linear.max_deceleration or params.linear.max_acceleration
    stop_s = params.cmd_vel_timeout + V / a + 1.0        # + slack for lag and a loaded VM
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    truths, robots = {}, {}
    for r in ROBOTS:
        rt = str(tmp_path / ('rt-' + r))
        os.makedirs(rt, mode=0o700)
        truths[r] = Truth(rt)
        robots[r] = procs.start(fleet.argv(r, [
            sys.executable, '-m', 'm4k_bringup.bringup', '--python-m', '--config', overlay,
            '--no-status', '--robot', r]), env=_env(rt),
            stdout=open(tmp_path / (r + '.out'), 'w'), stderr=open(tmp_path / (r + '.err'), 'w'))
    control, status = tmp_path / 'control', tmp_path / 'status'
    _say(control, {})
    laptop = procs.start(fleet.argv('laptop', [
        sys.executable, os.path.join(ROOT, 'test', 'netns_fleet.py'), str(control),
        str(status), *ROBOTS]), env=_env(str(tmp_path / 'rt-laptop')),
        stdout=open(tmp_path / 'laptop.out', 'w'), stderr=open(tmp_path / 'laptop.err', 'w'))
    everyone = list(robots.values()) + [laptop]

    def v(r):
        return truths[r].reports[-1]['v'] if truths[r].reports else None
    try:
        def ready():
            s = _status(status)
            return all(truths[r].latest() is not None and s.get(r, {}).get('matched', 0) > 0
                       for r in ROBOTS) or any(p.poll() is not None for p in everyone)
        _wait(ready, 180, 'three stacks up and the laptop matched on each cmd_vel', truths)
        for r, p in robots.items():
            assert p.poll() is None, (tmp_path / (r + '.err')).read_text()[-3000:]
        assert laptop.poll() is None, (tmp_path / 'laptop.err').read_text()[-3000:]

        # each TF tree whole and separate, as a listener of /rN/tf sees it
        _wait(lambda: all(len(_status(status).get(r, {}).get('edges', [])) >= 4
                          for r in ROBOTS), 60, "every robot's transforms", truths)
        time.sleep(1.0)
        s = _status(status)
        for r in ROBOTS:
            _tree_is_whole_and_own([tuple(e) for e in s[r]['edges']], r)

        # r1's own cmd_vel moves r1 only
        _say(control, {'r1': V})
        _wait(lambda: v('r1') is not None and v('r1') > V - 0.02, 60, 'r1 to drive', truths)
        assert all(abs(v(r)) < AT_REST for r in ('r2', 'r3')), {r: v(r) for r in ROBOTS}

        # all drive; cut r2's link: r2 stops, r1 and r3 drive on
        _say(control, dict.fromkeys(ROBOTS, V))
        _wait(lambda: all(v(r) > V - 0.02 for r in ROBOTS), 60, 'all three to drive', truths)
        fleet.down('r2')
        t_cut = time.monotonic()
        _wait(lambda: time.monotonic() - t_cut > stop_s, stop_s + 5, 'the stop bound', truths)
        _wait(lambda: abs(v('r2')) < AT_REST, 10, 'r2 at rest', truths)
        assert v('r1') > V - 0.02 and v('r3') > V - 0.02, {r: v(r) for r in ROBOTS}
        _say(control, {})
        for r, p in robots.items():
            assert p.poll() is None, (tmp_path / (r + '.err')).read_text()[-3000:]
    finally:
        for proc in [laptop] + list(robots.values()):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in [laptop] + list(robots.values()):
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
