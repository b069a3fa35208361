"""Three robots and a laptop on one DDS domain, each in a network namespace, one argument each.

Each robot is ``bringup --robot rN`` (its own simulated world, runtime directory and RT core)
in a namespace of its own; the laptop (``netns_fleet.py``) in a fourth. The four are joined by
veth pairs to a Linux bridge in a fifth namespace, on 10.232.x.0/24 (nothing else gets an
address), discovery by multicast over UDP only (as test_two_machines: shared memory would
carry the data past a cut link). Ground truth is each simulator's.

* each robot's namespaced cmd_vel reaches that robot's bridge and no other (the laptop's
  publisher on /rN/cmd_vel matches exactly one subscription across the link);
* each TF tree is whole and separate: /rN/tf and /rN/tf_static carry one tree from odom to
  the laser (Nav2's multi-robot layout: the topic tells the robots apart, frames are
  unprefixed);
* each robot is driven by its own cmd_vel, on its own simulator's truth: r1 forward, r2 turning
  on the spot, r3 commanded zero and standing, each only as commanded;
* a link drop stops only that robot: r1's link down while it drives, the laptop still
  commanding all three; r1 stops on its RT actuator's command supervision (no VELOCITY_CMD for
  control.cmd_vel_timeout) and stays stopped, r2 turns on, r3 stands.

Three full stacks on this shared 2-core VM are more than its cores (each idle stack is ~0.6-1
core: bridge, simulator, driver host, RT core): the robots drive in bursts, stopping whenever
a starved process makes a guard sensor, the encoders or the commands late (the fail-safe
reaction), and the motor service drops part of the wheel commands as older than its
two-period freshness window.
The waits are therefore long and the judgments are on where each robot went and which way it
turned, and that the robots commanded to stand stood -- never on how fast it got there, the
speed it reached or how straight it drove (printed: the load's, not the stack's). A bridge
starved at the moment of the drop may still forward commands it took in before it, for at most
cmd_vel_timeout after they arrived (later ones it drops, counted cmd_vel_late: before that
rule such a robot was seen driving short bursts up to 16 s after its link went down); the
stopped robot is judged from its last motion on, for HOLD_S and for as long as r2 needs to
turn on.
Needs root (namespaces); every namespace and link is removed at the end.
"""

import json
import math
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
from twomachines import ip, net_env
from wsenv import ROOT, stack_env

from m4k_bringup.bringup import bringup_argv
from m4k_rt import config

pytestmark = [
    pytest.mark.allow_leaks('fds'),
    pytest.mark.needs_root('network namespaces (ip netns, veth pairs, a bridge)'),
    pytest.mark.skipif(shutil.which('ip') is None, reason='iproute2 (ip) is not installed'),
]

ROBOTS = ('r1', 'r2', 'r3')


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
            ip('netns', 'add', self.hub)
            self.created.append(self.hub)
            ip('-n', self.hub, 'link', 'add', 'br0', 'type', 'bridge')
            ip('-n', self.hub, 'link', 'set', 'br0', 'up')
            for i, m in enumerate(machines):
                ns, (inner, outer) = self.ns[m], self.veth[m]
                ip('netns', 'add', ns)
                self.created.append(ns)
                ip('link', 'add', inner, 'type', 'veth', 'peer', 'name', outer)
                ip('link', 'set', inner, 'netns', ns)
                ip('link', 'set', outer, 'netns', self.hub)
                ip('-n', self.hub, 'link', 'set', outer, 'master', 'br0')
                ip('-n', self.hub, 'link', 'set', outer, 'up')
                ip('-n', ns, 'addr', 'add', '10.232.{}.{}/24'.format(net, i + 1), 'dev', inner)
                ip('-n', ns, 'link', 'set', 'lo', 'up')
                self.up(m)
        except BaseException:
            self.close()
            raise

    def up(self, m):
        ns, inner = self.ns[m], self.veth[m][0]
        ip('-n', ns, 'link', 'set', inner, 'multicast', 'on', 'up')
        ip('-n', ns, 'route', 'replace', '224.0.0.0/4', 'dev', inner)

    def down(self, m):
        ip('-n', self.ns[m], 'link', 'set', self.veth[m][0], 'down')

    def argv(self, m, argv):
        return ['ip', 'netns', 'exec', self.ns[m], *argv]

    def close(self):
        for ns in reversed(self.created):
            ip('netns', 'del', ns, check=False)
        self.created = []


@pytest.fixture
def fleet():
    f = Fleet(ROBOTS + ('laptop',))
    try:
        yield f
    finally:
        f.close()
        left = ip('netns', 'list').stdout
        assert not any(ns in left for ns in list(f.ns.values()) + [f.hub])


