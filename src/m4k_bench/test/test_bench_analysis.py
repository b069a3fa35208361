"""Tests of the bench's pure parts: samples CSV, condition stats, ratios, targets, plan."""

import math

import pytest

from m4k_bench import bench
from m4k_bench.benchlib import analysis, stack

MS = 1_000_000


def _rows(n, period=10 * MS, latency=50_000, response=20_000, late_every=0, late_by=0):
    rows = []
    for k in range(n):
        rel = 10**9 + k * period
        start = rel + latency + (late_by if late_every and k % late_every == 0 else 0)
        rows.append((rel, start, start + response, 1))
    return rows


def _cond(jitter_p99, latency_p99):
    return {'jitter_us': {'p99': jitter_p99}, 'latency_us': {'p99': latency_p99}}


def _summary():
    return {
        'conditions': {'m4k_idle': _cond(10.0, 60.0), 'm4k_stress': _cond(20.0, 90.0),
                       'baseline_idle': _cond(500.0, 900.0),
                       'baseline_stress': _cond(2000.0, 4000.0),
                       'm4k_alone': _cond(8.0, 50.0)},
        'cyclictest': {'idle': {'latency_us': {'p99': 40}},
                       'stress': {'latency_us': {'p99': 30}}},
        'xddp_rtt': {'xddp': {'p50_us': 12.0}, 'raw': {'p50_us': 10.0}},
        'rt_cpu_percent': 6.5,
    }


def test_load_samples_csv_groups_rows_by_task(tmp_path):
    p = tmp_path / 's.csv'
    p.write_text('task,t_rel_ns,t_start_ns,t_end_ns,expirations\n'
                 'a,1,2,3,1\nb,10,20,30,2\na,4,5,6,1\n')
    got = analysis.load_samples_csv(str(p))
    assert got == {'a': [(1, 2, 3, 1), (4, 5, 6, 1)], 'b': [(10, 20, 30, 2)]}


def test_load_samples_csv_rejects_wrong_header_and_bad_rows(tmp_path):
    p = tmp_path / 'x.csv'
    p.write_text('a,b,c\n1,2,3\n')
    with pytest.raises(ValueError, match='not a timing samples CSV'):
        analysis.load_samples_csv(str(p))
    p.write_text('task,t_rel_ns,t_start_ns,t_end_ns,expirations\na,1,two,3,1\n')
    with pytest.raises(ValueError, match=r'x.csv:2: bad sample row'):
        analysis.load_samples_csv(str(p))


def test_condition_summary_measures_jitter_of_late_cycles():
    # every 10th cycle starts 2 ms late: two periods per late cycle deviate by 2 ms
    rows = _rows(200, late_every=10, late_by=2 * MS)
    c = analysis.condition_summary(analysis.series_from_rows('baseline', 10 * MS, rows))
    assert c['samples'] == 200
    assert c['jitter_us']['max'] == pytest.approx(2000.0)
    assert c['jitter_us']['p50'] == pytest.approx(0.0)
    assert c['latency_us']['min'] == pytest.approx(50.0)
    assert c['deadline_misses'] == 0


def test_condition_summary_of_empty_series_is_none():
    assert analysis.condition_summary(analysis.series_from_rows('x', 10 * MS, [])) is None


def test_ratio_handles_missing_zero_and_nan():
    assert analysis.ratio(10.0, 4.0) == 2.5
    assert analysis.ratio(None, 4.0) is None
    assert analysis.ratio(1.0, 0.0) is None
    assert analysis.ratio(math.nan, 1.0) is None


def test_compute_ratios_from_summary():
    r = analysis.compute_ratios(_summary())
    assert set(r) == set(analysis.RATIO_KEYS)
    assert r['release_p99_over_cyclictest_idle'] == pytest.approx(1.5)
    assert r['release_p99_over_cyclictest_stress'] == pytest.approx(3.0)
    assert r['baseline_over_m4k_jitter_p99_stress'] == pytest.approx(100.0)
    assert r['baseline_over_m4k_jitter_p99_idle'] == pytest.approx(50.0)
    assert r['five_tasks_over_alone_p99'] == pytest.approx(1.2)
    assert r['xddp_rtt_p50_over_raw'] == pytest.approx(1.2)


def test_compute_ratios_without_measurements_are_none():
    assert set(analysis.compute_ratios({}).values()) == {None}


