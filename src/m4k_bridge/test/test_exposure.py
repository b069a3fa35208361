"""The doctor's open-graph check: the discovery range of this shell and of a running bridge.

The bridge here is a real child process whose command line names ``m4k_bridge.node`` (a
sleeping Python started as ``python -c ... m4k_bridge.node``): the check reads its
environment from /proc as it reads the real bridge's.
"""

import os
import subprocess
import sys

import pytest

from m4k_bridge.exposure import graph_problems, range_problem


@pytest.mark.parametrize('rng', ['', 'SUBNET', 'SYSTEM_DEFAULT'])
def test_subnet_unset_and_system_default_are_open(rng):
    env = {'ROS_DOMAIN_ID': '42'}
    if rng:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = rng
    line = range_problem(env, 'x')
    assert line is not None and 'open to the subnet' in line and 'ROS_DOMAIN_ID 42' in line
    assert 'LOCALHOST' in line and 'ROS_STATIC_PEERS' in line


@pytest.mark.parametrize('rng', ['LOCALHOST', 'OFF'])
def test_localhost_and_off_are_not_reported(rng):
    assert range_problem({'ROS_AUTOMATIC_DISCOVERY_RANGE': rng}, 'x') is None
    assert range_problem({'ROS_LOCALHOST_ONLY': '1'}, 'x') is None


def test_a_running_bridge_with_an_open_range_is_named_by_pid():
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET')
    # The child says it is up first: a Python of this venv re-executes itself once at start
    # (the ROS wheels' bootstrapper), and /proc is not read in the middle of that.
    child = subprocess.Popen([sys.executable, '-c',
                              'import time; print("up", flush=True); time.sleep(60)',
                              'm4k_bridge.node'], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'up'
        here = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                'ROS_DOMAIN_ID': env.get('ROS_DOMAIN_ID', '0')}
        lines = graph_problems(here)
        assert any('the bridge (pid {})'.format(child.pid) in ln for ln in lines), lines
        assert not any('this shell' in ln for ln in lines)
        # a bridge on another domain is another graph: not this doctor's
        other = str((int(here['ROS_DOMAIN_ID'] or '0') + 1) % 100 + 1)
        lines = graph_problems(dict(here, ROS_DOMAIN_ID=other))
        assert not any('the bridge (pid {})'.format(child.pid) in ln for ln in lines), lines
    finally:
        child.kill()
        child.wait()
