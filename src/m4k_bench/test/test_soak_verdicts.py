"""Soak and fuzz verdicts on counters whose answers were worked out by hand."""

import pytest

from m4k_bench import soak


def test_every_task_is_judged_on_overruns_plus_misses_against_cyclictest_late_samples():
    tasks = {'actuator': {'overruns': 3, 'deadline_misses': 0},   # 3 <= 4
             'imu': {'overruns': 2, 'deadline_misses': 3},        # 5 > 4: judged, fails
             'lrf': {'overruns': 0, 'deadline_misses': 0}}
    v = soak.late_verdict(tasks, 4)
    assert v['tasks'] == {'actuator': {'late': 3, 'ok': True}, 'imu': {'late': 5, 'ok': False},
                          'lrf': {'late': 0, 'ok': True}}
    assert v['all_ok'] is False and v['cyclictest_late'] == 4
    assert soak.late_verdict({'actuator': tasks['actuator']}, 4)['all_ok'] is True


def test_without_cyclictest_or_counters_there_is_no_verdict():
    assert soak.late_verdict({'a': {'overruns': 1, 'deadline_misses': 0}}, None)['all_ok'] is None
    v = soak.late_verdict({'a': {'overruns': None, 'deadline_misses': 0}}, 3)
    assert v['tasks']['a'] == {'late': None, 'ok': None} and v['all_ok'] is None
    assert soak.late_verdict({}, 3)['all_ok'] is None


def test_fuzz_port_count_is_bounded_by_the_owners_drain_rate():
    from m4k_bench import fuzz
    # 1 s monitor, 32 per cycle, 8 s at 80 %: 8 * 1 * 32 * 0.8 = 204.8 -> 204
    assert fuzz.port_count(100_000, 8.0, 1_000_000_000, 32) == 204
    # 10 ms actuator: 8 * 100 * 32 * 0.8 = 20 480 > 10 000 -> the count
    assert fuzz.port_count(10_000, 8.0, 10_000_000, 32) == 10_000


def test_fuzz_cycle_verdict_within_one_percent_and_no_overrun():
    from m4k_bench import fuzz
    # 120 s at 10 ms: 12 000 expected, slack 120
    assert fuzz.cycle_verdict(120 * 10**9, 10_000_000, 11_881, 0)['ok'] is True
    assert fuzz.cycle_verdict(120 * 10**9, 10_000_000, 11_879, 0)['ok'] is False
    assert fuzz.cycle_verdict(120 * 10**9, 10_000_000, 12_000, 1)['ok'] is False  # overrun
    # 120 s at 1 s: 120 expected, slack max(1.2, 1) = 1.2 -> 119 ok, 118 not
    v = fuzz.cycle_verdict(120 * 10**9, 10**9, 119, 0)
    assert v['ok'] and v['expected'] == 120.0 and v['slack'] == pytest.approx(1.2)
    assert fuzz.cycle_verdict(120 * 10**9, 10**9, 118, 0)['ok'] is False
