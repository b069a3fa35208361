"""SIGTERM during start-up: every long-running m4k process still stops cleanly and says so.

Issue 10: a driver host restarted by bringup got SIGTERM 1.3 s later, while still importing,
and died of it (exit -15, outputs never made safe). The contract (m4k_rt.stopsignals): a
supervisor starts m4k children with the stop signals blocked; each executable installs its
handlers first thing and unblocks them, and a stop that lands anywhere in start-up takes the
clean path: exit code 0 and a "stopped (SIGTERM)" line.

The signal is sent at deterministic points: the instant after spawn (the race of the issue),
and after a start-up line the process prints (config read, children starting). No sleeps.
"""

import os
import signal
import time

import pytest
from wsenv import LineWatch, stack_env
import yaml

from m4k_bringup.bringup import bringup_argv
from m4k_rt.stopsignals import blocked_stop_signals
from m4k_testing import child_pids

OVERLAY = {'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10}}
TIMEOUT_S = 60.0  # generous: start-up of an rclpy process under load takes seconds

EXECUTABLES = {
    'rt_core': (['python', '-m', 'm4k_rt.rt_core'], 'rt_core: stopped (SIGTERM)'),
    'driver_host': (['python', '-m', 'm4k_drivers.host'],
                    'driver_host: stopped (SIGTERM); outputs safe'),
    'bridge': (['python', '-m', 'm4k_bridge.node'], 'm4k_bridge: stopped (SIGTERM)'),
    'bringup': (bringup_argv() + ['--no-status'],
                'bringup: stopped (SIGTERM)'),
    'baseline': (['python', '-m', 'm4k_bench.baseline', '--duration', '60'],
                 'baseline: stopped (SIGTERM); motors safe'),
    'sim_robot': (['python', '-m', 'm4k_drivers.sim_robot'], 'sim_robot: stopped (SIGTERM)'),
}
BRINGUP_CHILDREN = ('bridge', 'driver_host', 'rt_core', 'sim_robot')


def _overlay(tmp_path):
    path = tmp_path / 'overlay.yaml'
    path.write_text(yaml.safe_dump(OVERLAY))
    return str(path)


def _argv(name, tmp_path, runtime_dir):
    argv = list(EXECUTABLES[name][0])
    if name in ('rt_core', 'bringup', 'sim_robot'):
        argv += ['--config', _overlay(tmp_path)]
    if name == 'driver_host':
        argv += ['--runtime-dir', runtime_dir]
    return argv


def _start(procs, name, tmp_path, runtime_dir, blocked):
    kwargs = {'env': stack_env(runtime_dir), 'stdout': open(os.devnull, 'w')}
    if blocked:  # as bringup starts its children
        with blocked_stop_signals():
            p = procs.start(_argv(name, tmp_path, runtime_dir), **kwargs)
    else:
        p = procs.start(_argv(name, tmp_path, runtime_dir), **kwargs)
    kwargs['stdout'].close()
    return p, LineWatch(p.stderr, TIMEOUT_S)


def _assert_clean_stop(p, watch, name):
    rc = p.wait(TIMEOUT_S)
    err = watch.close()
    assert rc == 0, '{} exit code {}:\n{}'.format(name, rc, err[-3000:])
    assert EXECUTABLES[name][1] in err, err[-3000:]
    return err


@pytest.mark.parametrize('name', sorted(EXECUTABLES))
def test_sigterm_right_after_spawn_stops_cleanly(procs, tmp_path, m4k_runtime_dir, name):
    p, watch = _start(procs, name, tmp_path, m4k_runtime_dir, blocked=True)
    p.send_signal(signal.SIGTERM)  # the interpreter has not even started its imports
    _assert_clean_stop(p, watch, name)


@pytest.mark.parametrize('name, line', [
    ('rt_core', 'rt_core: '),                 # the hardening report: ports not bound yet
    ('rt_core', 'running '),                  # tasks started
    ('driver_host', 'serving '),              # services started
    ('bringup', 'starting '),                 # then: all its children spawned
])
def test_sigterm_after_a_startup_line_stops_cleanly(procs, tmp_path, m4k_runtime_dir, name,
                                                     line):
    p, watch = _start(procs, name, tmp_path, m4k_runtime_dir, blocked=False)
    watch.wait_for(line)
    if name == 'bringup':  # all children exist (bringup waits for sim_robot's readiness)
        deadline = time.monotonic() + TIMEOUT_S
        while len(child_pids(p.pid)) < len(BRINGUP_CHILDREN) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(child_pids(p.pid)) == len(BRINGUP_CHILDREN)
    p.send_signal(signal.SIGTERM)
    err = _assert_clean_stop(p, watch, name)
    if name == 'bringup':  # its children got SIGTERM while starting up: each stopped cleanly
        for child in BRINGUP_CHILDREN:
            assert 'bringup: {} stopped (exit code 0)'.format(child) in err, err[-3000:]
