"""The configuration schema (pure): Field messages, nested sections, defaults, the docs table."""

import math

import pytest

from m4k_rt import schema
from m4k_rt.control.params import CONTROL
from m4k_rt.schema import ConfigError, Field


@pytest.mark.parametrize('field, value, message', [
    (Field('int', 1, lo=1, hi=99, expect='an int in 1..99'), 120,
     'expected an int in 1..99, got 120'),
    (Field('int', 1, lo=1, hi=99), 80.5, 'expected an int, got 80.5'),
    (Field('int', 1, lo=1, hi=99), True, 'expected an int, got True'),
    (Field('float', 1.0, lo=0, lo_open=True), -1, 'must be > 0, got -1'),
    (Field('float', 1.0, lo=0), -0.5, 'must be >= 0, got -0.5'),
    (Field('float', 1.0, lo=0, lo_open=True, hi=1.0), 1.5, 'must be in (0, 1], got 1.5'),
    (Field('int', 5, lo=1, hi=100), 101, 'must be in 1..100, got 101'),
    (Field('float', 1.0), math.nan, 'expected a number, got nan'),
    (Field('float', 1.0, nullable=True), 'x', "expected a number or null, got 'x'"),
    (Field('str', 'a', choices=('a', 'b')), 'c', "expected one of a, b, got 'c'"),
    (Field('float[]', [0.0, 0.0], length=2, lo=0), [1.0], 'expected a list of 2 numbers, '
     'got [1.0]'),
    (Field('float[]', [0.0, 0.0], length=2, lo=0), [1.0, -1.0], 'must be >= 0, got [1.0, -1.0]'),
    (Field('bool', True), 'yes', "expected true or false, got 'yes'"),
    (Field('str', 'x', check=lambda v: 'too long' if len(v) > 3 else None), 'abcd', 'too long'),
])
def test_a_wrong_value_gets_the_fields_message(field, value, message):
    assert field.problem(value) == message
    with pytest.raises(ConfigError) as info:
        field.validate('a.b', value)
    assert str(info.value) == 'a.b: ' + message and info.value.path == 'a.b'


def test_valid_values_pass_and_floats_are_coerced():
    assert Field('float', 1.0).validate('x', 2) == 2.0
    assert isinstance(Field('float', 1.0).validate('x', 2), float)
    assert Field('float[]', [0.0]).validate('x', [1, 2]) == [1.0, 2.0]
    assert Field('int|str', 0, lo=0).validate('x', 'lbl') == 'lbl'
    assert Field('float', None, nullable=True, lo=0, lo_open=True).validate('x', None) is None
    assert Field('str', 'a', choices=('a', 'b')).validate('x', 'b') == 'b'


def test_validate_tree_fills_defaults_and_names_unknown_and_missing_keys():
    table = {'a': Field('int', 1), 'g.b': Field('float', 0.5), 'g.c': Field('str')}
    assert schema.validate_tree(table, {'g': {'c': 'x'}}, 'sec') == {
        'a': 1, 'g.b': 0.5, 'g.c': 'x'}
    with pytest.raises(ConfigError, match=r'^sec\.g\.d: unknown key \(allowed: b, c\)'):
        schema.validate_tree(table, {'g': {'c': 'x', 'd': 1}}, 'sec')
    with pytest.raises(ConfigError, match=r'^sec\.g\.c: missing'):
        schema.validate_tree(table, {}, 'sec')
    with pytest.raises(ConfigError, match=r"^sec: expected a mapping, got 'x'"):
        schema.validate_tree(table, 'x', 'sec')


def test_a_custom_error_class_is_raised_with_path_and_message():
    class Mine(Exception):
        def __init__(self, path, message):
            super().__init__(path + ' | ' + message)

    with pytest.raises(Mine, match=r'^p \| must be > 0, got 0$'):
        Field('float', 1.0, lo=0, lo_open=True).validate('p', 0, Mine)


def test_markdown_lists_every_field_with_type_default_unit_range_and_description():
    sec = schema.Section('demo', 'demo (x.yaml)', {
        'speed': Field('float', 2.0, 'How fast; too fast tips over.', unit='m/s', lo=0,
                       lo_open=True),
        'mode': Field('str', 'a', 'Mode.', choices=('a', 'b'), read_only=True)}, 'A note.')
    text = schema.markdown([sec])
    assert '## demo (x.yaml)' in text and 'A note.' in text
    assert '| `speed` | float | `2.0` | m/s | > 0 | How fast; too fast tips over. |' in text
    assert '| `mode` | str | `a` |  | a, b | Mode. (read-only) |' in text


def test_every_rt_field_has_a_description_and_a_default_inside_its_range():
    tables = {'runtime': schema.RUNTIME, 'tasks': schema.TASK, 'ports': {'<label>': schema.PORT},
              'control': CONTROL, 'robot': schema.ROBOT}
    for path, fields in tables.items():
        for name, field in fields.items():
            assert field.description, name
            if not field.required and field.default is not None and not isinstance(
                    field.default, str) and field.type in ('int', 'float', 'float[]'):
                assert field.problem(field.default) is None, (path, name)


def test_every_config_error_is_one_type_with_a_path():
    e = schema.ConfigError('world.start: expected 3 numbers, got 1')
    assert (str(e), e.path) == ('world.start: expected 3 numbers, got 1', 'world.start')
    e = schema.ConfigError('tasks.led.priority', 'expected an int in 1..99, got 120', 120)
    assert (str(e), e.path, e.value) == (
        'tasks.led.priority: expected an int in 1..99, got 120', 'tasks.led.priority', 120)
    assert isinstance(e, ValueError)


def test_a_setting_may_hold_the_parsed_shape_and_a_derived_field_is_no_setting():
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Room:
        walls: tuple = schema.setting(Field('list', [[0, 0, 1, 0]], 'Segments.'),
                                      value=((0.0, 0.0, 1.0, 0.0),))
        seed: int = schema.setting(Field('int', 0, 'Seed.'))
        kinds: tuple = schema.derived(())

    # The dataclass holds the parsed default, the table (docs, validation) the file's form.
    assert Room().walls == ((0.0, 0.0, 1.0, 0.0),) and Room().kinds == ()
    table = schema.table(Room)
    assert list(table) == ['walls', 'seed'] and table['walls'].default == [[0, 0, 1, 0]]
    assert schema.build(Room, {'seed': 3}) == Room(seed=3)

