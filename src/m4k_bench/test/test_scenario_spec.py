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
    # a turn in place: the centre may wander TURN_WANDER, never less; a straight 'must not
    # move' stays exact
    assert bounds.bounds(raw, 0.0, None, turning=True).distance_tol == bounds.TURN_WANDER
    assert bounds.bounds(raw, 0.0, None).distance_tol == 0.0
    # a guard stop is held to the speed-aware stop zone: t_react = 2 x 30 ms sonar + 10 ms
    # actuator + 20 ms pipeline + 30 ms scheduling + 50 ms amplifier, braking at
    # guard.brake_deceleration 1.5; no slack beyond what the guard itself takes
    g = raw['control']['guard']
    assert 'reaction_time' not in g            # no key replaces the whole t_react
    assert (g['brake_deceleration'], g['stop_distance']) == (1.5, 0.35)
    assert b.stop_s is None and b.t_react == pytest.approx(0.06 + 0.01 + 0.02 + 0.03 + 0.05)
    assert b.stop_distance(0.25) == pytest.approx(
        0.25 * 0.17 + 0.25 ** 2 / (2 * 1.5) + bounds.STOP_MARGIN_M)
    assert b.reach(0.25) == pytest.approx(0.25 * 0.17 + bounds.STOP_MARGIN_M)
    # the guard's stop line: both sensors in use, so the laser's delay (2 periods + a sweep,
    # or its timeout when that is longer: the guard acts on a scan until it is that old)
    lrf = raw['tasks']['lrf']['period_ms'] / 1000.0
    assert lrf > 0.03 and g['use_laser'] and g['use_sonar']
    sensor = max(2 * lrf + 0.1, g['laser_timeout'], g['sonar_timeout'])
    assert bounds.stop_line(raw, 0.25) == pytest.approx(
        0.25 * (sensor + 0.01 + 0.02 + 0.03 + 0.05) + 0.25 ** 2 / 3.0 + 0.35)
    quick = dict(raw, control=dict(raw['control'], guard=dict(raw['control']['guard'],
                                                              laser_timeout=0.1)))
    assert bounds.stop_line(quick, 0.25) == pytest.approx(
        0.25 * (2 * lrf + 0.1 + 0.01 + 0.02 + 0.03 + 0.05) + 0.25 ** 2 / 3.0 + 0.35)


def test_the_judges_t_react_is_the_guards_and_calibration_cannot_loosen_it():
    """One derivation (m4k_rt.control.reaction) for rt_core and the judge; an overlay's
    actuation part (what calibrate writes) changes the guard's t_react, never the judge's."""
    from m4k_rt.control.params import control_params
    from m4k_rt.control.reaction import reaction
    from m4k_rt.tasks.actuator import guard_plan
    raw = config.load_layered(None, os.path.join(ROOT, 'config'))
    cfg = config.parse(raw)
    shared = type('S', (), {'config': cfg})()
    ta = cfg.task('actuator').period_ns * 1e-9
    plan = guard_plan(control_params(raw['control']), ta, shared)
    assert bounds.judge_reaction(raw, 'laser', timeouts=True) == pytest.approx(
        plan.reaction_time)
    calibrated = config.deep_merge(raw, {'control': {'guard': {'amplifier_lag': 0.012}}})
    cal_plan = guard_plan(control_params(calibrated['control']), ta, shared)
    assert cal_plan.reaction_time == pytest.approx(plan.reaction_time - 0.038)
    assert bounds.judge_reaction(calibrated, 'laser', timeouts=True) == bounds.judge_reaction(
        raw, 'laser', timeouts=True)
    assert bounds.stop_line(calibrated, 2.0) == bounds.stop_line(raw, 2.0)
    gp = control_params(raw['control']).guard
    r = reaction(gp, 'laser', 0.2, ta, timeouts=True)
    assert (r.sensor_part, r.total) == (pytest.approx(max(0.5, gp.laser_timeout)),
                                        pytest.approx(plan.reaction_time))
    assert reaction(gp, 'laser', 0.2, ta).sensor_part == pytest.approx(0.5)
    with pytest.raises(ValueError, match='sensor must be one of'):
        reaction(control_params(raw['control']).guard, 'radar', 0.2, ta)


def test_a_whole_t_react_override_is_refused():
    """The key that let calibrate drop the sensor part is gone: an old overlay is refused."""
    from m4k_rt.control.params import control_params, ControlConfigError
    with pytest.raises(ControlConfigError, match=r'guard\.reaction_time.*unknown key'):
        control_params({'guard': {'reaction_time': 0.012}})


def test_bounds_scale_with_the_configured_sensor_period():
    raw = config.load_layered(None, os.path.join(ROOT, 'config'))
    slower = dict(raw, control=dict(raw['control'], guard=dict(raw['control']['guard'],
                                                               sonar_timeout=1.0)))
    assert (bounds.bounds(slower, 0.25, 'sonar_unplugged').stop_s
            - bounds.bounds(raw, 0.25, 'sonar_unplugged').stop_s) == pytest.approx(0.8)


