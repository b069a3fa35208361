"""bringup: pure helpers, configuration errors, single instance, supervision, ordered stop."""

import ast
import os
import py_compile
import re
import signal
import sys
import time
import types

import pytest
from wsenv import ROOT, stack_env
import yaml

from m4k_bridge import params as bridge_params
from m4k_bringup import bringup
from m4k_testing import child_pids
from m4k_testing.ros import call

LAUNCH = os.path.join(ROOT, 'src', 'm4k_bringup', 'launch', 'm4k.launch.py')
BASE_OVERLAY = {'runtime': {'mlockall': False, 'cpu_dma_latency': False,
                            'start_delay_ms': 10}}


def write_overlay(tmp_path, extra=None, name='overlay.yaml'):
    doc = dict(BASE_OVERLAY)
    doc.update(extra or {})
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def start_bringup(procs, tmp_path, runtime_dir, overlay, tag='bringup', extra=()):
    out = open(tmp_path / (tag + '.out'), 'w')
    err = open(tmp_path / (tag + '.err'), 'w')
    try:
        return procs.start(bringup.bringup_argv(str(overlay)) + ['--status-interval', '1',
                                                                 *extra],
                           env=stack_env(runtime_dir), stdout=out, stderr=err)
    finally:
        out.close()
        err.close()


