import ast
import inspect
import os

import pytest
import yaml

from m4k_drivers import config as dconfig
from m4k_drivers import motors, registry
from m4k_drivers.handler import DeviceIOError, DeviceNotFoundError, retry, RetryPolicy, State
from m4k_drivers.imu.handler import ImuHandler
from m4k_drivers.motors.handler import HANDLER_PARAMS, MotorHandler
from m4k_rt.config import load_layered, shipped_period_s


def test_registry_lists_backends_per_kind():
    assert registry.backends('motor') == ['real', 'sim']
    assert registry.backends('imu') == ['real', 'sim']
    assert registry.backends('sonar') == ['gpio', 'iio', 'real', 'sim']
    assert registry.backends('led') == ['led_class', 'led_class_rgb', 'pixel_spi', 'pwm', 'real',
                                        'sim']


def test_registry_unknown_backend_lists_valid_ones():
    with pytest.raises(registry.RegistryError,
                       match=r"unknown backend 'i2c' for device 'imu'; valid backends: "
                             r'real, sim'):
        registry.get('imu', 'i2c')
    with pytest.raises(registry.RegistryError, match="unknown device kind 'gps'"):
        registry.backends('gps')


def test_create_builds_handler_for_mixed_backends(sim_robot):
    cfg = dconfig.validate({'devices': {
        'motor': {'backend': 'sim'},
        'imu': {'backend': 'real', 'bus': 97},
    }})
    ctx = registry.BuildContext()
    motor = registry.create('motor', cfg.devices['motor'], ctx)
    imu = registry.create('imu', cfg.devices['imu'], ctx)
    assert isinstance(motor, MotorHandler) and isinstance(imu, ImuHandler)
    assert not ctx.has_world        # the sim motor talks to sim_robot, it has no world
    with pytest.raises(DeviceNotFoundError, match='/dev/i2c-97'):
        imu.configure()
    assert imu.state == State.ERROR
    motor.configure()
    motor.shutdown()


@pytest.mark.parametrize('devices, match', [
    ({'imu': {'backend': 'i2c'}},
     r"devices\.imu\.backend: unknown backend 'i2c' for device 'imu'; valid backends: real, sim"),
    ({'imu': {}}, r'devices\.imu\.backend: missing; valid backends: real, sim'),
    ({'imu': {'backend': 'real'}}, r"devices\.imu\.bus: missing, required by backend 'real'"),
    ({'motor': {'backend': 'real', 'left_dac': '/dev/spidev0.0'}},
     r'devices\.motor\.right_dac: missing'),
    ({'imu': {'backend': 'sim', 'address': '0x20'}},
     r"devices\.imu\.address: expected int, got '0x20'"),
    ({'motor': {'backend': 'sim', 'period_s': True}},
     r'devices\.motor\.period_s: expected float, got True'),
    ({'imu': {'backend': 'sim', 'enabled': 'yes'}}, r'devices\.imu\.enabled: expected bool'),
    ({'imu': {'backend': 'sim', 'xddp_port': -1}}, r'devices\.imu\.xddp_port: expected a port'),
    ({'imu': {'backend': 'sim', 'bsu': 1}},
     r"devices\.imu: unknown field\(s\) \['bsu'\] for backend 'sim'"),
    ({'gps': {'backend': 'sim'}}, r'devices\.gps: unknown device; valid: imu, led, lrf'),
    ({'led': 'sim'}, r"devices\.led: expected a mapping, got 'sim'"),
    ({'motor': {'backend': 'sim', 'lead_bits': 7}},
     r'devices\.motor\.lead_bits: must be an int 0\.\.6 .*, got 7'),
    ({'motor': {'backend': 'sim', 'dac_sign': [1, 2]}},
     r'devices\.motor\.dac_sign: expected \[left, right\], each 1 or -1, got \[1, 2\]'),
    ({'motor': {'backend': 'sim', 'dac_zero_trim': [0, -100]}},
     r'devices\.motor\.dac_zero_trim: .*-64\.\.64 \(codes\), got \[0, -100\]'),
    ({'motor': {'backend': 'sim', 'enc_direction': [True, 1]}},
     r'devices\.motor\.enc_direction: expected \[left, right\]'),
    ({'motor': {'backend': 'sim', 'enc_zero': [0, 5000]}},
     r'devices\.motor\.enc_zero: .*0\.\.4095'),
    ({'motor': {'backend': 'real', 'left_dac': 'a', 'right_dac': 'b', 'left_enc': 'c',
                'right_enc': 'd', 'ldac': 'floating'}},
     r"devices\.motor\.ldac: must be one of tied_low, gpio, got 'floating'"),
])
def test_config_errors_name_the_field(devices, match):
    with pytest.raises(dconfig.ConfigError, match=match):
        dconfig.validate({'devices': devices})


def test_config_world_error_is_config_error():
    with pytest.raises(dconfig.ConfigError, match=r'world\.start'):
        dconfig.validate({'world': {'start': 'home'}})


def test_config_defaults_applied_and_int_promoted_to_float():
    cfg = dconfig.validate({'devices': {'motor': {'backend': 'sim', 'period_s': 1}}})
    m = cfg.devices['motor']
    assert m['period_s'] == 1.0 and isinstance(m['period_s'], float)
    assert m['watchdog_periods'] == 10 and m['xddp_port'] == 'motor' and m['enabled'] is True


