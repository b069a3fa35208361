"""Pure tests of the loop-timing arithmetic, statistics and schedulability tests."""

import math

from hypothesis import given
from hypothesis import strategies as st
import numpy as np
import pytest

from m4k_rt import timing

MS = 1_000_000


# --- release arithmetic (cf. ros2_control sleeping_policies tests) ---

def test_first_release_aligns_to_period_boundary():
    assert timing.first_release(now_ns=25 * MS, period_ns=10 * MS) == 30 * MS
    assert timing.first_release(now_ns=30 * MS, period_ns=10 * MS) == 30 * MS
    assert timing.first_release(now_ns=25 * MS, period_ns=10 * MS, lead_ns=6 * MS) == 40 * MS


def test_first_release_uses_future_start_and_ignores_past_start():
    assert timing.first_release(25 * MS, 10 * MS, start_ns=27 * MS) == 27 * MS
    assert timing.first_release(25 * MS, 10 * MS, start_ns=5 * MS) == 30 * MS


def test_first_release_rejects_bad_period():
    with pytest.raises(ValueError, match='period_ns'):
        timing.first_release(0, 0)


def test_expirations_before_release_is_zero():
    assert timing.expirations_at(next_release_ns=100, period_ns=10, now_ns=99) == 0


def test_expirations_on_time_is_one():
    assert timing.expirations_at(100, 10, 100) == 1
    assert timing.expirations_at(100, 10, 109) == 1


def test_expirations_after_overrun_counts_every_passed_release():
    assert timing.expirations_at(100, 10, 110) == 2
    assert timing.expirations_at(100, 10, 135) == 4


def test_advance_skips_ahead_to_latest_release_never_bursts():
    # Woken at 135 for a timer due at 100: releases 100, 110, 120, 130 passed; the task
    # serves 130 once, skipping three, and the next wake-up is 140 -- not 110.
    prev = 90
    exp = timing.expirations_at(100, 10, 135)
    rel = timing.advance_release(prev, 10, exp)
    assert rel == 130
    assert timing.overruns(exp) == 3
    assert rel + 10 > 135


def test_overruns_of_normal_cycle_is_zero():
    assert timing.overruns(1) == 0
    assert timing.overruns(0) == 0


def test_deadline_miss_is_strictly_after_release_plus_period():
    assert not timing.deadline_missed(100, 110, 10)
    assert timing.deadline_missed(100, 111, 10)


@given(st.integers(1, 10**9), st.integers(1, 10**7), st.integers(0, 10**10))
def test_advanced_release_is_latest_passed_and_next_is_future(first, period, delay):
    now = first + delay
    exp = timing.expirations_at(first, period, now)
    rel = timing.advance_release(first - period, period, exp)
    assert rel <= now < rel + period
    assert (rel - first) % period == 0


# --- sample ring ---

def test_ring_records_and_reads_back_in_order():
    ring = timing.SampleRing(4)
    for i in range(3):
        ring.record(i * 10, i * 10 + 1, i * 10 + 2, 1)
    first, end, lost = ring.available(0)
    assert (first, end, lost) == (0, 3, 0)
    assert ring.rows(first, end) == [(0, 1, 2, 1), (10, 11, 12, 1), (20, 21, 22, 1)]


def test_ring_overwrite_reports_lost_rows_to_slow_reader():
    ring = timing.SampleRing(4)
    for i in range(10):
        ring.record(i, i, i, 1)
    first, end, lost = ring.available(2)
    assert (first, end, lost) == (6, 10, 4)
    assert [r[0] for r in ring.rows(first, end)] == [6, 7, 8, 9]
    rel, start, end_a, exp = ring.arrays()
    assert rel.tolist() == [6, 7, 8, 9]
    assert exp.dtype == np.int64


def test_ring_cursor_after_full_read_has_nothing_new():
    ring = timing.SampleRing(8)
    ring.record(1, 2, 3, 2)
    assert ring.available(1) == (1, 1, 0)


def test_ring_rejects_bad_capacity():
    with pytest.raises(ValueError, match='capacity'):
        timing.SampleRing(1)


# --- statistics ---

def test_describe_known_values():
    s = timing.describe([1, 2, 3, 4])
    assert s.n == 4
    assert s.avg == 2.5 and s.max == 4 and s.min == 1
    assert s.std == pytest.approx(math.sqrt(1.25))
    assert s.p50 == 2.5
    assert s.p99 == pytest.approx(3.97)


def test_describe_percentiles_on_large_uniform_set():
    s = timing.describe(np.arange(100001))
    assert s.p50 == 50000 and s.p99 == 99000 and s.p999 == pytest.approx(99900)


def test_describe_empty_is_nan_not_crash():
    s = timing.describe([])
    assert s.n == 0 and math.isnan(s.avg) and math.isnan(s.p999)


def test_analyze_computes_period_latency_response_overruns_misses():
    p = 10 * MS
    rel = [0, p, 2 * p, 4 * p]           # cycle 3 overran: one release skipped
    exp = [1, 1, 1, 2]
    start = [r + 100 for r in rel]
    start[1] += 50
    end = [s + 1000 for s in start]
    end[2] = rel[2] + p + 1              # deadline miss
    t = timing.analyze(rel, start, end, exp, p, name='a')
    assert t.cycles == 4
    assert t.overruns == 1
    assert t.deadline_misses == 1
    # The overrun cycle serves releases 3p and 4p: its latency counts from the missed 3p.
    assert t.latency.max == p + 100 and t.latency.min == 100
    assert t.period.n == 3
    assert t.period.max == 2 * p
    assert sorted([p + 50, p - 50, 2 * p]) == sorted(
        [t.period.min, t.period.max, 3 * t.period.avg - t.period.min - t.period.max])
    assert t.jitter.max == p
    assert t.wcrt_ns == p + 1 - 100


