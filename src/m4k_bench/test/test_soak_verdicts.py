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


MS = 1_000_000


def _series():
    from m4k_bench.recorder import TaskSeries
    t = TaskSeries('actuator', period_ns=10 * MS)
    # (release, start, end, expirations) in ms. The release at 40 ms is missed: the wake-up at
    # 50.5 ms serves 40 and 50 (10.5 ms late from 40); the cycle at 60 ms ends at 70.5 (a
    # deadline miss); the samples of 70 and 80 never arrived.
    for rel, start, end, exp in ((10, 10.1, 10.3, 1), (20, 20.1, 20.3, 1), (30, 30.1, 30.3, 1),
                                 (50, 50.5, 50.7, 2), (60, 60.1, 70.5, 1), (90, 90.1, 90.2, 1)):
        t.t_rel.append(rel * MS)
        t.t_start.append(int(start * MS))
        t.t_end.append(int(end * MS))
        t.expirations.append(exp)
    return t


def test_fuzz_window_counts_cycles_overruns_misses_and_missing_samples():
    from m4k_bench import fuzz
    w = fuzz.window_timing(_series(), 15 * MS, 100 * MS, [])
    assert (w['cycles'], w['overruns'], w['deadline_misses'], w['missing_samples']) == (
        5, 1, 1, 2)
    # No probe saw a stall: the overrun is held against the RT process (the fuzzing).
    assert w['own_overruns'] == 1 and w['host_overruns'] == 0
    assert w['own'][0]['late_ms'] == pytest.approx(10.5)


def test_fuzz_overrun_is_the_hosts_only_when_a_probe_stalled_for_half_its_lateness():
    from m4k_bench import fuzz
    from m4k_bench.benchlib import stallprobe
    # Lateness 10.5 ms -> a probe must have been stalled >= 5.25 ms in [30, 50.5] ms.
    long_stall = [(1, 39 * MS, 49 * MS)]                      # 10 ms of it
    w = fuzz.window_timing(_series(), 15 * MS, 100 * MS, long_stall)
    assert w['host_overruns'] == 1 and w['own_overruns'] == 0
    assert w['host'][0]['stall_cpu'] == 1 and w['host'][0]['stall_ms'] == pytest.approx(10.0)
    short = [(0, 44 * MS, 46 * MS), (1, 45 * MS, 47 * MS)]   # 2 ms on each CPU: not enough
    assert fuzz.window_timing(_series(), 15 * MS, 100 * MS, short)['own_overruns'] == 1
    split = [(0, 41 * MS, 44 * MS), (0, 46 * MS, 49 * MS)]   # 6 ms on one CPU: enough
    assert stallprobe.explained_by(30 * MS, int(50.5 * MS), int(5.25 * MS), split) == (
        0, 6 * MS)
    outside = [(0, 60 * MS, 80 * MS)]                        # long, but after the start
    assert stallprobe.explained_by(30 * MS, int(50.5 * MS), MS, outside) is None


def test_fuzz_port_judgement_names_every_counter_that_disagrees():
    from m4k_bench import fuzz
    from m4k_bench.fuzzstream import Expectation
    e = Expectation(sent=100, oversize=3, malformed=50, unexpected=20, accepted=27)
    assert fuzz.judge_port(e, 97, 3, 50, 20) == []
    assert fuzz.judge_port(e, 96, 4, 50, 19) == [
        'oversize: expected 3, counted 4', 'unexpected: expected 20, counted 19',
        'received: expected 97, counted 96']


def _rss(rate_kib_s, seconds, base=80_000, every=5.0, noise=(0, 12, -8, 4)):
    """An RSS series sampled every ``every`` s: a steady leak plus a little sampling noise."""
    n = int(seconds / every) + 1
    return [(i * every, int(base + rate_kib_s * i * every + noise[i % len(noise)]))
            for i in range(n)]


def test_a_20_kib_per_s_leak_fails_the_short_soak():
    # A 60 s soak with a 15 s warm-up judges 45 s: 900 KiB of growth, under the old fixed
    # 2 MiB limit; as a slope it is 1200 KiB/min against a limit of 256 KiB / 45 s.
    v = soak.leak_verdict(_rss(20.0, 60), 15.0)
    assert v['verdict'] == 'GROWING'
    assert v['slope_kib_per_min'] == pytest.approx(1200.0, rel=0.02)
    assert v['limit_kib_per_min'] == pytest.approx(256.0 / 45.0 * 60.0)


def test_a_20_kib_per_s_leak_fails_the_soak_make_test_runs_at_its_real_window():
    # test/test_faults_soak.py runs soak.QUICK_*: sampled every second, judged after the
    # warm-up. At that window the limit is 256 KiB / 20 s = 12.8 KiB/s: 20 KiB/s fails,
    # 5 KiB/s (one allocator step spread over the window) does not.
    def at_quick(rate: float) -> dict:
        return soak.leak_verdict(_rss(rate, soak.QUICK_DURATION_S, every=soak.QUICK_SAMPLE_S),
                                 soak.QUICK_WARMUP_S)

    v = at_quick(20.0)
    assert v['window_s'] == soak.QUICK_DURATION_S - soak.QUICK_WARMUP_S
    assert v['verdict'] == 'GROWING', v
    assert v['limit_kib_per_min'] < 20.0 * 60.0
    assert at_quick(5.0)['verdict'] == 'flat'
    assert at_quick(0.0)['verdict'] == 'flat'


def test_a_20_kib_per_s_leak_fails_the_long_soak_and_a_flat_process_passes():
    assert soak.leak_verdict(_rss(20.0, 600), 60.0)['verdict'] == 'GROWING'
    assert soak.leak_verdict(_rss(0.0, 600), 60.0)['verdict'] == 'flat'
    assert soak.leak_verdict(_rss(0.0, 60), 15.0)['verdict'] == 'flat'


def test_the_slope_limit_tightens_with_the_window_down_to_the_floor():
    # 1 KiB/s: tolerated as one step over 45 s (limit 5.7 KiB/s), a leak over 540 s
    # (limit max(0.5, 0.47) = 0.5 KiB/s).
    assert soak.leak_verdict(_rss(1.0, 60), 15.0)['verdict'] == 'flat'
    long = soak.leak_verdict(_rss(1.0, 600), 60.0)
    assert long['verdict'] == 'GROWING'
    assert long['limit_kib_per_min'] == pytest.approx(soak.LEAK_SLOPE_KIB_S * 60.0)


def test_one_allocator_step_in_a_short_window_is_not_a_leak():
    series = [(t, k + (200 if t >= 30 else 0)) for t, k in _rss(0.0, 60)]
    assert soak.leak_verdict(series, 15.0)['verdict'] == 'flat'


def test_too_few_samples_give_no_verdict():
    assert soak.leak_verdict(_rss(20.0, 60), 55.0)['verdict'] == 'too short'