def _env(runtime_dir):
    return net_env(stack_env(runtime_dir))


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
    assert frames and not any('/' in f for f in frames), (robot, sorted(frames))
    parents = {}
    for p, c in edges:
        parents.setdefault(c, set()).add(p)
    assert all(len(ps) == 1 for ps in parents.values()), (robot, parents)
    roots = {f for f in frames if f not in parents}
    assert roots == {'odom'}, (robot, roots, sorted(edges))
    for f in ('base_footprint', 'base_link', 'laser'):
        assert f in frames, (robot, f)


# What the laptop commands, each robot something else: (linear.x m/s, angular.z rad/s).
V, W = 0.2, 0.6
COMMANDS = {'r1': [V, 0.0], 'r2': [0.0, W], 'r3': [0.0, 0.0]}
DRIVE_M = 0.4        # r1's true travel, r2's true turn, before the link drop
TURN_RAD = 1.5
AT_REST = 0.005      # m/s of true speed (test_estop_e2e)
AT_REST_W = 0.02     # rad/s of true turn rate
STILL_M = 0.005      # m of true travel at rest
# How far the centre of a robot commanded to turn on the spot may move: with one wheel
# standing (a starved robot's command reaching one wheel, not the other) it pivots about that
# wheel, its centre on a circle of half the track -- never further than the track from where
# it started. A robot driving forward as it turns leaves that circle.
SPOT_M = config.load_layered()['control']['track_width']
HOLD_S = 3.0         # s the stopped robot is watched staying stopped (6 cmd_vel timeouts)
LONG_S = 180         # s any one wait may take (three stacks on 2 shared cores)


def _dead(procs):
    return any(p.poll() is not None for p in procs)


def _alive(robots, laptop, tmp_path):
    for r, p in robots.items():
        assert p.poll() is None, (tmp_path / (r + '.err')).read_text()[-3000:]
    assert laptop.poll() is None, (tmp_path / 'laptop.err').read_text()[-3000:]


def _travel(reports):
    """Return the true straight-line distance between the first and the last report (m)."""
    if len(reports) < 2:
        return 0.0
    (x0, y0, _), (x1, y1, _) = reports[0]['pose'], reports[-1]['pose']
    return math.hypot(x1 - x0, y1 - y0)


def _ahead(reports):
    """Return how far (m) the robot went along its first heading, and how far across it."""
    (x0, y0, th), (x1, y1, _) = reports[0]['pose'], reports[-1]['pose']
    dx, dy = x1 - x0, y1 - y0
    return (dx * math.cos(th) + dy * math.sin(th), -dx * math.sin(th) + dy * math.cos(th))


def _turned(reports):
    """Return the true heading change over the reports, unwrapped (rad)."""
    total = 0.0
    for a, b in zip(reports, reports[1:], strict=False):
        d = b['pose'][2] - a['pose'][2]
        total += math.atan2(math.sin(d), math.cos(d))
    return total


def _vw(reports):
    """Return (t s, v, w, motor_enabled) of each report, for a failure message."""
    return [(round(g['t_ns'] / 1e9, 3), round(g['v'], 4), round(g['w'], 4),
             g.get('motor_enabled')) for g in reports]


def _at_rest(g):
    return abs(g['v']) < AT_REST and abs(g['w']) < AT_REST_W


def _moving_as_commanded(reports):
    """Assert on ground truth that each robot moves as COMMANDS says, and only so.

    On a loaded machine a robot may drive in bursts (its commands late past the RT
    actuator's cmd_vel timeout, it brakes, and drives on with the next), a wheel PI braking on
    late feedback may overshoot into a brief reverse, and one wheel's stale command dropped
    curves the path: judged here are the directions and the robots that must not move; the
    speeds reached and the path's shape are printed.
    """
    if 'r1' in reports:      # forward: further along its heading than across it
        g = reports['r1']
        along, across = _ahead(g)
        print('fleet r1: {:.3f} m ahead, {:.3f} m across, turned {:.3f} rad, v {:.3f}..{:.3f} '
              'm/s'.format(along, across, _turned(g), min(x['v'] for x in g),
                           max(x['v'] for x in g)))
        assert along > abs(across), (along, across, _vw(g)[-20:])
    if 'r2' in reports:      # counter-clockwise, on the spot
        g = reports['r2']
        print('fleet r2: turned {:.3f} rad, centre moved {:.3f} m, w {:.3f}..{:.3f} rad/s, '
              '|v| <= {:.3f} m/s'.format(_turned(g), _travel(g), min(x['w'] for x in g),
                                       max(x['w'] for x in g), max(abs(x['v']) for x in g)))
        assert _turned(g) > 0, (_turned(g), _vw(g)[-20:])
        assert _travel(g) < SPOT_M, (_travel(g), _vw(g)[-20:])
    if 'r3' in reports:      # commanded zero: stands
        g = reports['r3']
        assert len(g) >= 2
        assert all(_at_rest(x) for x in g), _vw(g)
        assert _travel(g) < STILL_M and abs(_turned(g)) < 0.01, _vw(g)


