"""Parameter files with wrong types, unknown keys, missing or impossible values.

Each case starts the real executable with one broken overlay and asserts the exit code (2:
configuration error, nothing started) and a message naming the field and the bad value --
teleop_tools' test_parameter_failures habit. No socket may be left in the runtime directory.
"""

import os
import subprocess
import sys

import pytest
from wsenv import stack_env

RT_CASES = [
    ('tasks: {actuator: {period_ms: fast}}',
     "tasks.actuator.period_ms: expected a number of ms > 0, got 'fast'"),
    ('tasks: {actuator: {colour: red}}', 'tasks.actuator.colour: unknown key'),
    ('runtime: {poolsz: 12.5}', 'runtime.poolsz: expected bytes in'),
    ('ports: {cmd: 99}', 'ports.cmd: expected a port number in 0..31, got 99'),
    ('tasks: {actuator: {ports: [nope]}}', "tasks.actuator.ports: unknown port label 'nope'"),
    ('runtime: [1, 2]', 'runtime: expected a mapping, got [1, 2]'),
    ('control: {cmd_vel_timeout: -1}', 'cmd_vel_timeout'),
    ('control: {linear: {max_velocity: .nan}}', 'max_velocity'),
    ('control: {linear: {max_acceleration: fast}}', 'max_acceleration'),
    ('tasks: {led: {priority: 120}}', 'tasks.led.priority: expected an int in 1..99, got 120'),
    ('[unclosed', 'o.yaml'),
]

HOST_CASES = [
    ('devices: {motor: {watchdog_periods: ten}}',
     "devices.motor.watchdog_periods: expected int, got 'ten'"),
    ('devices: {motor: {speed: 3}}', "devices.motor: unknown field(s) ['speed']"),
    ('devices: {imu: {backend: quantum}}',
     "devices.imu.backend: unknown backend 'quantum' for device 'imu'"),
    ('world: {seed: x}', "world.seed: expected an integer, got 'x'"),
]


def _run(argv, runtime_dir):
    return subprocess.run([sys.executable, *argv], env=stack_env(runtime_dir), capture_output=True,
                          text=True, timeout=60)


@pytest.mark.parametrize(('doc', 'message'), RT_CASES, ids=[c[0] for c in RT_CASES])
def test_rt_core_refuses_a_bad_parameter_file_naming_the_field(doc, message, tmp_path,
                                                               m4k_runtime_dir):
    over = tmp_path / 'o.yaml'
    over.write_text(doc + '\n')
    p = _run(['-m', 'm4k_rt.rt_core', '--config', str(over), '--duration', '0.1'],
             m4k_runtime_dir)
    assert p.returncode in (1, 2), p.stderr
    assert message in p.stderr, p.stderr
    assert 'Traceback' not in p.stderr
    left = [e for e in os.listdir(m4k_runtime_dir) if e.startswith('xddp')] \
        if os.path.isdir(m4k_runtime_dir) else []
    assert left == []


@pytest.mark.parametrize(('doc', 'message'), HOST_CASES, ids=[c[0] for c in HOST_CASES])
def test_driver_host_refuses_a_bad_parameter_file_naming_the_field(doc, message, tmp_path,
                                                                   m4k_runtime_dir):
    over = tmp_path / 'o.yaml'
    over.write_text(doc + '\n')
    p = _run(['-m', 'm4k_drivers.host', '--overlay', str(over)], m4k_runtime_dir)
    assert p.returncode == 2, p.stderr
    assert message in p.stderr, p.stderr
    assert 'Traceback' not in p.stderr
