"""Real motors without their protections are refused at configuration load: exit 2, one line.

driver_host (serving the stack) and sim_robot are started as processes with the bad overlay;
each must exit 2 naming the field and its value, before any device is touched.  The override
``devices.motor.external_stop: true`` accepts the heartbeat and the timeout being off (the
hardware stops the motors), never a simulated sensor beside real motors.
"""

import pytest
from wsenv import stack_env
import yaml

REAL_MOTOR = {'backend': 'real', 'left_dac': '/nonexistent/spidev0.0',
              'right_dac': '/nonexistent/spidev0.1', 'left_enc': '/nonexistent/spidev1.0',
              'right_enc': '/nonexistent/spidev1.1'}
REAL_SENSORS = {'lrf': {'backend': 'real', 'port': '/nonexistent/ttyACM0'},
                'imu': {'backend': 'real', 'bus': '/nonexistent/i2c-1'},
                'sonar': {'backend': 'iio', 'device': '/nonexistent/iio:device0'}}


def _overlay(tmp_path, devices, control=None):
    doc = {'devices': devices}
    if control is not None:
        doc['control'] = control
    path = tmp_path / 'overlay.yaml'
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def _run(procs, module, overlay, runtime_dir):
    proc = procs.start(['python', '-m', module, '--runtime-dir', runtime_dir,
                        '--overlay', overlay], env=stack_env(runtime_dir))
    out, err = proc.communicate(timeout=60)
    return proc.returncode, err


def _lines(err):
    return [line for line in err.splitlines() if line.strip()]


@pytest.mark.parametrize('module', ['m4k_drivers.host', 'm4k_drivers.sim_robot'])
@pytest.mark.parametrize('sensor', ['sonar', 'lrf', 'imu'])
def test_real_motors_with_a_simulated_guard_sensor_exit_2(procs, tmp_path, m4k_runtime_dir,
                                                          module, sensor):
    devices = {'motor': REAL_MOTOR} | {k: v for k, v in REAL_SENSORS.items() if k != sensor}
    devices[sensor] = {'backend': 'sim'}
    code, err = _run(procs, module, _overlay(tmp_path, devices), m4k_runtime_dir)
    assert code == 2, err
    assert len(_lines(err)) == 1, err
    assert f"devices.{sensor}.backend: 'sim' refused with real motors" in err


@pytest.mark.parametrize('module', ['m4k_drivers.host', 'm4k_drivers.sim_robot'])
@pytest.mark.parametrize('motor, control, field', [
    ({'heartbeat': False}, None, 'devices.motor.heartbeat: False refused'),
    ({}, {'cmd_vel_timeout': 0}, 'control.cmd_vel_timeout: 0 refused'),
    ({}, {'cmd_vel_timeout': 0.0}, 'control.cmd_vel_timeout: 0.0 refused'),
])
def test_real_motors_without_heartbeat_or_timeout_exit_2(procs, tmp_path, m4k_runtime_dir,
                                                         module, motor, control, field):
    devices = {'motor': REAL_MOTOR | motor} | REAL_SENSORS
    code, err = _run(procs, module, _overlay(tmp_path, devices, control), m4k_runtime_dir)
    assert code == 2, err
    assert len(_lines(err)) == 1 and field in err, err


def test_external_stop_accepts_the_heartbeat_off_but_not_a_simulated_sensor(
        procs, tmp_path, m4k_runtime_dir):
    # sim_robot with every device real has nothing to simulate: it starts (and is stopped).
    devices = {'motor': REAL_MOTOR | {'heartbeat': False, 'external_stop': True}} | REAL_SENSORS
    proc = procs.start(['python', '-m', 'm4k_drivers.sim_robot', '--runtime-dir',
                        m4k_runtime_dir, '--overlay', _overlay(tmp_path, devices,
                                                               {'cmd_vel_timeout': 0})],
                       env=stack_env(m4k_runtime_dir))
    from m4k_drivers.sim_robot import wait_ready
    assert wait_ready(m4k_runtime_dir, 30.0), proc.stderr.read() if proc.poll() else ''
    assert procs.stop(proc) == 0
    devices['sonar'] = {'backend': 'sim'}
    code, err = _run(procs, 'm4k_drivers.sim_robot', _overlay(tmp_path, devices),
                     m4k_runtime_dir)
    assert code == 2 and "devices.sonar.backend: 'sim' refused" in err, err