def test_three_robots_one_argument_each_trees_apart_driven_apart_link_drop_stops_one(
        fleet, procs, tmp_path):
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    truths, robots = {}, {}
    for r in ROBOTS:
        rt = str(tmp_path / ('rt-' + r))
        os.makedirs(rt, mode=0o700)
        truths[r] = Truth(rt)
        robots[r] = procs.start(fleet.argv(r, bringup_argv(overlay) + [
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
            return ('odom', 'base_footprint') in edges and ('base_link', 'laser') in edges
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

        # each robot driven by its own cmd_vel, judged on its own simulator's truth
        _say(control, COMMANDS)
        t0 = {r: truths[r].latest()['t_ns'] for r in ROBOTS}

        def since(r, t_ns):
            return [g for g in truths[r].reports if g['t_ns'] >= t_ns]

        def driven():
            return (_travel(since('r1', t0['r1'])) > DRIVE_M
                    and _turned(since('r2', t0['r2'])) > TURN_RAD)
        _wait(lambda: driven() or _dead(everyone), LONG_S,
              'r1 to drive {} m and r2 to turn {} rad'.format(DRIVE_M, TURN_RAD), truths)
        _alive(robots, laptop, tmp_path)
        _moving_as_commanded({r: since(r, t0[r]) for r in ROBOTS})

        # r1's link down while r1 drives, the laptop still commanding all three. r1 stops on
        # its RT actuator's command supervision: no VELOCITY_CMD for control.cmd_vel_timeout
        # (0.5 s) -> target zero, ramped down at the deceleration limit (flag BRAKING; the
        # bridge only labels its cmd_vel input idle). It stays stopped; r2 and r3 carry on.
        _wait(lambda: truths['r1'].latest()['v'] > V / 2 or _dead(everyone), LONG_S,
              'r1 to be driving before its link goes down', truths)
        sent = _status(status)
        fleet.down('r1')
        t_down = {r: truths[r].latest()['t_ns'] for r in ROBOTS}
        (tmp_path / 'down').write_text(str(t_down['r1']))

        def resting(r):
            """Return the time r has been at rest since t_down (s; 0 while it moves)."""
            g = since(r, t_down[r])
            moving = [x['t_ns'] for x in g if not _at_rest(x)]
            calm = [x for x in g if x['t_ns'] > max(moving, default=0)]
            return (calm[-1]['t_ns'] - calm[0]['t_ns']) / 1e9 if len(calm) >= 2 else 0.0
        _wait(lambda: resting('r1') > HOLD_S or _dead(everyone), LONG_S,
              'r1 to stop after its link went down and stay stopped {} s'.format(HOLD_S),
              truths)
        _alive(robots, laptop, tmp_path)
        t_rest = next((x['t_ns'] for x in reversed(since('r1', t_down['r1']))
                       if not _at_rest(x)), t_down['r1'])
        t_more = {r: truths[r].latest()['t_ns'] for r in ROBOTS}
        _wait(lambda: _dead(everyone) or _turned(since('r2', t_more['r2'])) > TURN_RAD / 2,
              LONG_S, 'r2 to turn on after r1 stopped', truths)
        _alive(robots, laptop, tmp_path)
        after = {r: since(r, t_more[r]) for r in ROBOTS}
        rest = [x for x in since('r1', t_rest) if x['t_ns'] > t_rest]
        assert len(rest) >= 2 and len(after['r1']) >= 2, _vw(rest)
        assert all(_at_rest(x) for x in rest), (t_down['r1'] / 1e9, _vw(rest))
        assert _travel(rest) < STILL_M, _vw(rest)
        # r2 still turns on the spot as commanded, r3 still stands
        _moving_as_commanded({'r2': after['r2'], 'r3': after['r3']})
        # the laptop kept commanding all three, and still reaches r2 and r3
        now = _status(status)
        assert all(now[r]['sent'] > sent[r]['sent'] for r in ROBOTS), (sent, now)
        assert now['r2']['matched'] == 1 and now['r3']['matched'] == 1, now
    finally:
        for r in ROBOTS:     # for a failure's post-mortem: every truth report seen
            (tmp_path / ('truth-' + r + '.json')).write_text(json.dumps(truths[r].reports))
        for proc in [laptop] + list(robots.values()):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in [laptop] + list(robots.values()):
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
