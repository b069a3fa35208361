import math

import pytest

from m4k_rt.control.params import control_params, ControlConfigError


def test_defaults_follow_table2():
    p = control_params(None)
    assert p.wheel_radius == 0.1016
    assert p.gear_ratio == 12.0
    assert p.linear.max_velocity == 2.0
    assert p.linear.max_acceleration == 0.37
    assert p.cmd_vel_timeout == 0.5
    assert p.odom_every_n == 5
    assert (p.odom_velocity_window, p.speed_feedback_window) == (5, 2)
    assert p.feed_forward == pytest.approx(1 / p.full_scale_wheel_speed)
    assert p.wheel_limit == p.full_scale_wheel_speed


def test_overrides_are_applied():
    p = control_params({'track_width': 0.42, 'linear': {'max_acceleration': 0.5},
                        'pi': {'anti_windup': 'back_calculation', 'kff': 0.05},
                        'guard': {'stop_distance': 0.5, 'enabled': False}})
    assert p.track_width == 0.42
    assert p.linear.max_acceleration == 0.5
    assert p.linear.max_velocity == 2.0
    assert p.pi.anti_windup == 'back_calculation'
    assert p.feed_forward == 0.05
    assert p.guard.stop_distance == 0.5 and not p.guard.enabled


@pytest.mark.parametrize('section,field,bad', [
    ({'track_width': 0}, 'control.track_width', '0'),
    ({'wheel_radius': 'big'}, 'control.wheel_radius', "'big'"),
    ({'cmd_vel_timeout': -1}, 'control.cmd_vel_timeout', '-1'),
    ({'odom_every_n': 2.5}, 'control.odom_every_n', '2.5'),
    ({'linear': {'max_acceleration': math.inf}}, 'control.linear.max_acceleration', 'inf'),
    ({'angular': {'max_velocity': -1}}, 'control.angular.max_velocity', '-1'),
    ({'pi': {'anti_windup': 'off'}}, 'control.pi.anti_windup', "'off'"),
    ({'guard': {'enabled': 'yes'}}, 'control.guard.enabled', "'yes'"),
    ({'guard': {'brake_deceleration': 0.2}}, 'control.guard.brake_deceleration', '0.2'),
    ({'guard': {'brake_deceleration': 20.0}}, 'control.guard.brake_deceleration', '20.0'),
    ({'supervision': {'frozen_time': 0.5}}, 'control.supervision.frozen_time', '0.5'),
    ({'e_stop': {'contact_samples': 0}}, 'control.e_stop.contact_samples', '0'),
    ({'trackwidth': 0.4}, 'control.trackwidth', 'unknown'),
    ({'speed_filter_alpha': 1.5}, 'control.speed_filter_alpha', '1.5'),
    ({'odom_velocity_window': 0}, 'control.odom_velocity_window', '0'),
    ({'odom_velocity_window': 2.0}, 'control.odom_velocity_window', '2.0'),
    ({'speed_feedback_window': 101}, 'control.speed_feedback_window', '101'),
])
def test_bad_values_name_the_field_and_value(section, field, bad):
    with pytest.raises(ControlConfigError) as info:
        control_params(section)
    assert info.value.field == field
    assert field in str(info.value)
    assert bad in str(info.value)


def test_shipped_control_yaml_is_valid():
    import pathlib

    import yaml
    path = pathlib.Path(__file__).resolve().parents[3] / 'config' / 'control.yaml'
    data = yaml.safe_load(path.read_text())
    p = control_params(data['control'])
    assert p.odom_every_n == 5
    assert (p.odom_velocity_window, p.speed_feedback_window) == (5, 2)
    assert p.linear.max_acceleration == 0.37


# --- one declaration: the dataclasses carry their Fields, CONTROL is derived -----------------

def _leaves(obj, prefix=''):
    import dataclasses
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            yield from _leaves(v, prefix + f.name + '.')
        else:
            yield prefix + f.name, v, f.type


def test_control_table_is_derived_from_the_dataclasses_and_matches_their_defaults():
    from m4k_rt.control.params import CONTROL, ControlParams
    leaves = list(_leaves(ControlParams()))
    assert [k for k, _, _ in leaves] == list(CONTROL)
    for key, value, annotation in leaves:
        f = CONTROL[key]
        assert value == f.default, key
        assert ('None' in annotation) == f.nullable, key       # float | None <-> nullable
        assert annotation.split(' |')[0] == f.type, key
        assert f.description, key


def test_validated_values_land_in_the_dataclass_fields():
    from m4k_rt.control.params import CONTROL
    p = control_params({'pi': {'kp': 0.5}, 'angular': {'max_jerk': 3},
                        'guard': {'stale_policy': 'ignore'}, 'odom_every_n': 2})
    assert (p.pi.kp, p.angular.max_jerk, p.guard.stale_policy, p.odom_every_n) == \
        (0.5, 3.0, 'ignore', 2)
    assert isinstance(p.angular.max_jerk, float)                # coerced by its Field
    assert p.linear.max_jerk is CONTROL['linear.max_jerk'].default


def test_a_dataclass_field_without_a_declaration_is_refused():
    import dataclasses

    from m4k_rt.schema import Field, section, setting, table

    @dataclasses.dataclass(frozen=True)
    class Bad:
        a: float = setting(Field('float', 1.0, 'declared'))
        b: float = 2.0

    with pytest.raises(TypeError, match='Bad.b'):
        table(Bad)

    @dataclasses.dataclass(frozen=True)
    class Shared:
        x: float

    with pytest.raises(TypeError, match='do not match'):
        section(Shared, {'y': Field('float', 1.0)})


def test_a_break_away_effort_at_or_below_the_moving_effort_is_refused_naming_it():
    with pytest.raises(ControlConfigError, match=r'control\.pi\.breakaway_effort: must be > '
                       r'supervision\.moving_effort'):
        control_params({'pi': {'breakaway_effort': 0.12}})
    control_params({'pi': {'breakaway_effort': 0.12, 'breakaway_rate': 0.0}})   # boost off