def wait_for(predicate, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError('timed out after {} s waiting for {}'.format(timeout, what))


def cmdline(pid):
    try:
        with open('/proc/{}/cmdline'.format(pid), 'rb') as f:
            return f.read().replace(b'\0', b' ').decode()
    except OSError:
        return ''


# --- pure helpers --------------------------------------------------------------------------------

def test_restart_delay_doubles_and_is_capped():
    assert bringup.restart_delay(0) == 0.0
    assert [bringup.restart_delay(n) for n in (1, 2, 3, 4)] == [0.5, 1.0, 2.0, 4.0]
    assert bringup.restart_delay(20) == 10.0


def test_bridge_overlay_coerces_integers_and_adds_the_runtime_dir():
    doc = {'m4k_bridge': {'ros__parameters': {
        'stats_window': 20, 'topics': {'odom': 'o'},
        'odom_pose_covariance_diagonal': [0, 0, 1, 0, 0, 0]}}}
    out = bringup.bridge_overlay(doc, '/run/x')['m4k_bridge']['ros__parameters']
    assert out['stats_window'] == 20.0 and isinstance(out['stats_window'], float)
    assert out['topics'] == {'odom': 'o'} and out['runtime_dir'] == '/run/x'
    assert all(isinstance(v, float) for v in out['odom_pose_covariance_diagonal'])


def test_bridge_overlay_names_a_bad_field():
    doc = {'m4k_bridge': {'ros__parameters': {'rt_stale_timeout': -3}}}
    with pytest.raises(bridge_params.ParamError) as info:
        bringup.bridge_overlay(doc, '/run/x')
    assert info.value.name == 'rt_stale_timeout'


def test_bridge_overlay_refuses_a_derived_value_set_beside_its_source():
    doc = {'m4k_bridge': {'ros__parameters': {'cmd_vel_timeout': 1.0}}}
    with pytest.raises(bridge_params.ParamError) as info:
        bringup.bridge_overlay(doc, '/run/x')
    assert info.value.name == 'cmd_vel_timeout'
    assert 'derived from control.cmd_vel_timeout' in str(info.value)


def test_bridge_overlay_takes_timeout_and_limits_from_the_control_section(tmp_path):
    from m4k_rt import config
    overlay = write_overlay(tmp_path, {'control': {
        'cmd_vel_timeout': 0.8, 'linear': {'max_velocity': 1.25}}})
    out = bringup.bridge_overlay(config.load_layered(overlay),
                                 '/run/x')['m4k_bridge']['ros__parameters']
    assert out['cmd_vel_timeout'] == 0.8 and out['max_linear_velocity'] == 1.25
    assert out['max_angular_velocity'] == config.load_layered()['control']['angular'][
        'max_velocity']
    assert out['ports'] == {r: r for r in bridge_params.PORT_ROLES}


def test_resolve_command_falls_back_to_python_m():
    spec = bringup.ChildSpec('x', 'no_such_pkg_m4k', 'x', 'm4k_rt.x', ('--a',))
    assert bringup.resolve_command(spec) == [sys.executable, '-m', 'm4k_rt.x', '--a']


def test_child_specs_pass_the_overlay_the_way_each_child_takes_it():
    sim, rt, host, bridge = bringup.child_specs('/o.yaml', '/tmp/p.yaml', '/c/bridge.yaml',
                                                '/run/m')
    assert sim.name == 'sim_robot' and sim.ready is not None    # started first, waited for
    assert sim.args == ('--runtime-dir', '/run/m', '--overlay', '/o.yaml')
    assert [s.name for s in bringup.child_specs(None, '/p', '/b', '/r', sim=False)] == [
        'rt_core', 'driver_host', 'bridge']
    assert rt.args == ('--config', '/o.yaml')
    assert host.args == ('--runtime-dir', '/run/m', '--overlay', '/o.yaml')
    assert bridge.args[-4:] == ('--params-file', '/c/bridge.yaml', '--params-file',
                                '/tmp/p.yaml')


def test_the_live_view_is_the_last_child_and_listens_where_it_is_told():
    specs = bringup.child_specs(None, '/p', '/b', '/r', sim=False, foxglove='127.0.0.1')
    assert [s.name for s in specs] == ['rt_core', 'driver_host', 'bridge', 'foxglove']
    assert specs[-1].module == 'm4k_bridge.foxglove.node'     # stopped first, before the bridge
    assert specs[-1].args == ('--ros-args', '-p', 'address:=127.0.0.1', '-p', 'port:=8765')
    assert bringup._parse_args([]).foxglove is False
    assert bringup._parse_args(['--foxglove']).foxglove_address == '127.0.0.1'


def _timing(samples, avg, jmax):
    return types.SimpleNamespace(samples=samples, avg=avg, max=jmax)


def test_format_status_shows_tasks_rates_jitter_guard_restarts():
    task = types.SimpleNamespace(name='actuator', period_measured=_timing(10, 0.01, 0.01),
                                 jitter=_timing(10, 0.0, 0.0004))
    lrf = types.SimpleNamespace(name='lrf', period_measured=_timing(5, 0.2, 0.2),
                                jitter=_timing(5, 0.0, 0.0021))
    rt = types.SimpleNamespace(tasks=[task, lrf], collision_guard_active=True, rt_link_age=0.1)
    line = bringup.format_status(rt, {'actuator': 0, 'lrf': 1}, 3, 75.0, ['bridge'])
    assert line.startswith('m4k 1:15 | tasks 1/2 OK | act 100.0 lrf 5.0 Hz')
    assert 'worst jitter 2.10 ms (lrf)' in line and 'guard ACTIVE' in line
    assert 'restarts 3' in line and 'down: bridge' in line and '\n' not in line
    assert 'waiting for rt_status' in bringup.format_status(None, {}, 0, 1.0)


def test_lock_owner_sees_a_held_flock(tmp_path):
    import fcntl
    assert bringup.lock_owner(str(tmp_path)) is None
    path = tmp_path / 'rt_core.lock'
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        os.write(fd, b'4242\n')
        assert bringup.lock_owner(str(tmp_path)) is None   # file exists but nobody holds it
        fcntl.flock(fd, fcntl.LOCK_EX)
        assert bringup.lock_owner(str(tmp_path)) == '4242'
    finally:
        os.close(fd)


def test_launch_file_compiles_and_defines_the_entry_point(tmp_path):
    py_compile.compile(LAUNCH, cfile=str(tmp_path / 'launch.pyc'), doraise=True)
    with open(LAUNCH, encoding='utf-8') as f:
        tree = ast.parse(f.read())
    names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert 'generate_launch_description' in names
    text = ast.unparse(tree)
    # What it starts comes from bringup's own plan, not a copy of it.
    for shared in ('bringup.child_specs', 'bringup.bridge_overlay', "'bridge.yaml'"):
        assert shared in text


def test_bridge_overlay_derives_the_description_and_frames_from_the_configuration():
    from m4k_rt import config, description
    doc = config.deep_merge(config.load_layered(), {'robot': {'sensors': {
        'laser': {'frame': 'urg', 'pose': [0.1, 0.0, 0.3, 0.0, 0.0, 0.0]}}}})
    out = bringup.bridge_overlay(doc, '/run/x')['m4k_bridge']['ros__parameters']
    assert out['laser_frame'] == 'urg' and out['imu_frame'] == 'imu_link'
    laser = {j.child: j for j in description.fixed_joints(out['robot_description'])}['urg']
    assert laser.xyz == pytest.approx((0.1, 0.0, 0.3))
    # The frame has one source: the overlay's m4k_bridge section may not restate it.
    doc['m4k_bridge'] = {'ros__parameters': {'laser_frame': 'mine'}}
    with pytest.raises(bridge_params.ParamError, match='robot.sensors.laser.frame'):
        bringup.bridge_overlay(doc, '/run/x')


# --- processes ---------------------------------------------------------------------------------

def test_bridge_with_a_bad_parameter_file_exits_2_naming_the_field(procs, tmp_path,
                                                                     m4k_runtime_dir):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('m4k_bridge:\n  ros__parameters:\n    cmd_vel_timeout: -4.0\n')
    p = procs.start(['python', '-m', 'm4k_bridge.node', '--ros-args', '--params-file',
                     str(bad)], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=30)
    assert p.returncode == 2, err
    assert "parameter 'cmd_vel_timeout'" in err and 'must be in 0..60' in err


def test_bridge_with_a_misspelt_parameter_exits_2(procs, tmp_path, m4k_runtime_dir):
    bad = tmp_path / 'typo.yaml'
    bad.write_text('m4k_bridge:\n  ros__parameters:\n    max_linear_velocty: 1.0\n')
    p = procs.start(['python', '-m', 'm4k_bridge.node', '--ros-args', '--params-file',
                     str(bad)], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=30)
    assert p.returncode == 2 and 'max_linear_velocty' in err and 'unknown parameter' in err


def _remote_parameters(names, timeout=30.0):
    """Return the m4k_bridge parameter values for ``names``, asked over DDS (rcl_interfaces)."""
    from rcl_interfaces.srv import GetParameters
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import parameter_value_to_python
    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('param_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        client = node.create_client(GetParameters, '/m4k_bridge/get_parameters')
        assert client.wait_for_service(timeout_sec=timeout), 'no /m4k_bridge/get_parameters'
        reply = call(client, GetParameters.Request(names=list(names)),
                     lambda t: executor.spin_once(timeout_sec=t), timeout,
                     '/m4k_bridge/get_parameters')
        values = [parameter_value_to_python(v) for v in reply.values]
        return dict(zip(names, values, strict=True))
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_bridge_started_by_hand_takes_the_derived_values_from_the_layered_configuration(
        procs, tmp_path, m4k_runtime_dir):
    # ros2 run m4k_bridge bridge, no parameters: the command timeout, limits and frames still come
    # from the configuration (here a config directory whose control and robot sections differ).
    import shutil
    conf = tmp_path / 'config'
    shutil.copytree(os.path.join(ROOT, 'config'), conf)
    control = yaml.safe_load((conf / 'control.yaml').read_text())
    control['control']['cmd_vel_timeout'] = 0.8
    control['control']['angular']['max_velocity'] = 1.1
    (conf / 'control.yaml').write_text(yaml.safe_dump(control))
    robot = yaml.safe_load((conf / 'robot.yaml').read_text())
    robot['robot']['sensors']['laser']['frame'] = 'urg_link'
    (conf / 'robot.yaml').write_text(yaml.safe_dump(robot))
    env = dict(stack_env(m4k_runtime_dir), M4K_CONFIG_DIR=str(conf))
    p = procs.start(['python', '-m', 'm4k_bridge.node'], env=env)
    names = ['cmd_vel_timeout', 'max_angular_velocity', 'max_linear_velocity', 'laser_frame',
             'ports.cmd']
    got = _remote_parameters(names)
    assert p.poll() is None
    assert got == {'cmd_vel_timeout': 0.8, 'max_angular_velocity': 1.1,
                   'max_linear_velocity': control['control']['linear']['max_velocity'],
                   'laser_frame': 'urg_link', 'ports.cmd': 'cmd'}


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_bringup_gives_the_bridge_the_overlays_command_timeout_and_limits(
        procs, tmp_path, m4k_runtime_dir):
    # One source: control.cmd_vel_timeout (and the speed limit) changed in the overlay reach the
    # running bridge's parameters, with nothing written in an m4k_bridge section.
    overlay = write_overlay(tmp_path, {'control': {'cmd_vel_timeout': 0.8,
                                                   'linear': {'max_velocity': 1.25}}})
    p = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, extra=['--no-status'])
    got = _remote_parameters(['cmd_vel_timeout', 'max_linear_velocity'], timeout=60.0)
    assert got == {'cmd_vel_timeout': 0.8, 'max_linear_velocity': 1.25}
    p.send_signal(signal.SIGTERM)
    assert p.wait(40) == 0, (tmp_path / 'bringup.err').read_text()[-2000:]


@pytest.mark.parametrize('extra, field', [
    ({'m4k_bridge': {'ros__parameters': {'odom_frame': ''}}}, 'odom_frame'),
    ({'tasks': {'led': {'priority': 120}}}, 'tasks.led.priority'),
    ({'control': {'linear': {'max_velocity': -1}}}, 'control.linear.max_velocity: must be > 0'),
    ({'m4k_bridge': {'ros__parameters': {'cmd_vel_timeout': 1.0}}},
     'derived from control.cmd_vel_timeout'),
])
def test_bringup_refuses_a_bad_overlay_naming_the_field(procs, tmp_path, m4k_runtime_dir,
                                                         extra, field):
    overlay = write_overlay(tmp_path, extra)
    p = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay)
    assert p.wait(30) == 2
    err = (tmp_path / 'bringup.err').read_text()
    assert field in err and 'config error' in err
    assert 'starting' not in err  # refused before any child started