def test_targets_say_met_missed_and_unmeasured():
    s = _summary()
    s['ratios'] = analysis.compute_ratios(s)
    s['ratios']['xddp_rtt_p50_over_raw'] = None
    s['skipped'] = {'xddp_rtt_p50_over_raw': 'phase skipped'}
    rows = {t['key']: t for t in analysis.evaluate_targets(s)}
    assert rows['release_p99_over_cyclictest_idle']['met'] is True
    assert rows['release_p99_over_cyclictest_stress']['met'] is False
    assert 'wake-up' in rows['release_p99_over_cyclictest_stress']['why']
    assert rows['baseline_over_m4k_jitter_p99_stress']['met'] is True   # >= 50
    assert rows['five_tasks_over_alone_p99']['met'] is True
    assert rows['rt_cpu_percent']['met'] is False
    assert rows['rt_cpu_percent']['target'] == '<= 5 %'
    assert rows['xddp_rtt_p50_over_raw']['met'] is None
    assert rows['xddp_rtt_p50_over_raw']['why'] == 'not measured in this run: phase skipped'


def test_plan_durations_quick_full_and_overrides():
    assert bench.plan_durations(False, None, None)['table1_s'] == bench.FULL['table1_s']
    q = bench.plan_durations(True, None, None)
    assert q['table1_s'] < bench.FULL['table1_s'] and q['condition_s'] <= q['table1_s']
    tiny = bench.plan_durations(True, 3.0, None)
    assert tiny['table1_s'] == 3.0 and tiny['condition_s'] == 3.0
    assert bench.plan_durations(False, None, 5.0)['condition_s'] == 5.0
    with pytest.raises(ValueError, match='--duration must be > 0'):
        bench.plan_durations(False, 0.0, None)


def test_bench_rejects_unknown_skip_phase(capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(['--skip', 'table1,nope'])
    assert exc.value.code == 2
    assert "unknown phase(s) ['nope']" in capsys.readouterr().err


def test_actuator_periods_skip_non_consecutive_cycles():
    rel = [0, 10 * MS, 30 * MS, 40 * MS]       # a batch lost between cycles 1 and 2
    start = [1, 10 * MS + 1, 30 * MS + 5, 40 * MS + 2]
    exp = [1, 1, 1, 1]
    per = bench._actuator_periods((rel, start, exp))
    assert list(per) == [10 * MS, 10 * MS - 3]


def test_velocity_profile_alternates_at_paper_speed():
    assert stack.velocity_profile(0.0) == (0.25, 0.0)
    assert stack.velocity_profile(5.0) == (-0.25, 0.0)
    assert stack.velocity_profile(8.5) == (0.25, 0.0)


def test_entry_argv_runs_module_main():
    argv = stack.entry_argv('m4k_rt.rt_core', '--tasks', 'actuator')
    assert argv[1] == '-c' and 'from m4k_rt.rt_core import main' in argv[2]
    assert argv[3:] == ['--tasks', 'actuator']


def test_trim_warmup_drops_the_first_second_of_every_task_and_reports_it():
    a = analysis.series_from_rows('actuator', 10 * MS, _rows(300, latency=50_000))
    a.t_start[0] += 5 * MS                    # a start-up hiccup
    b = analysis.series_from_rows('lrf', 200 * MS, _rows(10, period=200 * MS))
    got = analysis.trim_warmup([a, b], 1_000 * MS)
    assert got['cycles'] == {'actuator': 100, 'lrf': 5}
    assert got['max_latency_us'] == pytest.approx(5050.0)
    assert len(a.t_rel) == 200 and len(a.t_start) == 200 and len(a.expirations) == 200
    assert a.t_rel[0] == 10**9 + 1_000 * MS
    assert analysis.trim_warmup([], 1) == {'cycles': {}, 'max_latency_us': None}


def test_interference_finds_cycles_released_while_another_task_ran():
    act = analysis.series_from_rows('actuator', 10 * MS, _rows(100, latency=20_000))
    # imu runs [rel - 5 us, rel + 300 us] on every 4th release: the actuator waits for it
    rows = []
    for k in range(0, 100, 4):
        rel = 10**9 + k * 10 * MS
        rows.append((rel, rel - 5_000, rel + 300_000, 1))
        act.t_start[k] = rel + 310_000
    imu = analysis.series_from_rows('imu', 10 * MS, rows)
    led = analysis.series_from_rows('led', 20 * MS, [(10**9 + 5 * MS, 10**9 + 5 * MS,
                                                       10**9 + 6 * MS, 1)])
    got = analysis.interference({'actuator': act, 'imu': imu, 'led': led}, 'actuator')
    assert got['cycles'] == 100
    assert got['interfered_share'] == pytest.approx(0.25)
    assert got['share_by_task'] == {'imu': 0.25, 'led': 0.0}
    assert got['latency_p99_interfered_us'] == pytest.approx(310.0)
    assert got['latency_p99_clean_us'] == pytest.approx(20.0)
    assert analysis.interference({'imu': imu}, 'actuator') is None