def test_repo_devices_yaml_is_valid():
    cfg = dconfig.load(dconfig.default_config_path())
    assert set(cfg.devices) >= {'motor', 'imu', 'sonar', 'led'}
    assert cfg.world.robot.track_width_m == 0.40
    assert cfg.world.obstacles[0][0] == (1.5, -0.25)


def test_load_file_errors_name_path(tmp_path):
    with pytest.raises(dconfig.ConfigError, match='nope.yaml: No such file'):
        dconfig.load_file(tmp_path / 'nope.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('- a\n- b\n')
    with pytest.raises(dconfig.ConfigError, match='top level must be a mapping'):
        dconfig.load_file(bad)


def test_merge_layers_mappings_replace_scalars():
    out = dconfig.merge({'devices': {'imu': {'backend': 'sim', 'rate_hz': 100}}},
                        {'devices': {'imu': {'backend': 'real', 'bus': 1}}})
    assert out == {'devices': {'imu': {'backend': 'real', 'rate_hz': 100, 'bus': 1}}}


def test_retry_backs_off_exponentially_then_raises():
    calls, sleeps = [], []

    def flaky():
        calls.append(1)
        raise DeviceIOError('/dev/x: busy (errno 16)')

    with pytest.raises(DeviceIOError):
        retry(flaky, RetryPolicy(attempts=4, base_s=0.01, factor=2.0, max_s=0.03),
              sleep=sleeps.append)
    assert len(calls) == 4 and sleeps == [0.01, 0.02, 0.03]


def test_retry_does_not_retry_missing_device():
    calls = []

    def missing():
        calls.append(1)
        raise DeviceNotFoundError('/dev/x: No such file or directory (errno 2)')

    with pytest.raises(DeviceNotFoundError):
        retry(missing, RetryPolicy(attempts=5), sleep=lambda s: None)
    assert calls == [1]


def test_the_motor_service_runs_at_the_actuator_tasks_period_unless_told_otherwise():
    raw = {'tasks': {'actuator': {'period_ms': 20}},
           'devices': {'motor': {'backend': 'sim'}, 'imu': {'backend': 'sim'}}}
    filled = dconfig.fill_actuator_period(raw)
    assert filled['devices']['motor']['period_s'] == pytest.approx(0.02)
    assert 'period_s' not in raw['devices']['motor']               # the input is left alone
    assert dconfig.validate({'devices': filled['devices']}).devices['motor']['period_s'] == \
        pytest.approx(0.02)
    own = {**raw, 'devices': {'motor': {'backend': 'sim', 'period_s': 0.005}}}
    assert dconfig.fill_actuator_period(own)['devices']['motor']['period_s'] == 0.005
    assert dconfig.fill_actuator_period({'devices': {'motor': {}}}) == {'devices': {'motor': {}}}


def test_a_bare_motor_section_runs_at_the_shipped_actuator_period(tmp_path, monkeypatch):
    # The default is read from tasks.actuator.period_ms, not restated: a configuration that
    # declares another actuator period gives a bare motor section that one.
    bare = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}}).devices['motor']
    assert bare['period_s'] == pytest.approx(shipped_period_s('actuator'))
    shipped = load_layered()
    shipped['tasks']['actuator']['period_ms'] = 25
    (tmp_path / 'm4k.yaml').write_text(yaml.safe_dump(shipped))
    monkeypatch.setenv('M4K_CONFIG_DIR', str(tmp_path))
    other = dconfig.validate({'devices': {'motor': {'backend': 'sim'}}}).devices['motor']
    assert other['period_s'] == pytest.approx(0.025)
    field = registry.get('motor', 'sim').params['period_s'].as_field()
    assert field.derived_from == 'tasks.actuator.period_ms'
    assert field.doc_default() == '<tasks.actuator.period_ms>'
    assert field.problem(bare['period_s']) is None


def test_the_motor_package_states_no_actuator_period_of_its_own():
    # the twins this closed: a 0.01 in the Param default, the service's fallback and the
    # handler's keyword default. The handler takes the period it is given.
    period = shipped_period_s('actuator')
    pkg = os.path.dirname(motors.__file__)
    found = []
    for name in sorted(os.listdir(pkg)):
        if name.endswith('.py'):
            with open(os.path.join(pkg, name), encoding='utf-8') as f:
                tree = ast.parse(f.read())
            found += [f'{name}:{n.lineno}' for n in ast.walk(tree)
                      if isinstance(n, ast.Constant) and type(n.value) is float
                      and n.value == period]
    assert found == []
    param = inspect.signature(MotorHandler).parameters['period_s']
    assert param.default is inspect.Parameter.empty


def test_the_motor_handlers_defaults_are_its_config_schemas():
    # MotorHandler restated the seven defaults its Param table declares (10, 30.0, 1, [1, 1],
    # ...): the keyword defaults are now the table's own objects, for both backends' schemas.
    sig = inspect.signature(MotorHandler).parameters
    for name, p in HANDLER_PARAMS.items():
        if name != 'period_s':
            assert sig[name].default is p.default, name
    for backend in ('real', 'sim'):
        params = registry.get('motor', backend).params
        assert all(params[k] is p for k, p in HANDLER_PARAMS.items()), backend


def test_a_device_links_to_the_port_labelled_with_its_kind_by_default():
    cfg = dconfig.validate({'devices': {k: {'backend': 'sim'} for k in
                                        ('motor', 'imu', 'sonar', 'lrf', 'led')}})
    assert {k: d['xddp_port'] for k, d in cfg.devices.items()} == {
        k: k for k in ('motor', 'imu', 'sonar', 'lrf', 'led')}
