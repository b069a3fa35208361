"""An engaged e-stop survives ``systemctl restart m4k``: the shipped unit's paths, the whole stack.

The unit (config/systemd/m4k.service) is parsed for its runtime and state directories and its
environment; both roots are moved under the test's directory. The stack (bringup) runs with
that environment, an operator engages the e-stop over ROS, the service stops as systemd stops
it (SIGTERM to bringup, then the runtime directory deleted: no RuntimeDirectoryPreserve=), and
starts again: rt_core must come up latched (its start-up line), the bridge must report the
latch and gate cmd_vel, and the simulator's ground truth must show no motion under a command.
"""

import os
import shutil
import signal

import pytest
from std_msgs.msg import Bool
from test_bringup import write_overlay
from test_stack_e2e import RosUser, START
from wsenv import ground_truth, ROOT, stack_env

from m4k_bringup.bringup import bringup_argv
from m4k_rt import estop_request

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process

UNIT = os.path.join(ROOT, 'config', 'systemd', 'm4k.service')


def _service(path):
    out, section = {}, None
    with open(path, encoding='utf-8') as f:
        for line in f:
            line = line.strip()
            if line.startswith('['):
                section = line.strip('[]')
            elif line and not line.startswith('#') and section == 'Service':
                key, _, value = line.partition('=')
                out.setdefault(key, []).append(value)
    return out


def _unit_env(tmp_path):
    """Return (environment, runtime dir, state dir) of the unit, its roots under tmp_path."""
    svc = _service(UNIT)
    env = dict(e.split('=', 1) for e in svc['Environment'])
    env['STATE_DIRECTORY'] = '/var/lib/' + svc['StateDirectory'][0]

    def host(path):
        for real, here in (('/run/', 'run'), ('/var/lib/', 'var/lib')):
            if path.startswith(real):
                return str(tmp_path / here / path[len(real):])
        raise AssertionError(path)
    for k in ('M4K_RUNTIME_DIR', 'M4K_STATE_DIR', 'STATE_DIRECTORY'):
        if k in env:
            env[k] = host(env[k])
    assert env['M4K_RUNTIME_DIR'] == host('/run/' + svc['RuntimeDirectory'][0])
    return env, env['M4K_RUNTIME_DIR'], estop_request.state_dir(env)


def _start(procs, tmp_path, env, overlay, tag):
    runtime = env['M4K_RUNTIME_DIR']
    os.makedirs(runtime, mode=0o700, exist_ok=True)          # systemd creates both, 0700
    os.makedirs(env['M4K_STATE_DIR'], mode=0o700, exist_ok=True)
    full = dict(stack_env(runtime), **{k: v for k, v in env.items()
                                       if k.startswith(('M4K_', 'STATE_'))})
    full['M4K_WORLD_REPORT'] = stack_env(runtime)['M4K_WORLD_REPORT']
    with open(tmp_path / f'{tag}.err', 'w') as err:
        return procs.start(bringup_argv(str(overlay)) + ['--no-status'], env=full, stdout=err,
                           stderr=err)


def test_an_engaged_e_stop_survives_a_service_restart_through_the_units_paths(procs, tmp_path):
    env, runtime, state = _unit_env(tmp_path)
    assert not state.startswith(runtime)
    overlay = write_overlay(tmp_path, {'world': {'start': START}})
    proc = _start(procs, tmp_path, env, overlay, 'first')
    user = RosUser()
    try:
        user.spin_until(lambda: user.got['rt_status'] or proc.poll() is not None, 60,
                        'the stack up')
        e_stop = user.publisher(Bool, 'e_stop')
        user.spin_until(lambda: user.got['rt_status'][-1].e_stop_active, 20,
                        'the latch engaged', each=lambda: e_stop.publish(Bool(data=True)),
                        period=0.25)
        assert estop_request.read_request(state).engaged is True
        # systemctl stop: SIGTERM (KillMode=mixed: to bringup), then the runtime dir goes
        proc.send_signal(signal.SIGTERM)
        proc.wait(40)
        shutil.rmtree(runtime)
        user.got['rt_status'].clear()
        proc = _start(procs, tmp_path, env, overlay, 'second')
        user.spin_until(lambda: len(user.got['rt_status']) > 2 or proc.poll() is not None, 60,
                        'the restarted stack reporting')
        assert user.got['rt_status'][-1].e_stop_active
        from geometry_msgs.msg import Twist
        cmd = user.publisher(Twist, 'cmd_vel')
        turn = Twist()
        turn.linear.x = 0.25
        start = ground_truth(runtime)
        user.spin_for(2.0, lambda: cmd.publish(turn), 0.05)
        end = ground_truth(runtime)
        assert start is not None and end is not None
        assert abs(end['pose'][0] - start['pose'][0]) < 0.005, (start, end)
    finally:
        user.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(40)
    log = (tmp_path / 'second.err').read_text()
    assert 'e-stop latch ENGAGED at start-up' in log, log[-3000:]
    assert estop_request.request_path(state) in log
