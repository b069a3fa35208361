"""End to end: ``fleetdrops`` runs three robots, drives them, stops them and reads their drops.

One short run of :func:`m4k_bench.fleetdrops.run_fleet` in this process (so its bringups are
this test's children and the leak check sees them). Judged on structure only: every robot's
driver host logged its motor counters and served commands, the pooled count is the robots'
sum, the RT side's motor port was read, and no process of the fleet is left. The drop rates
and the load are the benchmark's figures, never asserted.
"""

import os

import pytest
from wsenv import stack_env

from m4k_bench import fleetdrops
from m4k_bench.benchlib import fleetagg

pytestmark = pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node


def _fleet_processes(work_dir):
    """Return the pids of processes whose runtime directory lies in ``work_dir``."""
    found = []
    for name in os.listdir('/proc'):
        if not name.isdigit():
            continue
        try:
            with open('/proc/{}/environ'.format(name), 'rb') as f:
                env = f.read().split(b'\0')
        except OSError:
            continue
        if any(e.startswith(b'M4K_RUNTIME_DIR=' + work_dir.encode()) for e in env):
            found.append(int(name))
    return found


def test_three_robots_driven_and_every_robots_motor_counters_read(tmp_path):
    env = stack_env(str(tmp_path / 'unused'))
    env.pop('M4K_WORLD_REPORT')     # one ground-truth file per runtime dir: not shared by three
    res = fleetdrops.run_fleet(5.0, str(tmp_path / 'logs'), env=env, tag='smoke')
    assert res['errors'] == [], res['errors']
    assert _fleet_processes(res['work_dir']) == []
    assert not os.path.exists(res['work_dir'])
    drops = res['drops']
    assert set(drops['robots']) == set(fleetagg.ROBOTS)
    for r, d in drops['robots'].items():
        host = d['host']
        assert host is not None, r
        assert host['commands'] >= host['dropped'] >= 0
        assert host['commands'] > 0, r      # the motor service served this robot's commands
        assert d['rt'] is not None and d['rt']['sent'] > 0, r
    assert drops['pooled']['commands'] == sum(d['host']['commands']
                                              for d in drops['robots'].values())
    # the drops before the stop signal are counted over the same commands, and no more
    assert drops['pooled_running']['commands'] == drops['pooled']['commands']
    assert drops['pooled_running']['dropped'] <= drops['pooled']['dropped']
    # every robot was sent cmd_vel while driving; its bridge's late drops are at most those
    assert all(0 <= b['cmd_vel_late'] <= b['cmd_vel_sent'] and b['cmd_vel_sent'] > 0
               for b in res['bridge'].values()), res['bridge']
    load = res['load']
    assert set(load['stack_cores']) == set(fleetagg.ROBOTS) and load['cpus'] >= 1
