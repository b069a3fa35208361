"""The rounds arithmetic of the bench, on inputs whose answers were worked out by hand."""

import pytest

from m4k_bench.benchlib import rounds


def test_spread_is_the_median_with_min_and_max_of_the_rounds():
    # Sorted 1.2, 1.4, 1.5, 2.0, 9.0: median 1.5 (the 9.0 stall round does not move it).
    s = rounds.spread([1.4, 9.0, 1.2, 2.0, 1.5])
    assert s == {'median': 1.5, 'min': 1.2, 'max': 9.0, 'n': 5,
                 'values': [1.4, 9.0, 1.2, 2.0, 1.5]}


def test_spread_of_an_even_count_averages_the_middle_two_and_skips_missing_rounds():
    s = rounds.spread([3.0, None, 1.0, float('nan'), 2.0, 4.0])
    assert s['median'] == 2.5 and s['n'] == 4 and (s['min'], s['max']) == (1.0, 4.0)
    assert s['values'] == [3.0, None, 1.0, None, 2.0, 4.0]
    assert rounds.spread([None, None]) is None


def test_per_round_ratios_divide_within_each_round():
    rs = [{'m': {'p99': 30.0}, 'ct': {'p99': 20.0}},
          {'m': {'p99': 45.0}, 'ct': {'p99': 30.0}},
          {'m': {'p99': 10.0}, 'ct': {'p99': 0}},        # zero denominator: no ratio
          {'m': {'p99': 10.0}}]                           # cyclictest missing in that round
    assert rounds.per_round_ratios(rs, ('m', 'p99'), ('ct', 'p99')) == [1.5, 1.5, None, None]


def test_a_stall_cyclictest_also_saw_is_the_hosts():
    # m4k max 20 000 us; concurrent cyclictest max 12 000 us >= 0.5 * 20 000: the host's.
    a = rounds.attribute_stall(20_000.0, 12_000.0, 10_000.0)
    assert a == {'stall_us': 20_000.0, 'cyclictest_max_us': 12_000.0, 'owner': 'host'}
    # cyclictest saw 900 us < 10 000: the measured process's own stall.
    assert rounds.attribute_stall(20_000.0, 900.0, 10_000.0)['owner'] == 'own'
    assert rounds.attribute_stall(20_000.0, None, 10_000.0)['owner'] == 'unknown'
    # 800 us at a 10 ms period is not a stall (<= period / 10).
    assert rounds.attribute_stall(800.0, 10.0, 10_000.0) is None


def test_hardening_label_never_calls_a_degraded_run_m4k():
    good = rounds.hardening_label({'policy': 1, 'mem_locked': 1, 'degraded': 0})
    assert good['ok'] and good['policy'] == 'SCHED_FIFO' and good['why'] == ''
    bad = rounds.hardening_label({'policy': 0, 'mem_locked': 0, 'degraded': 1})
    assert not bad['ok']
    assert bad['why'] == 'not SCHED_FIFO, memory not locked, degraded'
    assert not rounds.hardening_label(None)['ok']


def test_cpu_per_cycle_over_the_summed_task_rates():
    # 0.29 s of CPU over 10 s with tasks at 100 + 100 + 50 + 40 Hz = 2900 cycles -> 100 us.
    assert rounds.cpu_per_cycle_us(0.29, 10.0, [100, 100, 50, 40]) == pytest.approx(100.0)
    assert rounds.cpu_per_cycle_us(None, 10.0, [100]) is None
    assert rounds.cpu_per_cycle_us(1.0, 0.0, [100]) is None
