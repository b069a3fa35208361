"""Tests of the layered configuration loader and its validation messages."""

import os

import pytest
import yaml

from m4k_rt import config

REPO_CONFIG = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'config')


def _write(path, doc):
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def test_repo_config_is_valid_and_rate_monotonic():
    cfg = config.load(config_dir=REPO_CONFIG)
    names = [t.name for t in cfg.tasks]
    assert names == ['actuator', 'imu', 'led', 'sonar', 'lrf', 'monitor']
    prios = [t.priority for t in cfg.tasks]
    periods = [t.period_ns for t in cfg.tasks]
    assert prios == sorted(prios, reverse=True)
    assert periods == sorted(periods)
    assert cfg.task('actuator').period_ns == 10_000_000
    assert cfg.ports['status'] == 0 and cfg.ports['stat'] == 11
    assert cfg.runtime.switch_interval_s == pytest.approx(1e-4)
    assert cfg.task('monitor').ports == ('status', 'stat')


def test_find_config_dir_prefers_env(monkeypatch, tmp_path):
    monkeypatch.setenv('M4K_CONFIG_DIR', str(tmp_path))
    assert config.find_config_dir() == str(tmp_path)
    monkeypatch.delenv('M4K_CONFIG_DIR')
    assert os.path.isfile(os.path.join(config.find_config_dir(), 'm4k.yaml'))


def test_layers_merge_in_order_and_overlay_wins(tmp_path):
    base = {'runtime': {'mlockall': True, 'stats_batch': 10},
            'tasks': {'a': {'period_ms': 10, 'priority': 50, 'ports': ['p']}},
            'ports': {'p': 1}}
    _write(tmp_path / 'm4k.yaml', base)
    _write(tmp_path / 'devices.yaml', {'devices': {'motor': {'backend': 'sim'}},
                                       'runtime': {'stats_batch': 20}})
    _write(tmp_path / 'control.yaml', {'control': {'kp': 1.0}})
    over = _write(tmp_path / 'over.yaml', {'runtime': {'stats_batch': 30},
                                           'tasks': {'a': {'cpu': 1}}})
    cfg = config.load(over, config_dir=str(tmp_path))
    assert cfg.runtime.stats_batch == 30 and cfg.runtime.mlockall is True
    assert cfg.task('a').cpu == 1 and cfg.task('a').priority == 50
    assert cfg.raw['devices']['motor']['backend'] == 'sim'
    assert cfg.raw['control']['kp'] == 1.0


def test_deep_merge_replaces_lists_and_keeps_base():
    out = config.deep_merge({'a': {'x': [1, 2], 'y': 1}}, {'a': {'x': [3]}})
    assert out == {'a': {'x': [3], 'y': 1}}


def _bad(tmp_path, overlay, body_exists=None):
    over = _write(tmp_path / 'bad.yaml', overlay)
    with pytest.raises(config.ConfigError) as ei:
        config.load(over, config_dir=REPO_CONFIG, body_exists=body_exists)
    return str(ei.value)


def test_priority_out_of_range_names_field_and_value(tmp_path):
    msg = _bad(tmp_path, {'tasks': {'led': {'priority': 120}}})
    assert msg == 'tasks.led.priority: expected an int in 1..99, got 120'


def test_zero_period_is_rejected(tmp_path):
    assert _bad(tmp_path, {'tasks': {'imu': {'period_ms': 0}}}).startswith(
        'tasks.imu.period_ms: expected a number of ms > 0, got 0')


def test_duplicate_port_is_rejected(tmp_path):
    msg = _bad(tmp_path, {'ports': {'stat': 1}})
    assert msg.startswith('ports.stat: duplicate port 1 (also ports.cmd)')


def test_unknown_key_is_rejected(tmp_path):
    assert _bad(tmp_path, {'tasks': {'led': {'prio': 3}}}).startswith(
        'tasks.led.prio: unknown key')
    assert _bad(tmp_path, {'runtime': {'mlock': True}}).startswith('runtime.mlock: unknown key')


def test_wrong_types_are_rejected(tmp_path):
    assert "got 'yes'" in _bad(tmp_path, {'runtime': {'require_rt': 'yes'}})
    assert _bad(tmp_path, {'tasks': {'led': {'priority': 80.5}}}).startswith(
        'tasks.led.priority')
    assert _bad(tmp_path, {'tasks': {'led': {'ports': 'led'}}}).startswith('tasks.led.ports')
    assert _bad(tmp_path, {'tasks': {'led': {'cpu': -1}}}).startswith('tasks.led.cpu')


def test_unknown_body_and_port_label_are_rejected(tmp_path):
    msg = _bad(tmp_path, {'tasks': {'led': {'body': 'nope'}}}, body_exists=lambda n: n != 'nope')
    assert msg == "tasks.led.body: unknown task body 'nope'"
    assert "unknown port label 'zz'" in _bad(tmp_path, {'tasks': {'led': {'ports': ['zz']}}})


def test_port_shared_by_two_tasks_is_rejected(tmp_path):
    msg = _bad(tmp_path, {'tasks': {'imu': {'ports': ['imu', 'cmd']}}})
    assert "port 'cmd' already used by task 'actuator'" in msg


def test_disabled_task_is_dropped(tmp_path):
    over = _write(tmp_path / 'o.yaml', {'tasks': {'lrf': {'enabled': False}}})
    cfg = config.load(over, config_dir=REPO_CONFIG)
    assert 'lrf' not in [t.name for t in cfg.tasks]


def test_broken_yaml_names_the_file(tmp_path):
    p = tmp_path / 'x.yaml'
    p.write_text('tasks: [\n')
    with pytest.raises(config.ConfigError, match='x.yaml: not valid YAML'):
        config.load(str(p), config_dir=REPO_CONFIG)
    with pytest.raises(config.ConfigError, match='cannot read'):
        config.load(str(tmp_path / 'missing.yaml'), config_dir=REPO_CONFIG)


def test_offset_outside_the_period_is_rejected(tmp_path):
    assert _bad(tmp_path, {'tasks': {'led': {'offset_ms': 20}}}) == (
        'tasks.led.offset_ms: expected ms in 0..period_ms (20), got 20')


def test_default_offsets_never_release_a_task_with_the_actuator():
    # The phasing argument of config/m4k.yaml: no release of another task coincides with an
    # actuator release over the hyperperiod (checked on a 1 ms grid, which the offsets use).
    cfg = config.load(config_dir=REPO_CONFIG)
    act = cfg.task('actuator')
    hyper = 1_000_000_000  # 1 s: a common multiple of every default period
    act_releases = {act.offset_ns + k * act.period_ns for k in range(hyper // act.period_ns)}
    for t in cfg.tasks:
        if t.name == 'actuator':
            continue
        mine = {t.offset_ns + k * t.period_ns for k in range(hyper // t.period_ns)}
        assert not mine & act_releases, t.name
