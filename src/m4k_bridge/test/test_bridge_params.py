"""Bridge parameters: the spec table, config/bridge.yaml defaults, validation (no rclpy)."""

import math
import os

import pytest
import yaml

from m4k_bridge import params

BRIDGE_YAML = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config', 'bridge.yaml')


def _yaml_params():
    with open(BRIDGE_YAML, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    return doc, params.check_section(doc)


def test_bridge_yaml_holds_exactly_the_declared_defaults_of_the_bridges_own_parameters():
    _, found = _yaml_params()
    own = [s for s in params.SPECS if s.name not in params.DERIVED]
    assert set(found) == {s.name for s in own}      # derived values have one source elsewhere
    for s in own:
        assert found[s.name] == s.default, s.name
        assert type(found[s.name]) is type(s.default), s.name


def test_derived_values_follow_the_layered_configuration():
    from m4k_rt import config
    doc = config.deep_merge(config.load_layered(), {
        'control': {'cmd_vel_timeout': 0.8, 'linear': {'max_velocity': 1.2},
                    'angular': {'max_velocity': 0.9}},
        'robot': {'sensors': {'imu': {'frame': 'ahrs', 'pose': [0, 0, 0.1, 0, 0, 0]}}}})
    out = params.derived_values(doc)
    assert set(out) == set(params.DERIVED)
    assert (out['cmd_vel_timeout'], out['max_linear_velocity'], out['max_angular_velocity']) \
        == (0.8, 1.2, 0.9)
    assert out['imu_frame'] == 'ahrs' and out['laser_frame'] == 'laser'
    assert out['ports.cmd'] == 'cmd' and '<link name="ahrs"' in out['robot_description']
    # The static defaults of the derived parameters are the shipped configuration's values.
    shipped = params.derived_values(config.load_layered())
    for name, value in shipped.items():
        if name != 'robot_description':
            assert params.spec(name).default == value, name


def test_derived_values_name_the_source_of_a_bad_value():
    with pytest.raises(params.ParamError) as info:
        params.derived_values({'control': {'cmd_vel_timeout': 90.0}})
    assert info.value.name == 'cmd_vel_timeout'
    assert 'must be in 0..60, got 90.0' in info.value.reason
    assert 'derived from control.cmd_vel_timeout' in info.value.reason
    with pytest.raises(params.ParamError, match="no label 'lrf_out'"):
        params.derived_values({'ports': {r: i for i, r in enumerate(params.PORT_ROLES[:-1])}})


def test_derived_parameters_may_not_be_set_beside_their_source():
    with pytest.raises(params.ParamError) as info:
        params.check_not_derived(['stats_window', 'max_linear_velocity'])
    assert info.value.name == 'max_linear_velocity'
    assert 'control.linear.max_velocity' in info.value.reason


def test_defaults_validate_and_types_are_ros_friendly():
    p = params.from_values({})
    assert p['cmd_vel_timeout'] == 0.5 and p.topic('cmd_vel') == 'cmd_vel'
    assert p.port('cmd') == 'cmd'
    for s in params.SPECS:
        assert s.description and s.name == s.name.lower()
        if isinstance(s.default, list):
            assert all(isinstance(x, float) for x in s.default), s.name


def test_every_number_parameter_has_a_range_with_the_default_inside():
    for s in params.SPECS:
        if isinstance(s.default, (float, list)):
            assert s.lo is not None and s.hi is not None, s.name
            for x in s.default if isinstance(s.default, list) else [s.default]:
                assert s.lo <= x <= s.hi, s.name


def test_resource_parameters_are_read_only():
    for name in ('runtime_dir', 'ports.cmd', 'topics.odom', 'use_stamped_vel',
                 'robot_description', 'publish_robot_state'):
        assert params.spec(name).read_only, name
    assert not params.spec('max_linear_velocity').read_only


@pytest.mark.parametrize('name, value, words', [
    ('cmd_vel_timeout', -1.0, 'must be in 0..60, got -1.0'),
    ('cmd_vel_timeout', 1, 'write 1.0'),
    ('cmd_vel_timeout', 'fast', 'expected a double'),
    ('max_linear_velocity', math.nan, 'expected a number, got nan'),
    ('odom_pose_covariance_diagonal', [0.1] * 5, 'expected a list of 6 numbers'),
    ('odom_pose_covariance_diagonal', [0.1, 0.1, 0.1, 0.1, 0.1, -0.1], 'must be in 0..'),
    ('odom_frame', '', 'frame id'),
    ('odom_frame', 'has space', 'frame id'),
    ('topics.odom', 'bad topic', 'topic name'),
    ('topics.odom', '', 'topic name'),
    ('ports.cmd', 'no/slash', 'port label'),
    ('runtime_dir', 'relative/dir', 'absolute path'),
    ('use_stamped_vel', 'yes', 'expected a bool'),
    ('cmd_vel_timout', 0.5, 'unknown parameter'),
])
def test_wrong_values_are_rejected_with_a_reason(name, value, words):
    reason = params.validate(name, value)
    assert reason is not None and words in reason


def test_sonar_range_cross_check_names_the_parameter():
    with pytest.raises(params.ParamError) as info:
        params.from_values({'sonar_min_range': 2.0, 'sonar_max_range': 1.0})
    assert info.value.name == 'sonar_max_range'
    assert 'must exceed sonar_min_range' in str(info.value)


def test_check_section_names_the_bad_field_of_a_parameter_file():
    doc = {'m4k_bridge': {'ros__parameters': {'ports': {'cmd': 'cmd'},
                                              'max_angular_velocity': 99.0}}}
    with pytest.raises(params.ParamError) as info:
        params.check_section(doc)
    assert info.value.name == 'max_angular_velocity'


def test_check_section_rejects_a_misspelt_name():
    doc = {'/m4k_bridge': {'ros__parameters': {'cmd_vel_timout': 0.5}}}
    with pytest.raises(params.ParamError, match='cmd_vel_timout'):
        params.check_section(doc)


def test_check_section_ignores_other_nodes_and_foreign_wildcard_names():
    doc = {'other_node': {'ros__parameters': {'x': 1}},
           '/**': {'ros__parameters': {'use_sim_time': False, 'foo': 1,
                                       'cmd_vel_timeout': 0.25}}}
    assert params.check_section(doc) == {'cmd_vel_timeout': 0.25}


def test_check_section_flattens_nested_names():
    doc = {'m4k_bridge': {'ros__parameters': {'topics': {'odom': 'wheel_odom'}}}}
    assert params.check_section(doc) == {'topics.odom': 'wheel_odom'}


def test_parse_port_accepts_numbers_and_labels():
    assert params.parse_port('7') == 7 and params.parse_port('sonar') == 'sonar'


def test_one_type_table_gives_every_parameter_its_schema_and_ros_type():
    known = {t.schema for t in params.PARAM_TYPES}
    for s in params.SPECS:
        assert s.type in known or s.type == 'any', s.name
    assert params.param_type(True).ros == 'bool'              # bool before int: a subclass
    assert params.param_type(3).ros == 'int' and params.param_type(3.0).ros == 'double'
    assert params.param_type([1.0]).schema == 'float[]' and params.param_type(None) is None
    assert params.validate('cmd_vel_timeout', 1) == (
        'expected a double, got the integer 1 (write 1.0)')
    with pytest.raises(TypeError, match="parameter 'x'"):
        params.ParamSpec('x', object(), 'no ROS type')


def test_units_are_declared_on_the_parameters_themselves():
    by_name = {s.name: s for s in params.SPECS}
    assert by_name['cmd_vel_timeout'].unit == 's'
    assert by_name['max_angular_velocity'].unit == 'rad/s'
    assert by_name['flight_recorder.max_bytes'].unit == 'bytes'
    assert by_name['frame_prefix'].unit == ''
