"""Configuration YAML refuses duplicate keys, naming the key and both lines."""

import pytest

from m4k_rt import config, yamlload


def test_a_duplicate_key_is_refused_naming_the_key_and_both_lines():
    text = 'control:\n  stop_distance: 0.5\n  linear:\n    max_velocity: 1.0\n' \
           '  stop_distance: 0.1\n'
    with pytest.raises(yamlload.DuplicateKeyError) as exc:
        yamlload.load(text)
    assert (exc.value.key, exc.value.line, exc.value.first_line) == ('stop_distance', 5, 2)
    assert str(exc.value) == ("duplicate key 'stop_distance' at line 5 (first given at line 2)"
                              ': one of the two would be silently ignored')


def test_duplicates_are_found_at_any_depth_and_in_flow_mappings():
    with pytest.raises(yamlload.DuplicateKeyError,
                       match=r"'x' at line 4 \(first given at line 3\)"):
        yamlload.load('a:\n  b: {x: 1, y: 2}\n  c: {x: 1,\n      x: 2}\n')
    with pytest.raises(yamlload.DuplicateKeyError, match="'period_ms'"):
        yamlload.load('tasks:\n  - {period_ms: 10, period_ms: 20}\n')


def test_distinct_keys_and_merge_keys_load_as_yaml_means_them():
    doc = yamlload.load('base: &b {x: 1, y: 2}\nover:\n  <<: *b\n  y: 3\n')
    assert doc == {'base': {'x': 1, 'y': 2}, 'over': {'x': 1, 'y': 3}}
    assert yamlload.load('a: 1\nb: {a: 2}\n') == {'a': 1, 'b': {'a': 2}}
    # Still the safe loader: no Python objects.
    with pytest.raises(yamlload.yaml.YAMLError):
        yamlload.load('x: !!python/object/apply:os.system ["true"]\n')


def test_the_layered_configuration_refuses_an_overlay_with_a_duplicate(tmp_path):
    over = tmp_path / 'over.yaml'
    over.write_text('control:\n  cmd_vel_timeout: 0.5\n  cmd_vel_timeout: 0.2\n')
    with pytest.raises(config.ConfigError) as exc:
        config.load_layered(str(over))
    assert "duplicate key 'cmd_vel_timeout' at line 3 (first given at line 2)" in str(exc.value)
    assert str(over) in str(exc.value)


def test_bytes_that_are_not_utf8_are_a_yaml_error_naming_the_byte(tmp_path):
    import yaml
    f = tmp_path / 'x.yaml'
    f.write_bytes(b'a: 1\nb: caf\xe9\n')
    with open(f, encoding='utf-8') as fh, pytest.raises(yamlload.EncodingError,
                                                        match='byte 0xe9'):
        yamlload.load(fh)
    assert issubclass(yamlload.EncodingError, yaml.YAMLError)
    with pytest.raises(yaml.YAMLError):                 # the bytes form: PyYAML's own error
        yamlload.load(f.read_bytes())


@pytest.mark.parametrize('depth', [65, 200, 5000])
def test_nesting_past_the_bound_is_a_yaml_error_and_within_it_loads(depth):
    with pytest.raises(yamlload.NestingError, match='nested deeper than 64'):
        yamlload.load('[' * depth + ']' * depth)
    with pytest.raises(yamlload.NestingError):
        yamlload.load('{a: ' * depth + '1' + '}' * depth)
    doc = yamlload.load('[' * 63 + ']' * 63)
    for _ in range(62):
        doc = doc[0]
    assert doc == []
