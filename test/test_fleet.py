"""Three robots and a laptop on one DDS domain, each in a network namespace, one argument each.

Each robot is ``bringup --robot rN`` (its own simulated world, runtime directory and RT core)
in a namespace of its own; the laptop (``netns_fleet.py``) in a fourth. The four are joined by
veth pairs to a Linux bridge in a fifth namespace, on 10.232.x.0/24 (nothing else gets an
address), discovery by multicast over UDP only (as test_two_machines: shared memory would
carry the data past a cut link). Ground truth is each simulator's.

* each robot's namespaced cmd_vel reaches that robot's bridge and no other (the laptop's
  publisher on /rN/cmd_vel matches exactly one subscription across the link);
* each TF tree is whole and separate: on /rN/tf and /rN/tf_static only rN/ frames, one tree
  from rN/odom to the laser.

Not here yet (issue 29): driving each robot by its own cmd_vel judged on ground truth, and a
link drop stopping only that robot -- on this shared 2-core VM three stacks overran their RT
tasks so far that the motor service dropped the commands as stale and no robot reached speed.
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
from test_estop_e2e import Truth
from test_stack_e2e import START
from wsenv import ROOT, stack_env

pytestmark = [
    pytest.mark.allow_leaks('fds'),
    pytest.mark.needs_root('network namespaces (ip netns, veth pairs, a bridge)'),
    pytest.mark.skipif(shutil.which('ip') is None, reason='iproute2 (ip) is not installed'),
]

ROBOTS = ('r1', 'r2', 'r3')


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


def test_three_robots_one_argument_each_cmd_vel_apart_trees_whole_and_apart(
        fleet, procs, tmp_path):
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
        def heard(r):
            edges = {tuple(e) for e in _status(status).get(r, {}).get('edges', [])}
            return (r + '/odom', r + '/base_footprint') in edges and \
                (r + '/base_link', r + '/laser') in edges
        _wait(lambda: all(heard(r) for r in ROBOTS), 90, "every robot's transforms", truths)
        time.sleep(1.0)
        s = _status(status)
        for r in ROBOTS:
            _tree_is_whole_and_own([tuple(e) for e in s[r]['edges']], r)

        # each /rN/cmd_vel reaches exactly one subscriber: robot rN's bridge (the laptop's
        # publisher matched it across the link, and no other robot's)
        assert all(s[r]['matched'] == 1 for r in ROBOTS), s
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
