"""Scenario files: validation naming the field, expectations in words, bounds from config/."""

import os

import pytest

from m4k_bench.scenarios import bounds, spec
from m4k_rt import config

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(
    __file__)))))
GOOD = {'world': {'obstacles': []}, 'commands': [{'v': 0.25, 't': 4.0}, {'w': 0.5, 't': 2.0}],
        'expect': {'distance': 'commanded'}, 'short': 0.5}


def test_a_scenario_commands_and_short_version():
    sc = spec.parse(dict(GOOD), 'x.yaml')
    assert sc.name == 'x' and sc.distance and sc.stop is None
    assert sc.commanded_distance() == pytest.approx(1.0)
    assert sc.commanded_distance(short=True) == pytest.approx(0.5)
    assert sc.expected() == 'commanded distance; no contact'


@pytest.mark.parametrize('change, message', [
    ({'commands': []}, r'x\.yaml\.commands'),
    ({'commands': [{'v': 'fast', 't': 1}]}, r'commands\[0\]\.v'),
    ({'expect': {'stop': 'bumper'}}, r'expect\.stop'),
    ({'expect': {}}, r'expect'),
    ({'faults': [{'kill': 'nav2', 'at': {'travelled': 1}}]}, r'faults\[0\]'),
    ({'colour': 'red'}, r'x\.yaml\.colour: unknown key \(allowed: commands, '),
    ({'config': {'world': {}}}, r'x\.yaml\.config'),
])
def test_bad_scenarios_name_the_field(change, message):
    with pytest.raises(spec.ScenarioError, match=message):
        spec.parse(dict(GOOD, **change), 'x.yaml')


def test_a_bad_world_is_refused_when_loading(tmp_path):
    path = tmp_path / 'w.yaml'
    path.write_text('commands: [{v: 0.1, t: 1}]\nexpect: {distance: commanded}\n'
                    'world: {obstacles: [{polygon: [[0, 0], [1, 0], [1, 1]], surface: fog}]}\n')
    with pytest.raises(spec.ScenarioError, match=r'w\.yaml: world\.obstacles\[0\]\.surface'):
        spec.load(str(path))


def test_the_shipped_suite_loads():
    scs = spec.load_dir(os.path.join(ROOT, 'config', 'scenarios'))
    assert len(scs) >= 16 and len({s.name for s in scs}) == len(scs)


def test_bounds_follow_config():
    raw = config.load_layered(None, os.path.join(ROOT, 'config'))
    b = bounds.bounds(raw, 0.25, 'sonar')
    # v^2 / 2a with 0.37 m/s^2
    assert b.distance_tol == pytest.approx(0.25 ** 2 / (2 * 0.37))
    # a guard stop is held to the speed-aware stop zone: t_react = 2 x 30 ms sonar + 10 ms
    # actuator + 20 ms pipeline + 50 ms amplifier, braking at guard.brake_deceleration 1.5
    g = raw['control']['guard']
    assert (g['reaction_time'], g['brake_deceleration'], g['stop_distance']) == (None, 1.5, 0.35)
    assert b.stop_s is None and b.t_react == pytest.approx(0.06 + 0.01 + 0.02 + 0.05)
    assert b.stop_distance(0.25) == pytest.approx(
        0.25 * (0.14 + bounds.SCHED_S) + 0.25 ** 2 / (2 * 1.5) + bounds.STOP_MARGIN_M)
    assert b.reach(0.25) == pytest.approx(0.25 * (0.14 + bounds.SCHED_S) + bounds.STOP_MARGIN_M)
    # the guard's stop line: both sensors in use, so twice the slower one's (the laser's)
    # period, or the longest timeout when that is longer (the guard acts on a reading until
    # it is that old)
    lrf = raw['tasks']['lrf']['period_ms'] / 1000.0
    assert lrf > 0.03 and g['use_laser'] and g['use_sonar']
    sensor = max(2 * lrf, g['laser_timeout'], g['sonar_timeout'])
    assert bounds.stop_line(raw, 0.25) == pytest.approx(
        0.25 * (sensor + 0.01 + 0.02 + 0.05) + 0.25 ** 2 / 3.0 + 0.35)
    quick = dict(raw, control=dict(raw['control'], guard=dict(raw['control']['guard'],
                                                              laser_timeout=0.1)))
    assert bounds.stop_line(quick, 0.25) == pytest.approx(
        0.25 * (2 * lrf + 0.01 + 0.02 + 0.05) + 0.25 ** 2 / 3.0 + 0.35)
    slower = dict(raw, control=dict(raw['control'], guard=dict(raw['control']['guard'],
                                                               sonar_timeout=1.0)))
    assert (bounds.bounds(slower, 0.25, 'sonar_unplugged').stop_s
            - bounds.bounds(raw, 0.25, 'sonar_unplugged').stop_s) == pytest.approx(0.8)


def test_heading_hold_segments():
    sc = spec.parse(dict(GOOD, commands=[{'v': 0.5, 't': 2.0, 'heading': 'hold'}]), 'x.yaml')
    assert sc.commands[0].hold and sc.scaled(True)[0].hold
    with pytest.raises(spec.ScenarioError, match=r'commands\[0\]'):
        spec.parse(dict(GOOD, commands=[{'v': 0.5, 'w': 0.1, 't': 2, 'heading': 'hold'}]), 'x')
