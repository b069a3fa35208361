"""Refusals at start-up, through the real command lines.

* A duplicate key in any configuration YAML (the overlay of bringup / rt_core / driver_host,
  a devices file, a bridge parameter file) exits 2 naming the key and its line.
* A standalone driver host or bridge checks the runtime directory as the RT side does before
  it links anything there: a directory others may write, a symlink or one owned by another
  user exits 2 naming the directory and why.
"""

import os

import pytest
from wsenv import stack_env

from m4k_bringup.bringup import bringup_argv

DUP = 'control:\n  cmd_vel_timeout: 0.5\n  odom_every_n: 5\n  cmd_vel_timeout: 0.2\n'
WHY = "duplicate key 'cmd_vel_timeout' at line 4 (first given at line 2)"


@pytest.mark.parametrize('argv', [
    [*bringup_argv(), '--no-status', '--config'],
    ['python', '-m', 'm4k_rt.rt_core', '--config'],
    ['python', '-m', 'm4k_drivers.host', '--overlay'],
], ids=['bringup', 'rt_core', 'driver_host'])
def test_a_duplicate_key_in_the_overlay_exits_2_naming_the_key_and_line(procs, tmp_path,
                                                                         m4k_runtime_dir,
                                                                         argv):
    bad = tmp_path / 'bad.yaml'
    bad.write_text(DUP)
    p = procs.start(argv + [str(bad)], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert WHY in err and str(bad) in err, err


def test_a_duplicate_key_in_a_devices_file_exits_2(procs, tmp_path, m4k_runtime_dir):
    bad = tmp_path / 'devices.yaml'
    bad.write_text('devices:\n  imu:\n    backend: sim\n  imu:\n    backend: real\n')
    p = procs.start(['python', '-m', 'm4k_drivers.host', '--config', str(bad)],
                    env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert "duplicate key 'imu' at line 4 (first given at line 2)" in err, err


def test_a_duplicate_key_in_a_bridge_parameter_file_exits_2(procs, tmp_path, m4k_runtime_dir):
    bad = tmp_path / 'params.yaml'
    bad.write_text('m4k_bridge:\n  ros__parameters:\n    odom_frame: odom\n'
                   '    odom_frame: world\n')
    p = procs.start(['python', '-m', 'm4k_bridge.node', '--ros-args', '--params-file',
                     str(bad)], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert "duplicate key 'odom_frame' at line 4 (first given at line 3)" in err, err


def _bad_runtime_dirs(tmp_path):
    wide = tmp_path / 'wide'
    wide.mkdir()
    os.chmod(wide, 0o777)
    real = tmp_path / 'real'
    real.mkdir(mode=0o700)
    link = tmp_path / 'link'
    link.symlink_to(real)
    foreign = tmp_path / 'foreign'
    foreign.mkdir(mode=0o700)
    os.chown(foreign, 54321, -1)
    return [(wide, 'wider than 0700'), (link, 'symlinks are refused'),
            (foreign, 'owned by uid 54321')]


@pytest.mark.needs_root('chown to another uid')
def test_a_standalone_driver_host_refuses_a_runtime_directory_the_rt_side_would(
        procs, tmp_path, m4k_runtime_dir):
    for path, why in _bad_runtime_dirs(tmp_path):
        p = procs.start(['python', '-m', 'm4k_drivers.host', '--runtime-dir', str(path)],
                        env=stack_env(m4k_runtime_dir))
        _, err = p.communicate(timeout=60)
        assert p.returncode == 2, err
        assert why in err and str(path) in err, err


@pytest.mark.needs_root('chown to another uid')
def test_a_standalone_bridge_refuses_a_runtime_directory_the_rt_side_would(
        procs, tmp_path, m4k_runtime_dir):
    for path, why in _bad_runtime_dirs(tmp_path):
        p = procs.start(['python', '-m', 'm4k_bridge.node', '--ros-args', '-p',
                         'runtime_dir:={}'.format(path)], env=stack_env(m4k_runtime_dir))
        _, err = p.communicate(timeout=60)
        assert p.returncode == 2, err
        assert "parameter 'runtime_dir'" in err and why in err, err


@pytest.mark.parametrize('args, why', [
    (['-p', 'token_file:=/nonexistent/token'], "token_file '/nonexistent/token': cannot open"),
    (['-p', "allowed_origins:=['app.foxglove.dev']"], "'app.foxglove.dev' is not scheme://"),
    (['-p', 'max_clients:=0'], 'max_clients out of range'),
], ids=['token_file', 'allowed_origins', 'max_clients'])
def test_the_live_view_refuses_a_bad_access_setting_with_exit_2(procs, m4k_runtime_dir,
                                                                args, why):
    p = procs.start(['python', '-m', 'm4k_bridge.foxglove.node', '--ros-args', '-p',
                     'port:=0', *args], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert why in err, err


def test_the_live_view_refuses_a_parameter_file_with_a_misspelt_key(procs, tmp_path,
                                                                    m4k_runtime_dir):
    bad = tmp_path / 'live.yaml'
    bad.write_text('m4k_foxglove:\n  ros__parameters:\n    token_fle: /x\n')
    p = procs.start(['python', '-m', 'm4k_bridge.foxglove.node', '--ros-args', '--params-file',
                     str(bad)], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2, err
    assert "unknown parameter 'token_fle'" in err, err


# --- every configuration file through the one loader (m4k_rt.yamlload) -----------------------

NOT_UTF8 = b'control:\n  cmd_vel_timeout: 0.5\n  # caf\xe9 in Latin-1\n'
DEEP = 'a: ' + '[' * 200 + ']' * 200 + '\n'
BRIDGE = 'm4k_bridge:\n  ros__parameters:\n'
FOX = 'm4k_foxglove:\n  ros__parameters:\n'


def _write(path, body):
    (path.write_bytes if isinstance(body, bytes) else path.write_text)(body)
    return str(path)


def _prefixed(prefix, body):
    if isinstance(body, bytes):
        return prefix.encode() + b'    x: 1\n' + body
    return prefix + '    ' + body


# Every path a configuration file takes at start-up: (argv before the file, the section the
# bad body goes under).
PATHS = {
    'bringup --config': ([*bringup_argv(), '--no-status', '--config'], ''),
    'rt_core --config': (['python', '-m', 'm4k_rt.rt_core', '--config'], ''),
    'driver_host --overlay': (['python', '-m', 'm4k_drivers.host', '--overlay'], ''),
    'bridge --params-file': (['python', '-m', 'm4k_bridge.node', '--ros-args',
                              '--params-file'], BRIDGE),
    'bringup --namespace --bridge-params': (
        [*bringup_argv(), '--no-status', '--namespace', 'r1', '--bridge-params'], BRIDGE),
    'bringup --robot --bridge-params': (
        [*bringup_argv(), '--no-status', '--robot', 'r1', '--bridge-params'], BRIDGE),
    'foxglove --params-file': (['python', '-m', 'm4k_bridge.foxglove.node', '--ros-args',
                                '--params-file'], FOX),
    'bringup --foxglove-params': ([*bringup_argv(), '--no-status', '--foxglove',
                                   '--foxglove-params'], FOX),
}


@pytest.mark.parametrize('kind', ['not_utf8', 'deep'])
@pytest.mark.parametrize('path', sorted(PATHS))
def test_a_file_not_utf8_or_nested_too_deep_exits_2_on_every_path(procs, tmp_path,
                                                                   m4k_runtime_dir, path,
                                                                   kind):
    argv, section = PATHS[path]
    body = NOT_UTF8 if kind == 'not_utf8' else DEEP
    if section:
        body = _prefixed(section, body)
    bad = _write(tmp_path / 'bad.yaml', body)
    p = procs.start(argv + [bad], env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=120)
    assert p.returncode == 2, err
    assert 'Traceback' not in err, err
    why = 'not UTF-8 text: byte 0xe9' if kind == 'not_utf8' else 'nested deeper than 64'
    assert why in err, err


@pytest.mark.parametrize('flag', [['--robot', 'r1'], ['--namespace', 'r1']])
def test_a_duplicate_key_in_a_namespaced_bridge_parameter_file_exits_2(procs, tmp_path,
                                                                        m4k_runtime_dir, flag):
    # The namespacing step rewrites this file for /r1/m4k_bridge; it used to re-read it with
    # plain PyYAML first, which kept 0.9 without a word.
    bad = _write(tmp_path / 'params.yaml', BRIDGE + '    max_linear_velocity: 0.2\n'
                 '    max_linear_velocity: 0.9\n')
    p = procs.start([*bringup_argv(), '--no-status', *flag, '--bridge-params', bad],
                    env=stack_env(m4k_runtime_dir))
    _, err = p.communicate(timeout=120)
    assert p.returncode == 2, err
    assert "duplicate key 'max_linear_velocity' at line 4 (first given at line 3)" in err, err
    assert bad in err