def test_release_latency_counts_from_the_missed_release():
    p = 1000
    # Cycle 0 on time (+30); cycle 1 woke 2.5 periods after release p: the timer reports
    # releases 2p and 3p as passed too (3 expirations, t_rel = 3p), the wake-up is at 3.5p.
    lat = timing.release_latency([0, 3 * p], [30, 3 * p + 500], [1, 3], p)
    assert lat.tolist() == [30, 2 * p + 500]    # from release p, not from 3p (that gives 500)


def test_analyze_skips_periods_across_lost_samples():
    p = 1000
    rel = [0, p, 5 * p, 6 * p]           # rows 2..4 lost in transit
    start = [r + 10 for r in rel]
    t = timing.analyze(rel, start, start, [1, 1, 1, 1], p)
    assert t.period.n == 2 and t.period.max == p and t.jitter.max == 0


def test_analyze_rejects_mismatched_arrays():
    with pytest.raises(ValueError, match='length'):
        timing.analyze([0, 1], [0], [0], [1], 10)


# --- Liu-Layland and utilization ---

def test_liu_layland_bound_values():
    assert timing.liu_layland_bound(1) == pytest.approx(1.0)
    assert timing.liu_layland_bound(2) == pytest.approx(0.8284, abs=1e-4)
    assert timing.liu_layland_bound(5) == pytest.approx(0.743, abs=5e-4)


def test_liu_layland_bound_tends_to_ln2():
    assert timing.liu_layland_bound(10000) == pytest.approx(math.log(2), abs=1e-4)


def test_utilization_test_paper_like_set_is_schedulable():
    res = timing.utilization_test([
        ('actuator', 29e3, 10e6), ('imu', 432e3, 10e6), ('led', 590e3, 20e6),
        ('sonar', 460e3, 30e6), ('lrf', 762e3, 200e6)])
    assert res.passes
    assert res.total == pytest.approx(sum(res.per_task.values()))
    assert res.per_task['imu'] == pytest.approx(0.0432)


def test_utilization_test_verdicts_inconclusive_and_overloaded():
    assert timing.utilization_test([('a', 5, 10), ('b', 4, 10)]).verdict == 'inconclusive'
    assert timing.utilization_test([('a', 6, 10), ('b', 5, 10)]).verdict == 'overloaded'


def test_utilization_test_rejects_bad_period():
    with pytest.raises(ValueError, match="'a'"):
        timing.utilization_test([('a', 1, 0)])


# --- response-time analysis ---

def test_rta_textbook_example():
    # Classic example: (C, T) = (1, 4), (2, 6), (3, 13) under RM -> R = 1, 3, 10.
    tasks = [timing.RtaTask('t1', 1, 4, 3), timing.RtaTask('t2', 2, 6, 2),
             timing.RtaTask('t3', 3, 13, 1)]
    res = timing.response_time_analysis(tasks)
    assert [r.response_ns for r in res] == [1, 3, 10]
    assert all(r.schedulable for r in res)


def test_rta_set_above_ll_bound_still_schedulable():
    # U = 0.5 + 0.4 = 0.9 > 0.828 but harmonic periods: R2 = 4 + 2*... fits.
    tasks = [timing.RtaTask('a', 5, 10, 2), timing.RtaTask('b', 8, 20, 1)]
    assert timing.utilization_test([('a', 5, 10), ('b', 8, 20)]).verdict == 'inconclusive'
    res = timing.response_time_analysis(tasks)
    assert res[1].response_ns == 18 and res[1].schedulable


def test_rta_overloaded_low_priority_task_diverges():
    tasks = [timing.RtaTask('hi', 6, 10, 2), timing.RtaTask('lo', 5, 12, 1)]
    res = timing.response_time_analysis(tasks)
    assert res[0].schedulable and res[0].response_ns == 6
    assert not res[1].schedulable and res[1].response_ns is None


def test_rta_equal_priorities_interfere_both_ways():
    tasks = [timing.RtaTask('a', 2, 10, 5), timing.RtaTask('b', 3, 10, 5)]
    res = timing.response_time_analysis(tasks)
    assert [r.response_ns for r in res] == [5, 5]


def test_rta_release_jitter_adds_interference_and_own_delay():
    # hi (C 1, T 4, J 2), lo (C 2, T 10, J 1). By hand: R_hi = J + C = 3.
    # lo: w = 2 + 1 = 3; 2 + ceil((3 + 2) / 4) * 1 = 4; 2 + ceil((4 + 2) / 4) * 1 = 4 -> w = 4,
    # R_lo = J_lo + w = 5 (without jitter: 2 + ceil(3 / 4) = 3).
    tasks = [timing.RtaTask('hi', 1, 4, 2, jitter_ns=2), timing.RtaTask('lo', 2, 10, 1,
                                                                          jitter_ns=1)]
    assert [r.response_ns for r in timing.response_time_analysis(tasks)] == [3, 5]
    no_jitter = [t._replace(jitter_ns=0) for t in tasks]
    assert [r.response_ns for r in timing.response_time_analysis(no_jitter)] == [1, 3]


def test_rta_jitter_alone_can_miss_the_deadline():
    res = timing.response_time_analysis([timing.RtaTask('x', 3, 10, 1, jitter_ns=8)])
    assert not res[0].schedulable and res[0].response_ns is None
    with pytest.raises(ValueError):
        timing.response_time_analysis([timing.RtaTask('x', 3, 10, 1, jitter_ns=-1)])


def test_rta_explicit_deadline_is_used():
    res = timing.response_time_analysis([timing.RtaTask('x', 3, 10, 1, deadline_ns=2)])
    assert not res[0].schedulable and res[0].deadline_ns == 2
