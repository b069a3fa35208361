"""m4k_drivers.safety: which mixes of real motors and other devices are refused (pure)."""

from m4k_drivers.safety import unsafe_mix

REAL_MOTOR = {'backend': 'real', 'left_dac': '/dev/spidev0.0', 'right_dac': '/dev/spidev0.1',
              'left_enc': '/dev/spidev1.0', 'right_enc': '/dev/spidev1.1'}
REAL_SENSORS = {'lrf': {'backend': 'real', 'port': '/dev/ttyACM0'},
                'imu': {'backend': 'real', 'bus': 1},
                'sonar': {'backend': 'gpio', 'chip': '/dev/gpiochip0', 'trigger_line': 23,
                          'echo_line': 24}}


def test_a_disabled_simulated_sensor_is_not_refused():
    devices = {'motor': REAL_MOTOR} | REAL_SENSORS
    devices['lrf'] = {'backend': 'sim', 'enabled': False}
    assert unsafe_mix({'devices': devices, 'control': {'cmd_vel_timeout': 0.5}}) is None
    assert unsafe_mix({'devices': {'motor': {'backend': 'sim', 'heartbeat': False}},
                       'control': {'cmd_vel_timeout': 0}}) is None


def test_the_override_accepts_heartbeat_and_timeout_off_only():
    motor = REAL_MOTOR | {'heartbeat': False, 'external_stop': True}
    doc = {'devices': {'motor': motor} | REAL_SENSORS, 'control': {'cmd_vel_timeout': 0}}
    assert unsafe_mix(doc) is None
    doc['devices']['imu'] = {'backend': 'sim'}
    assert unsafe_mix(doc).startswith("devices.imu.backend: 'sim' refused")


def test_ldac_on_the_heartbeat_line_is_refused_at_build():
    import pytest

    from m4k_drivers import config as dconfig
    from m4k_drivers import registry
    section = REAL_MOTOR | {'ldac': 'gpio', 'ldac_chip': '/dev/gpiochip0', 'ldac_line': 25}
    cfg = dconfig.validate({'devices': {'motor': section}})
    with pytest.raises(ValueError, match=r'devices.motor.ldac_line: 25 is also the heartbeat'):
        registry.create('motor', cfg.devices['motor'], registry.BuildContext())
    cfg = dconfig.validate({'devices': {'motor': section | {'ldac_line': 22}}})
    registry.create('motor', cfg.devices['motor'], registry.BuildContext()).shutdown()