def test_second_bringup_is_refused_and_first_stops_in_order_after_a_restart(
        procs, tmp_path, m4k_runtime_dir):
    overlay = write_overlay(tmp_path)
    first = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, 'first', ['--no-status'])
    wait_for(lambda: bringup.lock_owner(m4k_runtime_dir) is not None, 30, 'rt_core lock')

    second = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, 'second')
    assert second.wait(30) == 2
    err2 = (tmp_path / 'second.err').read_text()
    assert 'another m4k stack owns {}'.format(m4k_runtime_dir) in err2

    # Supervision: a crashed driver host is restarted and the restart is reported.
    def host_pid():
        pids = [p for p in child_pids(first.pid) if 'm4k_drivers.host' in cmdline(p)]
        return pids[0] if pids else None

    def sim_pid():
        pids = [p for p in child_pids(first.pid) if 'm4k_drivers.sim_robot' in cmdline(p)]
        return pids[0] if pids else None

    wait_for(lambda: host_pid() is not None, 20, 'driver_host')
    sim = sim_pid()
    assert sim is not None
    old = host_pid()
    os.kill(old, signal.SIGKILL)
    wait_for(lambda: host_pid() not in (None, old), 20, 'driver_host restart')
    err1 = lambda: (tmp_path / 'first.err').read_text()  # noqa: E731
    wait_for(lambda: 'driver_host restarted (restart 1)' in err1(), 10, 'restart report')
    assert re.search(r'driver_host exited with code -9 after [\d.]+ s; restart 1', err1())

    assert sim_pid() == sim      # the robot (the world) outlived the driver host
    kids = child_pids(first.pid)
    assert len(kids) == 4
    first.send_signal(signal.SIGTERM)
    assert first.wait(40) == 0
    text = err1()
    order = [text.index('bringup: {} stopped'.format(n))
             for n in ('bridge', 'driver_host', 'rt_core', 'sim_robot')]
    assert order == sorted(order), text[-2000:]
    for name in ('bridge', 'driver_host', 'rt_core', 'sim_robot'):   # each one shut down cleanly
        assert 'bringup: {} stopped (exit code 0)'.format(name) in text, text[-3000:]
    for pid in kids:
        assert not os.path.exists('/proc/{}'.format(pid)) or 'Z' in open(
            '/proc/{}/stat'.format(pid)).read().split(')')[-1][:3]
    assert bringup.lock_owner(m4k_runtime_dir) is None


