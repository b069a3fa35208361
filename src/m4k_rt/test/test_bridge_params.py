"""Bridge parameters: the spec table, config/bridge.yaml defaults, validation (no rclpy)."""

import math
import os

import pytest
import yaml

from m4k_rt.bridge import params

BRIDGE_YAML = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config', 'bridge.yaml')


def _yaml_params():
    with open(BRIDGE_YAML, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    return doc, params.check_section(doc)


def test_bridge_yaml_holds_exactly_the_declared_defaults():
    _, found = _yaml_params()
    assert set(found) == {s.name for s in params.SPECS}
    for s in params.SPECS:
        assert found[s.name] == s.default, s.name
        assert type(found[s.name]) is type(s.default), s.name


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
    ('cmd_vel_timeout', -1.0, 'within [0.0, 60.0]'),
    ('cmd_vel_timeout', 1, 'write 1.0'),
    ('cmd_vel_timeout', 'fast', 'expected a double'),
    ('max_linear_velocity', math.nan, 'finite'),
    ('odom_pose_covariance_diagonal', [0.1] * 5, 'expected 6 numbers'),
    ('odom_pose_covariance_diagonal', [0.1, 0.1, 0.1, 0.1, 0.1, -0.1], 'within'),
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
