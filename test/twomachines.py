"""Robot and laptop on two machines, for tests: two network namespaces joined by a veth pair.

test_two_machines and test_dds_discovery_range share what this holds: the link, the
discovery environment of each side, the robot's stack (bringup) and the laptop's cmd_vel
publisher (``netns_driver.py``) started in their namespaces, the CONTROL/STATUS files between
the test and the laptop, and the teardown that stops both.
"""

import os
import random
import signal
import subprocess

from wsenv import ROOT

from m4k_bringup.bringup import bringup_argv

STOP_S = 40.0      # bringup stops its own children on SIGTERM: this long for that


def ip(*args, check=True):
    """Run ``ip ARGS`` and return the completed process."""
    return subprocess.run(['ip', *args], check=check, capture_output=True, text=True,
                          timeout=10)


class Link:
    """Two namespaces and the veth pair between them (removed by ``close``)."""

    def __init__(self):
        tag = '{:x}'.format(random.getrandbits(20))
        self.robot, self.laptop = 'm4kr' + tag, 'm4kl' + tag
        self.veth = {self.robot: 'vr' + tag, self.laptop: 'vl' + tag}
        net = random.randrange(256)
        self.addr = {self.robot: '10.231.{}.1'.format(net), self.laptop: '10.231.{}.2'.format(net)}
        self.created = []
        try:
            for ns in (self.robot, self.laptop):
                ip('netns', 'add', ns)
                self.created.append(ns)
            ip('link', 'add', self.veth[self.robot], 'type', 'veth', 'peer', 'name',
               self.veth[self.laptop])
            for ns in (self.robot, self.laptop):
                ip('link', 'set', self.veth[ns], 'netns', ns)
                ip('-n', ns, 'addr', 'add', self.addr[ns] + '/30', 'dev', self.veth[ns])
                ip('-n', ns, 'link', 'set', 'lo', 'up')
            self.up()
        except BaseException:
            self.close()
            raise

    def up(self):
        for ns in (self.robot, self.laptop):
            ip('-n', ns, 'link', 'set', self.veth[ns], 'multicast', 'on', 'up')
            # taking the link down drops its routes: (re)add the multicast one each time
            ip('-n', ns, 'route', 'replace', '224.0.0.0/4', 'dev', self.veth[ns])

    def down(self):
        for ns in (self.robot, self.laptop):
            ip('-n', ns, 'link', 'set', self.veth[ns], 'down')

    def argv(self, ns, argv):
        return ['ip', 'netns', 'exec', ns, *argv]

    def close(self):
        for ns in reversed(self.created):
            ip('netns', 'del', ns, check=False)   # deleting a namespace deletes its veth end
        self.created = []


def net_env(base, discovery_range='SUBNET', peer=''):
    """Return ``base`` with one side's DDS discovery: its range, its static peer (if any).

    Fast DDS is told to use UDP only: its shared-memory transport would otherwise carry the
    data between two processes of one kernel, and a cut link would cut nothing.
    """
    env = dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE=discovery_range,
               FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    env.pop('ROS_STATIC_PEERS', None)
    if peer:
        env['ROS_STATIC_PEERS'] = peer
    return env


def say(path, word):
    """Tell the laptop what to publish (its CONTROL file, replaced atomically)."""
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(word)
    os.replace(tmp, path)


def laptop_status(path):
    """(matched, sent, word) from the laptop's STATUS file; zeros before its first write."""
    try:
        matched, sent, word = path.read_text().split()
        return int(matched), int(sent), word
    except (OSError, ValueError):
        return 0, 0, ''


def start_pair(procs, link, tmp_path, overlay, control, status_path, robot_env, laptop_env):
    """Start the robot's stack and the laptop's publisher in their namespaces; return both.

    Their output goes to ``bringup.out/.err`` and ``laptop.out/.err`` in ``tmp_path``.
    """
    robot = procs.start(link.argv(link.robot, bringup_argv(overlay) + ['--no-status']),
                        env=robot_env, stdout=open(tmp_path / 'bringup.out', 'w'),
                        stderr=open(tmp_path / 'bringup.err', 'w'))
    laptop = procs.start(link.argv(link.laptop, [
        'python', os.path.join(ROOT, 'test', 'netns_driver.py'), str(control),
        str(status_path)]), env=laptop_env, stdout=open(tmp_path / 'laptop.out', 'w'),
        stderr=open(tmp_path / 'laptop.err', 'w'))
    return robot, laptop


def stop(*procs):
    """Stop each process still running: SIGTERM, then SIGKILL after :data:`STOP_S`."""
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(STOP_S)
            except subprocess.TimeoutExpired:
                proc.kill()