def test_plain_status_lines_when_stdout_is_not_a_tty(procs, tmp_path, m4k_runtime_dir):
    overlay = write_overlay(tmp_path)
    p = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay)
    out = lambda: (tmp_path / 'bringup.out').read_text()  # noqa: E731
    wait_for(lambda: re.search(r'tasks \d/6 OK', out()), 40, 'a status line with 6 tasks')
    p.send_signal(signal.SIGINT)
    assert p.wait(40) == 0
    err = (tmp_path / 'bringup.err').read_text()
    assert 'bringup: bridge stopped (exit code 0)' in err, err[-3000:]
    lines = [ln for ln in out().splitlines() if 'tasks' in ln]
    assert lines and '\r' not in out() and all(ln.startswith('m4k ') for ln in lines)
    assert any(re.search(r'act \d+\.\d .* Hz \| worst jitter [\d.]+ ms', ln) for ln in lines)



def test_the_live_view_takes_a_parameter_file_and_bringup_checks_it_first(procs, tmp_path):
    specs = bringup.child_specs(None, '/p', '/b', '/r', sim=False, foxglove='0.0.0.0',
                                foxglove_params='/f.yaml')
    assert specs[-1].args == ('--ros-args', '--params-file', '/f.yaml', '-p',
                              'address:=0.0.0.0', '-p', 'port:=8765')
    # A misspelt key would be ignored by rclpy (a LAN live view without its token): refused.
    bad = tmp_path / 'live.yaml'
    bad.write_text('m4k_foxglove:\n  ros__parameters:\n    token_fle: /x\n')
    p = procs.start(bringup.bringup_argv() + ['--foxglove', '--foxglove-params', str(bad),
                                              '--no-status'], env=stack_env(str(tmp_path / 'rt')))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert "unknown parameter 'token_fle'" in err