def test_heading_hold_segments():
    sc = spec.parse(dict(GOOD, commands=[{'v': 0.5, 't': 2.0, 'heading': 'hold'}]), 'x.yaml')
    assert sc.commands[0].hold and sc.scaled(True)[0].hold
    with pytest.raises(spec.ScenarioError, match=r'commands\[0\]'):
        spec.parse(dict(GOOD, commands=[{'v': 0.5, 'w': 0.1, 't': 2, 'heading': 'hold'}]), 'x')


def test_the_cli_expands_the_envelope_grid_and_states_what_is_not_promised(tmp_path, capsys):
    """``scenarios config/envelope.yaml`` takes the grid's cells as scenarios; the cells outside
    the promise are named in the report, never run (here: --only selects none)."""
    from m4k_bench import scenarios
    from m4k_bench.scenarios import grid
    envelope = os.path.join(ROOT, 'config', 'envelope.yaml')
    assert grid.is_grid(envelope) and not grid.is_grid(os.path.join(ROOT, 'config',
                                                                     'control.yaml'))
    out = tmp_path / 'res'
    assert scenarios.main([envelope, '--only', 'no.such.cell', '--results', str(out)]) == 0
    readme = (out / 'README.md').read_text()
    n_out = len(list(grid.not_promised(envelope)))
    assert f'{n_out} envelope cells are not promised' in readme
    assert 'a box under its plane, glass it sees through' in readme
    # a bad declaration is a clear error naming the key (exit 2)
    bad = tmp_path / 'bad.yaml'
    bad.write_text('envelope: {speeds: {creep: -1}, motions: {straight: {}}, '
                   'kinds: {wall: {class: obstacle, stop: sonar}}}\n')
    assert scenarios.main([str(bad), '--results', str(out)]) == 2
    assert 'envelope.speeds.creep' in capsys.readouterr().err



def test_a_partial_run_keeps_the_published_results(tmp_path, monkeypatch):
    """``--only`` (or ``--short``) without ``--results`` writes to log/scenarios: one scenario
    run alone had rewritten docs/results/scenarios/README.md, and with it docs/safety.md's
    hazard table, with only itself."""
    from m4k_bench import scenarios
    envelope = os.path.join(ROOT, 'config', 'envelope.yaml')
    monkeypatch.chdir(tmp_path)
    for extra in (['--only', 'no.such.cell'], ['--short', '--only', 'no.such.cell']):
        assert scenarios.main([envelope, *extra]) == 0
        assert (tmp_path / 'log' / 'scenarios' / 'README.md').is_file()
        assert not (tmp_path / 'docs').exists()

def test_a_clearance_expectation_is_parsed_and_stated():
    doc = {'description': 'd', 'world': {}, 'commands': [{'v': 0.5, 'w': 0.5, 't': 1.0}],
           'expect': {'min_clearance': 0.25}}
    sc = spec.parse(doc, 'x.yaml')
    assert sc.min_clearance == 0.25 and 'clearance >= 0.25 m' in sc.expected()
    with pytest.raises(spec.ScenarioError, match='min_clearance'):
        spec.parse(dict(doc, expect={'min_clearance': -1}), 'x.yaml')


def test_a_creep_fault_is_held_below_the_break_away_cap_from_config():
    doc = {'description': 'd', 'world': {}, 'commands': [{'v': 0.05, 't': 1.0}],
           'expect': {'max_speed': 'breakaway', 'motor_fault': True}}
    sc = spec.parse(doc, 'x.yaml')
    assert sc.max_speed == spec.BREAKAWAY
    assert sc.expected() == 'peak speed < the break-away cap, motor fault latched; no contact'
    with pytest.raises(spec.ScenarioError, match=r'expect\.max_speed'):
        spec.parse(dict(doc, expect={'max_speed': 'fast'}), 'x.yaml')
    raw = config.load_layered(None, os.path.join(ROOT, 'config'))
    c = raw['control']
    cap = c['pi']['breakaway_effort'] * c['full_scale_wheel_speed'] * c['wheel_radius']
    assert bounds.bounds(raw, 0.05, None).breakaway_speed == pytest.approx(cap)
    # the cap follows the configuration it is judged in
    low = dict(raw, control=dict(c, pi=dict(c['pi'], breakaway_effort=0.135)))
    assert bounds.bounds(low, 0.05, None).breakaway_speed == pytest.approx(cap * 0.9)


def test_a_failed_runs_report_quotes_the_logs_warnings_before_its_tail():
    from m4k_bench.scenarios.run import log_digest
    log = (['[rt_core] rt_core: task actuator: started'] * 40
           + ['[rt_core] rt_core WARNING: motor fault latched: left wheel frozen']
           + ['[bridge] odom'] * 40 + [f'bringup: stop {i}' for i in range(6)])
    out = log_digest(log).splitlines()
    assert out[0].endswith('motor fault latched: left wheel frozen')
    assert out[1] == '...' and out[2:] == [f'bringup: stop {i}' for i in range(6)]
    many = [f'x ERROR {i}' for i in range(30)] + ['end']
    out = log_digest(many, notable=3, tail=1).splitlines()
    assert out == ['x ERROR 0', 'x ERROR 1', 'x ERROR 2', '... (27 more such lines)', 'end']
    assert log_digest(['a', 'b']) == 'a\nb'
